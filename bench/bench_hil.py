"""HIL benchmark: the full four-scenario comparison on the emulator (paper Fig. 10C/D).

Usage: ``python bench/bench_hil.py [--quick] [--sets K] [--launches L] [--repeat N] [--out DIR]``

In a temporary folder: ``snan-hil train`` of K weight sets (default 10, 20 cycles, seed 1),
then ``compare`` (programming every set, 4 scenarios x K sets x L launches, default 10) exactly
as ``snan-hil compare --weights W --port emu`` runs it, on a fresh default chip (seed 0).
``--repeat N`` runs the compare N times, each on a fresh chip (so every run computes the same
results; the script checks that), and reports the best wall time: the machine's 2 cores are
shared, so the best of several runs is the figure least disturbed by other jobs; the process
CPU time is printed next to it. Prints the comparison, the acceptance checks, the compare wall
time against the 40 s target (issue 14; 100-131 s before the emulator's whole-batch SPIKE_BATCH
path), the hardware decisions/s (wall), the virtual board time per decision, and the split of
the wall time. ``--quick``: 3 sets x 3 launches (the target applies to the full size only).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

WALL_TARGET_S = 40.0
"""Issue 14: ``snan-hil compare`` at full size on the emulator (10 sets x 10 launches x 4
scenarios, programming included) in at most 40 s of wall time."""


UART_FIELDS = ("virtual_us", "wire_us", "virtual_s")
"""Board-time fields that include UART time. A frame's COBS length (so its UART time) depends
by one byte on the link's first sequence number and the board's boot nonce in a few frames per
compare; on ``--port emu`` both are seeded now, so every run on a fresh chip gives the same
board times: they are compared with everything else (``differences()``), and
:meth:`CompareTiming.uart_spread_us` must be 0."""


def comparable(res: dict, skip: tuple[str, ...] = ()) -> str:
    """The results without wall-clock fields, the board id (each fresh chip has its own
    serial) and ``skip``: what must not change between runs."""
    def strip(x):
        if isinstance(x, dict):
            return {k: strip(v) for k, v in x.items()
                    if "wall" not in k
                    and k not in ("created", "decisions_per_s", "board_id", "chip_id", *skip)}
        if isinstance(x, list):
            return [strip(v) for v in x]
        return x
    keep = {k: v for k, v in res.items() if k not in ("speed_energy", "files")}
    return json.dumps(strip(keep), sort_keys=True, default=str)


@dataclass
class CompareTiming:
    """The compare runs of :func:`measure_compare`: wall and CPU time (s) and results of each."""

    runs: list[tuple[float, float, dict]]
    train_s: float

    @property
    def best(self) -> tuple[float, float, dict]:
        """(wall s, CPU s, results) of the fastest run."""
        return min(self.runs, key=lambda r: r[0])

    @property
    def same(self) -> bool:
        """Every run gave the same results (apart from wall-clock fields)."""
        return not self.differences()

    def differences(self, skip: tuple[str, ...] = ()) -> list[str]:
        """Paths of the result fields that differ between the first run and a later one."""
        first = json.loads(comparable(self.runs[0][2], skip))
        out: list[str] = []
        for _wall, _cpu, res in self.runs[1:]:
            _diff(first, json.loads(comparable(res, skip)), "", out)
        return out

    def uart_spread_us(self) -> float:
        """Largest difference between runs of a launch's board time (us), see UART_FIELDS."""
        rows = [[r["virtual_us"] for r in res["launch_rows"] if r["virtual_us"] is not None]
                for _w, _c, res in self.runs]
        return max((abs(a - b) for other in rows[1:] for a, b in zip(rows[0], other)),
                   default=0.0)


def _diff(a, b, path: str, out: list[str]) -> None:
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            _diff(a.get(k), b.get(k), f"{path}.{k}", out)
    elif isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b)):
            _diff(x, y, f"{path}[{i}]", out)
    elif a != b:
        out.append(f"{path}: {a!r} != {b!r}"[:200])


def measure_compare(work: Path, *, sets: int = 10, launches: int = 10, seed: int = 1,
                    repeat: int = 1, log=print) -> CompareTiming:
    """Train ``sets`` weight sets in ``work``, then run the compare ``repeat`` times, each on
    a fresh default chip (seed 0) in ``work``, as ``snan-hil compare --port emu`` runs it."""
    os.environ["SNAN_HIL_EMU_STATE"] = str(work / "chip.npz")   # never the user's chip
    from snan_hil.host.checkpoint import open_run
    from snan_hil.host.hil.compare import CompareJob, CompareRequest
    from snan_hil.lab.runner import RunOptions, run_job
    from snan_hil.lab.opener import plan_board
    from snan_hil.lab.ports import BoardAddress
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.hil.train import save_weights, train_sets

    hil = load_hil_config()
    t0 = time.perf_counter()
    trained = train_sets(hil.train_config(), sets=sets, cycles=hil.task.cycles, seed=seed,
                         start=hil.task.start, goal=hil.task.goal)
    wpath = save_weights(trained, work / "weights.npz")
    timing = CompareTiming([], time.perf_counter() - t0)
    for _ in range(max(1, repeat)):
        chip = work / "chip"                     # a fresh default chip (seed 0) every run
        shutil.rmtree(chip, ignore_errors=True)
        state = chip / "chip.npz"
        t1, c1 = time.perf_counter(), time.process_time()
        # as the CLI runs it: a board session per set, per-set checkpoints, chip snapshots
        folder = open_run(chip / "out", "compare", {"bench": True}, resume=False)
        request = CompareRequest(str(wpath), hil, launches=launches, seed=seed,
                                 report_dir=chip / "out" / "programming")
        board = plan_board(BoardAddress("emu", baud=115200, state_file=str(state), seed=0))
        res = run_job(CompareJob(request), board, RunOptions(record="off", folder=folder)).result
        timing.runs.append((time.perf_counter() - t1, time.process_time() - c1, res))
        log(f"compare run {len(timing.runs)}: {timing.runs[-1][0]:.1f} s wall, "
            f"{timing.runs[-1][1]:.1f} s CPU")
    return timing


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 sets x 3 launches")
    ap.add_argument("--sets", type=int, default=None)
    ap.add_argument("--launches", type=int, default=None)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=1,
                    help="run the compare N times on fresh chips; report the best wall time")
    ap.add_argument("--out", default=None, help="keep the results in this folder")
    args = ap.parse_args(argv)
    sets = args.sets or (3 if args.quick else 10)
    launches = args.launches or (3 if args.quick else 10)
    tmp = tempfile.TemporaryDirectory(prefix="bench_hil_")
    work = Path(tmp.name)
    from snan_hil.host.hil.compare import write_outputs
    from snan_hil.tools.commands.compare import print_results

    timing = measure_compare(work, sets=sets, launches=launches, seed=args.seed,
                             repeat=args.repeat, log=lambda text: print(text, flush=True))
    runs, same, t_train = timing.runs, timing.same, timing.train_s
    t_compare, cpu_compare, res = timing.best
    out = Path(args.out) if args.out else work / "results"
    write_outputs(res, out)
    print_results(res)
    hw = [r for r in res["launch_rows"] if r["scenario"].startswith("hw_")]
    dec = sum(r["decisions"] for r in hw)
    hw_wall = sum(r["wall_s"] for r in hw)
    virt = sum(r["virtual_us"] for r in hw)
    wire = sum(r["wire_us"] for r in hw)
    spikes = sum(r["spikes"] for r in hw)
    prog_s = sum((p.get("wall_s") or 0.0) for p in res["programming"].values())
    sw_wall = sum(r["wall_s"] for r in res["launch_rows"] if r["scenario"].startswith("sw_"))
    print()
    print(f"HIL benchmark: {sets} sets x {launches} launches x 4 scenarios "
          f"(in-process emulator, 115200 baud, default chip seed 0)")
    full = sets == 10 and launches == 10
    rows = [
        ("compare wall time (program + 4 scenarios)", f"{t_compare:.1f} s",
         f"<= {WALL_TARGET_S:.0f} s" + ("" if full else " (full size only)"),
         ("ok" if t_compare <= WALL_TARGET_S else "OVER") if full else "-"),
        (f"  best of {len(runs)} run(s); all runs", ", ".join(f"{r[0]:.1f}" for r in runs)
         + " s", "", "same results" if same else "RESULTS DIFFER"),
        ("  largest run-to-run difference of a launch's board time",
         f"{timing.uart_spread_us():.0f} us", "0 (seeded link and nonce)", ""),
        ("  process CPU time of that run", f"{cpu_compare:.1f} s", "", ""),
        ("  of which programming", f"{prog_s:.1f} s", "", ""),
        ("  of which hardware launches", f"{hw_wall:.1f} s", "", ""),
        ("  of which software launches", f"{sw_wall:.2f} s", "", ""),
        ("training (not part of compare)", f"{t_train:.1f} s", "", ""),
        ("hw decisions", f"{dec}", "", ""),
        ("hw decisions/s (wall)", f"{dec / hw_wall:.1f}" if hw_wall else "-", "", ""),
        ("input spikes per decision", f"{spikes / dec:.0f}" if dec else "-", "", ""),
        ("virtual board time per decision incl. UART", f"{virt / dec / 1e3:.1f} ms"
         if dec else "-", "", ""),
        ("  on the board (without UART)", f"{(virt - wire) / dec / 1e3:.2f} ms"
         if dec else "-", "", ""),
        ("  per input spike on the board", f"{(virt - wire) / spikes:.0f} us"
         if spikes else "-", "", ""),
    ]
    w = max(len(r[0]) for r in rows)
    print(f"{'measurement':<{w}}  {'value':>12}  {'target':<24} status")
    for name, value, target, status in rows:
        print(f"{name:<{w}}  {value:>12}  {target:<24} {status}")
    print(f"results: {out}" + ("" if args.out else " (temporary, removed at exit)"))
    print("machine: 2 cores shared with other jobs; the best wall time of the runs is shown")
    for line in timing.differences()[:20]:
        print("results differ:", line)
    tmp.cleanup()
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
