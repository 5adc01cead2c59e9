"""Host-side safety limits: no request leaves the host with a read above ``max_read_v`` or a
write above ``max_write_v`` (V), whatever the firmware would do with it.

The limits come from the board's INFO (or its defaults before HELLO): the largest codes of
:class:`~snan_hil.protocol.board.BoardConstants` (a DAC code is allowed only if its voltage does
not exceed the limit: floor, not nearest). Compliance current depends on the cell's state and is
checked by the caller that knows it (calibration) and by the firmware.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from snan_hil.protocol.board import BoardConstants
from snan_hil.protocol.errors import ProtocolError

__all__ = ["HostSafetyError", "HostLimits"]


class HostSafetyError(ProtocolError):
    """A request would exceed a safety limit; it was not sent."""


@dataclass(frozen=True, slots=True)
class HostLimits:
    """Largest row-DAC code of a read and write-DAC code of a pulse this host sends."""

    max_read_code: int
    max_write_code: int
    max_read_v: float
    max_write_v: float

    @classmethod
    def from_board(cls, board: BoardConstants) -> HostLimits:
        """The limits of a board (its Info, or its defaults before HELLO)."""
        return cls(board.max_read_code, board.max_write_code, board.max_read_v,
                   board.max_write_v)

    def check_reads(self, codes: Iterable[int], what: str) -> None:
        """Refuse any read DAC code above ``max_read_code``."""
        top = max((int(c) for c in codes), default=0)
        if top > self.max_read_code:
            raise HostSafetyError(
                f"{what}: read DAC code {top} exceeds the read limit {self.max_read_v} V "
                f"(largest allowed code {self.max_read_code}); not sent")

    def check_write(self, code: int, what: str) -> None:
        """Refuse a write-DAC amplitude code above ``max_write_code``."""
        if int(code) > self.max_write_code:
            raise HostSafetyError(
                f"{what}: write amplitude code {int(code)} exceeds the write limit "
                f"{self.max_write_v} V (largest allowed code {self.max_write_code}); not sent")
