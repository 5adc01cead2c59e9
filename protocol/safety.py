"""Host-side safety policy: no request leaves the host with a read above ``max_read_v`` or a
write above the host's write limit (V), whatever the firmware would do with it.

This is *host policy*, on both protocols; what a board does with a request is *board
behaviour* (docs/protocol.md, "Host policy and board behaviour"): this project's framed
firmware refuses the same limits again (its interlock), the existing (legacy) firmware has no
interlock and applies any amplitude up to its clamp (RESET at 3.0 V).

* Reads: at most the board's ``max_read_v`` (0.3 V: reads above could change a cell), i.e.
  the largest DAC code at or below it (245 on MemriCore). Not configurable.
* Writes: at most ``max_write_v`` — the board's value (1.4 V) unless the user sets another
  with ``--max-write-v``; the largest write-DAC code at or below it (1146 for 1.4 V: floor,
  never nearest, so 1.4 V never becomes the old host's 1147 = 1.4005 V).

The limits come from the board's constants (its INFO, or the defaults before HELLO): no limit
is a literal here. Compliance current depends on the cell's state and is checked by the caller
that knows it (calibration) and by the framed firmware.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from snan_hil.protocol.board import BoardConstants
from snan_hil.protocol.errors import ProtocolError

__all__ = ["HostSafetyError", "HostLimits", "MAX_WRITE_OPTION", "check_max_write_v"]

MAX_WRITE_OPTION = "--max-write-v"
"""The command-line option that sets the host's write limit (named in every refusal)."""


class HostSafetyError(ProtocolError):
    """A request would exceed a safety limit of the host; it was not sent."""


def check_max_write_v(board: BoardConstants, max_write_v: float) -> float:
    """``max_write_v`` (V) if it is a usable host write limit for ``board`` (positive, at most
    the write DAC's reference); else :class:`HostSafetyError` naming the option."""
    v = float(max_write_v)
    top = board.write_dac_volts(board.write_dac_full_scale_code)
    if not (math.isfinite(v) and board.write_dac_volts(1) <= v <= top):
        raise HostSafetyError(
            f"{MAX_WRITE_OPTION} {max_write_v}: give a write limit between "
            f"{board.write_dac_volts(1):.4f} V (one DAC step) and {top:g} V (the write DAC's "
            f"full scale); the default is the board's {board.max_write_v} V")
    return v


@dataclass(frozen=True, slots=True)
class HostLimits:
    """Largest DAC code of a read and write-DAC code of a pulse this host sends.

    ``write_configured``: the write limit was set by the user (``--max-write-v``) rather than
    taken from the board."""

    max_read_code: int
    max_write_code: int
    max_read_v: float
    max_write_v: float
    write_configured: bool = False

    @classmethod
    def from_board(cls, board: BoardConstants, max_write_v: float | None = None) -> HostLimits:
        """The limits for a board (its Info, or its defaults before HELLO); ``max_write_v``
        (V) replaces the board's write limit (``--max-write-v``), checked by
        :func:`check_max_write_v`."""
        if max_write_v is None:
            return cls(board.max_read_code, board.max_write_code, board.max_read_v,
                       board.max_write_v)
        v = check_max_write_v(board, max_write_v)
        return cls(board.max_read_code, board.write_dac_floor_code(v), board.max_read_v, v,
                   True)

    def check_reads(self, codes: Iterable[int], what: str) -> None:
        """Refuse any read DAC code above ``max_read_code``."""
        top = max((int(c) for c in codes), default=0)
        if top > self.max_read_code:
            raise HostSafetyError(
                f"{what}: read DAC code {top} exceeds the host's read limit {self.max_read_v} V "
                f"(largest allowed code {self.max_read_code}; reads above it could change the "
                "cell); not sent")

    def check_write(self, code: int, what: str) -> None:
        """Refuse a write-DAC amplitude code above ``max_write_code``."""
        if int(code) > self.max_write_code:
            raise HostSafetyError(
                f"{what}: write amplitude code {int(code)} exceeds the host's write limit "
                f"{self.max_write_v:g} V (largest allowed code {self.max_write_code}; set "
                f"another limit with {MAX_WRITE_OPTION}); not sent")
