"""What higher layers see of a board: the :class:`BoardClient` interface.

Both :class:`~snan_hil.protocol.link.LinkClient` (framed protocol) and
:class:`~snan_hil.protocol.legacy.LegacyClient` (old line protocol) implement it; methods the
legacy protocol cannot offer raise :class:`~snan_hil.protocol.errors.UnsupportedError`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol, Self, runtime_checkable

from snan_hil.protocol.messages import (ClockReply, DecisionCandidate, DecisionParams,
                                        DecisionWindowReply, Info, Polarity, ProgramCellReply,
                                        ResetReply, SpikeGroup, StatusReply)
from snan_hil.protocol.safety import HostLimits
from snan_hil.protocol.transport import Transport

__all__ = ["BoardClient", "ClientBase", "SpikeBatchResult"]


@dataclass(frozen=True, slots=True)
class SpikeBatchResult:
    """Readings of one decision window.

    ``spikes[k] = (bin, group)`` of the k-th applied spike (absolute bin index, group index);
    ``codes[k][j]`` the ADC code of column ``columns[j]`` read for that spike.
    """

    spikes: tuple[tuple[int, int], ...]
    columns: tuple[int, ...]
    codes: tuple[tuple[int, ...], ...]
    round_trips: int = 1


class ClientBase:
    """Plumbing both clients share: ``name``, ``counters_dict()``, ``close()``, ``with``."""

    transport: Transport
    counters: Any   # a dataclass of ints
    host_max_write_v: float | None = None
    """The host's write limit (V) set by the user (``--max-write-v``); None: the board's
    ``max_write_v``. Host policy (protocol.safety), on both protocols."""

    @property
    def name(self) -> str:
        """The transport's name (the port), for messages."""
        return self.transport.name

    @property
    def limits(self) -> HostLimits:
        """Host-side safety limits from the board's INFO (its defaults before HELLO) and the
        configured write limit (``host_max_write_v``)."""
        return HostLimits.from_board(getattr(self, "info", None) or Info(),
                                     self.host_max_write_v)

    def counters_dict(self) -> dict[str, int]:
        """Host-side link counters as a dict."""
        return dataclasses.asdict(self.counters)

    def close(self) -> None:
        """Close the transport."""
        self.transport.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@runtime_checkable
class BoardClient(Protocol):
    """Typed access to a board: what calibration, host and tools may use of one.

    Implemented by :class:`~snan_hil.protocol.link.LinkClient`,
    :class:`~snan_hil.protocol.legacy.LegacyClient` and the
    :class:`~snan_hil.protocol.retry.RetryingClient` wrapper. Codes are raw DAC/ADC codes;
    ``info`` (the board's :class:`~snan_hil.protocol.board.BoardConstants`, None before HELLO)
    converts them.
    """

    @property
    def transport(self) -> Transport: ...
    @property
    def info(self) -> Info | None: ...

    def hello(self) -> Info: ...
    def read_cell(self, row: int, col: int, dac_code: int | None = None) -> int: ...
    def read_column(self, col: int, row_codes: Sequence[int]) -> int: ...
    def write_pulse(self, row: int, col: int, polarity: Polarity, amplitude_code: int,
                    width_us: int, read_code: int = 0) -> int: ...
    def spike_batch(self, groups: Sequence[SpikeGroup], columns: Sequence[int],
                    n_bins: int = 1000, bin_us: int = 1000,
                    paced: bool = False) -> SpikeBatchResult: ...
    def program_cell(self, row: int, col: int, target_adc: int, tolerance_adc: int, *,
                     max_pulses: int = 100, amp_start_code: int = 0, amp_stop_code: int = 0,
                     amp_step_code: int = 0, width_us: int = 100, read_code: int = 0,
                     fine_tune: bool = True) -> ProgramCellReply: ...
    def decision_window(self, key: int, rows: Sequence[int],
                        candidates: Sequence[DecisionCandidate], params: DecisionParams, *,
                        motor_spikes: bool = False, trace_stride: int = 0,
                        paced: bool = False) -> DecisionWindowReply: ...
    def status(self) -> StatusReply: ...
    def clock(self) -> ClockReply: ...
    def reset(self) -> ResetReply: ...
    def counters_dict(self) -> dict[str, int]: ...
    def close(self) -> None: ...
