"""DECISION_WINDOW on the emulated MCU: one decision window on the board (issue 23).

The request (``snan_hil.protocol.messages.DecisionWindow``, byte layout in docs/protocol.md
"0x0A DECISION_WINDOW") names the input neuron's rows, the candidate motor neurons' cells
and their interneuron spike trains, and the host's spike-stream state. The board

1. refuses, before anything is driven, what it cannot run (the checks below, in order);
2. draws the window's input spikes from the stream state, as the host does
   (:func:`~snan_hil.firmware_emu.lif_fixed.spike_steps`);
3. per input spike drives each row alone at the parameter block's row code and reads the
   union of the candidates' columns, ascending — exactly the SPI sequence of a SPIKE_BATCH
   with one group per row (:meth:`Firmware.spike_batch`, so the two modes see the same
   reads on the same chip);
4. turns each candidate's read into its drive and integrates the candidates' LIF motor
   neurons event by event in fixed point (:mod:`snan_hil.firmware_emu.lif_fixed`), with each
   interneuron spike subtracting the inhibition;
5. answers the spike count per candidate, and on request every motor spike and the potential
   trace.

The parameter block travels with the first window of a session (flag PARAMS) and is kept
until HELLO, RESET or a power cycle (:meth:`DecisionWindowOp.clear`). The C firmware
(``firmware/src/window.c``) does the same operations in the same order, streaming (no buffer
of reads): the conformance vectors ``conformance/v1/framed/decision_window.jsonl`` check both.

Checks (ERROR OUT_OF_RANGE unless said; ``detail`` in brackets):

* no parameter block in the request and none stored [0];
* a new block, field by field: ``n_bins`` 1..16384 [n_bins]; ``row_code`` 1..full scale
  [code] and at most the row DAC's read limit (SAFETY_LIMIT [code]); ``num_shift`` <= 17,
  ``den_shift`` <= 62, ``q_shift`` <= 31, ``spike_threshold`` <= 2^53, ``0 < thr`` <= 2^56,
  ``|reset|`` <= 2^56 and ``reset < thr``, ``0 <= inh`` <= 2^56, ``0 <= offset < 2^46``,
  ``d`` (the conversion's bounds at the ADC's full scale: the denominator fits 32 bits, stays
  >= 1 and the quotient < 2^32), ``0 <= k1`` <= 2^56, ``|k0|`` <= 2^56 [the field's byte
  offset in the block: 9, 10, 11, 12, 148, 156, 164, 172, 180, 188, 196];
* PACED with ``bin_us`` 0 [2];
* more than 4 rows [n]; a row outside the array or repeated [row];
* more than 4 candidates [n]; a column outside the array [col]; a row index beyond the rows
  [index]; an interneuron spike at or after ``n_bins`` [its step];
* a reply (worst case: every lane spiking as often as refractoriness allows) above the max
  payload [its size].
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

from snan_hil.firmware_emu import lif_fixed as fx
from snan_hil.firmware_emu import window_noise
from snan_hil.firmware_emu.spike_group import SpikeGroupSpec
from snan_hil.firmware_emu.window_reads import run_lean
from snan_hil.protocol import messages as m
from snan_hil.protocol.errors import OutOfRangeError

if TYPE_CHECKING:                                  # pragma: no cover - typing only
    from snan_hil.firmware_emu.firmware import Firmware

log = logging.getLogger(__name__)

MAX_THRESHOLD = 1 << 53
"""Largest spike threshold (p = 1: every step spikes)."""
OFFSET_LIMIT = 1 << 46
"""Q32.32 offsets below 2^14 codes (the 14-bit ADC)."""

MCU_US_PER_STEP = 1.317
"""MCU time of one step's input-spike draw (``next_spike``: two 64-bit multiplications by
constants), us."""
MCU_US_PER_LANE_SPIKE = 8.193
"""MCU time of one candidate's input-spike event: the read's code -> drive conversion (the
64-by-32-bit division) and the LIF update (the Q0.64 decay, saturation, threshold), us."""
MCU_US_PER_INHIBITION = 7.887
"""MCU time of one interneuron spike (decoding its gap, the LIF update, the lane's next
event), us."""
MCU_US_PER_READ = -0.426
"""The firmware's time of one column read of the standard plan minus the Python MCU's SPI
model of it (whose 4 us a transaction is the paper board's, calibrated to its 700 us a spike:
this firmware's drivers are faster), us."""
MCU_US_PER_ROW_SPIKE = -4.908
"""The same for a row driven at an input spike (its two row-DAC words and settling), us.

The five are the C firmware's own time (``firmware/src/window.c`` in the emulator's ISA MCU:
32 MHz, one instruction a cycle - a lower bound on the real SCR1 core, whose divider and flash
wait states are slower) of the standard read plan, fitted by least squares to the firmware's
board clock minus the Python MCU's SPIKE_BATCH time of the same reads over 60 random
300/1000-step windows (1-2 rows, 1-4 candidates, p = 0.15 and 0.3, 0/5/20/60 interneuron
spikes a candidate; ``bench/fit_window_costs.py``, residual 95 us rms on windows of 12-180 ms
of reads). The Python MCU advances its clock by them at the end of a window, so both MCUs
report comparable board times (``tests/firmware/test_decision_window.py``). The lean plan
times each step instead (:mod:`~snan_hil.firmware_emu.window_reads`)."""
MCU_US_PER_PARAMS = 243.3
"""MCU time of a window's parameter block: parsed (twice: checked, then stored) and checked
(the alpha table, the conversion's ranges), us; fitted like the others
(``bench/fit_window_costs.py``, from windows without candidates with and without the block)."""

#: byte offsets of the parameter block's fields (the ``detail`` of their refusals)
FIELD_OFFSET = {"n_bins": 0, "bin_us": 2, "row_code": 4, "ref_steps": 6, "lif_flags": 8,
                "num_shift": 9, "den_shift": 10, "q_shift": 11, "spike_threshold": 12,
                "alpha_pow": 20, "thr": 148, "reset": 156, "inh": 164, "offset": 172, "d": 180,
                "k1": 188, "k0": 196, "conversions": 204}


def worst_reply_size(req: m.DecisionWindow, p: m.DecisionParams) -> int:
    """Reply payload bytes if every lane spiked as often as refractoriness allows."""
    n = len(req.candidates)
    points = (p.n_bins + req.trace_stride - 1) // req.trace_stride if req.trace_stride else 0
    per_lane = (p.n_bins + p.ref_steps) // (p.ref_steps + 1)
    return m.decision_reply_size(n, trace_points=points,
                                 max_motor_spikes=n * per_lane if req.motor_spikes else None)


class DecisionWindowOp:
    """The board's DECISION_WINDOW operation and its stored parameter block."""

    def __init__(self) -> None:
        self.params: m.DecisionParams | None = None
        self.windows = 0
        self.last_pre: list[int] = []
        """The last window's input spike steps (on-board learning pairs them)."""
        self.last_post: list[tuple[int, int]] = []
        """The last window's motor spikes (step, lane), in time order."""

    def clear(self) -> None:
        """Forget the parameter block (HELLO, RESET, power-on)."""
        self.params = None

    # ------------------------------------------------------------------ checks
    def _check_params(self, fw: "Firmware", p: m.DecisionParams) -> None:
        cfg = fw.config

        def bad(field: str, what: str) -> None:
            fw._refuse(OutOfRangeError(f"DECISION_WINDOW parameter {field}: {what}",
                                       detail=FIELD_OFFSET[field]))

        if not 1 <= p.n_bins <= m.DW_MAX_BINS:
            fw._refuse(OutOfRangeError(f"n_bins {p.n_bins} outside 1..{m.DW_MAX_BINS}",
                                       detail=p.n_bins))
        if p.row_code == 0:
            fw._refuse(OutOfRangeError("row code 0: the rows would not be driven", detail=0))
        fw._check_row_code(p.row_code)
        if p.num_shift > 17:
            bad("num_shift", f"{p.num_shift} > 17")
        if p.den_shift > 62:
            bad("den_shift", f"{p.den_shift} > 62")
        if p.q_shift > 31:
            bad("q_shift", f"{p.q_shift} > 31")
        if p.spike_threshold > MAX_THRESHOLD:
            bad("spike_threshold", "above 2^53")
        lim = m.DW_FIELD_LIMIT
        if not 0 < p.thr <= lim:
            bad("thr", "outside 1..2^56 (the threshold must lie above the resting potential)")
        if abs(p.reset) > lim or p.reset >= p.thr:
            bad("reset", "magnitude above 2^56, or not below the threshold")
        if not 0 <= p.inh <= lim:
            bad("inh", "outside 0..2^56")
        if not 0 <= p.offset < OFFSET_LIMIT:
            bad("offset", "outside 0..2^46")
        if not m.decision_conversion_fits(p, cfg.adc_full_scale_code):
            bad("d", "the code -> drive division leaves its range at the ADC's full scale")
        if not 0 <= p.k1 <= lim:
            bad("k1", "outside 0..2^56")
        if abs(p.k0) > lim:
            bad("k0", "magnitude above 2^56")

    def check(self, fw: "Firmware", req: m.DecisionWindow) -> m.DecisionParams:
        """Every check of the module doc, in order; the parameter block to run with."""
        p = req.params if req.params is not None else self.params
        if p is None:
            fw._refuse(OutOfRangeError("no DECISION_WINDOW parameters stored: send them with "
                                       "the window (flag PARAMS)", detail=0))
        assert p is not None
        if req.params is not None:
            fw.clock.advance(MCU_US_PER_PARAMS, "mcu")
            self._check_params(fw, p)
            if p.conversions and not 1 <= p.conversions <= fw.config.adc_averages:
                fw._refuse(OutOfRangeError(f"DECISION_WINDOW parameter conversions: "
                                           f"{p.conversions} outside "
                                           f"1..{fw.config.adc_averages}",
                                           detail=FIELD_OFFSET["conversions"]))
        if req.paced and p.bin_us == 0:
            fw._refuse(OutOfRangeError("bin_us 0 with PACED: bins need a width",
                                       detail=FIELD_OFFSET["bin_us"]))
        if len(req.rows) > m.DW_MAX_ROWS:
            fw._refuse(OutOfRangeError(f"{len(req.rows)} rows, at most {m.DW_MAX_ROWS}",
                                       detail=len(req.rows)))
        for i, row in enumerate(req.rows):
            fw._check_cell(row, 0)
            if row in req.rows[:i]:
                fw._refuse(OutOfRangeError(f"row {row} named twice", detail=row))
        if len(req.candidates) > m.DW_MAX_CANDIDATES:
            fw._refuse(OutOfRangeError(f"{len(req.candidates)} candidates, at most "
                                       f"{m.DW_MAX_CANDIDATES}", detail=len(req.candidates)))
        for c in req.candidates:
            fw._check_cell(0, c.col)
            if c.row_index >= len(req.rows):
                fw._refuse(OutOfRangeError(f"candidate row index {c.row_index} beyond the "
                                           f"{len(req.rows)} rows", detail=c.row_index))
            for t in c.inh:
                if t >= p.n_bins:
                    fw._refuse(OutOfRangeError(f"interneuron spike at step {t} >= n_bins "
                                               f"{p.n_bins}", detail=t))
        size = worst_reply_size(req, p)
        if size > m.MAX_PAYLOAD:
            fw._refuse(OutOfRangeError(f"the reply could be {size} bytes, more than the "
                                       f"{m.MAX_PAYLOAD}-byte payload limit; trace with a larger "
                                       "stride or without motor spikes", detail=size))
        return p

    # ------------------------------------------------------------------ the window
    def run(self, fw: "Firmware", req: m.DecisionWindow, keep_post: bool = False
            ) -> m.DecisionWindowReply:
        """Check, then run the window (module doc); the reply. The lean read plan's reads
        draw their noise keyed by the window (:mod:`~snan_hil.firmware_emu.window_noise`), the
        standard reads from the chip's running streams (as SPIKE_BATCH: the batch mode's).
        ``keep_post``: keep the window's input and motor spike steps (``last_pre``,
        ``last_post``) for on-board learning (:mod:`~snan_hil.firmware_emu.learn_op`)."""
        p = self.check(fw, req)
        self.params = p
        self.windows += 1
        bins = fx.spike_steps(req.key, p.n_bins, p.spike_threshold)
        lanes = len(req.candidates)
        spiking = np.zeros(p.n_bins, dtype=np.bool_)
        spiking[bins] = True
        drive = np.zeros((p.n_bins, lanes), dtype=np.int64)
        inhibited = np.zeros((p.n_bins, lanes), dtype=np.bool_)
        for k, c in enumerate(req.candidates):
            inhibited[list(c.inh), k] = True
        if p.conversions:
            with window_noise.keyed(fw.board, req.key):
                drive[bins] = run_lean(fw, req, p, bins)
            return self._integrate(req, p, spiking, drive, inhibited, bins, keep_post)
        columns = req.union_columns()
        if bins.size and req.rows:
            b = tuple(int(x) for x in bins)
            groups = [SpikeGroupSpec(((int(r), p.row_code),), b) for r in req.rows]
            codes = fw.spike_batch(groups, columns, p.n_bins, p.bin_us, req.paced)
            if lanes:
                # spike order: by bin, then row; codes[i * n_rows + g][column index]
                arr = np.asarray(codes, dtype=np.int64).reshape(bins.size, len(req.rows),
                                                                len(columns))
                for k, c in enumerate(req.candidates):
                    drive[bins, k] = fx.drives(arr[:, c.row_index, columns.index(c.col)],
                                               p.offset, p.d, p.num_shift, p.den_shift,
                                               p.q_shift, p.k1, p.k0)
        row_spikes = bins.size * len(req.rows)
        fw.clock.advance(MCU_US_PER_STEP * p.n_bins + MCU_US_PER_LANE_SPIKE * lanes * bins.size
                         + MCU_US_PER_INHIBITION * sum(len(c.inh) for c in req.candidates)
                         + MCU_US_PER_READ * row_spikes * len(columns)
                         + MCU_US_PER_ROW_SPIKE * row_spikes, "mcu")
        return self._integrate(req, p, spiking, drive, inhibited, bins, keep_post)

    def _integrate(self, req: m.DecisionWindow, p: m.DecisionParams, spiking: np.ndarray,
                   drive: np.ndarray, inhibited: np.ndarray, bins: np.ndarray,
                   keep_post: bool) -> m.DecisionWindowReply:
        """The motor neurons of the window on its drives (lif_fixed.integrate); the reply."""
        counts, spikes, trace = fx.integrate(p.n_bins, spiking, drive, inhibited, p.alpha_pow,
                                             p.thr,
                                             p.reset, p.inh, p.ref_steps, p.integrate,
                                             req.trace_stride)
        if keep_post:
            self.last_pre = [int(x) for x in bins]
            self.last_post = [(int(t), int(k)) for t, k in spikes]
        n_in = int(bins.size)
        return m.DecisionWindowReply(
            n_in, tuple(int(x) for x in counts),
            tuple((int(t), int(k)) for t, k in spikes) if req.motor_spikes else None,
            tuple(tuple(int(v) for v in point) for point in trace) if req.trace_stride
            else None)
