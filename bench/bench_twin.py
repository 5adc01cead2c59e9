"""Your chip as a twin (issue 36 points 1-3), measured against the targets.

Usage: ``python bench/bench_twin.py [--out DIR] [--sessions N] [--quick] [--skip-learn]``

A. **The lab's chip**: a fresh emulated chip (seed 0), the 120 synapse cells of the 6x6 task
   (rows 0-14) characterised at the learning pulse over the framed protocol, 3 repeats
   (:func:`snan_hil.calibration.characterize.characterize_cells`): the device model of all
   pulses, and the **held-out validation** — fitted without every 3rd train of each cell, the
   held-out pulses predicted (:mod:`snan_hil.crossbar_model.validation`): the median of
   ``|Δ ln G observed - predicted|`` in read-noise sigma (target <= 1.5 over >= 10,000
   held-out pulses), beside what a perfect model would give (the noise the model states) and
   the model's error on held-out means.
B. **The round trip**: the emulator made the twin of that model (``emu://?device=``, seed 5:
   another draw of everything not measured), the same cells characterised (2 repeats), the
   model fitted again: each parameter against the original, with the stated bounds
   (docs/crossbar_model.md section 7).
C. **The route**: ``snan-hil learn --arms device,chip`` on each chip (the lab's and its twin),
   N paired sessions (default 20): the device-model arm's median cycle-20 route against the
   chip arm's (target within +-10 %), with both 95 % intervals.
D. **Wear where the data show it**: a chip that wears fast (endurance 40 device cycles),
   16 cells swept 8 times: the aging term's fitted window loss against the emulated truth;
   its twin swept the same way: the fitted loss back.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

HELDOUT_TARGET_SIGMA = 1.5
HELDOUT_MIN_PULSES = 10_000
ROUTE_TARGET = 0.10
#: the round trip's bounds (docs/crossbar_model.md section 7: the fit's own test bounds)
BOUNDS = {"dw_min": ("rel", 0.10), "up_down": ("abs", 0.05), "dw_min_dtod": ("rel", 0.35),
          "up_down_dtod": ("rel", 0.35), "dw_min_std": ("abs", 0.06), "g_min_s": ("rel", 0.20),
          "g_max_s": ("rel", 0.20), "read_noise": ("rel", 0.30), "up_rate": ("rel", 0.25),
          "down_rate": ("rel", 0.25)}


def characterise(state: Path, cells, repeats: int, *, device: str | None = None,
                 config=None):
    from snan_hil.calibration.bench import CellBench
    from snan_hil.calibration.characterize import CharacterizeConfig, characterize_cells
    from snan_hil.calibration.testing import session_of
    from snan_hil.firmware_emu.testing import lossy_inprocess_client
    client, emu = lossy_inprocess_client(state, seed=5 if device else 0, device=device)
    bench = CellBench(session_of(client))          # the nominal read chain: no layout
    cfg = config or CharacterizeConfig(repeats=repeats)
    m = characterize_cells(lambda r, c: bench.cell(r, c, width_us=cfg.pulse.width_us), cells,
                           cfg)
    truth = {"wear": emu.array.wear.copy(), "endurance": emu.array.endurance.copy()}
    client.close()
    return m, truth


def within(name: str, got: float, want: float) -> tuple[bool, str]:
    kind, tol = BOUNDS[name]
    if kind == "rel":
        rel = got / want - 1.0
        return abs(rel) <= tol, f"{100 * rel:+.1f} % (bound +-{100 * tol:.0f} %)"
    return abs(got - want) <= tol, f"{got - want:+.3f} (bound +-{tol:g})"


def learn_arms(work: Path, name: str, port_args: list[str], model: Path, sessions: int
               ) -> dict:
    from snan_hil.tools import cli
    out = work / f"learn-{name}"
    with contextlib.redirect_stdout(io.StringIO()):
        rc = cli.main(["learn", *port_args, "--arms", "device,chip", "--sessions",
                       str(sessions), "--model", str(model), "--out", str(out), "--json",
                       "--force", "--no-figure"] + (["--resume"] if (out / "checkpoint").exists()
                                                    else []))
    if rc:
        raise SystemExit(rc)
    return json.loads((out / "learn.json").read_text())


def part_a(work: Path, cells, repeats: int):
    from snan_hil.calibration.characterize import fit_measurement, validate_holdout
    t0 = time.perf_counter()
    m, _ = characterise(work / "lab-chip.npz", cells, repeats)
    model = fit_measurement(m, meta={"board_id": "lab chip (emulated, seed 0)"})
    (work / "model.json").write_text(json.dumps(model.to_dict()))
    held = validate_holdout(m.samples, model.pulse, g_ref_s=model.g_ref_s,
                            read_noise=model.read_noise, every=3)
    ok = held.median_abs_sigma <= HELDOUT_TARGET_SIGMA and held.n >= HELDOUT_MIN_PULSES
    ok_delta = held.median_abs_sigma_delta <= HELDOUT_TARGET_SIGMA
    print(f"A. lab chip: {len(cells)} cells, {len(m.samples)} pulses, {repeats} repeats "
          f"({time.perf_counter() - t0:.0f} s); read noise {model.read_noise:.4f}")
    print(f"   held out every 3rd train: {held.n} pulses (target >= {HELDOUT_MIN_PULSES}); "
          f"median |dlnG obs - pred| {held.median_abs_sigma:.2f} sigma of one read (target <= "
          f"{HELDOUT_TARGET_SIGMA}): {'MET' if ok else 'NOT MET'}; = "
          f"{held.median_abs_sigma_delta:.2f} sigma_delta, the read noise of a dlnG (two reads,"
          f" sqrt 2 sigma): {'MET' if ok_delta else 'NOT MET'}; a perfect model (the noise "
          f"the model states: two reads and the cycle-to-cycle spread {model.dw_min_std:.2f} "
          f"of one step) gives {held.floor_sigma:.2f}; bias {held.bias_sigma:+.2f} sigma; the "
          f"model's error on held-out means {held.binned_sigma:.2f} sigma ({held.bins} "
          f"groups); |z| median {held.z_median:.3f} (0.674 for the stated noise)")
    from snan_hil.crossbar_model.validation import estimate_read_noise
    est = estimate_read_noise(m.samples)
    print(f"   read noise from the steps' scatter alone (what a file without repeated reads "
          f"gives): {est:.4f}, the repeated reads {model.read_noise:.4f} "
          f"({100 * (est / model.read_noise - 1):+.0f} %)")
    a = model.aging
    if a is not None:
        print(f"   aging: {a.wear_source}; {a.drift_source}")
    return model, held


def part_b(work: Path, cells, model) -> bool:
    from snan_hil.calibration.characterize import fit_measurement
    t0 = time.perf_counter()
    m, _ = characterise(work / "twin-chip.npz", cells, 2, device=str(work / "model.json"))
    back = fit_measurement(m)
    print(f"B. round trip: the twin characterised the same way ({len(m.samples)} pulses, "
          f"{time.perf_counter() - t0:.0f} s); parameter: original -> back")
    all_ok = True
    for name in BOUNDS:
        want, got = getattr(model, name), getattr(back, name)
        ok, text = within(name, got, want)
        all_ok &= ok
        print(f"   {name:13s} {want:.5g} -> {got:.5g}  {text}  {'ok' if ok else 'OUTSIDE'}")
    print(f"   all within the stated bounds: {'MET' if all_ok else 'NOT MET'}")
    return all_ok


def part_c(work: Path, sessions: int) -> None:
    model = work / "model.json"
    os.environ["SNAN_HIL_EMU_STATE"] = str(work / "lab-chip.npz")
    os.environ["XDG_DATA_HOME"] = str(work / "data")
    t0 = time.perf_counter()
    for name, port in (("lab chip", ["--port", "emu"]),
                       ("its twin", ["--port", "emu", "--device", str(model)])):
        doc = learn_arms(work, name.replace(" ", "-"), port, model, sessions)
        dev, chip = (doc["arms"][a]["curves"] for a in ("device", "chip"))
        md, mc = dev["median"][-1], chip["median"][-1]
        rel = (md / mc - 1.0) if md and mc else math.nan
        ok = abs(rel) <= ROUTE_TARGET
        print(f"C. {name}: cycle-20 route, {sessions} paired sessions: device-model arm {md} "
              f"{dev['median_ci'][-1]} (success {100 * dev['success'][-1]:.0f} %), chip arm "
              f"{mc} {chip['median_ci'][-1]} (success {100 * chip['success'][-1]:.0f} %): "
              f"{100 * rel:+.0f} % (target +-{100 * ROUTE_TARGET:.0f} %): "
              f"{'MET' if ok else 'NOT MET'}  ({time.perf_counter() - t0:.0f} s)")


def part_d(work: Path) -> None:
    from snan_hil.calibration.characterize import CharacterizeConfig, fit_measurement
    from snan_hil.crossbar_model import ArrayConfig, CrossbarArray
    cfg = ArrayConfig.default().with_overrides({"wear.endurance_cycles": 40.0,
                                                "wear.endurance_sigma_log": 0.0})
    worn = work / "worn-chip.npz"
    CrossbarArray(cfg, seed=0).save(str(worn))
    cells = [(0, c) for c in range(8)] + [(1, c) for c in range(8)]
    sweep = CharacterizeConfig(repeats=8)
    m, truth = characterise(worn, cells, 8, config=sweep)
    model = fit_measurement(m)
    a = model.aging
    assert a is not None
    true_cycles = float(truth["wear"][[r for r, _ in cells], [c for _, c in cells]].mean())
    print(f"D. a fast-wearing chip (endurance 40 device cycles, closure 0.5: 0.0125 of the "
          f"window per device cycle), 16 cells swept 8 times ({true_cycles:.1f} device cycles "
          f"each, {a.cycles_seen:.1f} model cycles counted): {a.wear_source}")
    (work / "worn-model.json").write_text(json.dumps(model.to_dict()))
    m2, _ = characterise(work / "worn-twin.npz", cells, 8, device=str(work / "worn-model.json"),
                         config=sweep)
    back = fit_measurement(m2).aging
    assert back is not None
    print(f"   its twin, swept the same way: {back.wear_source}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None)
    ap.add_argument("--sessions", type=int, default=20)
    ap.add_argument("--quick", action="store_true", help="24 cells, 2 sessions")
    ap.add_argument("--skip-learn", action="store_true", help="leave out part C")
    a = ap.parse_args(argv)
    work = Path(a.out) if a.out else Path(tempfile.mkdtemp(prefix="bench-twin-"))
    work.mkdir(parents=True, exist_ok=True)
    rows = 3 if a.quick else 15
    cells = [(r, c) for r in range(rows) for c in range(8)]
    model, _held = part_a(work, cells, 3)
    part_b(work, cells, model)
    if not a.skip_learn:
        part_c(work, 2 if a.quick else a.sessions)
    part_d(work)
    print(f"(files in {work})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
