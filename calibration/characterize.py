"""Characterise the cells on a board at the learning pulse: ΔG per SET / RESET pulse against
the present conductance, with repeats, and the compact device model fitted to it
(``snan-hil characterize``; :mod:`snan_hil.crossbar_model.fitted` is the model).

Protocol per cell (:func:`characterize_cells`), every pulse one WRITE_PULSE with its read after:

1. ``noise_reads`` reads of the cell (the read noise of the measurement, its relative std);
2. ``2 x repeats`` trains, alternating: a RESET train (the learning pulse's RESET amplitude)
   until G <= the sweep's bottom ``g_low_s``, a SET train until G >= its top ``g_high_s``;
   the first goes the way the cell has more room from where it is (below the weight map's
   middle: SET first), so every repeat sweeps the whole window both ways; a train also
   stops after ``max_pulses_per_train`` pulses or when the cell has stopped moving
   (``stall_pulses`` pulses that together moved it by less than 3 read-noise sigma: a bound
   inside the sweep);
3. a pair (G read before, G read after) per pulse: the data of the fit.

Defaults: the sweep spans the weight map (50 uS..1 mS) widened by 10 % at the bottom and 20 %
at the top (the fit then sees the steps shrink towards both ends), inside what the board can
program and verify. Every pulse goes through
:class:`~snan_hil.calibration.board_io.BoardCellIO` (host safety limits, the pulse ledger:
a lost WRITE_PULSE is reconciled with the board's counter, never resent), and an observer gets
every pulse and each cell's result (the chip history). The cells are left at an end of the
sweep: a synapse measured here no longer holds its programmed weight (the command marks it
stale in the layout).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np

from snan_hil.calibration.board_io import BoardCellIO, BoardLimits, PulseLedger
from snan_hil.calibration.mapping import WeightMap
from snan_hil.calibration.observer import CellEvent, CellObserver
from snan_hil.calibration.readchain import ReadChain
from snan_hil.calibration.wv import PulseNotApplied
from snan_hil.common.polarity import Polarity
from snan_hil.common.progress import ProgressCallback, track
from snan_hil.crossbar_model.aging import fit_aging
from snan_hil.crossbar_model.fitted import (DeviceModel, LearningPulse, PulseSample,
                                             fit_device)
from snan_hil.crossbar_model.validation import HeldOut, score_heldout, split_trains
from snan_hil.protocol.client import BoardClient

__all__ = ["CharacterizeConfig", "CellRecord", "Measurement", "characterize_cells",
           "fit_measurement", "fit_samples", "validate_holdout"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CharacterizeConfig:
    """Settings of one characterisation (S, V, us, counts); see the module doc."""

    pulse: LearningPulse = field(default_factory=LearningPulse)
    weight_map: WeightMap = field(default_factory=WeightMap)
    repeats: int = 2
    low_margin: float = 0.9          #: sweep bottom = weight map's G_min x this
    high_margin: float = 1.2         #: sweep top = weight map's G_max x this
    max_pulses_per_train: int = 250
    stall_pulses: int = 25
    noise_reads: int = 8

    def __post_init__(self) -> None:
        if not 1 <= self.repeats <= 100:
            raise ValueError(f"repeats must be 1..100, got {self.repeats}")
        if not 1 <= self.max_pulses_per_train <= 10_000:
            raise ValueError("max_pulses_per_train must be 1..10000")
        if not 0 < self.low_margin <= 1 <= self.high_margin:
            raise ValueError("need 0 < low_margin <= 1 <= high_margin")
        if self.noise_reads < 2:
            raise ValueError("noise_reads must be >= 2")

    @property
    def g_low_s(self) -> float:
        return self.weight_map.g_min_s * self.low_margin

    @property
    def g_high_s(self) -> float:
        return self.weight_map.g_max_s * self.high_margin

    @property
    def g_ref_s(self) -> float:
        """Where the model states ``dw_min``: the weight map's middle (weight 0.5)."""
        return self.weight_map.conductance(0.5)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d.update(g_low_s=self.g_low_s, g_high_s=self.g_high_s, g_ref_s=self.g_ref_s)
        return d


@dataclass
class CellRecord:
    """What one cell gave: its pulses (before/after reads), read noise, how the trains ended."""

    row: int
    col: int
    samples: list[PulseSample] = field(default_factory=list)
    noise: float = math.nan
    trains: list[str] = field(default_factory=list)
    not_applied: int = 0
    swing: float = 0.0
    """Cumulative |Δ ln G| of the cell's pulses so far (the aging term's wear count)."""

    @property
    def pulses(self) -> int:
        return len(self.samples)


@dataclass
class Measurement:
    """Every measured cell, in order, and the settings."""

    config: CharacterizeConfig
    cells: list[CellRecord]

    @property
    def samples(self) -> list[PulseSample]:
        return [s for c in self.cells for s in c.samples]

    @property
    def read_noise(self) -> float:
        """Median relative std of one read over the cells."""
        vals = [c.noise for c in self.cells if math.isfinite(c.noise)]
        return float(np.median(vals)) if vals else 0.0


def _train(io: BoardCellIO, rec: CellRecord, polarity: Polarity, cfg: CharacterizeConfig,
           g: float) -> float:
    """One train of one polarity from conductance ``g``; returns G after it."""
    amp = cfg.pulse.amplitude(polarity)
    done = (lambda v: v <= cfg.g_low_s) if polarity == Polarity.RESET \
        else (lambda v: v >= cfg.g_high_s)
    noise = rec.noise if math.isfinite(rec.noise) else 0.01
    history: list[float] = [g]
    n = 0
    why = "pulse budget"
    while n < cfg.max_pulses_per_train:
        if done(g):
            why = "reached"
            break
        try:
            after = io.pulse(polarity, amp)
        except PulseNotApplied:
            rec.not_applied += 1
            g = io.read()
            continue
        rec.samples.append(PulseSample(rec.row, rec.col, polarity, g, after,
                                       swing_before=rec.swing))
        if g > 0 and after > 0:
            rec.swing += abs(math.log(after / g))
        g = after
        n += 1
        history.append(g)
        k = cfg.stall_pulses
        if len(history) > k and abs(math.log(history[-1] / history[-1 - k])) < 3 * noise:
            why = "stalled"
            break
    rec.trains.append(f"{polarity.name} {n} pulses: {why}")
    return g


def characterize_cells(client: BoardClient, chain: ReadChain, cells: list[tuple[int, int]],
                       limits: BoardLimits, ledger: PulseLedger, cfg: CharacterizeConfig, *,
                       progress: ProgressCallback | None = None,
                       observer: CellObserver | None = None) -> Measurement:
    """Run the protocol of the module doc on ``cells`` [(row, col)]. ``progress`` gets the
    task "characterising" (one unit per cell); ``observer`` every pulse (stage
    "characterize") and each cell's result (outcome "measured", detail: pulses, read noise,
    how each train ended)."""
    bar = track(progress, "characterising", len(cells))
    out = Measurement(cfg, [])
    for k, (row, col) in enumerate(cells):
        bar.advance(0, f"cell ({row},{col}) {k + 1}/{len(cells)}")
        io = BoardCellIO(client, chain, row, col, limits, ledger, cfg.pulse.width_us)
        io.stage = "characterize"
        rec = CellRecord(row, col)
        reads = np.array([io.read() for _ in range(cfg.noise_reads)])
        if np.all(reads > 0):
            rec.noise = float(np.std(np.log(reads), ddof=1))
        g = float(reads[-1])
        try:
            if g > 0:
                # the first train goes the way the cell has more room (both directions full)
                pol = Polarity.SET if g < cfg.g_ref_s else Polarity.RESET
                for _ in range(2 * cfg.repeats):
                    g = _train(io, rec, pol, cfg, g)
                    pol = Polarity.RESET if pol == Polarity.SET else Polarity.SET
        finally:
            if observer is not None:
                if io.applied:
                    observer.on_pulses(io.applied)
                observer.on_cell(CellEvent(row, col, "measured", g, pulses=rec.pulses,
                                           detail={"read_noise": rec.noise,
                                                   "trains": rec.trains,
                                                   "not_applied": rec.not_applied}))
        out.cells.append(rec)
        bar.advance(1, f"cell ({row},{col}): {rec.pulses} pulses")
    return out


def fit_measurement(m: Measurement, meta: dict[str, Any] | None = None) -> DeviceModel:
    """The device model of a measurement (:func:`snan_hil.crossbar_model.fitted.fit_device`)
    at the weight map's middle, with its aging term (:func:`snan_hil.crossbar_model.aging.
    fit_aging`: wear where the sweeps show it). ValueError when no cell gave a usable fit."""
    return fit_samples(m.samples, m.config.pulse, g_ref_s=m.config.g_ref_s,
                       read_noise=m.read_noise,
                       meta={"sweep": m.config.to_dict(), **(meta or {})})


def fit_samples(samples: Sequence[PulseSample], pulse: LearningPulse, *, g_ref_s: float,
                read_noise: float, meta: dict[str, Any] | None = None,
                retention: Sequence[tuple[float, float, float]] = ()) -> DeviceModel:
    """:func:`~snan_hil.crossbar_model.fitted.fit_device` of ``samples`` and the aging term
    (``retention``: consecutive-pulse pairs ``(gap s, G after S, G before S)`` for drift).
    ValueError when no cell gives a usable fit."""
    model = fit_device(samples, pulse, g_ref_s=g_ref_s, read_noise=read_noise, meta=meta)
    return replace(model, aging=fit_aging(samples, model, retention=retention))


def validate_holdout(samples: Sequence[PulseSample], pulse: LearningPulse, *, g_ref_s: float,
                     read_noise: float, every: int = 3, seed: int = 0) -> HeldOut:
    """Fit on all but every ``every``-th train of each cell and score the model on the trains
    held out (:mod:`snan_hil.crossbar_model.validation`); the stored model is fitted on all
    pulses, this fit only checks the form. ValueError when too little is left to fit or to
    score."""
    fit, held = split_trains(samples, every)
    if not held:
        raise ValueError(f"no train to hold out (every {every}-th train of a cell; the cells "
                         "have fewer trains)")
    model = fit_device(fit, pulse, g_ref_s=g_ref_s, read_noise=read_noise)
    return score_heldout(model, held, seed=seed)
