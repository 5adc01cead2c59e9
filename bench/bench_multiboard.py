"""Several boards in one run (issue 25): ``compare`` over 3 emulated boards vs 1.

Usage: ``python bench/bench_multiboard.py [--sets 6] [--boards 3] [--launches 10]
[--max-steps N]``

In a temporary folder: a 6x6 weights file (``snan-hil train``, --sets sets, 2 cycles, seed 3;
``--max-steps``: at most N steps a launch, default the config's), then ``snan-hil compare``
over all sets

1. on one emulated board (``--port emu://?state=one.npz``), and
2. over --boards emulated boards (``--boards emu://?state=b0.npz,...``: a Dask LocalCluster,
   one worker process per board),

each as a subprocess, timed with the wall clock (worker start-up included). Target: wall time
of the several-board run <= 0.5 x the one-board run's (the emulators share this machine's
cores: with 2 cores the ratio cannot go below about 0.5 whatever the boards).

``--paced S``: instead of in-process ``emu://`` chips (which never wait: pure host CPU, so three
of them on two cores cannot run faster than half of one's CPU work), each board is an emulator
served over TCP (``snan-hil emu --socket 127.0.0.1:0 --wall-scale S``) that holds every reply
until S x its board time has passed, as a real board takes its time (S = 1: real time; the
UART is not paced). That is the regime of real boards, where the host mostly waits.

Then the wire-time model for real boards: per set, the board time the one-board report records
(programming: ``virtual_s``; launches: ``virtual_us``, which includes the UART time at the
baud, and the UART share ``wire_us`` alone) summed per board as the several-board run
assigned the sets (balanced by each set's predicted board time, ``lab.boards.assign``; the
split by position, p mod B, is printed beside it); the expected speed-up of B real boards =
the one-board sum / the largest board's sum (the host's own time is left out: on a real
board the UART and the board dominate, e.g. ~94 min a compare over the legacy per-spike protocol).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PY = [sys.executable, "-m", "snan_hil.tools.cli"]
TARGET_RATIO = 0.5


def run(argv: list[str], env: dict[str, str]) -> float:
    t = time.perf_counter()
    done = subprocess.run([*PY, *argv], env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if done.returncode != 0:
        sys.exit(f"{' '.join(argv[:3])} failed: {done.stderr.strip()[-400:]}")
    return wall


def serve(chip: Path, scale: float, env: dict[str, str]) -> tuple[subprocess.Popen, str]:
    """An emulator serving ``chip`` on a free TCP port, replies paced at ``scale``: (process,
    its socket:// URL)."""
    proc = subprocess.Popen([*PY, "emu", "--socket", "127.0.0.1:0", "--state", str(chip),
                             "--wall-scale", str(scale)], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    assert proc.stdout is not None
    for line in proc.stdout:              # "... serving on socket://127.0.0.1:PORT"
        if "serving on" in line:
            return proc, line.split("serving on", 1)[1].split()[0]
    proc.kill()
    sys.exit(f"the emulator for {chip} did not start")


def board_seconds(res: dict, k: int) -> tuple[float, float]:
    """(board time, UART time) of set k in s: programming + hardware launches."""
    prog = res["programming"].get(str(k)) or {}
    board = float(prog.get("virtual_s") or 0.0)
    wire = 0.0
    for row in res["launch_rows"]:
        if row["set"] == k and row["scenario"].startswith("hw_"):
            board += (row["virtual_us"] or 0.0) * 1e-6
            wire += (row["wire_us"] or 0.0) * 1e-6
    return board, wire


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sets", type=int, default=6)
    ap.add_argument("--boards", type=int, default=3)
    ap.add_argument("--launches", type=int, default=10)
    ap.add_argument("--max-steps", type=int, default=None)
    ap.add_argument("--paced", type=float, default=None, metavar="S",
                    help="boards served over TCP, replies paced at S x board time "
                         "(default: in-process emu:// chips, no pacing)")
    args = ap.parse_args()
    short = [] if args.max_steps is None else ["--set", f"grid.max_steps={args.max_steps}"]
    with tempfile.TemporaryDirectory(prefix="bench-multiboard-") as tmp:
        d = Path(tmp)
        env = dict(os.environ, XDG_DATA_HOME=str(d / "xdg"))
        weights = d / "w.npz"
        run(["train", "--grid", "6", "--start", "18", "--goal", "0", "--sets", str(args.sets),
             "--cycles", "2", "--seed", "3", "-o", str(weights), "--json", *short], env)
        common = ["compare", "--weights", str(weights), "--launches", str(args.launches),
                  "--seed", "4", "--json", "--no-figure", "--record", "off", *short]
        servers: list[subprocess.Popen] = []

        def board(name: str) -> str:
            if args.paced is None:
                return f"emu://?state={d / name}"
            proc, url = serve(d / name, args.paced, env)
            servers.append(proc)
            return url
        try:
            one = run([*common, "--out", str(d / "one"), "--port", board("one.npz")], env)
            ports = ",".join(board(f"b{i}.npz") for i in range(args.boards))
            many = run([*common, "--out", str(d / "many"), "--boards", ports], env)
        finally:
            for proc in servers:
                proc.terminate()
                proc.wait(timeout=30)
        res = json.loads((d / "one" / "compare.json").read_text())
        multi = json.loads((d / "many" / "compare.json").read_text())
    ratio = many / one
    kind = "in-process emu:// chips" if args.paced is None else \
        f"emulators over TCP paced at {args.paced:g} x board time"
    steps = args.max_steps if args.max_steps is not None else "the config's"
    print(f"compare, {args.sets} sets x 4 scenarios x {args.launches} launches, max_steps "
          f"{steps}, {kind}, {os.cpu_count()} cores")
    print(f"  1 board:            {one:7.1f} s wall")
    print(f"  {args.boards} boards (Dask):   {many:7.1f} s wall")
    print(f"  ratio {ratio:.2f} (target <= {TARGET_RATIO}): "
          f"{'met' if ratio <= TARGET_RATIO else 'NOT met'}")
    units = {int(k): v["board"] for k, v in multi["units"].items()}
    print("  sets per board: " + ", ".join(
        f"board {b}: {[k for k, v in sorted(units.items()) if v == b]}"
        for b in range(args.boards)))
    per_set = {k: board_seconds(res, k) for k in res["sets"]}
    by_position = {k: p % args.boards for p, k in enumerate(res["sets"])}
    for label, idx in (("board time (programming + launches, incl. UART)", 0),
                       ("UART time of the launches alone", 1)):
        total = sum(v[idx] for v in per_set.values())
        for split, where in (("as assigned", units), ("by position", by_position)):
            per_board = [0.0] * args.boards
            for k in res["sets"]:
                per_board[where[k]] += per_set[k][idx]
            worst = max(per_board)
            speedup = total / worst if worst > 0 else float("nan")
            print(f"  wire-time model, {label}, {split}: 1 board {total:.1f} s, "
                  f"{args.boards} boards {worst:.1f} s (largest board; "
                  f"{' / '.join(f'{x:.1f}' for x in per_board)}) -> expected speed-up "
                  f"{speedup:.2f}x (ideal {args.boards}x)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
