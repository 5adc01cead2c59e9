"""Regenerate the live-view screenshots and the screening heat map of docs/bench.md on a fresh
emulated chip (a temporary folder: your chip and history are never touched).

    .venv/bin/python docs/figures/make_watch_figures.py [--out docs/figures]

Runs, through the CLI: a cell test with user criteria on 64 cells (``--criteria-png``), then
the ``programming`` preset plan on four cells, and draws that run with ``snan-hil watch --run
ID --screenshot watch_plan.svg`` (Textual's own SVG screenshot, headless). About 20 s.
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
    args = ap.parse_args()
    out = Path(args.out)
    tmp = Path(tempfile.mkdtemp(prefix="snan-watch-fig-"))
    os.environ.update(SNAN_HIL_EMU_STATE=str(tmp / "chip.npz"), XDG_DATA_HOME=str(tmp / "d"))
    os.environ.pop("SNAN_HIL_PORT", None)
    try:
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
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
