"""A chip's life of learning within a budget (issue 36 point 5, the lifetime run), measured
against its targets.

Usage: ``python bench/bench_lifetime.py [--sessions N] [--out DIR] [--readings packaged,
pessimistic] [--quick]``

1. The lab's chip: a fresh emulated chip (seed 0) characterised at the budget's learning
   pulse (SET 1.2 V / RESET 0.6 V, 100 us; docs/learning.md section 8) on the 120 synapse
   cells of the 6x6 task (rows 0-14), over the framed protocol (``snan-hil characterize``).
2. Its twin (:mod:`snan_hil.crossbar_model.device_twin`, seed 5) with the wear term on:
   ``packaged`` — the model's aging term as fitted (the sweeps show no wear: the packaged
   assumption, endurance 1e5 device cycles); ``pessimistic`` — endurance 1e3 device cycles,
   the lower bound of the source the packaged value cites (ZrO2(Y) devices keep
   potentiation and depression for at least 1000 training cycles, Koryazhkina et al. 2023),
   the host's model told the same.
3. N sessions (default 1000) of the 6x6 route task (18 -> 0, 20 cycles) on that one chip
   (:func:`snan_hil.host.hil.lifetime.run_lifetime`): each session the board's
   write-and-verify of its initial weights, the learning pulses within the budget (200 a
   session, 30 a cell, 2 a cell and cycle, pacing 0.15), the refresh policy (a re-read and
   correction every 5 cycles).

Printed, measured against the target: the cycle-20 test success of the last 100 sessions
(>= 90 %, Wilson 95 % interval), the learning pulses per session (<= 200) and per cell and
session (<= 30), the per-cell cumulative pulses, the wear the host predicts from its ledger
against the emulated chip's own, the predicted remaining endurance; the figure
``lifetime.png`` and ``lifetime.json`` in ``--out``.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

SUCCESS_TARGET = 0.90
SESSION_BUDGET = 200
CELL_BUDGET = 30
PESSIMISTIC_ENDURANCE = 1.0e3       #: device cycles (Koryazhkina et al. 2023: >= 1000)


def characterise(work: Path, cells: str) -> Path:
    """The lab's chip's model at the budget pulse (a fresh emulated chip, seed 0)."""
    from snan_hil.tools import cli
    os.environ["SNAN_HIL_EMU_STATE"] = str(work / "lab-chip.npz")
    os.environ["XDG_DATA_HOME"] = str(work / "data")
    path = work / "model-1.2V.json"
    if not path.is_file():
        with contextlib.redirect_stdout(io.StringIO()):
            rc = cli.main(["characterize", "--port", "emu", "--cells", cells, "--set-v", "1.2",
                           "--reset-v", "0.6", "--model", str(path), "--json", "--force"])
        if rc:
            raise SystemExit(rc)
    return path


def reading(name: str, model, seed: int):
    """(array, host model) of a wear reading."""
    from snan_hil.crossbar_model.aging import packaged_wear_per_cycle
    from snan_hil.crossbar_model.device_twin import twin_spec
    from snan_hil.firmware_emu.config import BoardConfig
    spec = twin_spec(model, read_draws=BoardConfig().adc_averages)
    if name == "pessimistic":
        config = spec.config.with_overrides({"wear.endurance_cycles": PESSIMISTIC_ENDURANCE})
        spec = dataclasses.replace(spec, config=config)
        loss, closure = packaged_wear_per_cycle(model, config)
        assert model.aging is not None
        aging = dataclasses.replace(
            model.aging, window_loss_per_cycle=loss, window_closure=closure,
            wear_source=f"assumption: pessimistic reading, endurance {PESSIMISTIC_ENDURANCE:g} "
                        "device cycles (Koryazhkina et al. 2023: >= 1000 training cycles)")
        model = dataclasses.replace(model, aging=aging)
    return spec.build(seed), model


def summarise(name: str, run: dict, model) -> dict:
    from snan_hil.host.intervals import wilson
    ses = run["sessions"]
    last = ses[-min(100, len(ses)):]
    ok = sum(1 for s in last if s["tests"][-1])
    lo, hi = wilson(ok, len(last))
    cells = run["cells"]
    pulses = np.array([c["learning_pulses"] + c["programming_pulses"] for c in cells])
    learn = np.array([c["learning_pulses"] for c in cells])
    pred = np.array([c["predicted_cycles"] for c in cells])
    true = np.array([c["true_wear_cycles"] for c in cells])
    frac_true = true / np.array([c["true_endurance_cycles"] for c in cells])
    end = run["model_endurance_cycles"]
    frac_pred = pred / end if math.isfinite(end) else np.full_like(pred, np.nan)
    per_session = pred.max() / len(ses)
    remaining = (end - pred.max()) / per_session if math.isfinite(end) and per_session > 0 \
        else math.inf
    return {"reading": name, "sessions": len(ses), "last": len(last),
            "success_last": ok / len(last),
            "success_ci": [lo, hi],
            "learning_pulses_mean": float(np.mean([s["learning_pulses"] for s in ses])),
            "learning_pulses_max": int(max(s["learning_pulses"] for s in ses)),
            "programming_pulses_mean": float(np.mean([s["programming_pulses"] for s in ses])),
            "cell_pulses_max_session": int(max(s["max_cell_pulses"] for s in ses)),
            "cell_pulses_median": float(np.median(pulses)), "cell_pulses_max": int(pulses.max()),
            "cell_learning_pulses_median": float(np.median(learn)),
            "life_used_true_max": float(frac_true.max()),
            "life_used_true_median": float(np.median(frac_true)),
            "life_used_pred_max": float(np.nanmax(frac_pred)),
            "life_used_pred_median": float(np.nanmedian(frac_pred)),
            "worn_cells": int(sum(c["worn"] for c in cells)),
            "remaining_sessions_worst_cell": remaining, "wall_s": run["wall_s"],
            "model_endurance_cycles": end}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=1000)
    ap.add_argument("--readings", default="packaged,pessimistic")
    ap.add_argument("--out", default=None)
    ap.add_argument("--quick", action="store_true", help="20 sessions, 24 cells")
    a = ap.parse_args(argv)
    if a.quick:
        a.sessions = 20
    from snan_hil.crossbar_model.fitted import DeviceModel
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.hil.learning import PulseBudget
    from snan_hil.host.hil.lifetime import LifetimeConfig, run_lifetime
    from snan_hil.tools.device_figures import plot_lifetime

    work = Path(a.out) if a.out else Path(tempfile.mkdtemp(prefix="bench-lifetime-"))
    work.mkdir(parents=True, exist_ok=True)
    rows = 3 if a.quick else 15
    cells = ";".join(f"{r},{c}" for r in range(rows) for c in range(8))
    model = DeviceModel.from_dict(json.loads(characterise(work, cells).read_text()))
    hil = load_hil_config(None, [])
    budget = PulseBudget(SESSION_BUDGET, CELL_BUDGET, 2, 0.5, 0.15)
    runs, summaries = {}, []
    for name in a.readings.split(","):
        array, host_model = reading(name, model, seed=5)
        lc = LifetimeConfig(start=hil.task.start, goal=hil.task.goal, sessions=a.sessions,
                            budget=budget, refresh_every=5, pulse=model.pulse)
        t0 = time.perf_counter()

        def tick(k: int, rec: dict, name=name, t0=t0) -> None:
            if (k + 1) % 50 == 0:
                print(f"  {name}: session {k + 1}/{a.sessions} ({time.perf_counter() - t0:.0f} s)",
                      file=sys.stderr, flush=True)
        run = run_lifetime(hil.model, lc, host_model, array, progress=tick)
        runs[name] = run
        summaries.append(summarise(name, run, host_model))
    (work / "lifetime.json").write_text(json.dumps({"runs": runs, "summary": summaries},
                                                   default=float))
    plot_lifetime(runs, work / "lifetime.png",
                  title=f"{a.sessions} learning sessions on one emulated chip (twin, wear on), "
                        f"budget {SESSION_BUDGET} pulses / session, {CELL_BUDGET} / cell")
    print(f"\nlifetime: {a.sessions} sessions of the 6x6 task on one emulated chip, budget "
          f"{SESSION_BUDGET}/session {CELL_BUDGET}/cell, SET 1.2 V / RESET 0.6 V, refresh every "
          f"5 cycles ({work})")
    for s in summaries:
        ok = s["success_last"] >= SUCCESS_TARGET
        print(f"  [{s['reading']}] cycle-20 success of the last {s['last']} sessions: "
              f"{100 * s['success_last']:.0f} % [{100 * s['success_ci'][0]:.0f}, "
              f"{100 * s['success_ci'][1]:.0f}] (target >= {100 * SUCCESS_TARGET:.0f} %): "
              f"{'MET' if ok else 'NOT MET'}")
        print(f"    learning pulses per session: mean {s['learning_pulses_mean']:.0f}, max "
              f"{s['learning_pulses_max']} (target <= {SESSION_BUDGET}); per cell and session "
              f"max {s['cell_pulses_max_session']} (target <= {CELL_BUDGET}); programming "
              f"{s['programming_pulses_mean']:.0f} per session")
        print(f"    cumulative pulses per cell: median {s['cell_pulses_median']:.0f}, max "
              f"{s['cell_pulses_max']} (learning: median "
              f"{s['cell_learning_pulses_median']:.0f})")
        print(f"    life used (worst / median cell): emulated chip "
              f"{100 * s['life_used_true_max']:.2f} / {100 * s['life_used_true_median']:.2f} %, "
              f"host's prediction "
              f"{100 * s['life_used_pred_max']:.2f} / {100 * s['life_used_pred_median']:.2f} % "
              f"(model endurance {s['model_endurance_cycles']:.3g} cycles); worn-out cells "
              f"{s['worn_cells']}; predicted remaining: {s['remaining_sessions_worst_cell']:.3g} "
              f"sessions for the worst cell ({s['wall_s']:.0f} s)")
    print(f"  figure: {work / 'lifetime.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
