"""A lab's first-day acceptance test of a board: does board, cable and chip behave as assumed?

:class:`SelfTest` runs a list of **items** on a :class:`~snan_hil.board.session.BoardSession`
(either protocol); each gives an :class:`ItemResult` - pass, fail or skip, the measured value,
the expected range, and for a failure the likely cause. Non-destructive by default: reads at or
below the read limit, no pulse except on the cells named in ``SelfTestConfig.allow_pulses``.

=============  ============================================================================
item           what it checks
=============  ============================================================================
identity       INFO: protocol version, the board's constants against MemriCore's, capabilities
link           round trips (STATUS, legacy: reads): lost/resent frames, latency, throughput
               against the line rate
clock          CLOCK: the board's time per column reading (the marginal cost of a spike in
               SPIKE_BATCH) against the datasheets (11 TLC3541 conversions 5 us apart + DAC
               and word-line settling); framed only
zero_reads     every cell read at 0 V (write-DAC code 0): the offset; framed only
cell_reads     every cell read at the read code: open cells, dead regions and lines
noise          repeated reads at 0 V and at the read code against the ADC's noise
adc_bits       the quiet readings (0 V, a fine voltage sweep of one cell): stuck ADC bits
column_path    READ_COLUMN of single driven cells against the cells' own reads
row_dacs       one SPIKE_BATCH per row DAC (8 rows, all columns): each DAC against the others,
               and whether its reading rises along the spike (slow settling)
gain           the read chain's common gain factor from the two read paths
               (:func:`~snan_hil.calibration.readchain.calibrate_read_chain`)
conformance    the conformance vectors that change nothing on the chip
               (:mod:`.selftest_conformance`)
mac            the column multiply against numpy on the layout's weights (only with a layout)
pulses         one SET and one RESET pulse per allowed cell: the conductance moves each way
=============  ============================================================================

Seams for a job runner: :meth:`SelfTest.plan` (the items that will run, and why others will
not), :meth:`SelfTest.run_item` (one item), :meth:`SelfTest.run` (all, in order);
:class:`SelfTestJob` is ``snan-hil selftest`` as the job runner runs it (an item a unit).
Items share what they measured (the cell map, all ADC readings) on the instance; an item
whose inputs failed is skipped with the reason. The expected ranges are
:class:`SelfTestConfig` fields with their sources; docs/bench.md ("Self-test") lists them.
"""

from __future__ import annotations

import logging
import statistics
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from snan_hil.board.session import BoardSession
from snan_hil.calibration import selftest_checks as chk
from snan_hil.calibration.bench import CellBench
from snan_hil.calibration.job import UnitContext
from snan_hil.calibration.mac import MacConfig, run_mac
from snan_hil.calibration.observer import CellEvent, CellObserver, PulseEvent
from snan_hil.calibration.readchain import ReadChain, calibrate_read_chain, \
    pick_calibration_cells
from snan_hil.calibration.selftest_conformance import DEFAULT_VECTORS, run_live_conformance
from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity
from snan_hil.common.progress import ProgressCallback, ProgressEvent
from snan_hil.protocol.board import MEMRICORE, BoardConstants
from snan_hil.protocol.errors import BoardError, ProtocolError, UnsupportedError
from snan_hil.protocol.messages import Capability, SpikeGroup

__all__ = ["SELFTEST_FORMAT", "ITEMS", "SelfTestConfig", "ItemResult", "SelfTestResult",
           "SelfTest", "SelfTestItem", "SelfTestJob"]

log = logging.getLogger(__name__)

SELFTEST_FORMAT = "snan-hil-selftest/1"
ITEMS = ("identity", "link", "clock", "zero_reads", "cell_reads", "noise", "adc_bits",
         "column_path", "row_dacs", "gain", "conformance", "mac", "pulses")
"""The items, in the order they run."""
_FRAMED_ONLY = {"clock": "no CLOCK", "zero_reads": "its reads are at 0.3 V only",
                "column_path": "no READ_COLUMN", "row_dacs": "no SPIKE_BATCH",
                "gain": "no READ_COLUMN for the two-path fit",
                "conformance": "the vectors are of the framed protocol"}


@dataclass(frozen=True)
class SelfTestConfig:
    """What the self-test does and the ranges it expects (sources in the comments).

    Counts: ``round_trips`` (link), ``timing_reads`` (clock), ``noise_cells`` x ``noise_reads``,
    ``column_rows`` (column_path: rows tried per column),
    ``mac_vectors``. ``allow_pulses``: cells (row, col) the pulse item may pulse (none: skipped);
    ``pulse_amplitude_v``, ``pulse_width_us`` its pulses. ``conformance``: the vectors' folder
    (None: this tree's). ``only``: run just these items. ``seed``: of the MAC vectors.
    """

    round_trips: int = 40
    timing_reads: int = 20
    noise_cells: int = 4
    noise_reads: int = 16
    column_rows: int = 8
    mac_vectors: int = 10
    seed: int = 0
    allow_pulses: tuple[tuple[int, int], ...] = ()
    pulse_amplitude_v: float = 0.8
    pulse_width_us: int = 100
    conformance: Path | None = None
    only: tuple[str, ...] = ()
    # ---- expected ranges
    max_lost_fraction: float = 0.0       # any resent or damaged frame on a bench cable is a fault
    max_rtt_ms: float = 50.0             # ASSUMPTION: USB-serial adapters add 1-16 ms
    min_throughput: float = 0.25         # of baud/10 bytes/s; ASSUMPTION (adapter latency)
    read_time_us: tuple[float, float] = (67.0, 500.0)   # >= 11 x 5 us (TLC3541 200 kS/s)
    #                                      + 2 x 6 us settling (AD5328, word line); upper:
    #                                      ASSUMPTION
    max_offset_codes: float = 6.0        # ASSUMPTION: ADC offset + amplifier offset x gain 11
    max_open_fraction: float = 0.05      # ASSUMPTION: the chip's yield (stuck/open cells)
    max_noise_zero_codes: float = 1.0    # TLC3541: 0.5 LSB rms a conversion (ASSUMPTION, SNR
    #                                      81 dB), a reading averages 10
    max_noise_rel: float = 0.02          # + read noise of the cell (crossbar_model: ~1 %)
    column_ratio: tuple[float, float] = (0.8, 1.25)     # column / cell path, both nominal
    row_dac_tolerance: float = 0.1       # one DAC against the others' median
    row_dac_trend: float = 0.05          # rise of the ratio along one spike
    gain_range: tuple[float, float] = (0.97, 1.03)      # common gain factor
    max_mac_rms_pct_fs: float = 5.0      # docs/bench.md: ~1 % FS on a calibrated layout
    min_pulse_change: float = 0.005      # relative conductance change of one pulse

    def __post_init__(self) -> None:
        for name in ("round_trips", "timing_reads", "noise_cells", "noise_reads",
                     "column_rows", "mac_vectors"):
            if getattr(self, name) < 1:
                raise UserError(f"self-test: {name} must be >= 1, got {getattr(self, name)}")
        unknown = sorted(set(self.only) - set(ITEMS))
        if unknown:
            raise UserError(f"unknown self-test item {unknown[0]!r}; the items are "
                            + ", ".join(ITEMS))

    def to_dict(self) -> dict[str, Any]:
        """JSON-able fields."""
        d = asdict(self)
        d["conformance"] = None if self.conformance is None else str(self.conformance)
        d["allow_pulses"] = [list(c) for c in self.allow_pulses]
        return d


@dataclass
class ItemResult:
    """One item's verdict: ``status`` pass / fail / skip, ``measured`` and ``expected`` as
    text, ``cause`` (the likely cause of a failure, or why it was skipped), ``data``
    (JSON-able measurements), ``seconds`` (wall time)."""

    item: str
    status: str
    measured: str = ""
    expected: str = ""
    cause: str = ""
    data: dict[str, Any] = field(default_factory=dict)
    seconds: float = 0.0

    @property
    def failed(self) -> bool:
        return self.status == "fail"


@dataclass
class SelfTestResult:
    """All items' results, the config and the session's provenance."""

    items: list[ItemResult]
    config: SelfTestConfig
    session: dict[str, Any]

    @property
    def passed(self) -> bool:
        """No item failed."""
        return not any(i.failed for i in self.items)

    def item(self, name: str) -> ItemResult:
        """The result of item ``name`` (KeyError if it did not run)."""
        for i in self.items:
            if i.item == name:
                return i
        raise KeyError(name)

    def summary(self) -> dict[str, Any]:
        """Counts and the failed items with their causes (JSON-able)."""
        by = {s: sum(1 for i in self.items if i.status == s) for s in ("pass", "fail", "skip")}
        return {"passed": self.passed, **by,
                "failed_items": {i.item: i.cause for i in self.items if i.failed}}

    def to_dict(self) -> dict[str, Any]:
        """The JSON report (format :data:`SELFTEST_FORMAT`)."""
        return {"format": SELFTEST_FORMAT, "summary": self.summary(),
                "config": self.config.to_dict(), "session": self.session,
                "items": [asdict(i) for i in self.items]}


Check = Callable[[], ItemResult]


class SelfTest:
    """The self-test of the board of ``session`` (module docstring). ``layout``: the board's
    layout (for ``mac``; None: skipped). ``observer``: gets the pulses of ``pulses`` (the chip
    history's Recorder). ``progress``: one unit per item."""

    def __init__(self, session: BoardSession, config: SelfTestConfig | None = None, *,
                 layout: Any = None, observer: CellObserver | None = None,
                 progress: ProgressCallback | None = None) -> None:
        self.session = session
        self.config = config or SelfTestConfig()
        self.layout = layout
        self.observer = observer
        self.progress = progress
        self.client = session.client
        self.info = session.info
        self.chain = ReadChain.nominal(session.info)
        self.results: dict[str, ItemResult] = {}
        # shared measurements
        self.readings: list[int] = []
        self.zero: NDArray[np.float64] | None = None      # (rows, cols) 0 V readings
        self.cells: NDArray[np.float64] | None = None     # (rows, cols) readings at read code
        self.offset = 0.0
        self._checks: dict[str, Check] = {
            "identity": self._identity, "link": self._link, "clock": self._clock,
            "zero_reads": self._zero_reads, "cell_reads": self._cell_reads,
            "noise": self._noise, "adc_bits": self._adc_bits,
            "column_path": self._column_path, "row_dacs": self._row_dacs,
            "gain": self._gain, "conformance": self._conformance, "mac": self._mac,
            "pulses": self._pulses}

    # ------------------------------------------------------------------ seams
    @property
    def framed(self) -> bool:
        return self.session.protocol == "framed"

    def plan(self) -> list[tuple[str, str]]:
        """(item, "" if it will run else why not), in order."""
        out = []
        for name in ITEMS:
            why = ""
            if self.config.only and name not in self.config.only:
                why = "not asked for"
            elif not self.framed and name in _FRAMED_ONLY:
                why = f"legacy protocol: {_FRAMED_ONLY[name]}"
            elif name == "mac" and self.layout is None:
                why = "no layout on this board (program weights first)"
            elif name == "pulses" and not self.config.allow_pulses:
                why = "no cells allowed (--allow-pulses CELLS)"
            out.append((name, why))
        return out

    def run_item(self, name: str) -> ItemResult:
        """Run item ``name`` (its plan entry may skip it) and keep its result."""
        why = dict(self.plan())[name]
        t0 = time.perf_counter()
        if why:
            result = ItemResult(name, "skip", cause=why)
        else:
            try:
                result = self._checks[name]()
            except (BoardError, UnsupportedError) as exc:
                result = ItemResult(name, "fail", cause=f"the board refused: {exc}")
            except ProtocolError as exc:
                result = ItemResult(name, "fail", cause=f"the link failed: {exc}")
        result.seconds = round(time.perf_counter() - t0, 3)
        self.results[name] = result
        log.info("self-test %s: %s %s", name, result.status, result.cause)
        return result

    def run(self) -> SelfTestResult:
        """Every item in order (:data:`ITEMS`)."""
        plan = self.plan()
        todo = [n for n, why in plan]
        for k, name in enumerate(todo):
            if self.progress is not None:
                self.progress(ProgressEvent("self-test", k, len(todo), name))
            self.run_item(name)
        if self.progress is not None:
            self.progress(ProgressEvent("self-test", len(todo), len(todo), "done"))
        return SelfTestResult([self.results[n] for n in todo], self.config,
                              self.session.snapshot())

    # ------------------------------------------------------------------ helpers
    def _needs(self, *items: str) -> str:
        """Why an item cannot be judged: one of ``items`` did not pass ("" if all did)."""
        for name in items:
            r = self.results.get(name)
            if r is None or r.status != "pass":
                state = "did not run" if r is None else r.status
                return f"not judged: {name} {'failed' if state == 'fail' else state}"
        return ""

    def _read(self, row: int, col: int, code: int | None = None) -> int:
        value = int(self.client.read_cell(row, col, code))
        self.readings.append(value)
        return value

    def _healthy(self) -> list[tuple[int, int]]:
        """Cells whose read at the read code carries current (cell_reads)."""
        if self.cells is None:
            return []
        rows, cols = self.cells.shape
        return [(r, c) for r in range(rows) for c in range(cols)
                if self.cells[r, c] > self.offset + chk.OPEN_CODES
                and self.cells[r, c] < self.info.adc_full_scale_code]

    # ------------------------------------------------------------------ items
    def _identity(self) -> ItemResult:
        info = self.info
        diffs = [f"{name} {getattr(info, name)!r} (MemriCore: {getattr(MEMRICORE, name)!r})"
                 for name in BoardConstants.__dataclass_fields__
                 if getattr(info, name) != getattr(MEMRICORE, name)]
        caps = [c.name for c in Capability if info.has(c)]
        data = {"board_id": self.session.identity.board_id,
                "firmware": info.firmware_version, "protocol_version": info.protocol_version,
                "capabilities": caps, "differences": diffs}
        measured = (f"{info.firmware_version}, protocol {info.protocol_version}, "
                    f"{info.rows}x{info.cols}, {len(caps)} capabilities")
        expected = "MemriCore constants (32x8, 12-bit DACs, 14-bit ADC, 3 kOhm, gain 11)"
        if diffs:
            return ItemResult("identity", "fail", measured, expected,
                              "the board announces other constants than MemriCore's: "
                              + "; ".join(diffs[:3]), data)
        return ItemResult("identity", "pass", measured, expected, data=data)

    def _link(self) -> ItemResult:
        cfg = self.config
        before = self.client.counters_dict()
        call: Callable[[], object] = self.client.status if self.framed \
            else (lambda: self.client.read_cell(0, 0))
        times = []
        for _ in range(cfg.round_trips):
            t0 = time.perf_counter()
            call()
            times.append(time.perf_counter() - t0)
        after = self.client.counters_dict()
        d = {k: after.get(k, 0) - before.get(k, 0) for k in after}
        lost = d.get("retries", 0) + d.get("timeouts", 0)
        damaged = d.get("crc_errors", 0) + d.get("framing_errors", 0) + \
            d.get("bad_crc_reported", 0) + d.get("malformed", 0)
        moved = d.get("bytes_in", 0) + d.get("bytes_out", 0)
        rtt_ms = statistics.median(times) * 1e3
        line_bytes_s = self.session.baud / 10.0
        throughput = (moved / sum(times)) / line_bytes_s if moved and sum(times) > 0 else None
        data = {"round_trips": cfg.round_trips, "rtt_ms_median": rtt_ms,
                "rtt_ms_max": max(times) * 1e3, "resent": lost, "damaged": damaged,
                "bytes": moved, "throughput_of_line": throughput, "counters": d}
        tput = "" if throughput is None else f", {100 * throughput:.0f} % of the line rate"
        measured = (f"{lost} resent, {damaged} damaged of {cfg.round_trips}; median "
                    f"{rtt_ms:.2f} ms{tput}")
        expected = (f"0 resent/damaged, median <= {cfg.max_rtt_ms:g} ms, >= "
                    f"{100 * cfg.min_throughput:.0f} % of {self.session.baud} baud")
        if lost + damaged > cfg.max_lost_fraction * cfg.round_trips:
            return ItemResult("link", "fail", measured, expected, (
                f"the link loses or damages bytes ({lost} requests resent, {damaged} damaged "
                f"frames in {cfg.round_trips} round trips): a UART that drops bytes - check "
                "the cable and its ground, the baud rate on both ends, the USB-serial adapter"),
                data)
        if rtt_ms > cfg.max_rtt_ms:
            return ItemResult("link", "fail", measured, expected,
                              "slow round trips: the USB-serial adapter's latency timer, a "
                              "busy host, or a board that answers late", data)
        if throughput is not None and throughput < cfg.min_throughput:
            return ItemResult("link", "fail", measured, expected,
                              "the line carries less than expected: baud mismatch or flow "
                              "control, or the adapter's latency", data)
        return ItemResult("link", "pass", measured, expected, data=data)

    def _spike_us(self, n: int) -> tuple[float, int]:
        """Board time (us, CLOCK) of one unpaced SPIKE_BATCH of ``n`` spikes of row 0 read on
        column 0, and the UART bytes it moved."""
        group = SpikeGroup(((0, self.info.max_row_read_code),), tuple(range(n)))
        t0 = self.client.clock().time_us
        before = self.client.counters_dict()
        self.client.spike_batch([group], [0], n_bins=n, bin_us=1)
        after = self.client.counters_dict()
        t1 = self.client.clock().time_us
        moved = sum(after.get(k, 0) - before.get(k, 0) for k in ("bytes_in", "bytes_out"))
        return float(t1 - t0), moved

    def _clock(self) -> ItemResult:
        why = self._needs("link")
        if why:
            return ItemResult("clock", "skip", cause=why)
        cfg = self.config
        n = cfg.timing_reads
        t1, b1 = self._spike_us(n)
        t2, b2 = self._spike_us(3 * n)
        us_per_byte = 10.0 / self.session.baud * 1e6
        # the marginal board time of a spike (one row up, one column read, back): the
        # request's and reply's fixed costs cancel, the UART bytes of the extra spikes are
        # taken out at the line rate
        per_read = ((t2 - t1) - (b2 - b1) * us_per_byte) / (2 * n)
        lo, hi = cfg.read_time_us
        data = {"spikes": [n, 3 * n], "board_us": [t1, t2], "bytes": [b1, b2],
                "read_us": per_read}
        measured = f"{per_read:.1f} us per column reading (board clock, UART excluded)"
        expected = f"{lo:g}..{hi:g} us (11 conversions >= 5 us apart + settling)"
        if t1 <= 0 or t2 <= t1:
            return ItemResult("clock", "fail", measured, expected,
                              "the board's clock does not advance: its timer or CLOCK", data)
        if per_read < lo:
            return ItemResult("clock", "fail", measured, expected,
                              "a reading takes less time than the ADC's conversions need: the "
                              "board's timer runs slow, or the firmware skips conversions "
                              "or the settling wait", data)
        if per_read > hi:
            return ItemResult("clock", "fail", measured, expected,
                              "a reading takes far longer than the datasheets need: the "
                              "board's timer runs fast, the SPI clock is slow, or the firmware "
                              "waits", data)
        return ItemResult("clock", "pass", measured, expected, data=data)

    def _map(self, code: int) -> NDArray[np.float64]:
        rows, cols = self.info.rows, self.info.cols
        out = np.zeros((rows, cols))
        for r in range(rows):
            for c in range(cols):
                out[r, c] = self._read(r, c, code)
        return out

    def _zero_reads(self) -> ItemResult:
        cfg = self.config
        zero = self.zero = self._map(0)
        self.offset = float(np.median(zero))
        worst = float(np.max(np.abs(zero)))
        data = {"median_code": self.offset, "max_abs_code": worst,
                "spread_codes": float(zero.max() - zero.min())}
        measured = f"median {self.offset:.1f}, max |code| {worst:.0f}"
        expected = f"|code| <= {cfg.max_offset_codes:g} on every cell"
        if worst <= cfg.max_offset_codes:
            return ItemResult("zero_reads", "pass", measured, expected, data=data)
        bit = int(round(np.log2(self.offset))) if self.offset >= 1 else -1
        if bit >= 2 and abs(self.offset - (1 << bit)) <= 2:
            cause = (f"0 V reads {self.offset:.0f} = 2^{bit} on every cell: ADC output bit "
                     f"{bit} stuck at 1")
        else:
            cause = ("0 V reads are off zero: the amplifier's or the ADC's offset, or the "
                     "write DAC does not reach 0 V")
        return ItemResult("zero_reads", "fail", measured, expected, cause, data)

    def _cell_reads(self) -> ItemResult:
        cfg = self.config
        cells = self.cells = self._map(self.info.read_code)
        zero = self.zero if self.zero is not None else np.zeros_like(cells)
        open_mask = cells <= zero + chk.OPEN_CODES
        full = cells >= self.info.adc_full_scale_code
        regions = chk.dead_regions(open_mask)
        n = cells.size
        g = self.chain.cell_conductance(cells[~open_mask & ~full])
        data = {"open": [[int(r), int(c)] for r, c in zip(*np.nonzero(open_mask))],
                "saturated": [[int(r), int(c)] for r, c in zip(*np.nonzero(full))],
                "regions": [list(x) for x in regions],
                "conductance_us": {"median": float(np.median(g)) * 1e6 if g.size else None,
                                   "min": float(g.min()) * 1e6 if g.size else None,
                                   "max": float(g.max()) * 1e6 if g.size else None},
                "codes": cells.astype(int).tolist()}
        bad = int(open_mask.sum() + full.sum())
        if self.observer is not None:            # one result per cell in the chip's history
            for r in range(cells.shape[0]):
                for c in range(cells.shape[1]):
                    state = "open" if open_mask[r, c] else "saturated" if full[r, c] else "ok"
                    g_rc = None if state != "ok" else \
                        float(self.chain.cell_conductance(cells[r, c] - self.offset))
                    self.observer.on_cell(CellEvent(r, c, state, g_rc,
                                                    detail={"adc": int(cells[r, c]),
                                                            "zero_adc": int(zero[r, c])}))
        measured = (f"{int(open_mask.sum())} open, {int(full.sum())} saturated of {n}"
                    + (f"; median {np.median(g) * 1e6:.0f} uS" if g.size else ""))
        expected = (f"<= {100 * cfg.max_open_fraction:.0f} % open/saturated, no dead region "
                    "or line")
        if regions:
            r0, r1, c0, c1, k = max(regions, key=lambda x: x[4])
            return ItemResult("cell_reads", "fail", measured, expected, (
                f"dead cell region: rows {r0}-{r1}, columns {c0}-{c1} read open ({k} cells): "
                "a broken bit line / word line or multiplexer channel, or damaged cells "
                "there"), data)
        if bad > cfg.max_open_fraction * n:
            return ItemResult("cell_reads", "fail", measured, expected,
                              "too many open or saturated cells for the chip's yield: the "
                              "read path (write DAC, multiplexers, load resistor) or the chip",
                              data)
        return ItemResult("cell_reads", "pass", measured, expected, data=data)

    def _noise(self) -> ItemResult:
        cfg = self.config
        cells = self._healthy()[::max(1, len(self._healthy()) // cfg.noise_cells)]
        cells = cells[:cfg.noise_cells] or [(0, 0)]
        zero_sd, rel_sd = [], []
        for r, c in cells:
            if self.framed:
                z = [self._read(r, c, 0) for _ in range(cfg.noise_reads)]
                zero_sd.append(statistics.pstdev(z))
            v = [self._read(r, c, self.info.read_code) for _ in range(cfg.noise_reads)]
            m = statistics.fmean(v) - self.offset
            if m > 0:
                rel_sd.append(statistics.pstdev(v) / m)
        worst_zero = max(zero_sd) if zero_sd else 0.0
        worst_rel = max(rel_sd) if rel_sd else 0.0
        data = {"cells": [list(c) for c in cells], "reads": cfg.noise_reads,
                "zero_sd_codes": zero_sd, "relative_sd": rel_sd}
        measured = (f"0 V: sd {worst_zero:.2f} codes; read code: sd {100 * worst_rel:.2f} %"
                    if zero_sd else f"read code: sd {100 * worst_rel:.2f} %")
        expected = (f"<= {cfg.max_noise_zero_codes:g} codes at 0 V, <= "
                    f"{100 * cfg.max_noise_rel:g} % at the read code")
        if worst_zero > cfg.max_noise_zero_codes:
            return ItemResult("noise", "fail", measured, expected,
                              "the ADC chain is noisier than the TLC3541 at 0 V: the amplifier, "
                              "the ADC reference or supply, or ground loops", data)
        if worst_rel > cfg.max_noise_rel:
            return ItemResult("noise", "fail", measured, expected,
                              "reads at the read voltage scatter more than the cell's read noise "
                              "and the ADC explain: the write DAC, the load resistor or a "
                              "noisy supply", data)
        return ItemResult("noise", "pass", measured, expected, data=data)

    def _adc_bits(self) -> ItemResult:
        quiet = [int(v) for v in self.zero.ravel()] if self.zero is not None else []
        healthy = self._healthy()
        if healthy and self.cells is not None:
            cells = self.cells
            ranked = sorted(healthy, key=lambda rc: float(cells[rc]))
            top = self.info.read_code
            # two cells of other slopes (a reading that lands on a boundary of a bit at every
            # k-th code of one cell does not at the other's); one DAC code a step where the
            # reading is low (quiet), then coarser
            for r, c in {ranked[-1], ranked[len(ranked) // 2]}:
                for code in sorted(set(range(0, min(top, 64) + 1)) | set(range(64, top + 1, 8))):
                    quiet.append(self._read(r, c, code))
        found = chk.stuck_bits(quiet, self.info.adc_bits)
        span = (min(quiet), max(quiet)) if quiet else (0, 0)
        data = {"quiet_readings": len(quiet), "span": list(span),
                "stuck": [list(f) for f in found]}
        measured = (f"{len(quiet)} quiet readings {span[0]}..{span[1]}; "
                    + (", ".join(f"bit {b} set in {100 * f:.0f} %" for b, _, f in found)
                       or "every exercised bit toggles"))
        expected = "each exercised bit set in some readings and clear in others"
        if found:
            text = "; ".join(f"ADC output bit {b} stuck at {v}" for b, v, _ in found)
            return ItemResult("adc_bits", "fail", measured, expected,
                              f"{text}: the TLC3541's data line, or the SPI (MISO) wiring",
                              data)
        return ItemResult("adc_bits", "pass", measured, expected, data=data)

    def _predict_column(self, cells: list[tuple[int, int]], code: int) -> float:
        """Predicted column-read code of ``cells`` (one column) driven at row code ``code``,
        from their single-cell reads (nominal chain)."""
        assert self.cells is not None
        x = self.chain.cell_resistance(np.array([self.cells[rc] - self.offset
                                                 for rc in cells]), self.info.read_code)
        return float(self.chain.column_scale(code) * np.sum(1.0 / (x + self.chain.r_switch_ohm)))

    def _column_path(self) -> ItemResult:
        why = self._needs("cell_reads")
        if why:
            return ItemResult("column_path", "skip", cause=why)
        cfg = self.config
        healthy = set(self._healthy())
        code = self.info.max_row_read_code
        offset = statistics.fmean(self.client.read_column(0, [0] * self.info.rows)
                                  for _ in range(4))
        ratios = []
        for c in range(self.info.cols):
            rows = [r for r in range(self.info.rows) if (r, c) in healthy]
            step = max(1, len(rows) // cfg.column_rows)
            for r in rows[::step][:cfg.column_rows]:
                codes = [0] * self.info.rows
                codes[r] = code
                got = self.client.read_column(c, codes) - offset
                pred = self._predict_column([(r, c)], code)
                if pred > 0:
                    ratios.append(got / pred)
        if not ratios:
            return ItemResult("column_path", "skip", cause="no healthy cell to drive")
        ratio = statistics.median(ratios)
        lo, hi = cfg.column_ratio
        data = {"offset_column_code": offset, "ratios": ratios, "median_ratio": ratio}
        measured = f"column / cell prediction {ratio:.3f} (median of {len(ratios)} cells)"
        expected = f"{lo:g}..{hi:g}"
        verdict = chk.judge_column_ratio(ratio, lo, hi, self.info.r_load_ohm,
                                         self.info.sum_gain_ohm)
        return ItemResult("column_path", "pass" if verdict.ok else "fail", measured, expected,
                          verdict.cause, data)

    def _row_dacs(self) -> ItemResult:
        why = self._needs("cell_reads", "column_path")
        if why:
            return ItemResult("row_dacs", "skip", cause=why)
        cfg = self.config
        healthy = set(self._healthy())
        cols = list(range(self.info.cols))
        fill = 0.6 * self.info.adc_full_scale_code
        ratios: dict[int, list[float]] = {}
        for k in range(self.info.rows // 8):
            rows = list(range(8 * k, 8 * k + 8))
            code = self.info.max_row_read_code
            # lower the drive until no column of the group would come near full scale
            while code > 8 and max(self._predict_column([(r, c) for r in rows
                                                         if (r, c) in healthy], code)
                                   for c in cols) > fill:
                code //= 2
            group = SpikeGroup(tuple((r, code) for r in rows), (0,))
            res = self.client.spike_batch([group], cols, n_bins=1, bin_us=1)
            got = res.codes[0]
            per = []
            for j, c in enumerate(cols):
                pred = self._predict_column([(r, c) for r in rows if (r, c) in healthy], code)
                if pred > 8:
                    per.append((got[j] - self.results["column_path"].data["offset_column_code"])
                               / pred)
            ratios[k] = per
        verdict, summary = chk.judge_row_dacs(ratios, cfg.row_dac_tolerance, cfg.row_dac_trend)
        data = {"ratios": {str(k): v for k, v in ratios.items()},
                "summary": {str(k): v for k, v in summary.items()}}
        measured = "; ".join(f"DAC{k} {s['mean']:.2f} ({s['first']:.2f}->{s['last']:.2f})"
                             for k, s in summary.items())
        expected = (f"each DAC within {100 * cfg.row_dac_tolerance:.0f} % of the others, no "
                    f"rise > {cfg.row_dac_trend:g} along a spike")
        return ItemResult("row_dacs", "pass" if verdict.ok else "fail", measured, expected,
                          verdict.cause, data)

    def _gain(self) -> ItemResult:
        why = self._needs("cell_reads", "column_path", "row_dacs")
        if why:
            return ItemResult("gain", "skip", cause=why)
        cfg = self.config
        assert self.cells is not None
        g = {rc: float(self.chain.cell_conductance(self.cells[rc] - self.offset))
             for rc in self._healthy()}
        cells, gain_cells = pick_calibration_cells(g)
        chain = calibrate_read_chain(self.client, cells, gain_cells)
        factor = chain.gain_factor
        lo, hi = cfg.gain_range
        data = {"gain_factor": factor, "details": chain.details}
        measured = f"common gain factor {factor:.4f}"
        expected = f"{lo:g}..{hi:g}"
        rejected = chain.details.get("gain")
        if rejected:
            return ItemResult("gain", "fail", measured, expected,
                              f"the gain could not be fitted ({rejected})", data)
        if not lo <= factor <= hi:
            return ItemResult("gain", "fail", measured, expected, (
                f"the read chain's gain is {factor:.3f} x what the board announces (gain "
                f"{self.info.gain:g}): a wrong amplifier gain (resistor), or the ADC / DAC "
                "reference voltage"), data)
        return ItemResult("gain", "pass", measured, expected, data=data)

    def _conformance(self) -> ItemResult:
        why = self._needs("link")
        if why:
            return ItemResult("conformance", "skip", cause=why)
        client = self.client

        def reset() -> None:
            client.hello()
            client.reset()
        folder = self.config.conformance or DEFAULT_VECTORS
        try:
            res = run_live_conformance(client.transport, reset, folder=folder)
        finally:
            client.hello()                       # the link's nonce and seq again
        data = {"sessions": res.sessions, "compared": res.compared, "skipped": res.skipped,
                "problems": res.problems[:50]}
        measured = (f"{res.compared - len(res.problems)} of {res.compared} steps conform "
                    f"({len(res.sessions)} sessions; {res.skipped} pulse steps left out)")
        expected = "every step"
        if res.compared == 0:
            return ItemResult("conformance", "fail", measured, expected,
                              f"no vectors found in {folder}", data)
        if res.problems:
            return ItemResult("conformance", "fail", measured, expected,
                              "the firmware answers differently from the protocol's vectors: "
                              + res.problems[0], data)
        return ItemResult("conformance", "pass", measured, expected, data=data)

    def _mac(self) -> ItemResult:
        cfg = self.config
        result = run_mac(self.client, self.layout,
                         MacConfig(vectors=cfg.mac_vectors, seed=cfg.seed))
        s = result.summary()
        rms = float(s["rms_error_pct_fs"])
        data = {"summary": s}
        measured = f"RMS error {rms:.2f} % FS over {s['samples']} multiplies"
        expected = f"<= {cfg.max_mac_rms_pct_fs:g} % FS"
        if rms > cfg.max_mac_rms_pct_fs:
            return ItemResult("mac", "fail", measured, expected,
                              "the column multiply disagrees with numpy on the programmed "
                              "weights: the cells drifted since programming, or the column "
                              "path", data)
        return ItemResult("mac", "pass", measured, expected, data=data)

    def _mean_g(self, row: int, col: int) -> float:
        reads = [self._read(row, col, self.info.read_code) for _ in range(4)]
        return float(self.chain.cell_conductance(statistics.fmean(reads) - self.offset))

    def _pulses(self) -> ItemResult:
        cfg = self.config
        code = self.info.write_dac_floor_code(cfg.pulse_amplitude_v)
        amp_v = self.info.write_dac_volts(code)
        rows: list[dict[str, Any]] = []
        bad: list[tuple[int, int, float, float]] = []
        for r, c in cfg.allow_pulses:
            g0 = self._mean_g(r, c)
            moves: list[tuple[str, float]] = []
            events: list[PulseEvent] = []
            for pol in (Polarity.SET, Polarity.RESET):
                before = g0 if not moves else moves[-1][1]
                self.client.write_pulse(r, c, pol, code, cfg.pulse_width_us)
                after = self._mean_g(r, c)
                events.append(PulseEvent(r, c, pol, amp_v, cfg.pulse_width_us, before, after,
                                         "selftest"))
                moves.append((pol.name, after))
            if self.observer is not None:
                self.observer.on_pulses(events)
            g_set, g_reset = moves[0][1], moves[1][1]
            up = (g_set - g0) / g0 if g0 > 0 else 0.0
            down = (g_set - g_reset) / g_set if g_set > 0 else 0.0
            rows.append({"cell": [r, c], "g0_us": g0 * 1e6, "g_set_us": g_set * 1e6,
                         "g_reset_us": g_reset * 1e6, "set_rel": up, "reset_rel": down})
            if up < cfg.min_pulse_change or down < cfg.min_pulse_change:
                bad.append((r, c, up, down))
        data = {"amplitude_v": amp_v, "width_us": cfg.pulse_width_us, "cells": rows}
        measured = "; ".join(f"({x['cell'][0]},{x['cell'][1]}) SET {100 * x['set_rel']:+.1f} %"
                             f" RESET {-100 * x['reset_rel']:+.1f} %" for x in rows)
        expected = (f"SET raises, RESET lowers G by >= {100 * cfg.min_pulse_change:.1f} % "
                    f"({amp_v:.3f} V, {cfg.pulse_width_us} us)")
        if bad:
            r, c, up, down = bad[0]
            return ItemResult("pulses", "fail", measured, expected, (
                f"cell ({r},{c}) does not respond to pulses as a 1T1R cell should (SET "
                f"{100 * up:+.1f} %, RESET {-100 * down:+.1f} %): the pulse gate, the polarity "
                "line, the write DAC, or the cell"), data)
        return ItemResult("pulses", "pass", measured, expected, data=data)


# ------------------------------------------------------------------ the job
@dataclass(frozen=True)
class SelfTestItem:
    """A unit of :class:`SelfTestJob`: one item (:data:`ITEMS`); the items of a run share
    what they measured, so they are one group, run in order on one board."""

    key: str
    group: str | None = "self-test"


class SelfTestJob:
    """``snan-hil selftest`` as a board job: every item of :data:`ITEMS` a unit (one that
    will not run is a unit too: its result says why it was skipped), the pulses of ``pulses``
    and the cell results recorded through the run's observer, the run's controlled client
    (``snan-hil watch`` pauses and stops it between requests). The result is the
    :class:`SelfTestResult`. A run cut short gives the items that finished. No resume: the
    items share measurements kept on the :class:`SelfTest` (a restored item's result is
    taken as it was)."""

    kind: ClassVar[str] = "selftest"
    restartable: ClassVar[bool] = False

    def __init__(self, config: SelfTestConfig | None = None) -> None:
        self.cfg = config or SelfTestConfig()
        self._test: SelfTest | None = None
        self._session: dict[str, Any] = {}
        self._order: list[str] = []

    def describe(self) -> dict[str, Any]:
        return self.cfg.to_dict()

    def plan(self, bench: CellBench) -> Sequence[SelfTestItem]:
        """The items (with the board's layout, for ``mac``; a layout of another board or
        chip is refused here, one line)."""
        self._test = SelfTest(bench.session, self.cfg, layout=bench.layout)
        self._session = bench.snapshot()
        self._order = [name for name, _why in self._test.plan()]
        return [SelfTestItem(name) for name in self._order]

    def run_unit(self, unit: SelfTestItem, bench: CellBench, ctx: UnitContext
                 ) -> dict[str, Any]:
        test = self._test
        assert test is not None, "plan() first"
        test.client, test.observer = bench.client, bench.observer   # the run's, controlled
        k, n = self._order.index(unit.key), len(self._order)
        if ctx.progress is not None:
            ctx.progress(ProgressEvent("self-test", k, n, unit.key))
        record = asdict(test.run_item(unit.key))
        if ctx.progress is not None and k == n - 1:
            ctx.progress(ProgressEvent("self-test", n, n, "done"))
        return record

    def restore(self, unit: SelfTestItem, record: dict[str, Any]) -> None:
        if self._test is not None:
            self._test.results[unit.key] = ItemResult(**record)

    def result(self, records: Mapping[str, dict[str, Any]], status: str) -> SelfTestResult:
        return SelfTestResult([ItemResult(**records[n]) for n in self._order if n in records],
                              self.cfg, self._session)

    def summary(self, result: SelfTestResult) -> dict[str, Any] | None:
        return result.summary()
