"""Learning within a budget (issue 36 point 5): the 6x6 route learning with <= 200 learning
pulses a session and <= 30 a synapse cell, against today's success on paired seeds.

Usage: ``python bench/bench_budget.py [--device-sessions N] [--chip-sessions M] [--out DIR]
[--quick]``

The budget (docs/learning.md section 8): buffered transfer with a session budget of 200
pulses granted first to the synapses the latest trial updated (then the largest pending change
left), at most 30 per cell and session and 2 per cell and cycle, paced (a cycle takes at most
15 % of what the session has left), at the learning pulse SET 1.2 V / RESET 0.6 V (100 us).
Today: no budget, SET 0.8 V / RESET 0.6 V.

1. A fresh emulated chip (seed 0) characterised at both pulses on the 120 synapse cells
   (rows 0-14).
2. **Device-model arm**, N paired sessions (default 100; seeds 1..): today's rule with
   today's model, the budget with the 1.2 V model: cycle-20 success and median route with
   95 % intervals, learning pulses per session (mean, largest) and per cell (largest), and
   the paired comparison (sessions one arm solved and the other did not; McNemar's exact
   test).
3. **Chip arm** on the emulated chip (``snan-hil learn --arms chip``), M paired sessions
   (default 20), today's and budgeted: the same figures, the per-cell counts from the run's
   ``cell_ledger.csv``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

SESSION_BUDGET = 200
CELL_BUDGET = 30
BUDGET_ARGS = ["--pulse-budget", "200", "--cell-budget", "30", "--plan-pulses", "2", "--pace",
               "0.15", "--set-v", "1.2", "--reset-v", "0.6"]


def mcnemar(a: list[bool], b: list[bool]) -> tuple[int, int, float]:
    """(a solved / b not, b solved / a not, exact two-sided p)."""
    n10 = sum(1 for x, y in zip(a, b) if x and not y)
    n01 = sum(1 for x, y in zip(a, b) if y and not x)
    m, k = n10 + n01, min(n10, n01)
    p = 1.0 if m == 0 else min(1.0, 2 * sum(math.comb(m, i) for i in range(k + 1)) / 2 ** m)
    return n10, n01, p


def characterise(work: Path, cells: str, set_v: float) -> Path:
    from snan_hil.tools import cli
    path = work / f"model-{set_v:g}V.json"
    if not path.is_file():
        with contextlib.redirect_stdout(io.StringIO()):
            rc = cli.main(["characterize", "--port", "emu", "--cells", cells, "--set-v",
                           f"{set_v:g}", "--reset-v", "0.6", "--model", str(path), "--json",
                           "--force"])
        if rc:
            raise SystemExit(rc)
    return path


def line(name: str, sessions: list[dict], curves: dict, cell_max: int | None) -> str:
    pulses = [sum(s["pulses"]) for s in sessions]
    ci = curves["success_ci"][-1]
    return (f"  {name:30s} success {100 * curves['success'][-1]:.0f} % [{100 * ci[0]:.0f}, "
            f"{100 * ci[1]:.0f}], median route {curves['median'][-1]} "
            f"{curves['median_ci'][-1]}; learning pulses / session mean "
            f"{sum(pulses) / len(pulses):.0f}, max {max(pulses)}"
            + ("" if cell_max is None else f"; per cell and session max {cell_max}"))


def device_arm(work: Path, n: int) -> None:
    from snan_hil.crossbar_model.fitted import DeviceModel
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.hil.learn import LearnConfig, run_learning
    from snan_hil.host.hil.learning import PulseBudget
    hil = load_hil_config(None, [])
    t0 = time.perf_counter()
    results = {}
    for name, set_v, budget in (("today (0.8 V, no budget)", 0.8, PulseBudget()),
                                ("budget (1.2 V, 200 / 30)", 1.2,
                                 PulseBudget(SESSION_BUDGET, CELL_BUDGET, 2, 0.5, 0.15))):
        model = DeviceModel.from_dict(json.loads((work / f"model-{set_v:g}V.json").read_text()))
        lc = LearnConfig(start=hil.task.start, goal=hil.task.goal, sessions=n, cycles=20,
                         seed=1, arms=("device",), budget=budget, pulse=model.pulse)
        results[name] = run_learning(hil.model, lc, model=model)["arms"]["device"]
    print(f"2. device-model arm, {n} paired sessions x 20 cycles "
          f"({time.perf_counter() - t0:.0f} s):")
    solved = {}
    for name, arm in results.items():
        cell_max = max(s["max_cell_pulses"] for s in arm["sessions"])
        print(line(name, arm["sessions"], arm["curves"], cell_max))
        solved[name] = [s["test_success"][-1] for s in arm["sessions"]]
    a, b = solved.values()
    n10, n01, p = mcnemar(a, b)
    print(f"  paired: today solved / budget not {n10}, budget solved / today not {n01}; "
          f"McNemar exact p = {p:.2f} (a difference is shown at p < 0.05)")


def chip_arm(work: Path, n: int, cells: str) -> None:
    from snan_hil.host.hil.learn_dataset import load_dataset
    from snan_hil.tools import cli
    t0 = time.perf_counter()
    out = {}
    for name, extra, model in (("today (0.8 V, no budget)", [], "model-0.8V.json"),
                               ("budget (1.2 V, 200 / 30)", BUDGET_ARGS, "model-1.2V.json")):
        folder = work / ("chip-today" if not extra else "chip-budget")
        with contextlib.redirect_stdout(io.StringIO()):
            rc = cli.main(["learn", "--port", "emu", "--arms", "chip", "--sessions", str(n),
                           "--model", str(work / model), "--out", str(folder), "--json",
                           "--force", "--no-figure", *extra]
                          + (["--resume"] if (folder / "checkpoint").exists() else []))
        if rc:
            raise SystemExit(rc)
        doc = json.loads((folder / "learn.json").read_text())
        data = load_dataset(folder)
        cell_max = max(max(data.per_cell(k).values(), default=0) for k in range(n))
        out[name] = ([s["test_success"][-1] for s in doc["arms"]["chip"]["sessions"]],
                     line(name, doc["arms"]["chip"]["sessions"], doc["arms"]["chip"]["curves"],
                          cell_max))
    print(f"3. chip arm on the emulated chip, {n} paired sessions ({time.perf_counter() - t0:.0f}"
          " s):")
    for _ok, text in out.values():
        print(text)
    a, b = (v[0] for v in out.values())
    n10, n01, p = mcnemar(a, b)
    print(f"  paired: today solved / budget not {n10}, budget solved / today not {n01}; "
          f"McNemar exact p = {p:.2f}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device-sessions", type=int, default=100)
    ap.add_argument("--chip-sessions", type=int, default=20)
    ap.add_argument("--out", default=None)
    ap.add_argument("--quick", action="store_true", help="24 cells, 10 / 2 sessions")
    a = ap.parse_args(argv)
    if a.quick:
        a.device_sessions, a.chip_sessions = 10, 2
    work = Path(a.out) if a.out else Path(tempfile.mkdtemp(prefix="bench-budget-"))
    work.mkdir(parents=True, exist_ok=True)
    os.environ["SNAN_HIL_EMU_STATE"] = str(work / "chip.npz")
    os.environ["XDG_DATA_HOME"] = str(work / "data")
    rows = 3 if a.quick else 15
    cells = ";".join(f"{r},{c}" for r in range(rows) for c in range(8))
    for v in (0.8, 1.2):
        characterise(work, cells, v)
    print(f"learning within a budget: <= {SESSION_BUDGET} learning pulses a session, <= "
          f"{CELL_BUDGET} a cell ({work})")
    device_arm(work, a.device_sessions)
    if a.chip_sessions:
        chip_arm(work, a.chip_sessions, cells)
    return 0


if __name__ == "__main__":
    sys.exit(main())
