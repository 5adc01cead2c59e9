"""Whole-batch fast path of SPIKE_BATCH: every spike of a batch in one pass (emulator-side).

The reference (:meth:`Firmware._spike`, per SPI frame with ``Firmware.fast = False``) drives one
spike as the MCU does: the group's row-DAC words, a DAC settling wait, then per column a
column-register byte (word line + summing path), a settling wait and ``adc_dummy +
adc_averages`` ADC frames, then the column register back to 0 and the rows back to 0. Between
spikes the board is always in the same state (rows at 0, word line off, row DACs enabled), so
a spike of a given group always sends the same bytes and the clock advances by the same
steps; only the ADC samples and, when paced, the waits for the bins differ.

:func:`run_spike_batch` uses that: it derives each group's spike schedule once (the row-DAC
writes and, per column, the power the open column dissipates), replays the clock of all
spikes in a numba kernel that performs the reference's float operations in the reference's
order (so time, energy and the per-category breakdown end bit for bit where the frame-by-frame
path leaves them), and draws all ADC samples of the batch in one vectorised call
(:meth:`AnalogFrontEnd.spike_train_codes`: the same read-noise and ADC-noise draws in the same
order). Counters, device registers, the ADC's pipelined result and busy time, and the SPI trace
(when one is recorded) are updated as the frame-by-frame path updates them.

It applies only in that steady state; :func:`applicable` checks it (otherwise the firmware runs
the spikes one by one). tests/emulator/test_emu_fastpath.py checks both paths agree bit for bit.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np
from numba import njit
from numpy.typing import NDArray

from snan_hil.firmware_emu import registers as reg
from snan_hil.firmware_emu.analog import IDLE
from snan_hil.firmware_emu.board import Board
from snan_hil.firmware_emu.spi_devices import AD5328, SpiTransaction, TLC3541
from snan_hil.firmware_emu.spike_group import SpikeGroupSpec

CATEGORIES = ("mcu", "adc", "spi", "settle", "idle")
"""Clock categories the kernel accumulates (indices MCU..IDLE below)."""
MCU, ADC, SPI, SETTLE, IDLE_WAIT = range(5)

IDLE_POWER_W = 0.0
"""Power of the idle circuit (word line off): :meth:`AnalogFrontEnd.power_w` gives 0 W."""


# ------------------------------------------------------------------------------ clock kernel
@njit(cache=True, inline="always")
def _transfer(now, energy, power, mcu, adc, spi, overhead_us, bits_us, ready_us):
    """SpiBus.transfer's clock: ``advance(overhead_us, "mcu")``, ``wait_until(ready_us,
    "adc")``, then ``advance(bits_us, "spi")``; each advance is VirtualClock.advance's
    ``now += us; energy += power * us * 1e-6; breakdown[category] += us`` (skipped when
    us <= 0). Returns the new (now, energy, mcu, adc, spi), whether it waited, and the frame's
    start time (CS falling)."""
    if overhead_us > 0.0:
        now += overhead_us
        energy += power * overhead_us * 1e-6
        mcu += overhead_us
    waited = ready_us > now
    if waited:
        us = ready_us - now
        now += us
        energy += power * us * 1e-6
        adc += us
    start = now
    if bits_us > 0.0:
        now += bits_us
        energy += power * bits_us * 1e-6
        spi += bits_us
    return now, energy, mcu, adc, spi, waited, start


@njit(cache=True)
def spike_clock_kernel(drive, targets, n_writes, col_power, clk, acc, touched, overhead_us,
                       bits1_us, bits2_us, dac_settle_us, settle_us, frames, cycle_us,
                       idle_power_w, starts):
    """Advance the virtual clock over the spikes of a batch, as the reference path does.

    drive int64[S]: group of each spike; targets float64[S]: paced start time of each spike
    (us; -inf when not paced); n_writes int64[G]: row-DAC words of a group's spike;
    col_power float64[G, m]: power (W) while column k of the batch is open in group g's spike;
    clk float64[4]: (now us, energy J, power W, ADC ready-at us), updated in place; acc
    float64[5] / touched bool[5]: per-category time (CATEGORIES) and whether it advanced,
    updated in place; starts float64[total]: out, the start time of every SPI frame in bus
    order. Returns the number of frames.
    """
    now, energy, power, adc_ready = clk[0], clk[1], clk[2], clk[3]
    mcu, adc, spi, settle, idle = acc[MCU], acc[ADC], acc[SPI], acc[SETTLE], acc[IDLE_WAIT]
    waited_adc = waited_idle = settled = False
    k = 0
    m = col_power.shape[1]
    for s in range(drive.size):
        g = drive[s]
        if targets[s] > now:                           # paced: wait for the bin
            us = targets[s] - now
            now += us
            energy += power * us * 1e-6
            idle += us
            waited_idle = True
        for _ in range(n_writes[g]):                   # row DACs to the group's codes
            now, energy, mcu, adc, spi, w, starts[k] = _transfer(
                now, energy, power, mcu, adc, spi, overhead_us, bits2_us, 0.0)
            k += 1
            power = idle_power_w
        if dac_settle_us > 0.0:
            now += dac_settle_us
            energy += power * dac_settle_us * 1e-6
            settle += dac_settle_us
            settled = True
        for c in range(m):
            now, energy, mcu, adc, spi, w, starts[k] = _transfer(
                now, energy, power, mcu, adc, spi, overhead_us, bits1_us, 0.0)
            k += 1
            power = col_power[g, c]                    # the column circuit is open
            if settle_us > 0.0:
                now += settle_us
                energy += power * settle_us * 1e-6
                settle += settle_us
                settled = True
            for _ in range(frames):                    # dummy + averaged ADC frames
                now, energy, mcu, adc, spi, w, start = _transfer(
                    now, energy, power, mcu, adc, spi, overhead_us, bits2_us, adc_ready)
                waited_adc |= w
                starts[k] = start
                k += 1
                adc_ready = start + cycle_us
        now, energy, mcu, adc, spi, w, starts[k] = _transfer(          # word line off
            now, energy, power, mcu, adc, spi, overhead_us, bits1_us, 0.0)
        k += 1
        power = idle_power_w
        for _ in range(n_writes[g]):                   # rows back to 0
            now, energy, mcu, adc, spi, w, starts[k] = _transfer(
                now, energy, power, mcu, adc, spi, overhead_us, bits2_us, 0.0)
            k += 1
            power = idle_power_w
    clk[0], clk[1], clk[2], clk[3] = now, energy, power, adc_ready
    acc[MCU], acc[ADC], acc[SPI], acc[SETTLE], acc[IDLE_WAIT] = mcu, adc, spi, settle, idle
    if k:
        touched[MCU] |= overhead_us > 0.0
        touched[SPI] |= bits1_us > 0.0 or bits2_us > 0.0
    touched[ADC] |= waited_adc
    touched[SETTLE] |= settled
    touched[IDLE_WAIT] |= waited_idle
    return k


# ------------------------------------------------------------------------------ the batch
def applicable(board: Board, columns: Sequence[int]) -> bool:
    """True if the board is in the steady state the fast path replays (see module doc): every
    row DAC at 0 (outputs following each write), word line off, row DACs enabled, no pulse
    open, the board's own ADC and front end on the bus, and an array with
    ``column_currents_sequence``. The firmware checks its own side (its row codes at 0, its
    column and row registers) and that it runs fast (:meth:`Firmware._in_batch_state`)."""
    t = board.config.timing
    fe = board.front_end
    if not columns or t.adc_dummy < 1 or board.config.adc_averages < 1:
        return False
    if getattr(board.array, "column_currents_sequence", None) is None:
        return False
    if (board.sr_col.latch, board.sr_col.shift) != (0, 0) or board.sr_row.latch != reg.ROWDAC_EN:
        return False
    if fe._pulse is not None or fe.circuit != IDLE or len(board.sr_col._listeners) != 1:
        return False
    for dac in board.row_dacs:
        if (dac.ldac_mode != AD5328.LDAC_CONTINUOUS or any(dac.input_reg) or any(dac.dac_reg)
                or len(dac._listeners) != 1):
            return False
    bus = board.bus
    adc = bus.devices.get(reg.CS_ADC)
    return (isinstance(adc, TLC3541) and adc is board.adc
            and all(bus.devices.get(cs) is dac for cs, dac in zip(reg.CS_ROW_DAC, board.row_dacs))
            and bus.devices.get(reg.CS_SR_COL) is board.sr_col)


def spike_order(groups: Sequence[SpikeGroupSpec]) -> tuple[np.ndarray, np.ndarray]:
    """(bin, group index) of every spike in application order — bin order, then group order,
    as ``sorted((b, gi) ...)`` orders them — as two int64 arrays."""
    lens = [len(g.bins) for g in groups]
    bins = np.fromiter(itertools.chain.from_iterable(g.bins for g in groups), dtype=np.int64,
                       count=sum(lens))
    group = np.repeat(np.arange(len(groups), dtype=np.int64), lens)
    order = np.lexsort((group, bins))
    return bins[order], group[order]


def run_spike_batch(board: Board, groups: Sequence[SpikeGroupSpec], columns: Sequence[int],
                    settle_us: float, paced_t0_us: float | None,
                    bin_us: int) -> tuple[list[list[int]], NDArray[np.bool_]]:
    """The spikes of a batch (bin order, then group order), each reading ``columns``: per spike
    the ADC codes (as :meth:`Firmware._spike` returns them), and (spikes, columns) bool, True
    where the reading saturated the ADC (the firmware counts them:
    :meth:`Firmware._count_batch`).

    The caller has checked the request and :func:`applicable`, and has put the board in the
    batch state (word line off, row DACs enabled). ``settle_us``: wait after opening a column;
    ``paced_t0_us``: None, or the batch's start time (us) when each spike waits for its bin's
    start, ``paced_t0_us + bin * bin_us``.
    """
    clock, bus = board.clock, board.bus
    fe, adc = board.front_end, board.adc
    cfg = board.config
    t = cfg.timing
    rows = cfg.rows
    columns = [int(c) for c in columns]
    bins, drive = spike_order(groups)
    m, n_spikes, frames = len(columns), int(drive.size), t.adc_dummy + cfg.adc_averages
    if n_spikes == 0:
        return [], np.zeros((0, m), dtype=np.bool_)

    # Per group: the row-DAC words _set_row_codes sends (dict order, codes that differ from
    # 0), the row voltages they produce, and the power of each open column.
    writes: list[list[tuple[int, int]]] = []
    volts = np.zeros((len(groups), rows))
    for gi, g in enumerate(groups):
        w = [(int(r), int(c)) for r, c in dict(g.rows).items() if c != 0]
        writes.append(w)
        for r, c in w:
            volts[gi, r] = board.row_dacs[r // AD5328.CHANNELS].code_volts(r % AD5328.CHANNELS, c)
    col_power = np.array([[fe.column_power(volts[gi], c) for c in columns]
                          for gi in range(len(groups))]).reshape(len(groups), m)
    n_writes = np.array([len(w) for w in writes], dtype=np.int64)

    # Clock.
    per_spike = 2 * n_writes[drive] + m * (1 + frames) + 1
    total = int(per_spike.sum())
    starts = np.empty(total)
    clk = np.array([clock.now_us, clock.energy_j, clock.power_w, adc.ready_at_us()])
    breakdown = clock.breakdown_us
    acc = np.array([breakdown.get(c, 0.0) for c in CATEGORIES])
    touched = np.zeros(len(CATEGORIES), dtype=np.bool_)
    # float(t0) + int(b * bin_us), as the reference's wait_until(t0 + b * bin_us)
    paced = (paced_t0_us + bins * int(bin_us) if paced_t0_us is not None
             else np.full(n_spikes, -np.inf))
    done = spike_clock_kernel(drive, paced, n_writes, col_power, clk, acc, touched,
                              float(clock.timing.mcu_overhead_us), clock.spi_bits_us(1),
                              clock.spi_bits_us(2), float(t.dac_settle_us), float(settle_us),
                              frames, float(adc.cycle_us), IDLE_POWER_W, starts)
    assert done == total
    clock.now_us, clock.energy_j = float(clk[0]), float(clk[1])
    clock.set_power(float(clk[2]))
    for i, cat in enumerate(CATEGORIES):
        if touched[i]:
            breakdown[cat] = float(acc[i])

    # ADC samples: frame j of a reading shifts out conversion j - 1 (frame 0 the previous
    # result); frames adc_dummy.. are averaged, i.e. conversions adc_dummy - 1 .. frames - 2.
    samples = fe.spike_train_codes(volts, drive, columns, frames)         # (S, m, frames)
    previous_result = adc.result
    used = samples[:, :, t.adc_dummy - 1:frames - 1]
    codes = (used.sum(axis=-1) + cfg.adc_averages // 2) // cfg.adc_averages
    saturated = used.max(axis=-1) >= cfg.adc_full_scale_code
    if bus.trace is not None:
        bus.trace.extend(_trace(writes, drive, columns, samples, previous_result, starts))

    # Device registers and counters, as the frames would leave them.
    for gi, w in enumerate(writes):
        count = int(np.count_nonzero(drive == gi))
        for r, _c in w:
            board.row_dacs[r // AD5328.CHANNELS].frames += 2 * count
    board.sr_col.frames += n_spikes * (m + 1)
    adc.frames += n_spikes * m * frames
    adc.conversions += n_spikes * m * frames
    adc.result = int(samples[-1, -1, -1]) & 0x3FFF
    adc._busy_until = float(clk[3])
    bus.transactions += total
    bus.bytes += int((4 * n_writes[drive]).sum()) + n_spikes * (m + 1 + 2 * m * frames)
    fe.circuit = IDLE
    return codes.tolist(), saturated


def _trace(writes, drive, columns, samples, previous_result, starts) -> list[SpiTransaction]:
    """The SPI transactions of the batch (only built while a trace is recorded)."""
    zero2 = bytes(2)
    col_bytes = [reg.col_select_byte(c, sum_path=True) for c in columns]
    out = []
    k = 0
    result = previous_result

    def add(cs, mosi, miso):
        nonlocal k
        out.append(SpiTransaction(float(starts[k]), cs, mosi, miso))
        k += 1

    for s, gi in enumerate(drive.tolist()):
        for r, c in writes[gi]:
            add(reg.CS_ROW_DAC[r // AD5328.CHANNELS], AD5328.data_word(r % AD5328.CHANNELS, c),
                zero2)
        shift = 0
        for ci, byte in enumerate(col_bytes):
            add(reg.CS_SR_COL, bytes((byte,)), bytes((shift,)))
            shift = byte
            for conversion in samples[s, ci].tolist():
                add(reg.CS_ADC, zero2, (result << 2).to_bytes(2, "big"))
                result = conversion & 0x3FFF
        add(reg.CS_SR_COL, b"\x00", bytes((shift,)))
        for r, _c in sorted(writes[gi]):
            add(reg.CS_ROW_DAC[r // AD5328.CHANNELS], AD5328.data_word(r % AD5328.CHANNELS, 0),
                zero2)
    return out


# An unreadable cache entry is compiled again instead of failing every run (the wrapper is
# plain Python around numba's cache loader; no compiled code depends on it).
from snan_hil.common.numba_cache import tolerate_damaged_cache  # noqa: E402

tolerate_damaged_cache(globals())
