"""Host-side safety limits: no request leaves the host with a read above ``max_read_v`` or a
write above ``max_write_v`` (V), whatever the firmware would do with it.

The limits come from the board's INFO (or its defaults before HELLO): the largest codes of
:class:`~snan_hil.protocol.board.BoardConstants` (a DAC code is allowed only if its voltage does
not exceed the limit: floor, not nearest). Compliance current depends on the cell's state and is
checked by the caller that knows it (calibration) and by the firmware.

This is *host policy*, the same on both protocols; what a board does with a request is *board
behaviour* (docs/protocol.md, "Host policy and board behaviour"): this project's framed
firmware refuses the same limits again (its interlock); the existing firmware behind the legacy
protocol has no interlock and applies any amplitude up to its clamp (RESET at 3.0 V). The read
limit is the board's ``max_read_v`` (0.3 V, not configurable); the write limit is the board's
``max_write_v`` (1.4 V on MemriCore, from its INFO). **One rule** for the user's
``--max-write-v`` (:data:`MAX_WRITE_OPTION`): it may lower the board's declared write limit,
never raise it (a value above it is refused in one line). The limit is derived once per
connection (:attr:`snan_hil.protocol.client.BoardClient.limits`); the board session and its
cell bench take it from there.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from snan_hil.protocol.board import BoardConstants
from snan_hil.protocol.errors import ProtocolError

__all__ = ["HostSafetyError", "HostLimits", "MAX_WRITE_OPTION", "check_max_write_v",
           "requested_write_limit_v", "offline_write_limit_v"]

MAX_WRITE_OPTION = "--max-write-v"
"""The command-line option that sets the host's write limit (named in every write refusal)."""


class HostSafetyError(ProtocolError):
    """A request would exceed a safety limit; it was not sent."""


def check_max_write_v(board: BoardConstants, max_write_v: float) -> float:
    """``max_write_v`` (V) if it is a usable host write limit for ``board`` (from one write-DAC
    step to its full scale); else :class:`HostSafetyError` naming the option."""
    v = float(max_write_v)
    low, top = board.write_dac_volts(1), board.write_dac_volts(board.write_dac_full_scale_code)
    if not (math.isfinite(v) and low <= v <= top):
        raise HostSafetyError(
            f"{MAX_WRITE_OPTION} {max_write_v}: give a write limit between {low:.4f} V (one DAC "
            f"step) and {top:g} V (the write DAC's full scale); the default is the board's "
            f"{board.max_write_v} V")
    return v


def requested_write_limit_v(board: BoardConstants, max_write_v: float | None) -> float:
    """The host's write limit (V) a run asks for before its board is known: ``max_write_v``
    (``--max-write-v``, checked by :func:`check_max_write_v`), else ``board``'s declared
    ``max_write_v``. ``board`` stands in for the board not yet opened (MemriCore's defaults:
    a real board's INFO may declare more); once it is known, :meth:`HostLimits.from_board`
    applies the whole rule (never above the board's declared limit). The one place the
    commands' early checks (``pulse``, ``plan``, ``characterize``, ``cells test``) take it
    from."""
    if max_write_v is None:
        return float(board.max_write_v)
    return check_max_write_v(board, max_write_v)


def offline_write_limit_v(board: BoardConstants, max_write_v: float | None) -> float:
    """The write limit (V) of work planned without a board answering (``plan run
    --dry-run``): the whole rule of :meth:`HostLimits.from_board` on ``board`` standing in for
    it (MemriCore's declared limit): ``max_write_v`` may lower it, never raise it
    (:class:`HostSafetyError`, one line, as the real run says it)."""
    return HostLimits.from_board(board, max_write_v).max_write_v


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
    def from_board(cls, board: BoardConstants, max_write_v: float | None = None) -> HostLimits:
        """The limits of a board (its Info, or its defaults before HELLO); ``max_write_v`` (V,
        ``--max-write-v``, checked by :func:`requested_write_limit_v`) lowers its write limit.
        :class:`HostSafetyError` (one line) for a ``max_write_v`` above the board's declared
        ``max_write_v``: the host may only lower it."""
        if max_write_v is None:
            return cls(board.max_read_code, board.max_write_code, board.max_read_v,
                       board.max_write_v, board.max_cell_read_code, board.max_row_read_code)
        v = requested_write_limit_v(board, max_write_v)
        if v > board.max_write_v + 1e-9:
            raise HostSafetyError(
                f"{MAX_WRITE_OPTION} {max_write_v}: above the board's declared write limit "
                f"{board.max_write_v:g} V (its INFO); the host's limit can only lower it: give "
                f"at most {board.max_write_v:g} V, or leave {MAX_WRITE_OPTION} out")
        return cls(board.max_read_code, board.write_dac_floor_code(v), board.max_read_v, v,
                   board.max_cell_read_code, board.max_row_read_code)

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
                f"{what}: write amplitude code {int(code)} exceeds the host's write limit "
                f"{self.max_write_v:g} V (largest allowed code {self.max_write_code}; set "
                f"another with {MAX_WRITE_OPTION}); not sent")
