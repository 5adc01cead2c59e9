"""The lean read plan of DECISION_WINDOW on the emulated MCU (issue 33).

With ``DecisionParams.conversions`` = N > 0 the board reads differently from SPIKE_BATCH
(docs/protocol.md "0x0A DECISION_WINDOW", "Read plan"); the C firmware does the same in
``firmware/src/window.c`` (``run_lean``), frame for frame:

* per input spike the reads of :meth:`~snan_hil.protocol.messages.DecisionWindow.reads`: each
  row's own candidates' columns (a column no candidate of that row uses is not read), every
  other spike in reverse order (a spike starts with the cell the previous one ended with: no
  select, no settling, and a neuron on two rows changes rows once a spike);
* a row DAC is written only when the driven row changes (the previous one back to 0 first), the
  column register only when the column changes; the rows stay driven between spikes (the word
  line is off only between reads of another column, or while a PACED window waits for a bin),
  and the window ends idle (word line off, rows at 0, row DACs disabled);
* after a change the first sample waits for the settling time (6 us, the DAC's and the front
  end's) counted from the change - while the ADC still converts the previous read's last sample;
  a read with no change waits only for the ADC;
* N conversions a read through the TLC3541's pipeline: a frame returns the previous conversion,
  so frames 2..N of a read return its conversions 1..N-1 and the next read's first frame its
  N-th; no dummy conversion - the window's first frame returns a stale result (dropped) and one
  frame at its end returns the last read's last conversion. A read is the rounded mean of its N
  conversions (saturated if one is at full scale);
* the MCU's arithmetic runs in the waits: before a read's first frame the previous spike's
  motor neurons (once all its reads are converted), then chunks of :data:`DRAW_CHUNK` steps of
  the search for the next input spike while the wait leaves room for one (:data:`DRAW_FIT_US`;
  what is left of the search runs after the spike's last read); after the first frame the read
  it completed is converted; what the waits do not absorb delays the next frame.

The MCU time of each step is the C firmware's own (:data:`COSTS`, fitted to the instruction-level
MCU; ``tests/firmware/test_decision_window.py`` checks that the two MCUs' window times agree).
The samples, bytes, clock and energy come from the board's devices as for any other request.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from snan_hil.firmware_emu import lif_fixed as fx
from snan_hil.firmware_emu import registers as reg
from snan_hil.firmware_emu.spi_devices import AD5328, TLC3541, SpiTransaction
from snan_hil.protocol import messages as m

if TYPE_CHECKING:                                  # pragma: no cover - typing only
    from snan_hil.firmware_emu.firmware import Firmware

DRAW_CHUNK = 2
"""Steps of the search for the next input spike the MCU draws at once (~1.1 us a step besides
~2.4 us a call): the C firmware's ``DW_DRAW_CHUNK``."""
DRAW_FIT_US = 4.5
"""The room a chunk needs: the MCU draws another chunk while the wait for the next frame has at
least this much left (~ ``draw_call + DRAW_CHUNK * draw_step`` of :data:`COSTS`; a fixed
estimate, the C firmware's ``DW_DRAW_FIT_TICKS``)."""


@dataclass(frozen=True)
class LeanCosts:
    """MCU time (us) of the lean plan's steps in the C firmware at 32 MHz (one instruction a
    cycle), fitted to the instruction-level MCU (:mod:`snan_hil.firmware_emu.mcu_isa`) on
    random windows: ``bench/fit_window_costs.py`` prints them.

    ``*_pre``: from the step's start to its chip select falling (the driver's work before the
    bits); ``*_post``: after the bits until the caller continues."""

    word_pre: float = 0.601           #: a row-DAC word (2 bytes)
    word_post: float = 0.521
    select_pre: float = 0.655         #: the column register byte
    select_post: float = 0.772
    frame_entry: float = 0.534        #: an ADC frame: before its wait for the sample time
    frame_pre: float = 0.534         #: after the wait, to the chip select falling
    frame_post: float = 0.497         #: after the bits: the bytes read, CS high, returned
    frame_code: float = 0.139        #: decode and sum one conversion (frames 2..N)
    convert: float = 4.875            #: a read completed: mean, code -> drive, stored per lane
    draw_call: float = 2.202          #: one chunk of the next-spike search in a wait (drawn
    #                                    only with room: rarely between two frames without a
    #                                    wait, so kept from an earlier fit, not refitted)
    search_call: float = 1.276        #: the search called outright (window start, the rest of
    #                                    it after a spike's last read, a window without reads)
    draw_step: float = 1.123          #: one step of that search (splitmix64, 38.5 instructions)
    lif_spike: float = 2.422          #: the motor neurons at an input spike, besides the lanes
    lif_lane: float = 3.020           #: one lane's update at an input spike
    lif_inh: float = 6.011            #: an interneuron spike (its gap decoded, the lane updated)
    lif_trace: float = 2.741          #: a trace point, per lane
    spike: float = 2.929              #: a spike's own bookkeeping (watchdog, counters)
    read: float = 1.600               #: a read's own bookkeeping (row and column checks)


COSTS = LeanCosts()


Ledger = list[tuple[str, float]]
"""(cost name, count) of the MCU steps since the last SPI frame started (the fit's input)."""


class _Timer:
    """The lean plan's clock steps on one board (mirrors ``run_lean`` in window.c).
    ``ledger``: a list that collects, per SPI frame, the MCU steps before it (for fitting
    :class:`LeanCosts`; None: not kept)."""

    def __init__(self, fw: "Firmware", costs: LeanCosts, ledger: list[Ledger] | None = None):
        self.fw, self.c = fw, costs
        self.cost = dataclasses.asdict(costs)
        self.clock, self.bus = fw.clock, fw.bus
        self.adc: TLC3541 = fw.board.adc
        self.ledger = ledger
        self._open: Ledger = []
        self.pending = 0.0

    def mcu(self, name: str, count: float = 1.0) -> None:
        """``count`` times the MCU step ``name`` (a :class:`LeanCosts` field); the MCU's steps
        between two frames or waits advance the clock as one (:meth:`flush`)."""
        if count:
            self.pending += self.cost[name] * count
            if self.ledger is not None:
                self._open.append((name, count))

    def now_us(self) -> float:
        """The MCU's time: the clock with the MCU steps not yet flushed (the firmware's
        ``hal_now()``)."""
        return self.clock.now_us + self.pending

    def adc_ready_us(self) -> float:
        """When the ADC may take its next frame (its conversion cycle)."""
        return self.adc.ready_at_us()

    def flush(self) -> None:
        """The MCU time summed since the last frame or wait, onto the clock."""
        if self.pending:
            self.clock.advance(self.pending, "mcu")
            self.pending = 0.0

    def _transfer(self, cs: str, mosi: bytes, pre: str) -> bytes:
        self.mcu(pre)
        self.flush()
        if self.ledger is not None:
            self.ledger.append(self._open)
            self._open = []
        return self.bus.transfer(cs, mosi, 0.0)

    def word(self, row: int, code: int) -> None:
        self._transfer(reg.CS_ROW_DAC[row // AD5328.CHANNELS],
                       AD5328.data_word(row % AD5328.CHANNELS, code), "word_pre")
        self.fw._row_codes[row] = code
        self.mcu("word_post")

    def select(self, byte: int) -> bool:
        """The column register to ``byte``; whether it was written."""
        fw = self.fw
        if byte == fw._sr_col:
            return False
        self._transfer(reg.CS_SR_COL, bytes((byte,)), "select_pre")
        fw._sr_col = byte
        self.mcu("select_post")
        return True

    def sr_row(self, byte: int) -> None:
        fw = self.fw
        if byte != fw._sr_row:
            self._transfer(reg.CS_SR_ROW, bytes((byte,)), "select_pre")
            fw._sr_row = byte
            self.mcu("select_post")

    def frame(self, not_before_us: float) -> int:
        """One ADC frame sampling no earlier than ``not_before_us`` (and the ADC's cycle);
        the conversion it returns (the previous one). A wait marks the ledger (the MCU steps
        before it do not set the frame's time)."""
        clock = self.clock
        self.mcu("frame_entry")
        self.flush()
        ready = self.adc.ready_at_us()
        target = max(not_before_us, ready)
        if target > clock.now_us:
            if self.ledger is not None:
                self._open.append(("wait", 1.0))
            if not_before_us > ready:
                clock.wait_until(not_before_us, "settle")
            clock.wait_until(ready, "adc")
        miso = self._transfer(reg.CS_ADC, b"\x00\x00", "frame_pre")
        self.mcu("frame_post")
        return TLC3541.decode(miso[0], miso[1])


class _FastTimer(_Timer):
    """:class:`_Timer` without a Python call per SPI frame (an emulator shortcut, not MCU
    behaviour): every sample of the window is drawn at once (the array's ``column_reads`` and
    the ADC noise, in frame order: the same draws as frame by frame), the clock takes the same
    steps with the same floats in the same order, the power follows the circuit each frame
    leaves, and the devices, counters and trace end as the frames would leave them
    (``tests/firmware/test_decision_window.py`` checks both paths agree bit for bit).
    ``frames``: the circuit of every ADC frame of the window, (row, column) or None (idle)."""

    def __init__(self, fw: "Firmware", costs: LeanCosts, ledger: list[Ledger] | None,
                 frames: list[tuple[int, int] | None], row_code: int):
        super().__init__(fw, costs, ledger)
        board = fw.board
        self.fe = board.front_end
        self.spi1, self.spi2 = self.clock.spi_bits_us(1), self.clock.spi_bits_us(2)
        self.row_volts = np.zeros(fw.config.rows)
        self.ops: list[tuple[str, bytes, float]] = []      # (chip select, MOSI, start)
        self.adc_ready = self.adc.ready_at_us()
        self.result = self.adc.result
        self.codes = self._sample(frames, row_code)
        self.next_frame = 0
        self.rowdac_en = False

    def _sample(self, frames: list[tuple[int, int] | None], row_code: int) -> list[int]:
        """The ADC code of every frame, drawn in frame order."""
        fe, cfg = self.fe, self.fw.config
        reads = [f for f in frames if f is not None]
        assert all(f is not None for f in frames[:len(reads)]), "idle frames come last"
        rows = sorted({r for r, _ in reads})
        volts = np.zeros((max(len(rows), 1), cfg.rows))
        dacs = self.fw.board.row_dacs
        for i, r in enumerate(rows):
            volts[i, r] = dacs[r // AD5328.CHANNELS].code_volts(r % AD5328.CHANNELS, row_code)
        ideal = np.zeros(0)
        if reads:
            current = fe.array.column_reads(volts, [rows.index(r) for r, _ in reads],
                                            [c for _, c in reads], 1)[:, 0]
            ideal = fe._column_lsb(current, True)
        idle = len(frames) - len(reads)
        if idle:
            extra = np.zeros(idle)
            if fe.adc_noise_lsb > 0.0:
                extra = extra + fe._rng.normal(0.0, fe.adc_noise_lsb, size=idle)
            ideal = np.concatenate([ideal, extra])
        codes = np.floor(ideal + 0.5)
        if not np.isfinite(codes).all():
            raise ValueError("ADC input is not finite")
        out = codes.astype(np.int64)
        full = cfg.adc_full_scale_code
        fe.samples += out.size
        clipped = (out > full) | (out < 0)
        if clipped.any():
            fe.saturated_samples += int(clipped.sum())
            out = np.clip(out, 0, full)
        return out.tolist()

    def _op(self, cs: str, mosi: bytes, pre: str, bits: float) -> float:
        """One SPI frame: the MCU step before it, the bits; its start (us)."""
        self.mcu(pre)
        self.flush()
        if self.ledger is not None:
            self.ledger.append(self._open)
            self._open = []
        clock = self.clock
        start = clock.now_us
        clock.advance(bits, "spi")
        self.ops.append((cs, mosi, start))
        return start

    def adc_ready_us(self) -> float:
        return self.adc_ready

    def _power(self) -> None:
        col = self.fw._sr_col
        power = 0.0
        if self.rowdac_en and col & reg.WL_EN:
            power = self.fe.column_power(self.row_volts, col & reg.WL_ADDR_MASK)
        self.clock.set_power(power)

    def word(self, row: int, code: int) -> None:
        self._op(reg.CS_ROW_DAC[row // AD5328.CHANNELS],
                 AD5328.data_word(row % AD5328.CHANNELS, code), "word_pre", self.spi2)
        dacs = self.fw.board.row_dacs
        self.row_volts[row] = dacs[row // AD5328.CHANNELS].code_volts(row % AD5328.CHANNELS,
                                                                      code)
        self.fw._row_codes[row] = code
        self._power()
        self.mcu("word_post")

    def select(self, byte: int) -> bool:
        fw = self.fw
        if byte == fw._sr_col:
            return False
        self._op(reg.CS_SR_COL, bytes((byte,)), "select_pre", self.spi1)
        fw._sr_col = byte
        self._power()
        self.mcu("select_post")
        return True

    def sr_row(self, byte: int) -> None:
        fw = self.fw
        if byte != fw._sr_row:
            self._op(reg.CS_SR_ROW, bytes((byte,)), "select_pre", self.spi1)
            fw._sr_row = byte
            self.rowdac_en = bool(byte & reg.ROWDAC_EN)
            self._power()
            self.mcu("select_post")

    def frame(self, not_before_us: float) -> int:
        clock = self.clock
        self.mcu("frame_entry")
        self.flush()
        ready = self.adc_ready
        if max(not_before_us, ready) > clock.now_us:
            if self.ledger is not None:
                self._open.append(("wait", 1.0))
            if not_before_us > ready:
                clock.wait_until(not_before_us, "settle")
            clock.wait_until(ready, "adc")
        start = self._op(reg.CS_ADC, b"\x00\x00", "frame_pre", self.spi2)
        self.adc_ready = start + self.adc.cycle_us
        previous, self.result = self.result, self.codes[self.next_frame]
        self.next_frame += 1
        self.mcu("frame_post")
        return previous

    def finish(self) -> None:
        """The devices, the bus and the trace as the frames would have left them."""
        board, bus, adc = self.fw.board, self.bus, self.adc
        assert self.next_frame == len(self.codes)
        shift = {reg.CS_SR_COL: board.sr_col, reg.CS_SR_ROW: board.sr_row}
        trace = bus.trace
        result, k, last_start = adc.result, 0, None
        for cs, mosi, start in self.ops:
            device = bus.devices[cs]
            device.frames += 1
            bus.transactions += 1
            bus.bytes += len(mosi)
            if cs in shift:
                sr = shift[cs]
                miso = bytes((sr.shift,))
                sr.shift = sr.latch = mosi[0]
            elif cs == reg.CS_ADC:
                miso = (result << 2).to_bytes(2, "big") if trace is not None else b""
                result = self.codes[k]
                k += 1
                last_start = start
            else:
                miso = bytes(len(mosi))
            if trace is not None:
                trace.append(SpiTransaction(start, cs, mosi, miso))
        adc.result = result
        adc.conversions += k
        if last_start is not None:
            adc._busy_until = last_start + adc.cycle_us
        codes = self.fw._row_codes
        for i, dac in enumerate(board.row_dacs):
            dac.input_reg = list(codes[i * AD5328.CHANNELS:(i + 1) * AD5328.CHANNELS])
            dac.dac_reg = list(dac.input_reg)
        self.fe._stale_dacs.update(range(len(board.row_dacs)))
        self.fe.circuit = self.fe.decode()
        self._power()


def run_lean(fw: "Firmware", req: m.DecisionWindow, p: m.DecisionParams, bins: np.ndarray,
             costs: LeanCosts = COSTS, ledger: list[Ledger] | None = None) -> np.ndarray:
    """Drive the lean plan's reads of window ``req`` (input spikes at ``bins``, int64) on the
    board of ``fw`` and time the MCU's arithmetic in its waits; returns the Q32.32 drive of
    every lane at every spike, int64[len(bins), lanes] (lif_fixed.drives of each read's mean).
    The caller integrates the motor neurons (their time is counted here). ``ledger``: see
    :class:`_Timer`."""
    reads = req.reads()
    tm: _Timer
    if bins.size and reads and _fast_applicable(fw):
        order = list(range(len(reads)))
        cells = [(req.rows[ri], col) for ri, col in reads]
        frames: list[tuple[int, int] | None] = [
            cells[j] for k in range(bins.size) for j in (order[::-1] if k % 2 else order)
            for _ in range(p.conversions)]
        tm = _FastTimer(fw, costs, ledger, frames + [None], p.row_code)
    else:
        tm = _Timer(fw, costs, ledger)
    drive = _LeanWindow(fw, req, p, bins, tm).run()
    tm.flush()
    if isinstance(tm, _FastTimer):
        tm.finish()
    return drive


def _fast_applicable(fw: "Firmware") -> bool:
    """Whether :class:`_FastTimer` may run the window: the fast mode, the board idle between
    requests (rows at 0 with their DACs following each write, word line off, row DACs off, no
    pulse open), the board's own devices on the bus, an array with ``column_reads``."""
    board, fe = fw.board, fw.board.front_end
    from snan_hil.firmware_emu.analog import IDLE
    if not fw.fast or getattr(board.array, "column_reads", None) is None:
        return False
    if any(fw._row_codes) or fw._sr_col or fw._sr_row:
        return False
    if (board.sr_col.latch, board.sr_col.shift, board.sr_row.latch) != (0, 0, 0):
        return False
    if fe._pulse is not None or fe.circuit != IDLE:
        return False
    if any(dac.ldac_mode != AD5328.LDAC_CONTINUOUS or any(dac.input_reg) or any(dac.dac_reg)
           for dac in board.row_dacs):
        return False
    bus = fw.bus
    return (bus.devices.get(reg.CS_ADC) is board.adc
            and all(bus.devices.get(cs) is dac for cs, dac in zip(reg.CS_ROW_DAC, board.row_dacs))
            and bus.devices.get(reg.CS_SR_COL) is board.sr_col
            and bus.devices.get(reg.CS_SR_ROW) is board.sr_row)


class _LeanWindow:
    """One window of :func:`run_lean`: the state of ``run_lean`` in window.c."""

    def __init__(self, fw: "Firmware", req: m.DecisionWindow, p: m.DecisionParams,
                 bins: np.ndarray, tm: _Timer):
        self.fw, self.req, self.p, self.tm = fw, req, p, tm
        self.reads = req.reads()
        self.spikes = [int(b) for b in bins]
        self.lanes = len(req.candidates)
        self.drive = np.zeros((len(self.spikes), self.lanes), dtype=np.int64)
        self.means = np.zeros((len(self.spikes), len(self.reads)), dtype=np.int64)
        self.lanes_of = [[k for k, cand in enumerate(req.candidates)
                          if (cand.row_index, cand.col) == r] for r in self.reads]
        self.row_of = [req.rows[ri] for ri, _ in self.reads]
        self.sr_of = [reg.col_select_byte(col, sum_path=True) for _, col in self.reads]
        self.inh = [np.asarray(cand.inh, dtype=np.int64) for cand in req.candidates]
        timing = fw.config.timing
        self.settle = max(timing.dac_settle_us, timing.frontend_settle_us)
        self.full = fw.config.adc_full_scale_code
        self.deadline = 0.0
        self.driven = -1
        self.prev: tuple[int, int, bool] | None = None  # (spike, read, spike's last read)
        #                                               the next frame completes
        self.acc_prev, self.sat_prev = 0, False
        self.lif_pending: int | None = None        # spike whose motor neurons wait
        self.lif_done = -1                         # last step whose events are processed
        self.draw_t, self.found = 0, False

    def run(self) -> np.ndarray:
        tm, spikes, n_bins = self.tm, self.spikes, self.p.n_bins
        self._draw(0, n_bins, spikes[0] if spikes else n_bins, "search_call")
        if not self.reads or not spikes:
            for k, t in enumerate(spikes):        # counted, nothing read
                tm.mcu("lif_spike")
                self._draw(t + 1, n_bins, self._next(k), "search_call")
            return self.drive
        clock = self.fw.clock
        tm.flush()
        t0 = clock.now_us
        tm.sr_row(reg.ROWDAC_EN)
        for k, t_cur in enumerate(spikes):
            self.draw_t, self.found = t_cur + 1, False
            if self.req.paced:
                tm.flush()
                clock.wait_until(t0 + t_cur * self.p.bin_us, "idle")
            tm.mcu("spike")
            order = range(len(self.reads))
            for i, j in enumerate(reversed(order) if k % 2 else order):
                self._read(k, j, i == len(self.reads) - 1)
            self.fw.counters.spikes_applied += len({ri for ri, _ in self.reads})
            self.fw.counters.column_reads += len(self.reads)
            if not self.found:
                self._draw(self.draw_t, n_bins, self._next(k), "search_call")
            if self.req.paced:
                tm.select(0)
        self._finish()
        p = self.p
        for j, lanes in enumerate(self.lanes_of):       # each read's mean -> drive, at once
            dv = fx.drives(self.means[:, j], p.offset, p.d, p.num_shift, p.den_shift,
                           p.q_shift, p.k1, p.k0)
            for lane in lanes:
                self.drive[:, lane] = dv
        return self.drive

    def _next(self, k: int) -> int:
        """The step of the spike after spike k (n_bins: none)."""
        return self.spikes[k + 1] if k + 1 < len(self.spikes) else self.p.n_bins

    def _draw(self, start: int, end: int, found: int, call: str = "draw_call") -> None:
        self.tm.mcu(call)
        self.tm.mcu("draw_step", found - start + 1 if found < end else end - start)

    def _read(self, k: int, j: int, last: bool) -> None:
        """Read j of spike k (``last``: the spike's last): row and column, the work before its
        first frame, its frames."""
        tm = self.tm
        tm.mcu("read")
        changed = False
        if self.row_of[j] != self.driven:
            if self.driven >= 0:
                tm.word(self.driven, 0)
            tm.word(self.row_of[j], self.p.row_code)
            self.driven = self.row_of[j]
            changed = True
        changed |= tm.select(self.sr_of[j])
        if changed:
            tm.flush()
            self.deadline = self.fw.clock.now_us + self.settle
        if self.lif_pending is not None:
            self._lif(self.lif_pending)
            self.lif_pending = None
        target = max(self.deadline, tm.adc_ready_us())
        while not self.found and target - tm.now_us() >= DRAW_FIT_US:
            end = min(self.draw_t + DRAW_CHUNK, self.p.n_bins)
            t_next = self._next(k)
            self._draw(self.draw_t, end, t_next)
            self.found = t_next < end or end == self.p.n_bins
            self.draw_t = end
        self._complete(tm.frame(self.deadline))
        acc, sat = 0, False
        for _ in range(1, self.p.conversions):
            code = tm.frame(0.0)
            tm.mcu("frame_code")
            acc += code
            sat |= code >= self.full
        self.prev, self.acc_prev, self.sat_prev = (k, j, last), acc, sat

    def _complete(self, code: int) -> None:
        """A first frame returned the previous read's last conversion: convert that read."""
        if self.prev is None:
            return                                 # the window's first frame: stale
        self.acc_prev += code
        self.sat_prev |= code >= self.full
        if self.sat_prev:
            self.fw.counters.saturated_reads += 1
        k, j, last = self.prev
        n_conv = self.p.conversions
        self.means[k, j] = (self.acc_prev + n_conv // 2) // n_conv
        self.tm.mcu("convert")
        if last:
            self.lif_pending = k

    def _lif(self, k: int) -> None:
        """The motor neurons' events up to spike k's (their MCU time)."""
        t = self.spikes[k]
        tm = self.tm
        tm.mcu("lif_spike")
        tm.mcu("lif_lane", self.lanes)
        tm.mcu("lif_inh", sum(int(np.count_nonzero((x > self.lif_done) & (x <= t)))
                              for x in self.inh))
        tm.mcu("lif_trace", self.lanes * _points(self.req.trace_stride, self.lif_done, t))
        self.lif_done = t

    def _finish(self) -> None:
        """The window back to idle, its last conversion, the motor neurons to its end."""
        tm = self.tm
        tm.select(0)
        if self.driven >= 0:
            tm.word(self.driven, 0)
        tm.sr_row(0)
        assert self.prev is not None
        pending, last = self.lif_pending, self.prev[0]
        self._complete(tm.frame(0.0))
        if pending is not None:
            self._lif(pending)
        self._lif(last)
        tm.mcu("lif_inh", sum(int(np.count_nonzero(x > self.lif_done)) for x in self.inh))
        tm.mcu("lif_trace", self.lanes * _points(self.req.trace_stride, self.lif_done,
                                                 self.p.n_bins - 1))


def _points(stride: int, after: int, upto: int) -> int:
    """Trace points (multiples of ``stride``) in ``(after, upto]``."""
    if not stride or upto <= after:
        return 0
    return upto // stride - (after // stride if after >= 0 else -1)
