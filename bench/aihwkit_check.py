"""Load a snan-hil aihwkit export in IBM aihwkit and pulse it (run by bench/bench_aihwkit.py
with an interpreter that has aihwkit; imports nothing of snan-hil).

Usage: ``python bench/aihwkit_check.py EXPORT.json PULSES`` -> JSON on stdout:

* ``up`` / ``down``: the weight after each of PULSES single up pulses from ``w_min`` (down
  pulses from ``w_max``), noise-free (``dw_min_std`` 0, no device-to-device spread): aihwkit's
  own ``get_tile_for_plotting`` / ``compute_pulse_response``;
* ``spread``: one up and one down pulse on 400 devices drawn with the export's spreads, from
  ``w = 0``: the steps (mean and std of each direction).
"""

from __future__ import annotations

import json
import sys

import numpy as np


def main() -> int:
    from aihwkit import __version__
    from aihwkit.simulator.configs import SingleRPUConfig, devices
    from aihwkit.utils.visualization import compute_pulse_response, get_tile_for_plotting

    doc = json.load(open(sys.argv[1]))
    pulses = int(sys.argv[2])
    d = doc["device"]
    cls = getattr(devices, d["class"])
    quiet = dict(d["parameters"], dw_min_dtod=0.0, up_down_dtod=0.0, w_min_dtod=0.0,
                 w_max_dtod=0.0)
    out = {"aihwkit": __version__, "class": d["class"]}
    for name, w0, sign in (("up", -1.0, 1.0), ("down", 1.0, -1.0)):
        config = SingleRPUConfig(device=cls(**quiet))
        tile = get_tile_for_plotting(config, 1, noise_free=True, w_init=w0)
        trace = compute_pulse_response(tile, np.full(pulses, sign))
        out[name] = [float(v) for v in trace[:, 0, 0]]
    config = SingleRPUConfig(device=cls(**d["parameters"]))
    tile = get_tile_for_plotting(config, 400, w_init=0.0)
    up = compute_pulse_response(tile, np.array([1.0]))[0, :, 0]
    tile = get_tile_for_plotting(config, 400, w_init=0.0)
    down = compute_pulse_response(tile, np.array([-1.0]))[0, :, 0]
    out["spread"] = {"up_mean": float(up.mean()), "up_std": float(up.std()),
                     "down_mean": float(down.mean()), "down_std": float(down.std())}
    json.dump(out, sys.stdout)
    return 0


if __name__ == "__main__":
    sys.exit(main())
