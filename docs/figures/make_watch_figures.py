"""Regenerate the live-view screenshots and the screening heat map of docs/bench.md on a fresh
emulated chip (a temporary folder: your chip and history are never touched).

    .venv/bin/python docs/figures/make_watch_figures.py [--out docs/figures] [--only plan|compare]

Runs, through the CLI: a cell test with user criteria on 64 cells (``--criteria-png``), then
the ``programming`` preset plan on four cells, and draws that run with ``snan-hil watch --run
ID --screenshot watch_plan.svg`` (Textual's own SVG screenshot, headless). About 20 s. Then
(``compare``) a reduced comparison -- ``train`` 2 sets x 2 cycles on the 6 x 6 task, at most 15
steps a launch, and ``compare`` of the four scenarios, 3 launches each, on the emulated chip --
drawn as ``watch_compare.svg`` (the grid of the last launch with its path and calcium, the
running medians per scenario). About 15 s more.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import shutil
import tempfile
from pathlib import Path

from snan_hil.tools import cli


def _run(argv: list[str]) -> str:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = cli.main(argv)
    if code != 0:
        raise SystemExit(f"snan-hil {' '.join(argv)} exited with {code}")
    return buf.getvalue()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(Path(__file__).parent))
    ap.add_argument("--only", choices=("plan", "compare"), default=None,
                    help="make only these figures (default: all)")
    args = ap.parse_args()
    out = Path(args.out)
    tmp = Path(tempfile.mkdtemp(prefix="snan-watch-fig-"))
    os.environ.update(SNAN_HIL_EMU_STATE=str(tmp / "chip.npz"), XDG_DATA_HOME=str(tmp / "d"))
    os.environ.pop("SNAN_HIL_PORT", None)
    try:
        if args.only != "compare":
            _plan_figures(tmp, out)
        if args.only != "plan":
            _compare_figure(tmp, out)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _compare_figure(tmp: Path, out: Path) -> None:
    short = ["--set", "grid.max_steps=15"]
    weights = str(tmp / "w.npz")
    _run(["train", "--grid", "6", "--start", "18", "--goal", "0", "--sets", "2", "--cycles",
          "2", "--seed", "3", "-o", weights, "--json", *short])
    data = json.loads(_run(["compare", "--weights", weights, "--port", "emu", "--out",
                            str(tmp / "res"), "--launches", "3", "--no-figure", "--sample",
                            "chip A", "--json", *short]))
    _run(["watch", "--port", "emu", "--run", data["run"]["uid"], "--screenshot",
          str(out / "watch_compare.svg"), "--size", "130x44", "--force"])
    print(f"wrote {out / 'watch_compare.svg'}")


def _plan_figures(tmp: Path, out: Path) -> None:
    cells = [f"{r},{c}" for r in range(8) for c in range(8)]
    _run(["cells", "test", "--port", "emu", "--cells", *cells, "--ratio-above", "1.15",
          "--rmax-above", "3000", "--criteria-png", str(tmp / "criteria.png"), "--json"])
    data = json.loads(_run(["plan", "run", "programming", "--cells", "3,5", "4,6", "10,2",
                            "20,7", "--port", "emu", "--sample", "chip A",
                            "--operator", "ana", "--tag", "docs", "--json"]))
    uid = data["run"]["uid"]
    _run(["watch", "--port", "emu", "--run", uid, "--screenshot",
          str(tmp / "watch_plan.svg"), "--size", "130x44"])
    for name in ("criteria.png", "watch_plan.svg"):
        shutil.copyfile(tmp / name, out / name)
        print(f"wrote {out / name}")


if __name__ == "__main__":
    main()
