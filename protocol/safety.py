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
    """Largest read codes (write DAC for single-cell reads, row DACs for driven rows) and
    write-DAC amplitude code this host sends."""

    max_read_code: int
    max_write_code: int
    max_read_v: float
    max_write_v: float
    max_cell_read_code: int = -1
    max_row_read_code: int = -1

    @classmethod
    def from_board(cls, board: BoardConstants) -> HostLimits:
        """The limits of a board (its Info, or its defaults before HELLO)."""
        return cls(board.max_read_code, board.max_write_code, board.max_read_v,
                   board.max_write_v, board.max_cell_read_code, board.max_row_read_code)

    def check_reads(self, codes: Iterable[int], what: str, dac: str = "cell") -> None:
        """Refuse any read code above the read limit of its DAC: ``dac="cell"`` for single-cell
        read codes (write DAC), ``"row"`` for row codes of READ_COLUMN / SPIKE_BATCH (row
        DACs). Limits not given fall back to ``max_read_code`` (safe on both DACs)."""
        if dac not in ("cell", "row"):
            raise ValueError(f"dac must be 'cell' or 'row', got {dac!r}")
        limit = self.max_cell_read_code if dac == "cell" else self.max_row_read_code
        if limit < 0:
            limit = self.max_read_code
        top = max((int(c) for c in codes), default=0)
        if top > limit:
            kind = "write-DAC (cell read)" if dac == "cell" else "row-DAC"
            raise HostSafetyError(
                f"{what}: {kind} read code {top} exceeds the read limit {self.max_read_v} V "
                f"(largest allowed code {limit}); not sent")

    def check_write(self, code: int, what: str) -> None:
        """Refuse a write-DAC amplitude code above ``max_write_code``."""
        if int(code) > self.max_write_code:
            raise HostSafetyError(
                f"{what}: write amplitude code {int(code)} exceeds the write limit "
                f"{self.max_write_v} V (largest allowed code {self.max_write_code}); not sent")
