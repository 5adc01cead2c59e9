"""Your chip as a twin (issue 36 points 1-3), measured against the targets.

Usage: ``python bench/bench_twin.py [--out DIR] [--sessions N] [--quick] [--skip-learn]
[--learn-dirs LAB TWIN REPLICA [--only-c]]``

A. **The lab's chip**: a fresh emulated chip (seed 0), the 120 synapse cells of the 6x6 task
   (rows 0-14) characterised at the learning pulse over the framed protocol, 3 repeats
   (:func:`snan_hil.calibration.characterize.characterize_cells`): the device model of all
   pulses, and the **held-out validation** — fitted without every 3rd train of each cell, the
   held-out pulses predicted (:mod:`snan_hil.crossbar_model.validation`): the median of
   ``|Δ ln G observed - predicted|`` in read-noise sigma (target <= 1.5 over >= 10,000
   held-out pulses), beside what a perfect model would give (the noise the model states) and
   the model's error on held-out means. **With the emulated device's truth** (the chip's own
   state at every pulse, :class:`PulseTruth`): the residual split into its read-noise and
   cycle-to-cycle parts, whether the cycle-to-cycle part is random per pulse (its lag-1
   correlation in a train, its correlation with ln G), the floor no model can go below (a
   predictor that knew each pulse's true state and the device's physics) and the fitted
   model's own error against the device's expected step (docs/crossbar_model.md 7.2).
B. **The round trip**: the emulator made the twin of that model (``emu://?device=``, seed 5:
   another draw of everything not measured), the same cells characterised (2 repeats), the
   model fitted again: each parameter against the original, with the stated bounds
   (docs/crossbar_model.md section 7).
C. **The route**: ``snan-hil learn --arms device,chip`` on the lab's chip and ``--arms chip``
   on its twin (the device-model arm depends on the model and the seeds only: run once), N
   paired sessions (default 20): the device-model arm's median cycle-20 route against each
   chip arm's, the ratio with its paired-bootstrap 95 % interval (target within +-10 %), and
   whether N sessions decide it; the same for each session's median route over cycles 11-20;
   the twin's chip arm against the lab chip's; and, as the yardstick of what any model can
   predict, another chip of the model against it (the device-model arm run again with
   ``--device-seed 1``: other devices and noise from the same model, the same sessions).
   ``--learn-dirs LAB TWIN REPLICA`` reports from three ``learn --out`` folders instead
   (finished, or stopped: the sessions their checkpoints hold whole), ``--only-c`` that
   alone.
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

import numpy as np

HELDOUT_TARGET_SIGMA = 1.5
HELDOUT_MIN_PULSES = 10_000
ROUTE_TARGET = 0.10
#: the round trip's bounds (docs/crossbar_model.md section 7: the fit's own test bounds)
BOUNDS = {"dw_min": ("rel", 0.10), "up_down": ("abs", 0.05), "dw_min_dtod": ("rel", 0.35),
          "up_down_dtod": ("rel", 0.35), "dw_min_std": ("abs", 0.06), "g_min_s": ("rel", 0.20),
          "g_max_s": ("rel", 0.20), "read_noise": ("rel", 0.30), "up_rate": ("rel", 0.25),
          "down_rate": ("rel", 0.25)}


def characterise(state: Path, cells, repeats: int, *, device: str | None = None,
                 config=None, recorder: "PulseTruth | None" = None):
    from snan_hil.calibration.bench import CellBench
    from snan_hil.calibration.characterize import CharacterizeConfig, characterize_cells
    from snan_hil.calibration.testing import session_of
    from snan_hil.firmware_emu.testing import lossy_inprocess_client
    client, emu = lossy_inprocess_client(state, seed=5 if device else 0, device=device)
    if recorder is not None:
        recorder.attach(emu.array)
    bench = CellBench(session_of(client))          # the nominal read chain: no layout
    cfg = config or CharacterizeConfig(repeats=repeats)
    m = characterize_cells(lambda r, c: bench.cell(r, c, width_us=cfg.pulse.width_us), cells,
                           cfg)
    truth = {"wear": emu.array.wear.copy(), "endurance": emu.array.endurance.copy()}
    client.close()
    return m, truth


class PulseTruth:
    """The emulated device's own state at every pulse, which no board gives: wraps the chip's
    ``apply_pulse`` and records, per pulse, the cell's state, bounds, switching parameters and
    its true (noise-free) memristor conductance before and after."""

    def __init__(self) -> None:
        self.pulses: list[dict] = []
        self.array = None

    def attach(self, array) -> None:
        self.array = array
        inner = array.apply_pulse

        def apply_pulse(row, col, amplitude_v, polarity, width_s):
            from snan_hil.common.polarity import Polarity
            cells, sw = array.cells, array.config.switching
            up = polarity == Polarity.SET
            rec = {"row": row, "col": col, "amplitude_v": amplitude_v, "polarity": polarity,
                   "width_s": width_s, "s": float(array.state[row, col]),
                   "g_lo": float(array._g_lo[row, col]), "g_hi": float(array._g_hi[row, col]),
                   "rate": float((cells.rate_set if up else cells.rate_reset)[row, col]),
                   "vth": float((cells.vth_set if up else cells.vth_reset)[row, col]),
                   "exponent": sw.set_exponent if up else sw.reset_exponent,
                   "stuck": bool(array.stuck_mask[row, col]),
                   "g_before": float(array._g[row, col])}
            out = inner(row, col, amplitude_v, polarity, width_s)
            rec["g_after"] = float(array._g[row, col])
            self.pulses.append(rec)
            return out
        array.apply_pulse = apply_pulse

    def of_samples(self, samples) -> list[dict]:
        """The record of each sample's pulse (a cell's samples are its pulses, in order)."""
        queues: dict = {}
        for rec in self.pulses:
            queues.setdefault((rec["row"], rec["col"]), []).append(rec)
        at = {k: 0 for k in queues}
        out = []
        for s in samples:
            k = (s.row, s.col)
            rec = queues[k][at[k]]
            at[k] += 1
            if rec["polarity"] != s.polarity:
                raise RuntimeError(f"cell {k}: the samples and the pulses applied disagree")
            out.append(rec)
        return out

    def expected_step(self, rec: dict, nodes: int = 16) -> float:
        """The device's expected Δ ln G of the cell (memristor + select transistor) for the
        pulse of ``rec`` from its true state: the cycle-to-cycle dose factor (log-normal,
        crossbar_model/noise.py) integrated by Gauss-Hermite quadrature over the exact
        response (crossbar_model/device.py ``pulse_response``); the random-walk term has mean
        0 in the state and is left out."""
        from snan_hil.crossbar_model.device import pulse_response
        arr = self.array
        if rec["stuck"]:
            return 0.0
        sig = arr.config.programming_noise.step_sigma_log
        xs, ws = np.polynomial.hermite_e.hermegauss(nodes)
        ws = ws / ws.sum()
        r_t = arr.config.transistor.on_resistance_ohm
        lo, hi = rec["g_lo"], rec["g_hi"]
        g0 = lo * math.exp(math.log(hi / lo) * rec["s"])
        total = 0.0
        for x, w in zip(xs, ws):
            res = pulse_response(rec["s"], rec["amplitude_v"], rec["polarity"], rec["width_s"],
                                 lo, hi, rec["rate"], rec["vth"], rec["exponent"],
                                 arr._r_write, arr.config.transistor.saturation_current_a,
                                 arr.config.switching.max_substep_dose,
                                 math.exp(sig * x - 0.5 * sig * sig))
            g1 = lo * math.exp(math.log(hi / lo) * res.s_after)
            total += w * math.log((g1 / (1.0 + g1 * r_t)) / (g0 / (1.0 + g0 * r_t)))
        return total


def truth_floor(model, held, records: list[dict], truth: PulseTruth) -> dict:
    """The held-out residuals split with the emulated device's truth (module doc, part A):
    what a predictor that knew every pulse's true state and the device's own physics would
    score, the read-noise and cycle-to-cycle parts of the residual, whether the
    cycle-to-cycle part depends on anything a model could capture, and the fitted model's
    own error against the device's expected step. Every figure in units of the model's
    read noise sigma."""
    sigma = model.read_noise
    r_t = truth.array.config.transistor.on_resistance_ohm
    rows = []
    for s, rec in zip(held, records):
        fit = model.cell_fit(s.row, s.col)
        if fit is None or s.g_before_s <= 0 or s.g_after_s <= 0:
            continue
        cell = [g / (1.0 + g * r_t) for g in (rec["g_before"], rec["g_after"])]
        rows.append((math.log(s.g_after_s / s.g_before_s),
                     float(fit.mean_dx(s.polarity, s.g_before_s)),
                     math.log(cell[1] / cell[0]), truth.expected_step(rec),
                     s.row, s.col, int(s.polarity), math.log(s.g_before_s)))
    obs, pred, true_dx, expect, row, col, pol, x = (np.array(v) for v in zip(*rows))
    c2c = true_dx - expect
    same = (row[1:] == row[:-1]) & (col[1:] == col[:-1]) & (pol[1:] == pol[:-1])
    big = np.abs(expect) > 1e-4
    cv = {}
    for lo, hi in ((0.0, 0.005), (0.005, 0.02), (0.02, 0.04), (0.04, 1.0)):
        m = big & (np.abs(expect) >= lo) & (np.abs(expect) < hi)
        cv[f"{100 * lo:g}-{100 * hi:g} %"] = float(np.std(c2c[m] / np.abs(expect[m])))
    return {"n": len(rows),
            "oracle_median_abs": float(np.median(np.abs(obs - expect)) / sigma),
            "model_median_abs": float(np.median(np.abs(obs - pred)) / sigma),
            "read_part_sd": float(np.std(obs - true_dx) / sigma),
            "c2c_part_sd": float(np.std(c2c) / sigma),
            "c2c_lag1": float(np.corrcoef(c2c[1:][same], c2c[:-1][same])[0, 1]),
            "c2c_vs_lng": float(np.corrcoef(c2c, x)[0, 1]),
            "c2c_cv_by_step": cv,
            "model_error_median": float(np.median(np.abs(pred - expect)) / sigma),
            "model_error_mean": float(np.mean(pred - expect) / sigma)}


def within(name: str, got: float, want: float) -> tuple[bool, str]:
    kind, tol = BOUNDS[name]
    if kind == "rel":
        rel = got / want - 1.0
        return abs(rel) <= tol, f"{100 * rel:+.1f} % (bound +-{100 * tol:.0f} %)"
    return abs(got - want) <= tol, f"{got - want:+.3f} (bound +-{tol:g})"


def learn_arms(work: Path, name: str, port_args: list[str], model: Path, sessions: int,
               arms: str = "device,chip") -> dict:
    from snan_hil.tools import cli
    out = work / f"learn-{name}"
    with contextlib.redirect_stdout(io.StringIO()):
        rc = cli.main(["learn", *port_args, "--arms", arms, "--sessions",
                       str(sessions), "--model", str(model), "--out", str(out), "--json",
                       "--force", "--no-figure"] + (["--resume"] if (out / "checkpoint").exists()
                                                    else []))
    if rc:
        raise SystemExit(rc)
    return json.loads((out / "learn.json").read_text())


def learn_document(out: Path) -> dict:
    """The results of a ``snan-hil learn --out`` folder: its ``learn.json``, or for a run that
    was stopped (SIGTERM; ``--resume`` would continue it) the tests of the sessions its
    checkpoint holds whole, sessions 0, 1, ... up to the first one not finished."""
    if (out / "learn.json").is_file():
        return json.loads((out / "learn.json").read_text())
    ck = out / "checkpoint"
    cycles = json.loads((ck / "run.json").read_text())["identity"]["learn"]["cycles"]
    arms: dict[str, list[dict]] = {}
    for arm in ("device", "chip"):
        sessions = []
        while True:
            k = len(sessions)
            if arm == "device":
                f = ck / f"unit-device-s{k}.json"
                if not f.is_file():
                    break
                sessions.append(json.loads(f.read_text())["data"]["result"])
                continue
            units = [ck / f"unit-chip-s{k}-c{c}.json" for c in range(cycles + 1)]
            if not all(u.is_file() for u in units):
                break
            tests = [json.loads(u.read_text())["data"]["test"] for u in units]
            sessions.append({"test_steps": [t[0] for t in tests],
                             "test_success": [bool(t[1]) for t in tests]})
        if sessions:
            arms[arm] = {"sessions": sessions}
    return {"protocol": {"cycles": cycles}, "arms": arms}


def routes(doc: dict, arm: str, late: bool = False):
    """(steps, success) per whole session of ``arm``: the cycle-20 test, or with ``late`` each
    session's median test route over cycles 11-20 (a failed test counts its steps, the
    step limit), every session counted."""
    cycles = doc["protocol"]["cycles"]
    done = [r for r in doc["arms"][arm]["sessions"] if len(r["test_steps"]) == cycles + 1]
    if late:
        steps = np.array([np.median(r["test_steps"][cycles // 2 + 1:]) for r in done])
        return steps, np.ones(steps.size, dtype=bool)
    return (np.array([r["test_steps"][-1] for r in done]),
            np.array([r["test_success"][-1] for r in done], dtype=bool))


def compare_routes(name: str, dev: dict, chip: dict, late: bool = False) -> str:
    """One line: the device-model arm's median route against the chip arm's over the paired
    sessions both finished, the ratio with its paired-bootstrap 95 % interval
    (:func:`snan_hil.host.intervals.median_ratio_interval`) and the +-10 % target."""
    from snan_hil.host.intervals import median_interval, median_ratio_interval
    (ds, dk), (cs, ck) = routes(dev, "device", late), routes(chip, "chip", late)
    n = min(ds.size, cs.size)
    ds, dk, cs, ck = ds[:n], dk[:n], cs[:n], ck[:n]
    got = median_ratio_interval(ds, dk, cs, ck, seed=1)
    if got is None:
        return f"{name}: no successful session in an arm"
    point, (lo, hi) = got
    band = (1 - ROUTE_TARGET, 1 + ROUTE_TARGET)
    verdict = "MET" if band[0] <= point <= band[1] else "NOT MET"
    if band[0] <= lo and hi <= band[1]:
        resolved = "the interval lies inside the +-10 % band"
    elif hi < band[0] or lo > band[1]:
        resolved = "the interval lies outside the +-10 % band: a bias"
    else:
        resolved = (f"the interval is wider than the band: {n} sessions do not decide the "
                    "target")

    def med(s, k):
        ci = median_interval(s[k], seed=1)
        return f"{float(np.median(s[k])):g} [{ci[0]:g}, {ci[1]:g}]" if ci else "-"
    what = "median route over cycles 11-20" if late else "cycle-20 route"
    return (f"{name}, {what}, {n} paired sessions: device-model arm {med(ds, dk)} (success "
            f"{100 * dk.mean():.0f} %), chip arm {med(cs, ck)} (success {100 * ck.mean():.0f} "
            f"%): ratio {point:.2f} [{lo:.2f}, {hi:.2f}], {100 * (point - 1):+.0f} % (target "
            f"+-{100 * ROUTE_TARGET:.0f} %): {verdict}; {resolved}")


def part_a(work: Path, cells, repeats: int):
    from snan_hil.calibration.characterize import fit_measurement, validate_holdout
    t0 = time.perf_counter()
    truth = PulseTruth()
    m, _ = characterise(work / "lab-chip.npz", cells, repeats, recorder=truth)
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
    from snan_hil.crossbar_model.fitted import fit_device
    from snan_hil.crossbar_model.validation import estimate_read_noise, split_trains
    fit, held_out = split_trains(m.samples, 3)         # what validate_holdout fitted and scored
    t1 = time.perf_counter()
    record = {id(s): r for s, r in zip(m.samples, truth.of_samples(m.samples))}
    t = truth_floor(fit_device(fit, model.pulse, g_ref_s=model.g_ref_s,
                               read_noise=model.read_noise), held_out,
                    [record[id(s)] for s in held_out], truth)
    cv = ", ".join(f"{k} {v:.2f}" for k, v in t["c2c_cv_by_step"].items())
    print(f"   with the emulated device's truth ({t['n']} held-out pulses, "
          f"{time.perf_counter() - t1:.0f} s): a predictor that knew each pulse's true state "
          f"and the device's own physics (its expected step) scores {t['oracle_median_abs']:.2f}"
          f" sigma (the fitted model {t['model_median_abs']:.2f}): the floor no model can go "
          f"below; the residual's read-noise part sd {t['read_part_sd']:.2f} sigma (sqrt 2 = "
          f"1.41), its cycle-to-cycle part sd {t['c2c_part_sd']:.2f} sigma, random per pulse "
          f"(lag-1 correlation in a train {t['c2c_lag1']:+.3f}, with ln G "
          f"{t['c2c_vs_lng']:+.3f}), its relative size by expected step: {cv}; the model's "
          f"own error |predicted - the device's expected step|: median "
          f"{t['model_error_median']:.2f} sigma, mean {t['model_error_mean']:+.2f} sigma")
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


def part_c(work: Path, sessions: int, learn_dirs: list[Path] | None = None) -> None:
    """The device-model arm against the chip arm on each chip. The device-model arm depends
    on the model and the session seeds only (host/hil/learn_arms.py ``device_session``), so
    it is run once, with the lab chip, and paired with both chips' chip arms. ``learn_dirs``:
    the two finished (or interrupted) ``learn --out`` folders, lab chip then twin, to report
    from instead of running."""
    t0 = time.perf_counter()
    if learn_dirs:
        lab, twin, replica = (learn_document(d) for d in learn_dirs)
    else:
        model = work / "model.json"
        os.environ["SNAN_HIL_EMU_STATE"] = str(work / "lab-chip.npz")
        os.environ["XDG_DATA_HOME"] = str(work / "data")
        lab = learn_arms(work, "lab-chip", ["--port", "emu"], model, sessions)
        twin = learn_arms(work, "its-twin", ["--port", "emu", "--device", str(model)], model,
                          sessions, arms="chip")
        replica = learn_arms(work, "replica", ["--device-seed", "1"], model, sessions,
                             arms="device")
    other = {"protocol": replica["protocol"], "arms": {"chip": replica["arms"]["device"]}}
    for late in (False, True):
        print("C. " + compare_routes("lab chip", lab, lab, late))
        print("   " + compare_routes("its twin", lab, twin, late))
        print("   " + compare_routes("another chip of the model (the device-model arm with "
                                     "--device-seed 1 in the chip arm's place)", lab, other,
                                     late))
    from snan_hil.host.intervals import median_ratio_interval
    (ts, tk), (ls, lk) = routes(twin, "chip"), routes(lab, "chip")
    n = min(ts.size, ls.size)
    got = median_ratio_interval(ts[:n], tk[:n], ls[:n], lk[:n], seed=1)
    if got is not None:
        print(f"   the twin's chip arm against the lab chip's, cycle-20 route, {n} paired "
              f"sessions: ratio {got[0]:.2f} [{got[1][0]:.2f}, {got[1][1]:.2f}]  "
              f"({time.perf_counter() - t0:.0f} s)")


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
    ap.add_argument("--learn-dirs", nargs=3, type=Path, metavar=("LAB", "TWIN", "REPLICA"),
                    default=None,
                    help="part C from three 'snan-hil learn --out' folders (the lab chip's "
                         "with --arms device,chip, its twin's with --arms chip, the replica's "
                         "with --arms device --device-seed 1)")
    ap.add_argument("--only-c", action="store_true", help="part C alone (with --learn-dirs)")
    a = ap.parse_args(argv)
    work = Path(a.out) if a.out else Path(tempfile.mkdtemp(prefix="bench-twin-"))
    work.mkdir(parents=True, exist_ok=True)
    rows = 3 if a.quick else 15
    cells = [(r, c) for r in range(rows) for c in range(8)]
    if a.only_c:
        if not a.learn_dirs:
            ap.error("--only-c needs --learn-dirs")
        part_c(work, a.sessions, a.learn_dirs)
        return 0
    model, _held = part_a(work, cells, 3)
    part_b(work, cells, model)
    if not a.skip_learn:
        part_c(work, 2 if a.quick else a.sessions, a.learn_dirs)
    part_d(work)
    print(f"(files in {work})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
