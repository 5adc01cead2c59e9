"""The 32x8 1T1R YSZ crossbar of the MemriCore chip.

Rows are bit lines (driven by the row DACs), columns are word lines (3.3 V opens the select
transistors of one column). A cell is read as the current through memristor + transistor
(+ external series resistance); a column is read as the sum of its cells' currents into a
virtual-ground summing node (multiply-accumulate). Pulses change one cell.

Randomness: one seed -> a SeedSequence split into an initialisation stream (device-to-device
spread, stuck cells, initial states, drift exponents — realised once and stored) and a runtime
stream (programming and read noise). :meth:`save`/:meth:`load` keep both the realised chip and
the runtime stream, so a loaded chip continues exactly where the saved one stopped.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from snan_hil.files.atomicio import atomic_path
from snan_hil.crossbar_model import noise
from snan_hil.crossbar_model.config import ArrayConfig
from snan_hil.crossbar_model.device import (
    POLARITIES,
    CellParams,
    conductance_of_state,
    pulse_response,
    sample_cells,
    series_current,
    state_of_conductance,
)
from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity

_FORMAT = "snan-hil-crossbar/1"
CHIP_STATE_FORMAT = _FORMAT     #: the ``format`` member of a saved chip (:meth:`CrossbarArray.save`)


class ChipStateError(UserError):
    """A saved chip-state file cannot be read. ``reason`` is the message without advice;
    ``ours``: the file carries this project's chip-state format marker (a damaged chip), else
    it may be anyone's file (another format, not an npz, unreadable) and must not be
    suggested for overwriting."""

    ADVICE = "delete it or save a new one"

    def __init__(self, reason: str, *, ours: bool = False):
        super().__init__(f"{reason}; {self.ADVICE}")
        self.reason = reason
        self.ours = ours


def _unreadable(path: str, exc: BaseException) -> str:
    """Why ``np.load`` failed on ``path``, in one line."""
    if isinstance(exc, OSError) and exc.strerror:
        return f"cannot read chip state {path}: {exc.strerror}"
    try:
        with open(path, "rb") as fh:
            head = fh.read(4)
    except OSError:
        head = b""
    if not head:
        return f"chip state {path} is empty"
    if head.startswith(b"PK"):
        return f"chip state {path} is a damaged or truncated npz file ({type(exc).__name__})"
    return f"chip state {path} is not an npz file"


def _sample_endurance(config: ArrayConfig, shape: tuple[int, int],
                      seed: np.random.SeedSequence) -> np.ndarray:
    """Per-cell endurance (full-window cycles): log-normal around ``wear.endurance_cycles``,
    drawn from its own stream (so the other streams are those of a chip without wear)."""
    w = config.wear
    rng = np.random.Generator(np.random.PCG64(seed))
    return w.endurance_cycles * np.exp(w.endurance_sigma_log * rng.standard_normal(shape))


class CrossbarArray:
    """Emulated 1T1R crossbar. Units: V, A, S, Ohm, s. Indexing: ``[row, col]`` = [bit line, word line]."""

    rows: int
    cols: int
    stuck_mask: np.ndarray
    revision: int
    """Counts changes of the conductances (pulses, set_conductance, drift, load): callers may
    cache values derived from them (e.g. :meth:`effective_conductance`) while it is unchanged."""

    def __init__(self, config: ArrayConfig | None = None, seed: int = 0) -> None:
        self.config = config if config is not None else ArrayConfig.default()
        self.seed = int(seed)
        self.rows = self.config.rows
        self.cols = self.config.cols
        shape = (self.rows, self.cols)
        # the third child (wear) leaves the first two as they were before wear was modelled
        init_ss, run_ss, wear_ss = np.random.SeedSequence(self.seed).spawn(3)
        init = np.random.Generator(np.random.PCG64(init_ss))
        self._rng = np.random.Generator(np.random.PCG64(run_ss))
        c = self.config
        self.cells: CellParams = sample_cells(c, init)
        ist = c.initial_state
        self.state = np.clip(ist.mean + ist.sigma * init.standard_normal(shape), 0.0, 1.0)
        n_cells = self.rows * self.cols
        n_stuck = int(round(c.stuck.fraction * n_cells))
        mask = np.zeros(n_cells, dtype=bool)
        mask[init.choice(n_cells, size=n_stuck, replace=False)] = True
        self.stuck_mask = mask.reshape(shape)
        high = init.random(shape) < c.stuck.high_fraction
        g_high = c.stuck.g_high_s * np.exp(c.variability.g_max_sigma_log * init.standard_normal(shape))
        g_low = c.stuck.g_low_s * np.exp(c.variability.g_min_sigma_log * init.standard_normal(shape))
        self.stuck_high = high & self.stuck_mask
        self.stuck_g = np.where(high, g_high, g_low)
        self.drift_nu = noise.sample_drift_nu(c.drift, shape, init)
        self.broken = np.zeros(shape, dtype=bool)
        """Cells destroyed by a pulse above the breakdown voltage (now stuck shorted)."""
        self.endurance = _sample_endurance(c, shape, wear_ss)
        """Per-cell endurance (full-window cycles, ``wear`` config section)."""
        self.wear = np.zeros(shape)
        """Per-cell wear: full-window swings so far, sum |ds| / 2 over switching pulses."""
        self.worn = np.zeros(shape, dtype=bool)
        """Cells worn out (wear >= endurance): stuck at the conductance they had."""
        self.t_prog = np.zeros(shape)
        self.time_s = 0.0
        self.meta: dict = {}
        """Caller's data saved with the chip (:meth:`save`'s ``meta``), e.g. the emulator's."""
        self._setup()

    # --- internal caches -------------------------------------------------------------------
    def _setup(self) -> None:
        self.changed_cells: set[tuple[int, int]] = set()
        """Cells whose state a pulse or :meth:`set_conductance` changed, for a caller that
        records changes (the emulator's journal takes and clears it)."""
        t = self.config.transistor
        self._r_mac = t.on_resistance_ohm + t.mac_row_series_ohm
        self._r_write = t.on_resistance_ohm + t.write_series_ohm
        self._i_sat = t.saturation_current_a
        rn = self.config.read_noise
        self._read_noisy = rn.relative_sigma > 0 or rn.absolute_sigma_s > 0
        self._drifting = bool(np.any(self.drift_nu > 0))
        self._g_lo, self._g_hi = self._worn_bounds(self.wear)
        self._refresh()

    def _worn_bounds(self, wear: np.ndarray, index=slice(None)) -> tuple[np.ndarray, np.ndarray]:
        """Device bounds (S) of cells ``index`` after ``wear``: the log-window closes towards
        its geometric middle by ``window_closure * min(wear / endurance, 1)``."""
        g_min, g_max = self.cells.g_min[index], self.cells.g_max[index]
        f = np.minimum(np.asarray(wear) / self.endurance[index], 1.0)
        if not np.any(f > 0):
            return np.array(g_min, dtype=float), np.array(g_max, dtype=float)
        closing = self.config.wear.window_closure * f / 2.0
        log_ratio = np.log(g_max / g_min)
        return g_min * np.exp(closing * log_ratio), g_max * np.exp(-closing * log_ratio)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(g_min, g_max) (rows, cols) of every cell now (S): its drawn bounds, narrowed by its
        wear (:attr:`wear`)."""
        return self._g_lo.copy(), self._g_hi.copy()

    def _refresh(self) -> None:
        g = conductance_of_state(self.state, self._g_lo, self._g_hi)
        if self._drifting:
            g = g * noise.drift_factor(self.config.drift, self.drift_nu, self.time_s - self.t_prog)
        g = np.where(self.stuck_mask, self.stuck_g, g)
        self._g = g
        self._g_cols = np.ascontiguousarray(g.T)
        self.revision = getattr(self, "revision", 0) + 1

    def _check_cell(self, row: int, col: int) -> None:
        if not (0 <= row < self.rows and 0 <= col < self.cols):
            raise IndexError(f"cell ({row}, {col}) outside the {self.rows}x{self.cols} array")

    # --- noiseless views ------------------------------------------------------------------
    def conductance(self) -> np.ndarray:
        """(rows, cols) true memristor conductance (S), no noise (drift and stuck cells included)."""
        return self._g.copy()

    def resistance(self) -> np.ndarray:
        """(rows, cols) true memristor resistance (Ohm)."""
        return 1.0 / self._g

    def effective_conductance(self, series_ohm: float | None = None) -> np.ndarray:
        """(rows, cols) conductance of memristor + transistor + series_ohm (S), no noise.

        ``None`` uses the column-read path (transistor + ``mac_row_series_ohm``), i.e. the G_eff
        that :meth:`column_current` multiplies by the row voltages.
        """
        r = self._r_mac if series_ohm is None else self.config.transistor.on_resistance_ohm + series_ohm
        return self._g / (1.0 + self._g * r)

    def usable_range(self) -> tuple[float, float]:
        """(min, max) conductance (S) that calibration may target on this chip model."""
        c = self.config.conductance
        return c.usable_min_s, c.usable_max_s

    # --- random stream ---------------------------------------------------------------------
    def rng_state(self) -> Mapping[str, Any]:
        """State of the array's random stream (read and programming noise), to return to with
        :meth:`set_rng_state` (the emulator's MCU draws ADC samples ahead and returns unused
        draws)."""
        return self._rng.bit_generator.state

    def set_rng_state(self, state: Mapping[str, Any]) -> None:
        """Return the random stream to a state from :meth:`rng_state`."""
        self._rng.bit_generator.state = state

    # --- reads -------------------------------------------------------------------------------
    def cell_current(self, row: int, col: int, volts: float, series_ohm: float) -> float:
        """Current (A) of one cell at ``volts`` on its bit line, word line open, in series with the
        transistor and ``series_ohm`` (Ohm). One read: includes read noise. Never changes state."""
        self._check_cell(row, col)
        if not (math.isfinite(volts) and math.isfinite(series_ohm) and series_ohm >= 0):
            raise ValueError(f"cell_current needs finite volts and series_ohm >= 0, got {volts}, {series_ohm}")
        g = float(self._g[row, col])
        if self._read_noisy:
            g = noise.read_conductance_scalar(self.config.read_noise, g, self._rng)
        if g <= 0.0:
            return 0.0
        i = volts / (1.0 / g + self.config.transistor.on_resistance_ohm + series_ohm)
        return float(math.copysign(min(abs(i), self._i_sat), i))

    def cell_currents(self, row: int, col: int, volts: float, series_ohm: float, n: int) -> np.ndarray:
        """``n`` independent reads of one cell (A), shape (n,): bit-identical to ``n`` calls of
        :meth:`cell_current` (same read-noise draws in the same order, same arithmetic; the
        random stream ends in the same state), in one vectorised call."""
        self._check_cell(row, col)
        if not (math.isfinite(volts) and math.isfinite(series_ohm) and series_ohm >= 0):
            raise ValueError(f"cell_currents needs finite volts and series_ohm >= 0, got {volts}, {series_ohm}")
        n = self._check_count(n)
        g0 = float(self._g[row, col])
        if self._read_noisy:                # (n, 2) normals, as n read_conductance_scalar calls
            g = noise.read_conductance_draws(self.config.read_noise, g0, n, self._rng)
        else:
            g = np.full(n, g0)
        i = np.zeros(n)
        on = g > 0.0
        i[on] = volts / (1.0 / g[on] + self.config.transistor.on_resistance_ohm + series_ohm)
        return np.copysign(np.minimum(np.abs(i), self._i_sat), i)

    def column_current(self, row_volts: np.ndarray, col: int) -> float:
        """Column multiply-accumulate sum_i V_i * G_eff_i (A) for the row voltages (V), word line
        ``col`` open, summing node at virtual ground. Read noise per driven cell (a cell at 0 V
        carries no current, so no noise is drawn for it). Never changes state."""
        v = np.asarray(row_volts, dtype=float)
        if v.shape != (self.rows,):
            raise ValueError(f"row_volts must have shape ({self.rows},), got {v.shape}")
        if not 0 <= col < self.cols:
            raise IndexError(f"column {col} outside 0..{self.cols - 1}")
        g = self._g_cols[col]
        driven = v.nonzero()[0]
        if driven.size < self.rows:
            g, v = g[driven], v[driven]
        if self._read_noisy:
            rn = self.config.read_noise
            z = self._rng.standard_normal((2, driven.size))
            g = np.maximum(g * (1.0 + rn.relative_sigma * z[0]) + rn.absolute_sigma_s * z[1], 0.0)
        # Elementwise product and numpy's sum (not BLAS dot): the arithmetic of
        # column_currents_sequence.
        return float((v * (g / (1.0 + g * self._r_mac))).sum())

    def column_read_kernel(self, row_volts: np.ndarray, col: int) -> tuple | None:
        """What one :meth:`column_current` computes, for a compiled kernel (the emulator MCU's
        native core): ``(g, v, r_mac, relative_sigma, absolute_sigma_s, noisy, generator)``
        with ``g`` (S) and ``v`` (V) the conductances and voltages of the driven rows (float
        lists, row order). A read is ``sum(v * (g' / (1 + g' r_mac)))`` (numpy's summation)
        with ``g' = max(g (1 + relative_sigma z0) + absolute_sigma_s z1, 0)`` for ``2 k``
        standard normals drawn from ``generator`` (the k relative ones first) when ``noisy``,
        else ``g' = g``. None when the read has no such form."""
        v = self._row_volts_of(row_volts)
        g = self._g_cols[self._col_of(col)]
        driven = v.nonzero()[0]
        if driven.size < self.rows:
            g, v = g[driven], v[driven]
        rn = self.config.read_noise
        return (g.tolist(), v.tolist(), float(self._r_mac), float(rn.relative_sigma),
                float(rn.absolute_sigma_s), bool(self._read_noisy), self._rng)

    def column_currents(self, row_volts: np.ndarray, col: int, n: int) -> np.ndarray:
        """``n`` independent reads of one column (A), shape (n,): bit-identical to ``n`` calls
        of :meth:`column_current` (same read-noise draws in the same order, same arithmetic; the
        random stream ends in the same state), in one vectorised call.

        The arithmetic of :meth:`column_currents_sequence` for one drive and one column,
        without its bookkeeping (the ISA-level MCU of the emulator reads one column at a time).
        """
        v = self._row_volts_of(row_volts)
        g = self._g_cols[self._col_of(col)]
        n = self._check_count(n)
        driven = v.nonzero()[0]
        if driven.size < self.rows:
            g, v = g[driven], v[driven]
        if self._read_noisy:
            rn = self.config.read_noise
            z = self._rng.standard_normal((n, 2, driven.size))
            g = np.maximum(g * (1.0 + rn.relative_sigma * z[:, 0])
                           + rn.absolute_sigma_s * z[:, 1], 0.0)
        else:
            g = np.broadcast_to(g, (n, driven.size))
        return (v * (g / (1.0 + g * self._r_mac))).sum(axis=-1)

    def multi_column_currents(self, row_volts: np.ndarray, cols, n: int) -> np.ndarray:
        """``n`` reads of each of the columns ``cols`` in turn (A), shape (len(cols), n):
        bit-identical to calling :meth:`column_currents` for each column in that order."""
        v = self._row_volts_of(row_volts)
        return self.column_currents_sequence(v[None, :], (0,), cols, n)[0]

    def column_currents_sequence(self, row_volts: np.ndarray, drive, cols, n: int) -> np.ndarray:
        """Reads for a sequence of drives (a spike train), shape (len(drive), len(cols), n) (A).

        ``row_volts`` (G, rows): the row voltages (V) of G drive patterns; drive ``s`` applies
        ``row_volts[drive[s]]`` and reads each column of ``cols`` ``n`` times in turn. Bit-identical
        to calling :meth:`multi_column_currents` ``(row_volts[drive[s]], cols, n)`` for each ``s``
        in order (the same read-noise draws in the same order, the same arithmetic; the random
        stream ends in the same state), with one draw and one vectorised pass per pattern.

        Per read, the noise of the k driven cells (V_i != 0) is drawn as (2, k) normals
        (relative, absolute), so one read at a time and many at once consume the stream alike.
        The sum is an elementwise product and numpy's sum along the last axis (not BLAS dot),
        which gives bit-identical values for any number of reads at once.
        """
        volts = np.asarray(row_volts, dtype=float)
        if volts.ndim != 2 or volts.shape[1] != self.rows:
            raise ValueError(f"row_volts must have shape (G, {self.rows}), got {volts.shape}")
        drive = np.asarray(drive, dtype=np.int64).reshape(-1)
        if drive.size and not (0 <= drive.min() and drive.max() < volts.shape[0]):
            raise IndexError(f"drive indices must lie in 0..{volts.shape[0] - 1}")
        cols = [self._col_of(c) for c in cols]
        n = self._check_count(n)
        m = len(cols)
        driven = [v.nonzero()[0] for v in volts]
        g_all = self._g_cols[cols]                                  # (m, rows)
        k_all = {d.size for d in driven}
        if len(k_all) == 1:
            # Every pattern drives k rows: one (S, m, n, 2, k) draw, all spikes at once.
            k = k_all.pop()
            g = np.stack([g_all[:, d] for d in driven])[drive][:, :, None, :]   # (S, m, 1, k)
            v = np.stack([volts[p, d] for p, d in enumerate(driven)])[drive][:, None, None, :]
            if self._read_noisy:
                rn = self.config.read_noise
                z = self._rng.standard_normal((drive.size, m, n, 2, k))
                g = np.maximum(g * (1.0 + rn.relative_sigma * z[:, :, :, 0])
                               + rn.absolute_sigma_s * z[:, :, :, 1], 0.0)
            else:
                g = np.broadcast_to(g, (drive.size, m, n, k))
            return (v * (g / (1.0 + g * self._r_mac))).sum(axis=-1)
        out = np.empty((drive.size, m, n))
        if self._read_noisy:
            # Per drive, (m, n, 2, k) normals in read order: one flat draw, cut up per drive.
            per_drive = np.array([m * n * 2 * d.size for d in driven], dtype=np.int64)[drive]
            offsets = np.concatenate(([0], np.cumsum(per_drive)))
            z_all = self._rng.standard_normal(int(offsets[-1]))
        for p, d in enumerate(driven):
            sel = np.flatnonzero(drive == p) if len(driven) > 1 else np.arange(drive.size)
            if not sel.size:
                continue
            g, v, k = g_all, volts[p], d.size
            if k < self.rows:
                g, v = g[:, d], v[d]
            g = g[:, None, :]                                       # (m, 1, k)
            if self._read_noisy:
                size = m * n * 2 * k
                if len(driven) == 1:
                    z = z_all.reshape(sel.size, m, n, 2, k)
                else:
                    z = z_all[offsets[sel][:, None] + np.arange(size)].reshape(sel.size, m, n, 2, k)
                rn = self.config.read_noise
                g = np.maximum(g * (1.0 + rn.relative_sigma * z[:, :, :, 0])
                               + rn.absolute_sigma_s * z[:, :, :, 1], 0.0)
            else:
                g = np.broadcast_to(g, (sel.size, m, n, k))
            out[sel] = (v * (g / (1.0 + g * self._r_mac))).sum(axis=-1)
        return out

    def column_reads(self, row_volts: np.ndarray, drive, cols, n: int) -> np.ndarray:
        """Reads of a sequence of (drive pattern, column) pairs, shape (len(drive), n) (A).

        Read ``s`` applies ``row_volts[drive[s]]`` (``row_volts``: (G, rows), V) and reads column
        ``cols[s]`` ``n`` times. Bit-identical to calling :meth:`column_current` n times for each
        read in order (the same read-noise draws in the same order, the same arithmetic; the
        random stream ends in the same state), in one draw when every pattern drives the same
        number of rows (else read by read). For the decision window's lean read plan, whose
        reads each have their own column."""
        volts = np.asarray(row_volts, dtype=float)
        if volts.ndim != 2 or volts.shape[1] != self.rows:
            raise ValueError(f"row_volts must have shape (G, {self.rows}), got {volts.shape}")
        drive = np.asarray(drive, dtype=np.int64).reshape(-1)
        cols = np.asarray([self._col_of(int(c)) for c in cols], dtype=np.int64)
        if cols.size != drive.size:
            raise ValueError("one column per read")
        n = self._check_count(n)
        driven = [v.nonzero()[0] for v in volts]
        sizes = {d.size for d in driven}
        if len(sizes) != 1:
            return np.array([[self.column_current(volts[p], int(c)) for _ in range(n)]
                             for p, c in zip(drive.tolist(), cols.tolist())]).reshape(-1, n)
        k = sizes.pop()
        idx = np.stack(driven)[drive]                               # (S, k)
        g = self._g_cols[cols[:, None], idx][:, None, :]            # (S, 1, k)
        v = np.stack([volts[p, d] for p, d in enumerate(driven)])[drive][:, None, :]
        if self._read_noisy:
            rn = self.config.read_noise
            z = self._rng.standard_normal((drive.size, n, 2, k))
            g = np.maximum(g * (1.0 + rn.relative_sigma * z[:, :, 0])
                           + rn.absolute_sigma_s * z[:, :, 1], 0.0)
        else:
            g = np.broadcast_to(g, (drive.size, n, k))
        return (v * (g / (1.0 + g * self._r_mac))).sum(axis=-1)

    def _row_volts_of(self, row_volts: np.ndarray) -> np.ndarray:
        v = np.asarray(row_volts, dtype=float)
        if v.shape != (self.rows,):
            raise ValueError(f"row_volts must have shape ({self.rows},), got {v.shape}")
        return v

    def _col_of(self, col: int) -> int:
        if not 0 <= col < self.cols:
            raise IndexError(f"column {col} outside 0..{self.cols - 1}")
        return int(col)

    @staticmethod
    def _check_count(n: int) -> int:
        if int(n) != n or n < 0:
            raise ValueError(f"number of reads must be an integer >= 0, got {n}")
        return int(n)

    # --- writes ------------------------------------------------------------------------------
    def pulse_current(self, row: int, col: int, amplitude_v: float) -> float:
        """Predicted current (A) at the start of a write pulse of ``amplitude_v`` (V); no state change."""
        self._check_cell(row, col)
        if not (math.isfinite(amplitude_v) and amplitude_v >= 0):
            raise ValueError(f"amplitude_v must be finite and >= 0, got {amplitude_v}")
        return series_current(amplitude_v, float(self._g[row, col]), self._r_write, self._i_sat)

    def apply_pulse(self, row: int, col: int, amplitude_v: float, polarity: Polarity,
                    width_s: float) -> float:
        """Apply one rectangular write pulse; return the peak current drawn (A).

        ``polarity`` :class:`~snan_hil.common.polarity.Polarity` SET (conductance up; a negative pulse
        on the real board) or RESET (conductance down; positive). ``amplitude_v`` >= 0 (V),
        ``width_s`` >= 0 (s). The state changes only when the voltage across the memristor exceeds its threshold (>= 0.3 V).
        A pulse that puts more than ``breakdown.v_breakdown_v`` across the memristor (at its
        start, or at its end after switching) destroys the cell: shorted at
        ``breakdown.g_short_s`` and stuck for good (``broken``).
        """
        self._check_cell(row, col)
        if polarity not in POLARITIES:
            raise ValueError(f"polarity must be Polarity.SET or Polarity.RESET, got {polarity!r}")
        if not (math.isfinite(amplitude_v) and amplitude_v >= 0):
            raise ValueError(f"amplitude_v must be finite and >= 0 (polarity gives the sign), got {amplitude_v}")
        if not (math.isfinite(width_s) and width_s >= 0):
            raise ValueError(f"width_s must be finite and >= 0, got {width_s}")
        g_now = float(self._g[row, col])
        if self.stuck_mask[row, col]:
            return series_current(amplitude_v, g_now, self._r_write, self._i_sat)
        if width_s > 0 and (self._memristor_volts(amplitude_v, g_now)
                            > self.config.breakdown.v_breakdown_v):
            return self._break_down(row, col, amplitude_v)
        cells, sw = self.cells, self.config.switching
        if polarity == Polarity.SET:
            rate, vth, expo = cells.rate_set[row, col], cells.vth_set[row, col], sw.set_exponent
        else:
            rate, vth, expo = cells.rate_reset[row, col], cells.vth_reset[row, col], sw.reset_exponent
        g_min, g_max = float(self._g_lo[row, col]), float(self._g_hi[row, col])
        s = float(self.state[row, col])
        if self._drifting:  # fold the drift so far into the state before programming again
            s = float(state_of_conductance(g_now, g_min, g_max))
        if amplitude_v <= vth or width_s == 0:
            return series_current(amplitude_v, g_now, self._r_write, self._i_sat)
        factor = noise.programming_dose_factor(self.config.programming_noise, self._rng)
        res = pulse_response(s, amplitude_v, polarity, width_s, g_min, g_max, float(rate), float(vth), expo,
                             self._r_write, self._i_sat, self.config.switching.max_substep_dose, factor)
        ds = res.s_after - s
        ds += noise.programming_hop(self.config.programming_noise, ds, self._rng)
        s_new = min(max(s + ds, 0.0), 1.0)
        self.state[row, col] = s_new
        self.t_prog[row, col] = self.time_s
        self.changed_cells.add((row, col))
        if s_new != s:
            self._add_wear(row, col, abs(s_new - s) / 2.0)
        self._refresh()
        g_end = float(self._g[row, col])
        if self._memristor_volts(amplitude_v, g_end) > self.config.breakdown.v_breakdown_v:
            return max(res.peak_current_a, self._break_down(row, col, amplitude_v))
        return res.peak_current_a

    def _add_wear(self, row: int, col: int, cycles: float) -> None:
        """Count ``cycles`` (full-window swings) of wear on a cell: its window narrows
        (:meth:`_worn_bounds`), keeping its conductance; at its endurance it is worn out and
        stuck at that conductance."""
        lo, hi = float(self._g_lo[row, col]), float(self._g_hi[row, col])
        log_g = math.log(lo) + math.log(hi / lo) * float(self.state[row, col])
        wear = float(self.wear[row, col]) + cycles
        self.wear[row, col] = wear
        g_min, g_max = float(self.cells.g_min[row, col]), float(self.cells.g_max[row, col])
        f = min(wear / float(self.endurance[row, col]), 1.0)
        closing = self.config.wear.window_closure * f / 2.0 * math.log(g_max / g_min)
        lo, hi = g_min * math.exp(closing), g_max * math.exp(-closing)
        self._g_lo[row, col], self._g_hi[row, col] = lo, hi
        self.state[row, col] = min(max((log_g - math.log(lo)) / math.log(hi / lo), 0.0), 1.0)
        if f >= 1.0 and not self.stuck_mask[row, col]:
            self.worn[row, col] = self.stuck_mask[row, col] = True
            self.stuck_high[row, col] = False
            self.stuck_g[row, col] = float(conductance_of_state(self.state[row, col], lo, hi))

    def _memristor_volts(self, amplitude_v: float, g: float) -> float:
        """Voltage (V) across a memristor of conductance g (S) during a pulse of
        ``amplitude_v``: the divider with the transistor and the write path, limited by the
        transistor's saturation current. Largest at the lowest conductance the pulse passes
        through: at its start for SET, at its end for RESET."""
        if g <= 0:
            return amplitude_v
        return series_current(amplitude_v, g, self._r_write, self._i_sat) / g

    def _break_down(self, row: int, col: int, amplitude_v: float) -> float:
        """The pulse broke the oxide down: the cell is shorted (``breakdown.g_short_s``) and
        stuck for good. Returns the current it draws shorted (A)."""
        g_short = self.config.breakdown.g_short_s
        self.broken[row, col] = True
        self.stuck_mask[row, col] = True
        self.stuck_high[row, col] = True
        self.stuck_g[row, col] = g_short
        self.t_prog[row, col] = self.time_s
        self._refresh()
        return series_current(amplitude_v, g_short, self._r_write, self._i_sat)

    def set_conductance(self, row: int, col: int, g_s: float) -> None:
        """Put a cell directly at conductance g_s (S), clipped to its bounds, bypassing pulse physics
        (presets and tests). Stuck cells do not change."""
        self._check_cell(row, col)
        if self.stuck_mask[row, col]:
            return
        self.state[row, col] = float(state_of_conductance(g_s, self._g_lo[row, col],
                                                          self._g_hi[row, col]))
        self.t_prog[row, col] = self.time_s
        self.changed_cells.add((row, col))
        self._refresh()

    def advance_time(self, seconds: float) -> None:
        """Advance the chip's clock (s); only drift depends on it (zero by default)."""
        if not (math.isfinite(seconds) and seconds >= 0):
            raise ValueError(f"seconds must be finite and >= 0, got {seconds}")
        self.time_s += seconds
        if self._drifting:
            self._refresh()

    # --- runtime state (for a write-ahead journal) ----------------------------------------
    @property
    def noise_state(self) -> Mapping[str, Any]:
        """State of the runtime random stream (programming and read noise), as numpy's
        ``bit_generator.state`` dict; assigning one continues the stream from there."""
        return self._rng.bit_generator.state

    @noise_state.setter
    def noise_state(self, value: Mapping[str, Any]) -> None:
        self._rng.bit_generator.state = value

    def restore_cells(self, rows, cols, state, t_prog, wear=None) -> None:
        """Put cells ``(rows[i], cols[i])`` back at internal ``state[i]`` (0..1) programmed at
        chip time ``t_prog[i]`` (s), with ``wear[i]`` (cycles; None: as they are): the exact
        values a journal recorded, no physics, no clipping (replay of :meth:`apply_pulse`
        results). A restored wear at or above the cell's endurance makes it worn out again,
        stuck at its restored conductance."""
        r = np.asarray(rows, dtype=np.intp)
        c = np.asarray(cols, dtype=np.intp)
        if r.size:
            self.state[r, c] = np.asarray(state, dtype=float)
            self.t_prog[r, c] = np.asarray(t_prog, dtype=float)
            if wear is not None:
                self.wear[r, c] = np.asarray(wear, dtype=float)
                lo, hi = self._worn_bounds(self.wear[r, c], (r, c))
                self._g_lo[r, c], self._g_hi[r, c] = lo, hi
                for i, j in zip(r.tolist(), c.tolist()):
                    if self.wear[i, j] >= self.endurance[i, j] and not self.stuck_mask[i, j]:
                        self.worn[i, j] = self.stuck_mask[i, j] = True
                        self.stuck_high[i, j] = False
                        self.stuck_g[i, j] = float(conductance_of_state(
                            self.state[i, j], self._g_lo[i, j], self._g_hi[i, j]))
        self._refresh()

    # --- persistence -------------------------------------------------------------------------
    def save(self, path: str, meta: dict | None = None) -> None:
        """Write the chip (config, realised variability, state, stuck cells, clock, RNG) as npz.

        ``meta``: a JSON-able dict stored with it (the emulator keeps the chip's serial, boot
        count and journal position there); :meth:`load` gives it back as :attr:`meta`.
        Written to a temporary file then renamed, so an interrupted save keeps the old file.
        """
        target = Path(path)
        arrays = {
            "format": np.array(_FORMAT),
            "config_json": np.array(self.config.to_json()),
            "seed": np.array(self.seed),
            "state": self.state,
            "stuck_mask": self.stuck_mask,
            "stuck_high": self.stuck_high,
            "stuck_g": self.stuck_g,
            "drift_nu": self.drift_nu,
            "broken": self.broken,
            "endurance": self.endurance,
            "wear": self.wear,
            "worn": self.worn,
            "t_prog": self.t_prog,
            "time_s": np.array(self.time_s),
            "rng_state_json": np.array(json.dumps(self._rng.bit_generator.state)),
        }
        arrays.update({f"cell_{k}": v for k, v in self.cells.arrays().items()})
        if meta is not None:
            arrays["meta_json"] = np.array(json.dumps(meta))
        # written through a file handle, so np.savez does not append .npz to the temp name
        with atomic_path(target, prefix=target.name + ".") as tmp, open(tmp, "wb") as fh:
            np.savez(fh, **arrays)

    @classmethod
    def load(cls, path: str) -> "CrossbarArray":
        """Read a chip written by :meth:`save` (no pickle)."""
        try:
            with np.load(path, allow_pickle=False) as d:
                data = {k: d[k] for k in d.files}
        except Exception as exc:  # noqa: BLE001 - zip/npy/EOF/OS errors: the file is unusable
            raise ChipStateError(_unreadable(path, exc)) from None
        if str(data.get("format", "")) != _FORMAT:
            raise ChipStateError(f"{path} is not a snan-hil chip state ({_FORMAT})")
        try:
            plain = json.loads(str(data["config_json"]))
            if isinstance(plain, dict) and "breakdown" not in plain:
                # saved before breakdown was modelled: the packaged breakdown parameters
                plain["breakdown"] = ArrayConfig.default().to_dict()["breakdown"]
            if isinstance(plain, dict) and "wear" not in plain:
                # saved before wear was modelled: the packaged wear parameters
                plain["wear"] = ArrayConfig.default().to_dict()["wear"]
            config = ArrayConfig.from_dict(plain)
            self = cls.__new__(cls)
            self.config = config
            self.seed = int(data["seed"])
            self.rows, self.cols = config.rows, config.cols
            self.cells = CellParams(**{k: np.array(data[f"cell_{k}"], dtype=float) for k in
                                       ("g_min", "g_max", "rate_set", "rate_reset", "vth_set", "vth_reset")})
            self.state = np.array(data["state"], dtype=float)
            self.stuck_mask = np.array(data["stuck_mask"], dtype=bool)
            self.stuck_high = np.array(data["stuck_high"], dtype=bool)
            self.stuck_g = np.array(data["stuck_g"], dtype=float)
            self.drift_nu = np.array(data["drift_nu"], dtype=float)
            self.broken = (np.array(data["broken"], dtype=bool) if "broken" in data
                           else np.zeros(self.stuck_mask.shape, dtype=bool))
            shape = self.stuck_mask.shape
            self.endurance = (np.array(data["endurance"], dtype=float) if "endurance" in data
                              else _sample_endurance(config, shape, np.random.SeedSequence(
                                  self.seed).spawn(3)[2]))
            self.wear = (np.array(data["wear"], dtype=float) if "wear" in data
                         else np.zeros(shape))
            self.worn = (np.array(data["worn"], dtype=bool) if "worn" in data
                         else np.zeros(shape, dtype=bool))
            self.t_prog = np.array(data["t_prog"], dtype=float)
            self.time_s = float(data["time_s"])
            self._rng = np.random.Generator(np.random.PCG64())
            self._rng.bit_generator.state = json.loads(str(data["rng_state_json"]))
            self.meta = json.loads(str(data["meta_json"])) if "meta_json" in data else {}
            if not isinstance(self.meta, dict):
                raise ValueError("meta_json is not an object")
        except (KeyError, ValueError, TypeError) as exc:
            raise ChipStateError(f"chip state {path} is incomplete or corrupt ({exc})",
                                 ours=True) from None
        shape = (self.rows, self.cols)
        arrays = {"state": self.state, "stuck_mask": self.stuck_mask, "stuck_high": self.stuck_high,
                  "broken": self.broken, "endurance": self.endurance, "wear": self.wear,
                  "worn": self.worn,
                  "stuck_g": self.stuck_g, "drift_nu": self.drift_nu, "t_prog": self.t_prog,
                  **{f"cell_{k}": v for k, v in self.cells.arrays().items()}}
        for name, a in arrays.items():
            if np.shape(a) != shape:
                raise ChipStateError(f"chip state {path}: {name} is {np.shape(a)}, "
                                     f"not {self.rows}x{self.cols}", ours=True)
            if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
                raise ChipStateError(f"chip state {path}: {name} holds NaN or infinite values",
                                     ours=True)
        if not math.isfinite(self.time_s):
            raise ChipStateError(f"chip state {path}: time_s is not finite", ours=True)
        self._setup()
        return self

    @classmethod
    def from_yaml(cls, path: str | None = None, seed: int = 0) -> "CrossbarArray":
        """A chip from a device YAML (None: the packaged configs/device-ysz.yaml)."""
        return cls(ArrayConfig.from_yaml(path), seed=seed)
