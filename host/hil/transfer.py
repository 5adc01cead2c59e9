"""Cross-chip transfer: the weights a ``snan-hil learn`` run's chip arm learnt on chip A,
programmed onto chip B by two-stage write-and-verify and tested there (``snan-hil transfer``;
docs/learning.md section 12; issue 35 point 3).

Session ``k`` of the source run left its learnt weights on chip A (read back after its last
cycle, ``learn.json``'s chip sessions' ``weights``, synapse order ``synapses``). A unit
(:class:`TransferUnit`) writes them onto this board (the board's layout and weight map, as
the chip arm programs a session) and runs the source run's test of cycle ``c`` -- the same
test trial (session ``k``'s streams, trial ``2 c``: the same input spikes and tie-breaks) with
astrocytes off -- so that the test on B differs from A's own only by the chip that holds the
weights. The job is the learn job's chip arm (:class:`~snan_hil.host.hil.learn.LearnJob`, its
board checks and back-ends) with the source run's configuration; no learning pulse is sent.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from snan_hil.calibration.bench import CellBench
from snan_hil.calibration.job import UnitContext
from snan_hil.common.errors import UserError
from snan_hil.common.progress import ProgressTracker, track
from snan_hil.crossbar_model.fitted import DeviceModel, LearningPulse
from snan_hil.host.config import from_stored
from snan_hil.host.hil.equivalence import transfer_summary
from snan_hil.host.hil.learn import LearnJob
from snan_hil.host.hil.learn_arms import LearnConfig
from snan_hil.host.hil.learning import PulseBudget

__all__ = ["TransferUnit", "TransferJob", "source_config"]

FORMAT = "snan-hil-transfer/1"
"""Format tag of a transfer result (``transfer.json``)."""


@dataclass(frozen=True)
class TransferUnit:
    """Session ``session`` of the source run, on this board."""

    session: int

    @property
    def key(self) -> str:
        return f"transfer-s{self.session}"

    @property
    def group(self) -> str | None:
        return None


def source_config(doc: Mapping[str, Any], where: str) -> tuple[Any, LearnConfig]:
    """(SNAN model config, learn config) of a ``learn.json`` document ``doc`` (``where``: how
    to name it in messages); UserError (one line) for a document of another kind."""
    try:
        cfg = from_stored(doc["model_config"], where=f"{where} model_config")
        d = dict(doc["config"])
        d["arms"] = ("chip",)
        d["pulse"] = LearningPulse(**d["pulse"])
        d["budget"] = PulseBudget(**d["budget"])
        lc = LearnConfig(**d)
    except (KeyError, TypeError, ValueError) as exc:
        raise UserError(f"{where}: not a 'snan-hil learn' result ({exc}); give the learn.json "
                        "(or its folder) of a learn run") from None
    return cfg, lc


class TransferJob:
    """The transfer of ``doc``'s (a ``learn.json``) learnt chip weights onto one board (module
    doc), tested at ``cycle`` (None: the run's last), of its first ``first`` sessions (None:
    all); ``source``: the source run's name in messages and results."""

    kind: ClassVar[str] = "transfer"
    restartable: ClassVar[bool] = False

    def __init__(self, doc: Mapping[str, Any], source: str, cycle: int | None = None,
                 first: int | None = None) -> None:
        cfg, lc = source_config(doc, source)
        chip = (doc.get("arms") or {}).get("chip") or {}
        sessions = chip.get("sessions") or []
        if not sessions or any(s.get("weights") is None for s in sessions):
            raise UserError(f"{source}: the learn run has no chip sessions with learnt weights; "
                            "transfer the run of a chip arm ('snan-hil learn --arms "
                            "software,chip')")
        if first is not None:
            if not 1 <= first <= len(sessions):
                raise UserError(f"--sessions {first}: {source} has {len(sessions)} chip "
                                f"sessions; give 1..{len(sessions)}")
            sessions = sessions[:first]
        c = lc.cycles if cycle is None else int(cycle)
        if c != lc.cycles:
            raise UserError(f"--cycle {c}: the learnt weights are those after the run's last "
                            f"cycle {lc.cycles}; leave --cycle out")
        model = doc.get("device_model")
        if model is None:
            raise UserError(f"{source}: the learn run holds no device model; transfer the run "
                            "of a chip arm")
        self.doc, self.source, self.cycle = doc, source, c
        self.learn = LearnJob(cfg, lc, DeviceModel.from_dict(model))
        keys = [tuple(k) for k in doc["synapses"]]
        if keys != [tuple(k) for k in self.learn.task.keys]:
            raise UserError(f"{source}: its synapses are not those of its own config; was the "
                            "file edited?")
        self.weights = [np.asarray(s["weights"], dtype=float) for s in sessions]
        self.own = [(int(s["test_steps"][c]), bool(s["test_success"][c])) for s in sessions]
        self._bar: ProgressTracker | None = None

    @property
    def config(self) -> dict[str, Any]:
        return {"source": self.source, "cycle": self.cycle, "sessions": len(self.weights),
                "learn": self.learn.lc.to_dict()}

    def describe(self) -> dict[str, Any]:
        return {"transfer": self.config}

    def units(self) -> list[TransferUnit]:
        return [TransferUnit(k) for k in range(len(self.weights))]

    def unit_order(self) -> list[str]:
        return [u.key for u in self.units()]

    def plan(self, bench: CellBench) -> list[TransferUnit]:
        """The units, after the learn job's board checks (the synapses fit, the layout, the
        mode the board runs)."""
        self.learn.plan(bench)
        return self.units()

    def compact(self, k: int) -> np.ndarray:
        """Session ``k``'s learnt weights in the agent's compact form, float[n_cells, 4]
        (clipped to the mapping window 0..1, as ``learnt.npz`` holds them)."""
        task = self.learn.task
        w = np.zeros(task.nbr.shape)
        for key, v in zip(task.keys, self.weights[k]):
            w[key] = min(max(float(v), 0.0), 1.0)
        return w

    def run_unit(self, unit: TransferUnit, bench: CellBench | None, ctx: UnitContext
                 ) -> dict[str, Any]:
        chip = self.learn.chip_arm
        if chip is None or bench is None:
            raise UserError("the transfer needs a board (--port)")
        t0 = time.perf_counter()
        k = unit.session
        record = chip.test_weights(k, self.compact(k), 2 * self.cycle, bench, ctx)
        record.update(own=list(self.own[k]), wall_s=time.perf_counter() - t0)
        if self._bar is None:
            self._bar = track(ctx.progress, "transfer", len(self.weights))
        self._bar.advance(1, f"session {k}: {record['test'][0]} steps "
                             f"({'success' if record['test'][1] else 'failed'})")
        return record

    def restore(self, unit: TransferUnit, record: dict[str, Any]) -> None:
        pass

    def result(self, records: Mapping[str, dict[str, Any]], status: str) -> dict[str, Any]:
        """The sessions tested (``records`` by unit key) and, with all of them, the summary
        against the source chip's own tests (:func:`transfer_summary`)."""
        rows = [records[u.key] for u in self.units() if u.key in records]
        doc: dict[str, Any] = {
            "format": FORMAT, "source": self.source, "cycle": self.cycle,
            "seed": self.learn.lc.seed, "sessions": [
                {"session": r["session"], "steps": r["test"][0], "success": r["test"][1],
                 "own_steps": r["own"][0], "own_success": r["own"][1],
                 "program": r["program"]} for r in rows],
            "config": self.config, "mode": self.learn.mode, "status": status}
        if rows and status == "complete":
            doc["summary"] = transfer_summary([r["own"][1] for r in rows],
                                              [r["test"][1] for r in rows])
        return doc

    def summary(self, result: dict[str, Any]) -> dict[str, Any]:
        s = result.get("summary") or {}
        return {"sessions": len(result.get("sessions", [])), "kept": s.get("kept")}

