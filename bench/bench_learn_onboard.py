"""On-board learning against the host's STDP on the chip (issue 34 stage 1, point 5): paired
sessions of the 6x6 task (18 -> 0) on copies of one fresh emulated chip (the Python MCU with
``BoardConfig.on_board_learning``), each session's initial weights programmed by two-stage
write-and-verify on both copies, the synapses read by the board's decision window in both;
learnt by the host (the motor spikes answered, STDP and the pulse plan on the host, every pulse
a WRITE_PULSE) or by the board (LEARN_WINDOW / LEARN_APPLY). Both plan with the same chip
curve (``host/hil/learn_onboard.py``).

Usage: ``python bench/bench_learn_onboard.py [--sessions 10] [--cycles 20] [--seed 1]``.

Targets (issue 34 point 4): wire bytes per learning cycle <= 1 kB; 0 pulses sent by the host;
route medians per cycle inside each other's 95 % intervals; ledger totals within 5 %. Prints
measured vs target.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

BYTES_TARGET = 1000
LEDGER_TOLERANCE = 0.05


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=10)
    ap.add_argument("--cycles", type=int, default=20)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args(argv)
    from snan_hil.firmware_emu.testing import learning_client
    from snan_hil.host.hil.learn_arms import LearnConfig, LearnTask
    from snan_hil.host.hil.learn_onboard import paired_session
    from snan_hil.host.hil.testing import program_session
    from snan_hil.host.intervals import interval_fields
    from snan_hil.tools.commands.learn import model_config
    from snan_hil.tools.learn_agreement import fitted_chip_model
    cfg, start, goal = model_config(argparse.Namespace(grid=6, start=None, goal=None,
                                                       config=None, overrides=[]))
    task = LearnTask(cfg, LearnConfig(start=start, goal=goal, sessions=a.sessions,
                                      cycles=a.cycles, seed=a.seed))
    model = fitted_chip_model()
    runs: dict[str, list] = {"host": [], "board": []}
    t0 = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        clients = {"host": learning_client(0), "board": learning_client(0)}
        for k in range(a.sessions):
            for name, client in clients.items():
                folder = Path(tmp) / name
                folder.mkdir(exist_ok=True)
                layout = program_session(client, task, k, folder / "layout.json")
                runs[name].append(paired_session(task, k, client, layout, model, name))
            print(f"session {k}: host {runs['host'][-1].tests[-1]}, board "
                  f"{runs['board'][-1].tests[-1]} ({time.time() - t0:.0f} s)", flush=True)
            if a.json:                              # what is done so far, after each session
                a.json.write_text(json.dumps({n: [r.to_dict() for r in rs]
                                              for n, rs in runs.items()}))
    cycles = a.cycles
    inside = 0
    rows = []
    for c in range(cycles + 1):
        f = {}
        for name, rs in runs.items():
            steps = np.array([r.tests[c][0] for r in rs])
            ok = np.array([r.tests[c][1] for r in rs], dtype=bool)
            f[name] = (float(np.median(steps[ok])) if ok.any() else None,
                       interval_fields(steps, ok, seed=0)["median_steps_ci"], ok.mean())
        (mh, ih, sh), (mb, ib, sb) = f["host"], f["board"]
        both = (mh is not None and mb is not None and ih[0] <= mb <= ih[1]
                and ib[0] <= mh <= ib[1])
        inside += both
        rows.append((c, mh, ih, sh, mb, ib, sb, both))
    for c, mh, ih, sh, mb, ib, sb, both in rows:
        print(f"cycle {c:2d}: host median {mh} {ih} success {sh:.0%} | board median {mb} {ib} "
              f"success {sb:.0%} | inside each other's intervals: {'yes' if both else 'NO'}")

    def per_cycle(name: str) -> float:
        return float(np.median([b for r in runs[name] for b in r.wire_bytes]))

    def decisions(name: str) -> float:
        return float(np.median([d for r in runs[name] for d in r.decisions]))
    host_sent = sum(sum(r.host_pulses) for r in runs["board"])
    led = {n: sum(r.ledger["set"] + r.ledger["reset"] for r in rs) for n, rs in runs.items()}
    counter = {n: sum(r.board_counter for r in rs) for n, rs in runs.items()}
    diff = abs(led["board"] - led["host"]) / max(led["host"], 1)
    print(f"wire bytes per learning cycle (median, train + plan + pulses + test): board "
          f"{per_cycle('board'):.0f} B over {decisions('board'):.0f} decisions, host STDP "
          f"{per_cycle('host'):.0f} B over {decisions('host'):.0f} (target <= {BYTES_TARGET} B: "
          f"{'met' if per_cycle('board') <= BYTES_TARGET else 'MISSED'})")
    print(f"pulses sent by the host with on-board learning: {host_sent} (target 0: "
          f"{'met' if host_sent == 0 else 'MISSED'})")
    print(f"ledger totals: board {led['board']} (its counter {counter['board']}), host STDP "
          f"{led['host']} (counter {counter['host']}): {100 * diff:.1f} % apart (target <= 5 %: "
          f"{'met' if diff <= LEDGER_TOLERANCE else 'MISSED'})")
    print(f"route medians inside each other's intervals: {inside} of {cycles + 1} cycles")
    print(f"{a.sessions} sessions x {cycles} cycles, {time.time() - t0:.0f} s wall")
    if a.json:
        a.json.write_text(json.dumps({n: [r.to_dict() for r in rs] for n, rs in runs.items()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
