"""A crossbar cell behind a :class:`~snan_hil.protocol.client.BoardClient`, for write-and-verify.

:class:`BoardCellIO` implements :class:`~snan_hil.calibration.wv.CellIO` with host-side safety
checks that hold whatever the firmware does: no read above the board's read limit (its
``max_read_code``, the DAC code at or below ``max_read_v``), no write above the configured
maximum amplitude (at most the board's ``max_write_v``), no pulse whose predicted current
(amplitude / (X + R_sw), X from the last read) exceeds the compliance limit less a margin.

:class:`PulseLedger` counts the pulses the host decided to apply and proves none was applied
twice: every WRITE_PULSE is one request (the link retransmits it with the same sequence number,
and the board answers a retransmission from its reply cache without executing it again); if a
request is lost for good, the board's STATUS counter ``pulses_applied`` tells whether it ran.
"""

from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass
from typing import Protocol

from snan_hil.calibration.observer import PulseEvent
from snan_hil.calibration.readchain import ReadChain
from snan_hil.calibration.wv import PulseNotApplied
from snan_hil.common.polarity import Polarity
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.errors import LinkTimeoutError, ProtocolError, UnsupportedError
from snan_hil.protocol.messages import Info
from snan_hil.protocol.safety import HostLimits, HostSafetyError
from snan_hil.records.control import StopRequested

__all__ = ["PulseLedger", "CellLimits", "PulseSink", "BoardCellIO"]

log = logging.getLogger(__name__)


@dataclass
class PulseLedger:
    """Pulses decided, confirmed and reconciled; checked against the board's counter."""

    decided: int = 0          # WRITE_PULSE requests issued (one per decision)
    confirmed: int = 0        # executed: reply received, or reconciled from STATUS
    not_applied: int = 0      # lost requests the board never executed (from STATUS)
    lost_in_reset: int = 0    # in flight when the board reset (cannot be known)
    reconciled: int = 0       # timeouts resolved with STATUS
    resyncs: int = 0          # board resets survived (HELLO + new baseline)
    fw_baseline: int | None = None
    confirmed_at_baseline: int = 0

    def rebaseline(self, client: BoardClient) -> None:
        """Remember the board's pulse counter now (after HELLO or a reset); boards without
        STATUS (legacy protocol) leave it unknown."""
        try:
            self.fw_baseline = int(client.status().pulses_applied)
        except UnsupportedError:
            self.fw_baseline = None
        self.confirmed_at_baseline = self.confirmed

    @property
    def host_pulses(self) -> int:
        """Pulses confirmed since the baseline."""
        return self.confirmed - self.confirmed_at_baseline

    def firmware_delta(self, client: BoardClient) -> int | None:
        """Pulses the board executed since the baseline (None without a STATUS counter)."""
        if self.fw_baseline is None:
            return None
        return int(client.status().pulses_applied) - self.fw_baseline

    def to_dict(self) -> dict[str, int | None]:
        return asdict(self)


@dataclass(frozen=True)
class CellLimits:
    """What a cell I/O may do: the board session's one read and write limit (``host``,
    :class:`~snan_hil.protocol.safety.HostLimits`: the board's INFO, lowered by
    ``--max-write-v``), the job's own amplitude ceiling (``ceiling_v``, V: e.g. the
    write-and-verify ``v_max``; at most the write limit), the compliance current (A) with its
    margin, and the read DAC code of the reads. Made by the cell bench
    (:meth:`snan_hil.calibration.bench.CellBench.limits_for`), never from the INFO again."""

    host: HostLimits
    compliance_a: float
    read_code: int
    compliance_margin: float = 0.95
    ceiling_v: float | None = None

    @classmethod
    def of(cls, host: HostLimits, board: Info, *, ceiling_v: float | None = None,
           compliance_margin: float = 0.95, read_code: int | None = None) -> CellLimits:
        """The limits of a cell I/O on a board whose one limit is ``host`` (the session's),
        ``board`` its INFO (compliance current); ``read_code`` default: the read limit's
        single-cell code. UserError (one line) for a read code outside the read limit."""
        top = host.max_cell_read_code if host.max_cell_read_code >= 0 else host.max_read_code
        code = top if read_code is None else int(read_code)
        if not 0 < code <= top:
            raise HostSafetyError(f"read DAC code {code} outside 1..{top} (the board's read "
                                  f"limit {host.max_read_v} V)")
        return cls(host, board.compliance_a, code, compliance_margin, ceiling_v)

    @property
    def max_write_v(self) -> float:
        """The largest amplitude a pulse of this I/O may have (V)."""
        if self.ceiling_v is None:
            return self.host.max_write_v
        return min(self.ceiling_v, self.host.max_write_v)

    @property
    def max_read_code(self) -> int:
        """The largest single-cell read code (the write DAC's, at most the read limit)."""
        top = self.host.max_cell_read_code
        return self.host.max_read_code if top < 0 else top


class PulseSink(Protocol):
    """Where a cell I/O reports each pulse as it goes (the cell bench: the run's pulse
    journal, written before the request and after its reply, and the run's observers)."""

    def sent(self, row: int, col: int, polarity: Polarity, amplitude_v: float,
             width_us: int, stage: str | None) -> int:
        """The pulse is about to be sent; a token for :meth:`applied` / :meth:`lost`."""

    def applied(self, token: int, event: PulseEvent) -> None:
        """The pulse ran (its reply, or the board's pulse counter)."""

    def lost(self, token: int) -> None:
        """The pulse verifiably did not run (the board's pulse counter)."""


class BoardCellIO:
    """One cell (row, col) of a board; conductances via the calibrated read chain."""

    def __init__(self, client: BoardClient, chain: ReadChain, row: int, col: int,
                 limits: CellLimits, ledger: PulseLedger, width_us: int = 100,
                 sink: PulseSink | None = None):
        if client.info is None:
            raise ProtocolError(f"{client.transport.name}: no HELLO yet (no board constants)")
        self.client, self.chain, self.row, self.col = client, chain, row, col
        self.limits, self.ledger, self.width_us = limits, ledger, int(width_us)
        self.info: Info = client.info
        self.last_g: float | None = None
        self.last_adc: int | None = None
        """ADC code of the last read (the read after a pulse included)."""
        self.reads = 0
        self.stage: str | None = None
        self.applied: list[PulseEvent] = []
        """Every pulse this cell received through :meth:`pulse` (for observers,
        :mod:`snan_hil.calibration.observer`), ``stage`` as set when it was applied."""
        self.sink = sink
        """Told of each pulse as it goes (the cell bench's journal and recorder)."""

    # -- CellIO -----------------------------------------------------------------------------
    def read(self) -> float:
        code = self.limits.read_code
        if code > self.limits.max_read_code:
            raise HostSafetyError(f"read code {code} above the read limit")
        adc = self.client.read_cell(self.row, self.col, code)
        self.last_adc = int(adc)
        self.reads += 1
        self.last_g = float(self.chain.cell_conductance(adc, code))
        return self.last_g

    def measure(self, volts: float) -> tuple[float, float, float]:
        """Read the cell at ``volts`` (the write DAC's code at or below it, at most the read
        limit): (G in S, the current measured in A, the voltage applied in V). The board's
        one current measurement: the ADC of a cell read (:meth:`BoardConstants.cell_current_a
        <snan_hil.protocol.board.BoardConstants.cell_current_a>`); HostSafetyError above the
        read limit or below one DAC step."""
        code = self.info.write_dac_floor_code(volts)
        if not 1 <= code <= self.limits.max_read_code:
            raise HostSafetyError(f"a read at {volts:g} V (code {code}) is outside the read "
                                  f"range 1..{self.limits.max_read_code}")
        adc = self.client.read_cell(self.row, self.col, code)
        self.last_adc = int(adc)
        self.reads += 1
        self.last_g = float(self.chain.cell_conductance(adc, code))
        return (self.last_g, float(self.chain.cell_current_a(adc)),
                float(self.chain.cell_read_volts(code)))

    def amplitude_cap(self, polarity: Polarity, conductance_s: float) -> float:
        lim = self.limits
        x = 1.0 / conductance_s if conductance_s > 0 else float("inf")
        v_comp = lim.compliance_a * lim.compliance_margin * (x + self.chain.r_switch_ohm)
        return min(lim.max_write_v, v_comp)

    def pulse(self, polarity: Polarity, amplitude_v: float) -> float:
        if polarity not in (Polarity.SET, Polarity.RESET):
            raise ValueError(f"polarity must be Polarity.SET or Polarity.RESET, got {polarity!r}")
        # round DOWN to a DAC code: the applied amplitude never exceeds the one decided (whose
        # cap already holds the compliance and the configured maximum)
        full = self.info.write_dac_full_scale_code
        code = int(math.floor(amplitude_v * full / self.info.write_dac_vref_v + 1e-9))
        while code > 0 and self.info.write_dac_volts(code) > self.limits.max_write_v + 1e-12:
            code -= 1
        volts = self.info.write_dac_volts(code)
        if volts > self.limits.max_write_v + 1e-12 or code <= 0:
            raise HostSafetyError(f"write amplitude {amplitude_v:.3f} V not sendable "
                                  f"(limit {self.limits.max_write_v} V)")
        g = self.last_g
        if g is not None and g > 0:
            predicted = volts / (1.0 / g + self.chain.r_switch_ohm)
            if predicted > self.limits.compliance_a * self.limits.compliance_margin * (1 + 1e-9):
                raise HostSafetyError(
                    f"pulse of {volts:.2f} V on ({self.row},{self.col}) would draw "
                    f"{predicted * 1e3:.2f} mA > {self.limits.compliance_a * 1e3:.2f} mA limit")
        read_code = self.limits.read_code
        self.ledger.decided += 1
        before = self.last_g
        token = None if self.sink is None else \
            self.sink.sent(self.row, self.col, Polarity(polarity), volts, self.width_us,
                           self.stage)
        try:
            adc = self.client.write_pulse(self.row, self.col, polarity, code, self.width_us,
                                          read_code)
        except StopRequested:
            # the run's control channel stops it *before* the request is sent
            # (ControlledClient checks first): the journalled pulse never went out
            self.ledger.decided -= 1
            if token is not None and self.sink is not None:
                self.sink.lost(token)
            raise
        except LinkTimeoutError:
            if self.ledger.fw_baseline is None:
                raise                     # no pulse counter: the pulse's fate is unknowable
            if not self._reconcile():
                if token is not None and self.sink is not None:
                    self.sink.lost(token)
                raise PulseNotApplied() from None
            after = self.read()
            self._log(polarity, volts, before, after, token)
            return after
        self.ledger.confirmed += 1
        self.last_adc = int(adc)
        self.last_g = float(self.chain.cell_conductance(adc, read_code))
        self._log(polarity, volts, before, self.last_g, token)
        return self.last_g

    def _log(self, polarity: Polarity, volts: float, before: float | None,
             after: float, token: int | None = None) -> None:
        event = PulseEvent(self.row, self.col, Polarity(polarity), volts, self.width_us,
                           before, after, self.stage)
        self.applied.append(event)
        if token is not None and self.sink is not None:
            self.sink.applied(token, event)

    # -- link trouble -------------------------------------------------------------------------
    def _reconcile(self) -> bool:
        """After a lost WRITE_PULSE: did the board execute it? (STATUS pulse counter)."""
        ledger = self.ledger
        executed = ledger.firmware_delta(self.client)   # STATUS (retried by RetryingClient)
        ledger.reconciled += 1
        expected = ledger.host_pulses
        if executed == expected + 1:
            ledger.confirmed += 1
            log.info("lost WRITE_PULSE on (%d,%d) was executed (board counter)", self.row,
                     self.col)
            return True
        if executed == expected:
            ledger.not_applied += 1
            log.info("lost WRITE_PULSE on (%d,%d) was not executed", self.row, self.col)
            return False
        raise ProtocolError(f"board pulse counter {executed} disagrees with the host's "
                            f"{expected} confirmed pulses; stop and check the board")
