"""Behaviour of the board's MCU firmware, written against the SPI bus of :class:`Board`.

Every operation sends the bytes the real chips expect (row DAC words, write-DAC words, 74HC595
bytes, 16-clock ADC frames) and waits the settling times, so its cost on the virtual clock and
its analog result follow from the device models. Safety interlocks are checked *before* any
byte is sent; a refused request changes nothing on the board:

* a read code above the read limit (``max_read_v``; ``max_cell_read_code`` on the write DAC
  for single-cell reads, ``max_row_read_code`` on the row DACs for driven rows)
  -> :class:`ReadVoltageRefused`
* a write amplitude above ``max_write_code`` (``max_write_v``) -> :class:`WriteAmplitudeRefused`
* a predicted pulse current above ``compliance_a`` -> :class:`ComplianceRefused`;
  the prediction uses the cell's last reading at a read voltage above 0 in integer
  arithmetic (:mod:`snan_hil.firmware_emu.compliance`), as the C firmware must (no FPU, no view
  of the true conductance); a cell not read so since boot is read first (a 0 V read, the
  calibration's offset read, carries no conductance: it is no basis, and would predict an
  unbounded current)
* rows, columns, codes, widths outside the board           -> :class:`OutOfRangeError`

The refusals are :class:`snan_hil.protocol.errors.BoardError` subclasses, which the protocol's
device endpoint turns into ERROR replies (code SAFETY_LIMIT or OUT_OF_RANGE, ``detail`` = the
offending value: a code, or the predicted current in uA).
"""

from __future__ import annotations

import logging
import random
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from snan_hil.firmware_emu import registers as reg
from snan_hil.firmware_emu import spike_fastpath
from snan_hil.firmware_emu.board import Board
from snan_hil.firmware_emu.compliance import ComplianceConstants
from snan_hil.firmware_emu.config import FIRMWARE_VERSION, BoardConfig, board_id_text
from snan_hil.firmware_emu.spike_group import SpikeGroupSpec
from snan_hil.firmware_emu.spi_devices import AD5328, TLC3541, WriteDac
from snan_hil.common.polarity import Polarity
from snan_hil.protocol.board import BoardConstants
from snan_hil.protocol.errors import OutOfRangeError, SafetyLimitError

log = logging.getLogger(__name__)

SET, RESET = Polarity.SET, Polarity.RESET

class ReadVoltageRefused(SafetyLimitError):
    """A read (or spike, or column-multiply) voltage above the read limit."""


class WriteAmplitudeRefused(SafetyLimitError):
    """A write-pulse amplitude above the configured maximum."""


class ComplianceRefused(SafetyLimitError):
    """A write pulse whose predicted current exceeds the compliance limit."""


@dataclass
class FirmwareCounters:
    """Firmware counters since boot/reset."""

    cell_reads: int = 0
    column_reads: int = 0
    pulses_requested: int = 0
    spikes_applied: int = 0
    saturated_reads: int = 0
    refusals: int = 0
    busy: int = 0


@dataclass(frozen=True)
class ProgramResult:
    """Outcome of :meth:`Firmware.program_cell`."""

    final_adc: int
    pulses_stage1: int
    pulses_stage2: int
    ok: bool


class Firmware:
    """The MCU's operations on one :class:`Board` (single-threaded, like the MCU)."""

    def __init__(self, board: Board, nonce_rng: random.Random | None = None, *,
                 fast: bool = True):
        self.board = board
        self.fast = bool(fast)
        """True: the ADC frames of a reading run as one batch (:meth:`SpiBus.transfer_many`);
        False: frame by frame (the reference path). Same bytes, times, energy and codes."""
        self.config: BoardConfig = board.config
        self.bus = board.bus
        self.clock = board.clock
        self._nonce_rng = nonce_rng or random.SystemRandom()
        self.chip_id: str | None = None
        """Serial of the chip on this board (the emulator's state file), reported in INFO
        after the board id: ``EMU-4D430001/<chip id>``; None: not reported."""
        self.boot_nonce = 0
        self.boots = 0
        self.counters = FirmwareCounters()
        self.last_saturated = False
        self._row_codes = [0] * self.config.rows
        self._wdac_code = 0
        self._sr_row = 0
        self._sr_col = 0
        self._compliance = ComplianceConstants.from_config(self.config)
        self._last_read: dict[tuple[int, int], tuple[int, int]] = {}
        """(row, col) -> (ADC code, read code) of the cell's last single-cell read at a read
        code above 0 (the compliance basis; a 0 V read leaves it unchanged)."""
        self.round_average = True
        """The reading is the rounded (True) or truncated (False: C integer division, as the
        existing firmware's driver computes it) mean of the averaged conversions."""
        self.boot()

    # ------------------------------------------------------------------ boot / reset
    def boot(self) -> int:
        """Power-on: chips to reset state, start-up configuration, new boot nonce."""
        self.board.power_cycle()
        self.clock.reset()
        self.counters = FirmwareCounters()
        self.board.front_end.pulses_applied = 0
        self._last_read = {}
        self._init_chips()
        self.boots += 1
        self.boot_nonce = self._new_nonce()
        log.info("boot #%d, nonce 0x%08x", self.boots, self.boot_nonce)
        return self.boot_nonce

    def reset(self) -> tuple[int, int]:
        """Soft reset: clock, energy and counters zeroed, chips re-initialised, new nonce.

        The array keeps its conductances. Returns (old nonce, new nonce).
        """
        old = self.boot_nonce
        return old, self.boot()

    def _new_nonce(self) -> int:
        while True:
            nonce = self._nonce_rng.getrandbits(32)
            if nonce and nonce != self.boot_nonce:
                return nonce

    def _init_chips(self) -> None:
        """Start-up sequence: for each row DAC a data+control reset, gain 1x / unbuffered /
        external 5 V reference, LDAC mode 'outputs follow each write'; the write DAC at code 0
        in normal mode; both shift registers cleared."""
        for cs in reg.CS_ROW_DAC:
            self.bus.transfer(cs, AD5328.control_word(0b11, 0x1000))   # data + control reset
            self.bus.transfer(cs, AD5328.control_word(0b00, 0x0000))   # gain/buffer/reference
            self.bus.transfer(cs, AD5328.control_word(0b01, 0b00))     # LDAC: continuous
        self.bus.transfer(reg.CS_WRITE_DAC, WriteDac.data_word(0))
        self.bus.transfer(reg.CS_SR_ROW, b"\x00")
        self.bus.transfer(reg.CS_SR_COL, b"\x00")
        self._row_codes = [0] * self.config.rows
        self._wdac_code = 0
        self._sr_row = self._sr_col = 0

    # ------------------------------------------------------------------ low-level drivers
    def _set_sr_row(self, value: int) -> None:
        if value != self._sr_row:
            self.bus.transfer(reg.CS_SR_ROW, bytes((value,)))
            self._sr_row = value

    def _set_sr_col(self, value: int) -> None:
        if value != self._sr_col:
            self.bus.transfer(reg.CS_SR_COL, bytes((value,)))
            self._sr_col = value

    def _set_wdac(self, code: int) -> None:
        if code != self._wdac_code:
            self.bus.transfer(reg.CS_WRITE_DAC, WriteDac.data_word(code))
            self._wdac_code = code

    def _set_row_codes(self, codes: dict[int, int]) -> int:
        """Write the row-DAC channels whose code changes; returns the number of writes."""
        writes = 0
        for row, code in codes.items():
            if self._row_codes[row] != code:
                self.bus.transfer(reg.CS_ROW_DAC[row // 8], AD5328.data_word(row % 8, code))
                self._row_codes[row] = code
                writes += 1
        return writes

    def _zero_rows(self) -> None:
        self._set_row_codes({r: 0 for r, c in enumerate(self._row_codes) if c})

    def _settle(self, us: float) -> None:
        self.clock.advance(us, "settle")

    def _adc_read(self) -> int:
        """One dummy conversion, then the rounded average of ``adc_averages`` conversions.

        Fast path: nothing changes on the board between the frames of one reading, so the bus
        runs them as one batch (the circuit is evaluated once, the per-sample read and ADC
        noise are drawn vectorised in the same order, the clock advances in one call); the
        bytes, frame times, energy and codes are those of :meth:`_adc_read_per_frame`.
        """
        if not self.fast:
            return self._adc_read_per_frame()
        t = self.config.timing
        n = self.config.adc_averages
        misos = self.bus.transfer_many(reg.CS_ADC, b"\x00\x00", t.adc_dummy + n)
        full = self.config.adc_full_scale_code
        # TLC3541.decode: (b0 << 6) | (b1 >> 2) == int.from_bytes((b0, b1), "big") >> 2
        codes = [int.from_bytes(m, "big") >> 2 for m in misos[t.adc_dummy:]]
        saturated = max(codes) >= full if codes else False
        self.last_saturated = saturated
        if saturated:
            self.counters.saturated_reads += 1
        return (sum(codes) + (n // 2 if self.round_average else 0)) // n

    def _adc_read_per_frame(self) -> int:
        """Reference path of :meth:`_adc_read`: one SPI transfer per ADC frame."""
        t = self.config.timing
        for _ in range(t.adc_dummy):
            self.bus.transfer(reg.CS_ADC, b"\x00\x00")
        total = 0
        saturated = False
        full = self.config.adc_full_scale_code
        n = self.config.adc_averages
        for _ in range(n):
            b0, b1 = self.bus.transfer(reg.CS_ADC, b"\x00\x00")
            code = TLC3541.decode(b0, b1)
            saturated |= code >= full
            total += code
        self.last_saturated = saturated
        if saturated:
            self.counters.saturated_reads += 1
        return (total + (n // 2 if self.round_average else 0)) // n

    def _idle(self) -> None:
        """Disconnect everything: word line off, multiplexers off, write bus at 0 V."""
        self._set_sr_col(0)
        self._set_sr_row(0)
        self._set_wdac(0)

    # ------------------------------------------------------------------ checks
    def _refuse(self, exc: Exception) -> None:
        self.counters.refusals += 1
        log.info("refused: %s", exc)
        raise exc

    def _check_cell(self, row: int, col: int) -> None:
        if not 0 <= row < self.config.rows:
            self._refuse(OutOfRangeError(f"row {row} outside 0..{self.config.rows - 1}",
                                         detail=row))
        if not 0 <= col < self.config.cols:
            self._refuse(OutOfRangeError(f"column {col} outside 0..{self.config.cols - 1}",
                                         detail=col))

    def _check_read_code(self, code: int) -> None:
        """A single-cell read code: a write-DAC code (the cell-read path is driven by the
        write DAC), at most ``max_cell_read_code``."""
        cfg = self.config
        self._check_dac_read_code(code, cfg.write_dac_full_scale_code, cfg.max_cell_read_code,
                                  cfg.write_dac_volts)

    def _check_row_code(self, code: int) -> None:
        """A driven row's code (READ_COLUMN, SPIKE_BATCH): a row-DAC code, at most
        ``max_row_read_code``."""
        cfg = self.config
        self._check_dac_read_code(code, cfg.dac_full_scale_code, cfg.max_row_read_code,
                                  cfg.dac_volts)

    def _check_dac_read_code(self, code: int, full_scale_code: int, max_code: int,
                             volts: Callable[[int], float]) -> None:
        """Refuse a read code outside ``0..full_scale_code`` (OUT_OF_RANGE) or above the read
        limit ``max_code`` (SAFETY_LIMIT); ``volts`` converts a code of that DAC to V."""
        if not 0 <= code <= full_scale_code:
            self._refuse(OutOfRangeError(f"DAC code {code} outside 0..{full_scale_code}",
                                         detail=max(code, 0)))
        if code > max_code:
            self._refuse(ReadVoltageRefused(
                f"read {volts(code):.3f} V (code {code}) > limit "
                f"{self.config.max_read_v} V (code {max_code})",
                detail=code))

    def _check_write(self, row: int, col: int, amp_code: int, width_us: float,
                     read_code: int) -> None:
        cfg = self.config
        if not 0 <= amp_code <= cfg.write_dac_full_scale_code:
            self._refuse(OutOfRangeError(
                f"amplitude code {amp_code} outside 0..{cfg.write_dac_full_scale_code}",
                detail=max(amp_code, 0)))
        if not 0 < width_us <= cfg.max_pulse_width_us:
            self._refuse(OutOfRangeError(
                f"pulse width {width_us} us outside 1..{cfg.max_pulse_width_us:.0f} us",
                detail=max(int(width_us), 0)))
        if amp_code > cfg.max_write_code:
            self._refuse(WriteAmplitudeRefused(
                f"write {cfg.write_dac_volts(amp_code):.3f} V (code {amp_code}) > limit "
                f"{cfg.max_write_v} V (code {cfg.max_write_code})", detail=amp_code))
        if (row, col) not in self._last_read:
            self._read_cell(row, col, read_code)        # no reading since boot: read first
        refused, current_ua = self._predict(row, col, amp_code)
        if refused:
            self._refuse(ComplianceRefused(
                f"{current_ua / 1e3:.2f} mA predicted at code {amp_code} on ({row},{col}) > "
                f"compliance {cfg.compliance_a * 1e3:.2f} mA", detail=current_ua))

    def _predict(self, row: int, col: int, amp_code: int) -> tuple[bool, int]:
        """(over the compliance?, predicted current in uA) from the cell's last reading."""
        adc, rc = self._last_read[(row, col)]
        return self._compliance.check(amp_code, adc, rc)

    def _read_code(self, read_code: int) -> int:
        return self.config.read_code if read_code == 0 else read_code

    # ------------------------------------------------------------------ operations
    def read_cell(self, row: int, col: int, vcode: int) -> int:
        """Read one cell at write-bus code ``vcode`` through the load resistor; ADC code."""
        self._check_cell(row, col)
        self._check_read_code(vcode)
        return self._read_cell(row, col, vcode)

    def _read_cell(self, row: int, col: int, vcode: int) -> int:
        self._set_sr_col(reg.col_select_byte(col))
        self._set_sr_row(reg.row_select_byte(row))
        self._set_wdac(vcode)
        self._settle(self.config.timing.dac_settle_us)
        adc = self._adc_read()
        self._idle()
        self.counters.cell_reads += 1
        if vcode:       # a 0 V read (the offset) says nothing about the cell's conductance:
            self._last_read[(row, col)] = (adc, vcode)   # the compliance basis stays as it was
        return adc

    def read_column(self, codes: Sequence[int], col: int) -> int:
        """Column multiply: row i at row-DAC code ``codes[i]``, column ``col`` summed; ADC code."""
        cfg = self.config
        self._check_cell(0, col)
        if len(codes) != cfg.rows:
            self._refuse(OutOfRangeError(f"{len(codes)} row codes for {cfg.rows} rows",
                                         detail=len(codes)))
        for code in codes:
            self._check_row_code(int(code))
        self._set_sr_col(0)
        self._set_sr_row(reg.ROWDAC_EN)
        self._set_row_codes({i: int(c) for i, c in enumerate(codes)})
        self._set_sr_col(reg.col_select_byte(col, sum_path=True))
        self._settle(max(cfg.timing.dac_settle_us, cfg.timing.frontend_settle_us))
        adc = self._adc_read()
        self._set_sr_col(0)
        self._zero_rows()
        self._set_sr_row(0)
        self.counters.column_reads += 1
        return adc

    def write_pulse(self, row: int, col: int, polarity: Polarity, amp_code: int,
                    width_us: float, read_code: int = 0) -> int:
        """One programming pulse (``SET`` raises G, ``RESET`` lowers it), then a read.

        Returns the ADC code of the read after the pulse (at ``read_code``, 0 = nominal).
        ``amp_code == 0`` applies no pulse (read only, like the legacy mode 7 with vol 0).
        """
        if polarity not in (SET, RESET):
            self._refuse(OutOfRangeError(f"polarity {polarity!r} is neither SET nor RESET"))
        self._check_cell(row, col)
        read_code = self._read_code(read_code)
        self._check_read_code(read_code)
        if amp_code:
            self._check_write(row, col, amp_code, width_us, read_code)
            self._pulse(row, col, polarity, amp_code, width_us)
        return self._read_cell(row, col, read_code)

    def _pulse(self, row: int, col: int, polarity: Polarity, amp_code: int,
               width_us: float) -> None:
        """Pulse sequence: amplitude on the write DAC with the word line closed, settle, select
        the row, open word line + pulse gate (pulse starts at that latch), wait, close (end)."""
        timing = self.config.timing
        self._set_sr_col(0)
        self._set_wdac(amp_code)
        self._set_sr_row(reg.row_select_byte(row))
        self._settle(timing.dac_settle_us)
        self._set_sr_col(reg.col_select_byte(col, set_polarity=polarity == SET, pulse=True))
        # The gate closes when the next register byte latches: wait the width minus the cost of
        # that transaction, so the latched pulse lasts width_us. A pulse shorter than one
        # transaction: the closing byte is shifted in while the gate is open and latched by one
        # chip-select edge at the end, as the C firmware's hal_pulse does for every width (the
        # gate lasts the width exactly; it lasted one transaction, 4.5 us, before: found by the
        # differential tester, issue 27). Width 0 (the legacy mode 7 only) stays the shortest
        # gate: one transaction.
        closing_cost = timing.mcu_overhead_us + self.clock.spi_bits_us(1)
        if 0 < width_us < closing_cost:
            self.clock.advance(width_us, "pulse")
            self.bus.latch(reg.CS_SR_COL, b"\x00")
            self._sr_col = 0
        else:
            self.clock.advance(max(width_us - closing_cost, 0.0), "pulse")
            self._set_sr_col(0)
        self._set_wdac(0)
        self.counters.pulses_requested += 1

    def spike_batch(self, groups: Sequence[SpikeGroupSpec], columns: Sequence[int],
                    n_bins: int, bin_us: int, paced: bool = False) -> list[list[int]]:
        """Apply the spikes of a window; per spike (bin order, then group order) the ADC codes
        of ``columns``. For each spike: the group's row DACs to their codes, settle, then per
        column: word line + summing path, settle, ADC read; then word line off and rows to 0.
        ``paced``: wait for each bin's start (``bin * bin_us`` after the batch start)."""
        cfg = self.config
        # docs/protocol.md, SPIKE_BATCH: the checks in this order, before anything is driven
        if n_bins < 1:
            self._refuse(OutOfRangeError("n_bins 0: a window has at least one bin", detail=0))
        if paced and bin_us < 1:
            self._refuse(OutOfRangeError("bin_us 0 with paced: bins need a width", detail=0))
        for c in columns:
            self._check_cell(0, c)
        if len(set(columns)) != len(columns):
            self._refuse(OutOfRangeError("duplicate column in spike batch"))
        for gi, g in enumerate(groups):
            if not g.rows:
                self._refuse(OutOfRangeError(f"group {gi} drives no row", detail=gi))
            seen: set[int] = set()
            for row, code in g.rows:
                self._check_cell(row, 0)
                if row in seen:
                    self._refuse(OutOfRangeError(f"row {row} repeated in group {gi}",
                                                 detail=row))
                seen.add(row)
                self._check_row_code(code)
            for b in g.bins:
                if not 0 <= b < n_bins:
                    self._refuse(OutOfRangeError(f"spike bin {b} outside 0..{n_bins - 1}",
                                                 detail=max(b, 0)))
        t0 = self.clock.now_us
        out: list[list[int]] = []
        self._set_sr_col(0)
        self._set_sr_row(reg.ROWDAC_EN)
        settle = max(cfg.timing.dac_settle_us, cfg.timing.frontend_settle_us)
        if self.fast and self._in_batch_state() and \
                spike_fastpath.applicable(self.board, columns):
            # Emulator-side shortcut, not MCU behaviour: all spikes in one pass, the same
            # bytes, clock, energy, draws and codes as the loop below (spike_fastpath).
            out, saturated = spike_fastpath.run_spike_batch(self.board, groups, columns, settle,
                                                            t0 if paced else None, bin_us)
            self._count_batch(saturated)
        else:
            order = sorted((b, gi) for gi, g in enumerate(groups) for b in g.bins)
            for b, gi in order:
                if paced:
                    self.clock.wait_until(t0 + b * bin_us, "idle")
                out.append(self._spike(groups[gi], columns, settle))
        self._set_sr_row(0)
        return out

    def _in_batch_state(self) -> bool:
        """The firmware's side of the fast path's steady state (the board's side:
        :func:`spike_fastpath.applicable`): row codes at 0, column register 0, row register
        with the row DACs enabled."""
        return not any(self._row_codes) and self._sr_col == 0 and self._sr_row == reg.ROWDAC_EN

    def _count_batch(self, saturated: NDArray[np.bool_]) -> None:
        """The counters after a fast-path batch, as :meth:`_spike` and :meth:`_adc_read` count
        them; ``saturated``: (spikes, columns) bool, True where a reading saturated the ADC."""
        if not saturated.size:
            return
        counters = self.counters
        counters.spikes_applied += saturated.shape[0]
        counters.column_reads += saturated.size
        counters.saturated_reads += int(saturated.sum())
        self.last_saturated = bool(saturated[-1, -1])

    def _spike(self, group: SpikeGroupSpec, columns: Sequence[int], settle: float) -> list[int]:
        self._set_row_codes(dict(group.rows))
        self._settle(self.config.timing.dac_settle_us)
        codes = []
        for col in columns:
            self._set_sr_col(reg.col_select_byte(col, sum_path=True))
            self._settle(settle)
            codes.append(self._adc_read())
        self._set_sr_col(0)
        self._zero_rows()
        self.counters.spikes_applied += 1
        self.counters.column_reads += len(columns)
        return codes

    def program_cell(self, row: int, col: int, target_adc: int, tolerance_adc: int,
                     max_pulses: int, amp_start_code: int, amp_stop_code: int,
                     amp_step_code: int, width_us: float, read_code: int = 0,
                     fine_tune: bool = True) -> ProgramResult:
        """Write-and-verify towards an ADC-code target (the paper's two-stage method).

        Stage 1: read; while outside ``target +- tolerance``: a pulse (SET below the target,
        RESET above), amplitude ramping from start to stop by step (restarting when the
        direction flips), a read after each. Stage 2 (``fine_tune``): RESET ramp until the code
        is <= target, then SET ramp until >= target. Pulses whose predicted current exceeds
        the compliance (predicted from the latest reading) are not applied (the ramp holds its
        amplitude; a ramp that cannot start ends the stage). At most ``max_pulses`` pulses in
        all. Amplitude codes of 0 mean the host software's ticket defaults (``PROGRAM_RAMP_V``).
        """
        cfg = self.config
        self._check_cell(row, col)
        read_code = self._read_code(read_code)
        self._check_read_code(read_code)
        ramp_start, ramp_stop, ramp_step = cfg.program_ramp_codes()
        amp_start_code = amp_start_code or ramp_start
        amp_stop_code = amp_stop_code or ramp_stop
        amp_step_code = amp_step_code or ramp_step
        if not 1 <= max_pulses <= cfg.max_program_pulses:
            self._refuse(OutOfRangeError(
                f"max_pulses {max_pulses} outside 1..{cfg.max_program_pulses}", detail=max_pulses))
        if not 0 <= target_adc <= cfg.adc_full_scale_code or tolerance_adc < 0:
            self._refuse(OutOfRangeError(f"target {target_adc} +- {tolerance_adc} outside the "
                                         f"ADC range", detail=max(target_adc, 0)))
        if not 1 <= amp_start_code <= amp_stop_code or amp_step_code < 1:
            self._refuse(OutOfRangeError(
                f"ramp {amp_start_code}..{amp_stop_code} step {amp_step_code} invalid",
                detail=max(amp_start_code, 0)))
        if amp_stop_code > cfg.max_write_code:
            self._refuse(WriteAmplitudeRefused(
                f"ramp end {cfg.write_dac_volts(amp_stop_code):.3f} V (code {amp_stop_code}) > "
                f"limit {cfg.max_write_v} V", detail=amp_stop_code))
        if not 0 < width_us <= cfg.max_pulse_width_us:
            self._refuse(OutOfRangeError(f"pulse width {width_us} us out of range",
                                         detail=max(int(width_us), 0)))

        budget = [max_pulses]

        def over_compliance(amp: int) -> bool:
            return self._predict(row, col, amp)[0]      # from the latest read of the cell

        def ramp(adc: int, polarity: Polarity, done: Callable[[int], bool]) -> tuple[int, int]:
            """Pulses of one polarity with a rising amplitude until ``done(adc)``."""
            amp, cap, used = amp_start_code, amp_stop_code, 0
            while not done(adc) and budget[0] > 0:
                while amp >= amp_start_code and over_compliance(amp):
                    cap = amp = amp - amp_step_code      # hold the ramp below the limit
                if amp < amp_start_code:
                    break
                self._pulse(row, col, polarity, amp, width_us)
                adc = self._read_cell(row, col, read_code)
                used += 1
                budget[0] -= 1
                amp = min(amp + amp_step_code, cap)
            return adc, used

        adc = self._read_cell(row, col, read_code)
        in_window = lambda a: abs(a - target_adc) <= tolerance_adc  # noqa: E731
        stage1 = 0
        while not in_window(adc) and budget[0] > 0:
            polarity = SET if adc < target_adc else RESET
            before = budget[0]
            def done(a: int, p: Polarity = polarity) -> bool:
                return in_window(a) or (a > target_adc if p == SET else a < target_adc)

            adc, used = ramp(adc, polarity, done)
            stage1 += used
            if budget[0] == before:
                break                           # nothing could be applied
        stage2 = 0
        if fine_tune and in_window(adc):
            adc, used = ramp(adc, RESET, lambda a: a <= target_adc)
            stage2 += used
            adc, used = ramp(adc, SET, lambda a: a >= target_adc)
            stage2 += used
        return ProgramResult(adc, stage1, stage2, in_window(adc))

    # ------------------------------------------------------------------ status
    def info(self) -> dict[str, Any]:
        """Board description: the board's constants (BoardConstants fields) plus the firmware
        version, board id and boot nonce (keys follow the protocol's Info message). The board
        id names the chip too when it is known: ``EMU-4D430001/<chip id>`` (docs/protocol.md,
        "Board identity")."""
        cfg = self.config
        constants = {name: getattr(cfg, name) for name in BoardConstants.__dataclass_fields__}
        board_id = board_id_text(cfg.board_id, self.chip_id)
        return {**constants,
                "firmware_version": "memricore-emu " + ".".join(map(str, FIRMWARE_VERSION)),
                "board_id": board_id, "boot_nonce": self.boot_nonce}

    def status(self) -> dict[str, int]:
        """Firmware counters (names follow the protocol's Status reply where they exist)."""
        c = self.counters
        return {"cell_reads": c.cell_reads, "column_reads": c.column_reads,
                "pulses_applied": self.board.front_end.pulses_applied,
                "spikes_applied": c.spikes_applied, "busy": c.busy,
                "saturated_reads": c.saturated_reads, "refusals": c.refusals}

    def clock_reading(self) -> tuple[float, float]:
        """(virtual time in us, array energy in J) since boot/reset."""
        return self.clock.now_us, self.clock.energy_j
