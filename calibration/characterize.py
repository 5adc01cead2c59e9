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
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any, ClassVar

import numpy as np

from snan_hil.calibration.bench import CellBench
from snan_hil.calibration.board_io import BoardCellIO
from snan_hil.calibration.job import ONE, SingleUnit, UnitContext
from snan_hil.calibration.layout import Layout, Synapse
from snan_hil.calibration.mapping import WeightMap
from snan_hil.calibration.observer import CellEvent, CellObserver
from snan_hil.calibration.wv import PulseNotApplied
from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity
from snan_hil.common.progress import ProgressCallback, track
from snan_hil.crossbar_model.aging import fit_aging
from snan_hil.crossbar_model.fitted import (DeviceModel, LearningPulse, PulseSample,
                                             fit_device)
from snan_hil.crossbar_model.validation import HeldOut, score_heldout, split_trains

__all__ = ["CharacterizeConfig", "CellRecord", "Measurement", "characterize_cells",
           "fit_measurement", "fit_samples", "validate_holdout", "check_holdout", "holdout_of",
           "choose_cells", "CharacterizeJob", "Characterization", "SYNAPSE_BLOCK_ROWS"]

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


def characterize_cells(make_io: Callable[[int, int], BoardCellIO],
                       cells: Sequence[tuple[int, int]], cfg: CharacterizeConfig, *,
                       progress: ProgressCallback | None = None,
                       observer: CellObserver | None = None) -> Measurement:
    """Run the protocol of the module doc on ``cells`` [(row, col)]; ``make_io(row, col)``
    gives the cell's I/O (a bench's cell: pulses of the learning pulse's width, stage
    "characterize", journalled and recorded as they are applied). ``progress`` gets the task
    "characterising" (one unit per cell); ``observer`` every pulse and each cell's result
    (outcome "measured", detail: pulses, read noise, how each train ended; a bench's
    ``cell_results`` passes the results on only)."""
    bar = track(progress, "characterising", len(cells))
    out = Measurement(cfg, [])
    for k, (row, col) in enumerate(cells):
        bar.advance(0, f"cell ({row},{col}) {k + 1}/{len(cells)}")
        io = make_io(row, col)
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


def check_holdout(every: int, name: str = "holdout") -> None:
    """UserError (one line) unless ``every`` is 0 (off) or >= 2 (every N-th train held out);
    ``name``: how the front door spells the field."""
    if every and every < 2:
        raise UserError(f"{name} must be >= 2 (every N-th train held out) or 0, got {every}")


def holdout_of(samples: Sequence[PulseSample], model: DeviceModel, every: int,
               warn: Callable[[str], object] = log.warning) -> HeldOut | None:
    """The held-out validation of ``model``'s pulses (:func:`validate_holdout` at its pulse,
    reference and read noise; ``every`` 0: off, None). When too little is left to fit or to
    score, one ``warn`` line and None."""
    if not every:
        return None
    try:
        return validate_holdout(samples, model.pulse, g_ref_s=model.g_ref_s,
                                read_noise=model.read_noise, every=every)
    except ValueError as exc:
        warn(f"held-out validation skipped: {exc}")
        return None


SYNAPSE_BLOCK_ROWS = 15
"""Rows of a 6x6 grid's synapse block (120 synapses on 15 x 8 cells): the cells ``synapses``
means on a board without a layout."""


def choose_cells(which: str | Sequence[tuple[int, int]], layout: Layout | None, rows: int,
                 cols: int, max_cells: int | None = None) -> list[tuple[int, int]]:
    """The cells to characterise: ``"synapses"`` (the layout's synapse cells; without a
    layout the 15 x ``cols`` block of a 6x6 grid), ``"all"`` (every cell), or the cells given;
    a layout's bad cells left out of the first two; the first ``max_cells`` of them."""
    bad = set(layout.bad_cells) if layout is not None else set()
    if which == "synapses":
        cells = [(s.row, s.col) for s in layout.synapses] if layout is not None \
            else [(r, c) for r in range(SYNAPSE_BLOCK_ROWS) for c in range(cols)]
        cells = [c for c in cells if c not in bad]
    elif which == "all":
        cells = [(r, c) for r in range(rows) for c in range(cols) if (r, c) not in bad]
    else:
        assert not isinstance(which, str), which
        cells = [(int(r), int(c)) for r, c in which]
    return cells if max_cells is None else cells[:max_cells]


@dataclass
class Characterization:
    """A characterisation as :class:`CharacterizeJob` ran it: the measurement, the fitted
    model, the cells, where the reads' conductances came from, the pulses applied (host
    ledger) and the board's pulse counter over the run (None without one), the synapses
    of the layout the sweep left stale, the held-out validation (None: off or skipped)."""

    measurement: Measurement
    model: DeviceModel
    cells: list[tuple[int, int]]
    read_chain: str
    pulses: int
    firmware_pulses: int | None
    host_pulses: int
    stale: list[tuple[int, int]]
    holdout: HeldOut | None = None

    @property
    def summary(self) -> dict[str, Any]:
        """Cells, fitted cells, pulses (host and board counter) and the model's parameters."""
        return {"cells": len(self.cells), "fitted": sum(1 for c in self.model.cells if c.ok),
                "pulses": self.pulses, "firmware_pulses": self.firmware_pulses,
                **self.model.parameters()}


class CharacterizeJob:
    """``snan-hil characterize`` as a board job (:mod:`snan_hil.calibration.job`): one unit,
    :func:`characterize_cells` on the chosen cells (:func:`choose_cells`: ``which``,
    ``max_cells``) at the learning ``pulse``, then the model fitted; the synapses of the
    board's layout swept over are marked stale there (also when the sweep is cut). The
    sweep's window is the layout's weight map (the default one without a layout).
    ``holdout``: also fit on all but every N-th train of each cell and score the model on the
    trains held out (:func:`holdout_of`; 0: off). ``names``: how the front door spells the
    fields in messages (``set_v``, ``reset_v``, ``cells``, ``holdout``)."""

    kind: ClassVar[str] = "characterize"
    restartable: ClassVar[bool] = False

    def __init__(self, which: str | Sequence[tuple[int, int]] = "synapses", *,
                 pulse: LearningPulse | None = None, repeats: int = 2,
                 max_pulses_per_train: int = 250, max_cells: int | None = None,
                 holdout: int = 0, names: Mapping[str, str] | None = None) -> None:
        self.which = which if isinstance(which, str) else [(int(r), int(c)) for r, c in which]
        self.pulse = pulse or LearningPulse()
        self.repeats, self.max_pulses, self.max_cells = repeats, max_pulses_per_train, max_cells
        self.holdout = int(holdout)
        self.names = dict(names or {})
        self.cfg = self._config(WeightMap())
        self.cells: list[tuple[int, int]] = []
        self._touched: list[Synapse] = []
        self._run: Characterization | None = None

    def _config(self, weight_map: WeightMap) -> CharacterizeConfig:
        try:
            return CharacterizeConfig(pulse=self.pulse, weight_map=weight_map,
                                      repeats=self.repeats,
                                      max_pulses_per_train=self.max_pulses)
        except ValueError as exc:
            raise UserError(f"characterize: {exc}") from None

    def describe(self) -> dict[str, Any]:
        return self.cfg.to_dict()

    def plan(self, bench: CellBench) -> Sequence[SingleUnit]:
        from snan_hil.calibration.job import check_cells
        from snan_hil.calibration.layout import check_layout_writable
        name = self.names.get
        for field_, v in (("set_v", self.pulse.set_v), ("reset_v", self.pulse.reset_v)):
            bench.check_amplitude(v, name(field_, field_))
        info, layout = bench.info, bench.layout
        check_holdout(self.holdout, name("holdout", "holdout"))
        if self.max_cells is not None and self.max_cells < 1:
            raise UserError(f"{name('max_cells', 'max_cells')} must be >= 1, got "
                            f"{self.max_cells}")
        self.cells = choose_cells(self.which, layout, info.rows, info.cols, self.max_cells)
        check_cells(self.cells, info, name("cells", "cells"))
        self.cfg = self._config(layout.weight_map if layout is not None else WeightMap())
        chosen = set(self.cells)
        self._touched = [s for s in (layout.synapses if layout is not None else [])
                         if (s.row, s.col) in chosen and s.weight is not None]
        if self._touched:
            check_layout_writable(bench.layout_path)
            bench.warn(f"{len(self._touched)} cell(s) hold synapses of {bench.layout_path}; "
                       "the sweep changes them, so the layout marks them stale until "
                       "program-weights writes them again")
        return ONE

    def run_unit(self, unit: SingleUnit, bench: CellBench, ctx: UnitContext) -> dict[str, Any]:
        cfg, layout = self.cfg, bench.layout
        width = cfg.pulse.width_us
        try:
            m = characterize_cells(
                lambda r, c: bench.cell(r, c, stage="characterize", width_us=width),
                self.cells, cfg, progress=ctx.progress, observer=bench.cell_results)
        finally:
            if self._touched and layout is not None and bench.layout_path is not None:
                for s in self._touched:
                    s.stale = "characterize: swept over the whole window"
                    s.ok = False
                layout.save(bench.layout_path)
        source = bench.chain_source
        try:
            model = fit_measurement(m, meta={"board_id": bench.info.board_id,
                                             "port": bench.session.port,
                                             "read_chain": source})
        except ValueError as exc:
            raise UserError(f"characterize: {exc}; check the cells (snan-hil cells test) "
                            f"or choose others with {self.names.get('cells', 'cells')}"
                            ) from None
        held = holdout_of(m.samples, model, self.holdout, bench.warn)
        ledger = bench.ledger
        self._run = Characterization(m, model, self.cells, source, ledger.confirmed,
                                     ledger.firmware_delta(bench.client), ledger.host_pulses,
                                     [(s.row, s.col) for s in self._touched], held)
        return {"summary": self._run.summary, "model": model.to_dict(),
                "holdout": None if held is None else held.to_dict()}

    def restore(self, unit: SingleUnit, record: dict[str, Any]) -> None:
        raise NotImplementedError("a characterisation is not resumed")

    def result(self, records: Mapping[str, dict[str, Any]], status: str
               ) -> Characterization | None:
        """The characterisation (None when it was stopped before the fit)."""
        return self._run if ONE[0].key in records else None

    def summary(self, result: Characterization | None) -> dict[str, Any] | None:
        return None if result is None else result.summary
