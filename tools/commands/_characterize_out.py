"""What ``snan-hil characterize`` writes and prints, on a board and ``--from`` a pulse file
alike: the output files' kinds, the ``--csv`` of the pulses, the model's table and the
held-out validation's line."""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence

from rich.table import Table

from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.fitted import MODEL_FORMAT, DeviceModel, PulseSample
from snan_hil.crossbar_model.validation import HeldOut
from snan_hil.files.atomicio import atomic_path
from snan_hil.files.outputs import csv_kind, json_kind, png_kind
from snan_hil.tools.console import console
from snan_hil.tools.device_figures import DEVICE_FIT_PNG_FORMAT

__all__ = ["SAMPLES_HEADER", "MODEL_JSON", "SAMPLES_CSV", "FIT_PNG", "MEANING",
           "write_samples_csv", "print_model", "print_holdout"]

SAMPLES_HEADER = "row,col,polarity,g_before_s,g_after_s"
MODEL_JSON = json_kind(MODEL_FORMAT, "a snan-hil device model")
SAMPLES_CSV = csv_kind(SAMPLES_HEADER, "a 'snan-hil characterize' CSV")
FIT_PNG = png_kind(DEVICE_FIT_PNG_FORMAT, "a 'snan-hil characterize' figure")

#: what each parameter means, for the printed table
MEANING = {
    "dw_min": "mean |dlnG| of one pulse at g_ref (both directions)",
    "up_down": "up/down bias: SET step dw_min(1+up_down), RESET dw_min(1-up_down)",
    "dw_min_dtod": "device-to-device spread of a cell's mean step (relative)",
    "up_down_dtod": "device-to-device spread of up_down",
    "dw_min_std": "cycle-to-cycle spread of one step (relative; read noise removed)",
    "g_min_s": "lower bound of the chip curve (S; aihwkit w_min)",
    "g_max_s": "upper bound of the chip curve (S; aihwkit w_max)",
    "g_min_dtod": "spread of the cells' lower bounds (std of ln)",
    "g_max_dtod": "spread of the cells' upper bounds (std of ln)",
    "up_rate": "SET: dlnG = up_rate exp(up_slope (x - x_ref)) (x_max - x)",
    "up_slope": "SET rate change per unit ln G (the 1T1R divider)",
    "down_rate": "RESET: -dlnG = down_rate exp(down_slope (x - x_ref)) (x - x_min)",
    "down_slope": "RESET rate change per unit ln G",
    "g_ref_s": "where dw_min is stated (S; weight 0.5 of the map)",
    "read_noise": "relative std of one read during the measurement",
}


def write_samples_csv(samples: Sequence[PulseSample], path: str) -> None:
    """Every pulse of ``samples`` as a ``--csv`` file (:data:`SAMPLES_HEADER`), atomically;
    UserError (one line) when it cannot be written."""
    try:
        with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(SAMPLES_HEADER.split(","))
            for s in samples:
                w.writerow([s.row, s.col, s.polarity.name, f"{s.g_before_s:.6g}",
                            f"{s.g_after_s:.6g}"])
    except OSError as exc:
        raise UserError(f"cannot write --csv {path}: {exc.strerror or exc}") from None


def print_model(model: DeviceModel, *, cells_text: str) -> None:
    """The parameter table and the mean steps in siemens of ``model``."""
    p = model.pulse
    t = Table(title=f"device model at SET {p.set_v:g} V / RESET {p.reset_v:g} V, {p.width_us} us "
                    f"({cells_text}, {model.points} pulses)")
    t.add_column("parameter")
    t.add_column("value", justify="right")
    t.add_column("meaning")
    for k, v in model.parameters().items():
        text = f"{v * 1e6:.2f} uS" if k.endswith("_s") and math.isfinite(v) else f"{v:.4g}"
        t.add_row(k, text, MEANING.get(k, ""))
    console.print(t)
    for polarity in (Polarity.SET, Polarity.RESET):
        steps = [model.mean_step_s(polarity, g) * 1e6 for g in (60e-6, 300e-6, 950e-6)]
        console.print(f"{polarity.name} mean step at 60 / 300 / 950 uS: "
                      + " / ".join(f"{s:+.2f}" for s in steps) + " uS", highlight=False)
    if model.aging is not None:
        a = model.aging
        console.print(f"wear: window loss {a.window_loss_per_cycle:.3g} per cycle, endurance "
                      f"{a.endurance_cycles:.3g} cycles ({a.wear_source})", highlight=False)
        console.print(f"drift: nu {a.drift_nu:.3g} ({a.drift_source})", highlight=False)


def print_holdout(held: HeldOut | None, every: int) -> None:
    """The held-out validation's lines (nothing when it was off)."""
    if held is None:
        return
    console.print(
        f"held out every {_ordinal(every)} train: {held.n} pulses; |dlnG observed - "
        f"predicted| median {held.median_abs_sigma:.2f} read-noise sigma "
        f"({held.median_abs_sigma_delta:.2f} sigma of a dlnG, two reads; a perfect model: "
        f"{held.floor_sigma:.2f}, the stated noise alone), bias {held.bias_sigma:+.2f}; "
        f"the model's error on held-out means {held.binned_sigma:.2f} sigma ({held.bins} "
        f"groups of cell, polarity, G); sigma = {held.read_noise:.4g}", highlight=False)


def _ordinal(n: int) -> str:
    return f"{n}{'th' if 10 <= n % 100 <= 20 else {1: 'st', 2: 'nd', 3: 'rd'}.get(n % 10, 'th')}"
