"""``snan-hil characterize --from FILE``: the device model of pulses measured elsewhere (a lab's
pulse CSV, this project's history export or characterise CSV), no board opened
(:mod:`snan_hil.calibration.pulse_files`, :func:`snan_hil.calibration.characterize.fit_samples`).

The model is fitted at one learning pulse (``--set-v/--reset-v/--width-us``, each defaulting to
the file's commonest pulse of its polarity), stated at the default weight map's middle
(525 uS) when the data cover it, else at the geometric middle of the data; the read noise is
``--read-noise`` or estimated from the steps' scatter. ``--holdout N`` (default 3) prints how
the model predicts every N-th train of each cell when fitted without them.
"""

from __future__ import annotations

import argparse
import json
import math

from snan_hil.calibration.characterize import check_holdout, fit_samples, holdout_of
from snan_hil.calibration.mapping import WeightMap
from snan_hil.calibration.pulse_files import read_pulse_file, retention_pairs
from snan_hil.common.errors import UserError
from snan_hil.crossbar_model.fitted import LearningPulse
from snan_hil.crossbar_model.validation import estimate_read_noise
from snan_hil.files.atomicio import atomic_write_json
from snan_hil.files.outputs import Outputs
from snan_hil.tools.commands._characterize_out import (FIT_PNG, MODEL_JSON, SAMPLES_CSV,
                                                       print_holdout, print_model,
                                                       write_samples_csv)
from snan_hil.tools.console import console, warn
from snan_hil.tools.device_figures import plot_device_fit

RESULT_FORMAT = "snan-hil-characterize-from/1"

_BOARD_ONLY = ("cells", "max_cells", "repeats", "max_pulses", "layout")


def _refuse_board_options(args: argparse.Namespace) -> None:
    defaults = {"cells": "synapses", "max_cells": None, "repeats": 2, "max_pulses": 250,
                "layout": None}
    for name in _BOARD_ONLY:
        if getattr(args, name, defaults[name]) != defaults[name]:
            raise UserError(f"--{name.replace('_', '-')} sets a sweep on a board; --from fits "
                            "pulses measured already: drop one of them")


def _pulse(args: argparse.Namespace, detected: LearningPulse) -> LearningPulse:
    set_v = args.set_v if args.set_v is not None else detected.set_v
    reset_v = args.reset_v if args.reset_v is not None else detected.reset_v
    width = args.width_us if args.width_us is not None else detected.width_us
    try:
        return LearningPulse(set_v, reset_v, width)
    except ValueError as exc:
        raise UserError(f"characterize --from: {exc}") from None


def run_from_file(args: argparse.Namespace) -> int:
    _refuse_board_options(args)
    if args.read_noise is not None and not (math.isfinite(args.read_noise)
                                            and 0 < args.read_noise < 1):
        raise UserError(f"--read-noise is a relative std between 0 and 1, got {args.read_noise}")
    every = 3 if args.holdout is None else args.holdout
    check_holdout(every, "--holdout")
    outs = Outputs({"--from": args.from_file}, force=args.force)
    png = outs.file("--png", args.png, FIT_PNG) if args.png else None
    csv_path = outs.file("--csv", args.csv, SAMPLES_CSV) if args.csv else None
    model_path = outs.file("--model", args.model, MODEL_JSON) if args.model else None
    pf = read_pulse_file(args.from_file)
    given = all(getattr(args, k) is not None for k in ("set_v", "reset_v", "width_us"))
    pulse = _pulse(args, LearningPulse() if given or pf.form == "characterize"
                   else pf.most_common_pulse())
    samples = pf.samples(pulse)
    lo = min(min(s.g_before_s, s.g_after_s) for s in samples)
    hi = max(max(s.g_before_s, s.g_after_s) for s in samples)
    g_ref = WeightMap().conductance(0.5)
    if not lo < g_ref < hi:
        g_ref = math.sqrt(lo * hi)
    if args.read_noise is not None:
        read_noise, noise_source = float(args.read_noise), "--read-noise"
    else:
        read_noise = estimate_read_noise(samples)
        noise_source = "estimated from the steps' scatter"
        if not math.isfinite(read_noise):
            raise UserError(f"{pf.path}: too few pulses per cell to estimate the read noise "
                            "from the steps' scatter; give --read-noise (relative std of one "
                            "read)")
    meta = {"source": str(pf.path), "form": pf.form, "read_noise_source": noise_source,
            **({"cell_names": {k: list(v) for k, v in pf.cell_names.items()}}
               if pf.cell_names else {})}
    try:
        model = fit_samples(samples, pulse, g_ref_s=g_ref, read_noise=read_noise, meta=meta,
                            retention=retention_pairs(pf))
    except ValueError as exc:
        raise UserError(f"characterize --from {pf.path}: {exc}") from None
    held = holdout_of(samples, model, every, warn)
    if model_path is not None:
        atomic_write_json(model_path, model.to_dict(), indent=1, allow_nan=False)
    if csv_path is not None:
        write_samples_csv(samples, str(csv_path))
    if png is not None:
        plot_device_fit(model, samples, png, title=f"device response from {pf.path.name}")
    if args.json:
        doc = {"format": RESULT_FORMAT, "from": str(pf.path), "form": pf.form,
               "pulses_in_file": len(pf.rows), "samples": len(samples),
               "model": model.to_dict(), "holdout": None if held is None else held.to_dict()}
        print(json.dumps(doc, indent=1, allow_nan=False,
                         default=lambda v: None if isinstance(v, float) else str(v)))
        return 0
    fitted = sum(1 for c in model.cells if c.ok)
    print_model(model, cells_text=f"{fitted} of {len(model.cells)} cells fitted from "
                                  f"{pf.path.name}, {pf.form} form")
    console.print(f"{len(samples)} of the file's {len(pf.rows)} pulses are at this pulse; "
                  f"read noise {read_noise:.4g} ({noise_source})", highlight=False)
    print_holdout(held, every)
    for opt, path in (("--png", args.png), ("--csv", args.csv), ("--model", args.model)):
        if path:
            console.print(f"wrote {opt} {path}", highlight=False)
    return 0
