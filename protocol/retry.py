"""Link retries above the link: :class:`RetryingClient` sends a lost read again as a new request.

The link itself (:class:`~snan_hil.protocol.link.LinkClient`) retransmits a request with the
same sequence number a few times; when that budget is spent it raises
:class:`~snan_hil.protocol.errors.LinkTimeoutError`. Requests that change nothing on the chip
(HELLO, READ_CELL, READ_COLUMN, SPIKE_BATCH, DECISION_WINDOW, STATUS, CLOCK) can then safely be
sent again as new requests: that is what this wrapper does, up to ``tries`` requests - unless
the board sent no byte at all (``LinkTimeoutError.kind == "silent"``: it is gone, and asking
again only delays the error) or is busy (:class:`~snan_hil.protocol.errors.BoardBusyError`, not
retried). WRITE_PULSE, PROGRAM_CELL and RESET pass through unchanged: a lost pulse must be
reconciled from the board's pulse counter (calibration's ``BoardCellIO``), never blindly
resent.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from snan_hil.protocol.client import BoardClient, SpikeBatchResult
from snan_hil.protocol.errors import LinkTimeoutError
from snan_hil.protocol.messages import (ClockReply, DecisionCandidate, DecisionParams,
                                        DecisionWindowReply, Info, Polarity, ProgramCellReply,
                                        ResetReply, SpikeGroup, StatusReply)
from snan_hil.protocol.transport import Transport

__all__ = ["RetryingClient", "DEFAULT_READ_TRIES"]

log = logging.getLogger(__name__)

DEFAULT_READ_TRIES = 6
"""Requests (each with the link's own retransmissions) before a read is given up."""

T = TypeVar("T")


class RetryingClient:
    """A :class:`BoardClient` around another one whose non-destructive requests are resent
    after a :class:`LinkTimeoutError`, up to ``tries`` requests in all (``lost_requests``
    counts the timeouts). Other attributes (counters, limits, ``request``) are the inner
    client's."""

    def __init__(self, client: BoardClient, tries: int = DEFAULT_READ_TRIES):
        self._client = client
        self._tries = max(1, int(tries))
        self.lost_requests = 0

    @property
    def inner(self) -> BoardClient:
        """The wrapped client."""
        return self._client

    @property
    def transport(self) -> Transport:
        return self._client.transport

    @property
    def info(self) -> Info | None:
        return self._client.info

    def _retry(self, what: str, call: Callable[[], T]) -> T:
        for attempt in range(self._tries):
            try:
                return call()
            except LinkTimeoutError as exc:
                self.lost_requests += 1
                # a board that sends no byte at all is gone: asking again only delays the error
                if attempt == self._tries - 1 or exc.kind == "silent":
                    raise
                log.info("%s lost on the link; sending it again", what)
        raise AssertionError("unreachable")  # pragma: no cover - the loop returns or raises

    # -- non-destructive: retried ---------------------------------------------------------
    def hello(self) -> Info:
        return self._retry("HELLO", self._client.hello)

    def read_cell(self, row: int, col: int, dac_code: int | None = None) -> int:
        return self._retry("READ_CELL", lambda: self._client.read_cell(row, col, dac_code))

    def read_column(self, col: int, row_codes: Sequence[int]) -> int:
        return self._retry("READ_COLUMN", lambda: self._client.read_column(col, row_codes))

    def spike_batch(self, groups: Sequence[SpikeGroup], columns: Sequence[int],
                    n_bins: int = 1000, bin_us: int = 1000,
                    paced: bool = False) -> SpikeBatchResult:
        return self._retry("SPIKE_BATCH", lambda: self._client.spike_batch(
            groups, columns, n_bins, bin_us, paced))

    def decision_window(self, key: int, rows: Sequence[int],
                        candidates: Sequence[DecisionCandidate], params: DecisionParams, *,
                        motor_spikes: bool = False, trace_stride: int = 0,
                        paced: bool = False) -> DecisionWindowReply:
        return self._retry("DECISION_WINDOW", lambda: self._client.decision_window(
            key, rows, candidates, params, motor_spikes=motor_spikes,
            trace_stride=trace_stride, paced=paced))

    def status(self) -> StatusReply:
        return self._retry("STATUS", self._client.status)

    def clock(self) -> ClockReply:
        return self._retry("CLOCK", self._client.clock)

    # -- state-changing: passed through --------------------------------------------------
    def write_pulse(self, row: int, col: int, polarity: Polarity, amplitude_code: int,
                    width_us: int, read_code: int = 0) -> int:
        return self._client.write_pulse(row, col, polarity, amplitude_code, width_us,
                                        read_code)

    def program_cell(self, row: int, col: int, target_adc: int, tolerance_adc: int, *,
                     max_pulses: int = 100, amp_start_code: int = 0, amp_stop_code: int = 0,
                     amp_step_code: int = 0, width_us: int = 100, read_code: int = 0,
                     fine_tune: bool = True) -> ProgramCellReply:
        return self._client.program_cell(
            row, col, target_adc, tolerance_adc, max_pulses=max_pulses,
            amp_start_code=amp_start_code, amp_stop_code=amp_stop_code,
            amp_step_code=amp_step_code, width_us=width_us, read_code=read_code,
            fine_tune=fine_tune)

    def reset(self) -> ResetReply:
        return self._client.reset()

    def counters_dict(self) -> dict[str, int]:
        return self._client.counters_dict()

    def close(self) -> None:
        self._client.close()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._client, name)
