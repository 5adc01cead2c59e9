"""The aihwkit export loaded in IBM aihwkit (issue 36 point 4): the exported device, pulsed by
aihwkit itself, steps as the fitted model does.

Usage: ``python bench/bench_aihwkit.py [--model MODEL.json] [--python PYTHON] [--out DIR]``

aihwkit is an optional extra (``pip install -e '.[aihwkit]'``), not the test environment:
aihwkit 1.2.0 publishes no wheel for CPython 3.11 on Linux, so pip builds it from source
(CMake, a C++ compiler, OpenBLAS headers, torch at build time). The check runs
``bench/aihwkit_check.py`` with ``--python`` (default: ``$SNAN_HIL_AIHWKIT_PYTHON``, else this
interpreter); when no interpreter has aihwkit the bench says so with the import error.

Without ``--model`` the model is characterised first (a fresh emulated chip, seed 0, the 24
cells of rows 0-2). Printed, measured against the target (the export's mapping, docs/
crossbar_model.md section 7): the noise-free up / down traces of aihwkit's
``PiecewiseStepDevice`` against the model's chip curve pulsed the same way in the export's
weight (largest difference in weight units, target <= 0.02 of the range), and the spread of
one step over 400 aihwkit devices against the model's cycle-to-cycle and device-to-device
spreads.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

TRACE_TARGET = 0.02          #: of the weight range [-1, 1]
PULSES = 120


def model_trace(model, w0: float, up: bool, n: int) -> list[float]:
    from snan_hil.common.polarity import Polarity
    from snan_hil.crossbar_model.export import weight_scale
    x_c, s = weight_scale(model)
    pol = Polarity.SET if up else Polarity.RESET
    w, out = w0, []
    for _ in range(n):
        w += float(model.mean_dx(pol, math.exp(x_c + s * w))) / s
        out.append(w)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default=None)
    ap.add_argument("--python", default=os.environ.get("SNAN_HIL_AIHWKIT_PYTHON",
                                                       sys.executable))
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    from snan_hil.crossbar_model.device_twin import load_device_model
    from snan_hil.crossbar_model.export import aihwkit_export
    from snan_hil.tools import cli
    work = Path(a.out) if a.out else Path(tempfile.mkdtemp(prefix="bench-aihwkit-"))
    work.mkdir(parents=True, exist_ok=True)
    model_path = Path(a.model) if a.model else work / "model.json"
    if not a.model:
        os.environ["SNAN_HIL_EMU_STATE"] = str(work / "chip.npz")
        os.environ["XDG_DATA_HOME"] = str(work / "data")
        cells = ";".join(f"{r},{c}" for r in range(3) for c in range(8))
        with contextlib.redirect_stdout(io.StringIO()):
            rc = cli.main(["characterize", "--port", "emu", "--cells", cells, "--model",
                           str(model_path), "--json", "--force"])
        if rc:
            return rc
    model = load_device_model(model_path)
    export = work / "aihwkit.json"
    export.write_text(json.dumps(aihwkit_export(model)))
    proc = subprocess.run([a.python, str(Path(__file__).with_name("aihwkit_check.py")),
                           str(export), str(PULSES)], capture_output=True, text=True)
    if proc.returncode:
        last = (proc.stderr.strip().splitlines() or ["(no output)"])[-1]
        print(f"aihwkit check NOT RUN: {a.python} cannot run aihwkit ({last}); install it "
              "with pip install -e '.[aihwkit]' (a source build: CMake, C++, OpenBLAS, torch) "
              "or give --python / SNAN_HIL_AIHWKIT_PYTHON")
        return 0
    got = json.loads(proc.stdout)
    print(f"aihwkit {got['aihwkit']}: the export's {got['class']} loaded and pulsed by aihwkit "
          f"({work})")
    worst = 0.0
    for name, w0, up in (("up", -1.0, True), ("down", 1.0, False)):
        want = np.array(model_trace(model, w0, up, PULSES))
        have = np.array(got[name])
        diff = float(np.max(np.abs(have - want)))
        worst = max(worst, diff)
        print(f"  {PULSES} noise-free {name} pulses from w = {w0:+.0f}: aihwkit ends at "
              f"{have[-1]:+.3f}, the model at {want[-1]:+.3f}; largest difference "
              f"{diff:.4f} (of the range 2)")
    ok = worst <= TRACE_TARGET * 2
    print(f"  traces agree within {TRACE_TARGET:.0%} of the range: {'MET' if ok else 'NOT MET'}")
    sp = got["spread"]
    p = json.loads(export.read_text())["device"]["parameters"]
    for d, sign in (("up", 1), ("down", -1)):
        mean_want = p["dw_min"] * (1 + sign * p["up_down"])
        rel_std = sp[f"{d}_std"] / abs(sp[f"{d}_mean"])
        want_std = math.sqrt(p["dw_min_std"] ** 2 + p["dw_min_dtod"] ** 2
                             + p["up_down_dtod"] ** 2)
        print(f"  one {d} step over 400 aihwkit devices at w = 0: mean {abs(sp[d + '_mean']):.4g} "
              f"(export {mean_want:.4g}), relative std {rel_std:.3f} (cycle-to-cycle and "
              f"device-to-device combined: {want_std:.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
