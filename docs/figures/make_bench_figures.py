"""Regenerate the example figures of docs/bench.md (one of each kind) on a fresh emulated chip.

    .venv/bin/python docs/figures/make_bench_figures.py [--out docs/figures] [--vectors 100]

Runs the real commands through the CLI (``snan_hil.tools.cli.main``) on an in-process emulator
whose chip lives in a temporary folder (your default chip and history are never touched), with
fixed seeds, and writes small PNGs (and one GIF) into ``--out``. It prints the Fig. 10B numbers
(RMS and max error in % of full scale, both protocols) that docs/bench.md quotes. Takes about a
minute on two cores.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

from snan_hil.calibration.testing import grid_weights
from snan_hil.tools import cli

FIGURES = ("program_trace.png", "retention.png", "mac_framed.png", "mac_legacy.png",
           "cells.png", "pulse.png", "cell_life.png", "map.png", "sim_3x3.png",
           "animation_3x3.gif", "criteria.png", "plan_iv.png")


def _run(argv: list[str]) -> str:
    """Run one snan-hil command; its stdout (raises if it fails)."""
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = cli.main(argv)
    if code != 0:
        raise SystemExit(f"snan-hil {' '.join(argv)} exited with {code}")
    return buf.getvalue()


def _shrink(path: Path) -> None:
    """Re-save a figure as a 128-colour palette PNG (a third of the size), keeping its text
    tag (so the commands still recognise it as theirs)."""
    from PIL import Image, PngImagePlugin
    with Image.open(path) as im:
        text = dict(getattr(im, "text", {}) or {})
        small = im.convert("RGB").quantize(colors=128, method=Image.Quantize.MEDIANCUT)
    info = PngImagePlugin.PngInfo()
    for k, v in text.items():
        info.add_text(k, v)
    small.save(path, format="PNG", optimize=True, pnginfo=info)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent))
    ap.add_argument("--vectors", type=int, default=100)
    ap.add_argument("--only", nargs="+", choices=("screening",), default=None,
                    help="only these: screening = criteria.png and plan_iv.png (a fresh chip)")
    args = ap.parse_args()
    if args.only:
        return _screening(Path(args.out))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="snan-bench-figures-"))
    os.environ["SNAN_HIL_EMU_STATE"] = str(work / "chip.npz")
    os.environ.pop("SNAN_HIL_PORT", None)
    try:
        np.save(work / "w.npy", grid_weights(6, 6, seed=1))
        _run(["program-weights", str(work / "w.npy"), "--port", "emu", "--json",
              "--trace", str(out / "program_trace.png"), "--force"])
        _run(["retention", "--port", "emu", "--reads", "2000", "--json",
              "--png", str(out / "retention.png"), "--force"])
        numbers = {}
        for protocol in ("framed", "legacy"):
            res = json.loads(_run(["mac", "--port", "emu", "--protocol", protocol,
                                   "--vectors", str(args.vectors), "--seed", "0",
                                   "--out", str(work / f"mac-{protocol}"), "--json"]))
            shutil.copy(work / f"mac-{protocol}" / "mac.png", out / f"mac_{protocol}.png")
            numbers[protocol] = res["summary"]
        _run(["cells", "test", "--port", "emu", "--all", "--json",
              "--png", str(out / "cells.png"), "--force"])
        _run(["pulse", "--port", "emu", "--cell", "30,6", "--polarity", "set", "--amplitude",
              "0.4:1.4:0.05", "--until-g", "600", "--json", "--png", str(out / "pulse.png"),
              "--force"])
        _run(["pulse", "--port", "emu", "--cell", "30,6", "--polarity", "reset",
              "--amplitude", "0.8", "--count", "30", "--window", "200+-5%", "--json"])
        _run(["history", "--port", "emu", "--cell", "30,6", "--json",
              "--png", str(out / "cell_life.png"), "--force"])
        _run(["map", "--port", "emu", "--json", "--png", str(out / "map.png"), "--force"])
        _run(["sim", "--grid", "3", "--trials", "500", "--seed", "1", "--json",
              "--plot", str(out / "sim_3x3.png"), "--animate", str(out / "animation_3x3.gif"),
              "--force"])  # the default trial: the first with >= 5 steps
    finally:
        shutil.rmtree(work, ignore_errors=True)
    for name in FIGURES:
        if name.endswith(".png"):
            _shrink(out / name)
    print("Fig. 10B (column multiply vs numpy, % of full scale):")
    for protocol, s in numbers.items():
        print(f"  {protocol:6s} {s['method']}: {s['samples']} multiplies, RMS "
              f"{s['rms_error_pct_fs']:.3f} %, max {s['max_error_pct_fs']:.3f} %, mean "
              f"{s['mean_error_pct_fs']:+.3f} %; against the read-back conductances RMS "
              f"{s['rms_error_pct_fs_readback']:.3f} %, max "
              f"{s['max_error_pct_fs_readback']:.3f} %")
    for name in FIGURES:
        p = out / name
        print(f"  {p} ({p.stat().st_size // 1024} KiB)")
    return 0


def _screening(out: Path) -> int:
    """criteria.png (cells test with the user's criteria: the switching window) and
    plan_iv.png (plan run iv-curve --png) on a fresh emulated chip."""
    work = Path(tempfile.mkdtemp(prefix="snan-bench-figures-"))
    os.environ["SNAN_HIL_EMU_STATE"] = str(work / "chip.npz")
    os.environ.pop("SNAN_HIL_PORT", None)
    try:
        _run(["cells", "test", "--port", "emu", "--cells", *(f"{r},{c}" for r in range(12)
                                                              for c in range(8)),
              "--ratio-above", "2", "--rmax-above", "36000", "--json",
              "--criteria-png", str(out / "criteria.png"), "--force"])
        _run(["plan", "run", "iv-curve", "--cells", "3,5", "4,4", "--port", "emu", "--json",
              "--png", str(out / "plan_iv.png"), "--force"])
    finally:
        shutil.rmtree(work, ignore_errors=True)
    for name in ("criteria.png", "plan_iv.png"):
        _shrink(out / name)
        print(f"  {out / name} ({(out / name).stat().st_size // 1024} KiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
