"""The four-scenario comparison of the paper's Fig. 10C, and its speed/energy report (Fig. 10D).

:func:`run_compare`: for each weight set of a trained ``.npz``: the software launches (weights as
numbers), then the set is programmed into the chip (two-stage write-and-verify; cells already
inside their window get no stage-1 pulse) and launched on the crossbar, without and with
astrocytes. :func:`write_outputs` writes ``compare.json`` (everything: launches, seeds, config,
programming summaries, acceptance checks, speed/energy), ``launches.csv`` (one row per launch),
``summary.csv`` (one row per scenario and set), ``speed_energy.csv`` and ``fig10c.png``, each
atomically (temporary file + rename).
"""

from __future__ import annotations

import csv
import datetime as _dt
import io
import os
import statistics
import time
from pathlib import Path
from typing import Any

from collections.abc import Sequence

import numpy as np

from snan_hil import __version__
from snan_hil.atomicio import atomic_write_json, atomic_write_text
from snan_hil.calibration.observer import CellObserver
from snan_hil.calibration.programmer import ProgramConfig, program_weights
from snan_hil.calibration.weights_io import load_weight_set
from snan_hil.errors import UserError
from snan_hil.host.hil.config import SCENARIO_LABELS, SCENARIOS, HilConfig
from snan_hil.host.hil.report import measure_spike_geometry, speed_energy_table
from snan_hil.host.hil.runner import (ScenarioResult, check_layout, require_hardware,
                                      run_scenario)
from snan_hil.progress import ProgressCallback, track
from snan_hil.protocol.client import BoardClient

RESULTS_FORMAT = "snan-hil-compare/1"
HW_TOLERANCE = 0.20          #: acceptance: hardware median within +-20 % of software


def _median(values: Sequence[float]) -> float | None:
    return float(statistics.median(values)) if values else None


def task_of(meta: dict, hil: HilConfig) -> tuple[int, int]:
    """(start, goal): from the weights file if it records them, else the HIL config."""
    return int(meta.get("start", hil.task.start)), int(meta.get("goal", hil.task.goal))


def check_weights_grid(meta: dict, hil: HilConfig, path: str) -> None:
    grid = tuple(meta["grid"])
    cfg_grid = (hil.model.grid.rows, hil.model.grid.cols)
    if grid != cfg_grid:
        raise UserError(f"{path} holds {grid[0]}x{grid[1]} weights but the config is for "
                        f"{cfg_grid[0]}x{cfg_grid[1]}; pass a matching --config")


def run_compare(weights_path: str | os.PathLike, hil: HilConfig, *,
                client: BoardClient | None = None, port: str = "emu",
                layout_path: str | os.PathLike | None = None,
                sets: list[int] | None = None, launches: int = 10, seed: int = 1,
                mode: str | None = None, baud: int | None = None, program: bool = True,
                program_config: ProgramConfig | None = None,
                report_dir: str | os.PathLike | None = None,
                scenarios: tuple[str, ...] = SCENARIOS,
                progress: ProgressCallback | None = None,
                program_observer: CellObserver | None = None) -> dict[str, Any]:
    """Run the comparison; returns the results dict (see module doc). ``client`` is a
    connected board client (needed for hw scenarios); ``layout_path`` the chip's layout file;
    ``report_dir`` receives one programming report per set; ``program_observer`` sees every
    programming pulse and cell (:mod:`snan_hil.calibration.observer`; the chip history).
    ``mode``: how the hardware scenarios read the synapses (None: the board's default,
    :mod:`.synapses`). ``progress`` gets the task "launches" (one unit per launch, all sets and
    scenarios) and each set's "programming"
    (:func:`~snan_hil.calibration.programmer.program_weights`)."""
    t_wall = time.perf_counter()
    weights_path = str(weights_path)
    _w0, meta0 = load_weight_set(weights_path, 0)
    n_sets = int(meta0["n_sets"])
    sets = list(range(n_sets)) if sets is None else [int(k) for k in sets]
    data = {}
    for k in sets:                                   # validate every set before any I/O
        w, meta = load_weight_set(weights_path, k)
        check_weights_grid(meta, hil, weights_path)
        data[k] = (w, meta)
    start, goal = task_of(meta0, hil)
    hw_scen = [s for s in scenarios if s.startswith("hw_")]
    sw_scen = [s for s in scenarios if s.startswith("sw_")]
    hw_mode = None
    if hw_scen:
        if client is None or layout_path is None:
            raise UserError("hw scenarios need a board (--port) and a layout path")
        hw_mode = require_hardware(client, mode)
    info = getattr(client, "info", None)
    results: list[ScenarioResult] = []
    programming: dict[int, dict] = {}
    bar = track(progress, "launches", len(sets) * launches * len(scenarios))

    if sw_scen:                      # load the compiled kernels before timing the software
        run_scenario(sw_scen[0], data[sets[0]][0], hil, launches=1, seed=seed, start=start,
                     goal=goal)
    t_sw = time.perf_counter()
    for k in sets:
        for s in sw_scen:
            results.append(run_scenario(s, data[k][0], hil, set_index=k, launches=launches,
                                        seed=seed, start=start, goal=goal,
                                        progress=bar.nested(f"set {k} {s} ")))
    sw_wall = time.perf_counter() - t_sw
    geometry = None
    if hw_scen:
        from snan_hil.calibration.layout import Layout
        assert client is not None and layout_path is not None     # checked above
        for k in sets:
            w, meta = data[k]
            if program:
                bar.advance(0, f"programming set {k}")
                report_path = (Path(report_dir) / f"program-set{k}.json") if report_dir else None
                pr = program_weights(client, w, meta, layout_path=layout_path,
                                     config=program_config, port=port, report_path=report_path,
                                     progress=progress, observer=program_observer)
                layout = pr.layout
                summ = dict(pr.report["summary"])
                summ["all_ok"] = pr.all_ok
                programming[k] = summ
            else:
                layout = Layout.load(layout_path)
            check_layout(layout, w, tuple(meta["grid"]), port=port, weights_path=weights_path,
                         set_index=k)
            for s in hw_scen:
                results.append(run_scenario(s, w, hil, set_index=k, launches=launches,
                                            seed=seed, start=start, goal=goal, client=client,
                                            layout=layout, mode=hw_mode, baud=baud,
                                            progress=bar.nested(f"set {k} {s} ")))
        geometry = measure_spike_geometry(client, row_code=layout.chain.read_code, baud=baud)
    out = summarize(results, hil, sets=sets, launches=launches, seed=seed, start=start,
                    goal=goal, scenarios=scenarios)
    sw_dec = sum(r.decisions for sr in results if sr.scenario.startswith("sw_")
                 for r in sr.launches)
    hw_stats = _hw_totals(results, baud)
    if hw_stats and info is not None:
        hw_stats["conversion_us"] = float(info.conversion_us)
    out["speed_energy"] = speed_energy_table(
        hil.model.n_cells, hw=hw_stats or None, geometry=geometry,
        sw={"decisions": sw_dec, "wall_s": sw_wall} if sw_dec else None)
    out.update({
        "format": RESULTS_FORMAT, "snan_hil_version": __version__,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "weights": {"path": weights_path, "n_sets": n_sets,
                    "set_seeds": meta0.get("seeds"), "cycles": meta0.get("cycles"),
                    "fingerprints": {str(k): r.fingerprint for r in results
                                     for k in [r.set_index]}},
        "port": port if hw_scen else None, "mode": hw_mode if hw_scen else None,
        "baud": baud if hw_scen else None,
        "board": ({"board_id": info.board_id, "firmware_version": info.firmware_version}
                  if info is not None and hw_scen else None),
        "programming": {str(k): v for k, v in programming.items()},
        "config": hil.to_dict(),
        "wall_s": time.perf_counter() - t_wall,
    })
    return out


def _hw_totals(results: list[ScenarioResult], baud: int | None) -> dict[str, Any]:
    launches = [r for sr in results if sr.scenario.startswith("hw_") for r in sr.launches]
    if not launches:
        return {}
    have_clock = all(r.virtual_us is not None for r in launches)
    have_wire = all(r.wire_us is not None for r in launches)
    return {"decisions": sum(r.decisions for r in launches),
            "spikes": sum(r.spikes for r in launches),
            "requests": sum(r.requests for r in launches),
            "wall_s": sum(r.wall_s for r in launches),
            "virtual_us": sum(r.virtual_us for r in launches) if have_clock else None,
            "wire_us": sum(r.wire_us for r in launches) if have_wire else None,
            "energy_j": sum(r.energy_j for r in launches) if have_clock else None,
            "baud": baud}


def summarize(results: list[ScenarioResult], hil: HilConfig, *, sets: list[int], launches: int,
              seed: int, start: int, goal: int,
              scenarios: tuple[str, ...] = SCENARIOS) -> dict[str, Any]:
    """Per scenario (all sets pooled) and per scenario x set: medians (of successful launches)
    and success rates; the acceptance checks."""
    per_set = [r.summary() for r in results]
    scen: dict[str, Any] = {}
    for s in scenarios:
        rs = [r for r in results if r.scenario == s]
        lengths = [L.steps for r in rs for L in r.launches]
        ok = [L.steps for r in rs for L in r.launches if L.success]
        n = len(lengths)
        set_medians = [r.median_steps for r in rs if r.median_steps is not None]
        dec = sum(L.decisions for r in rs for L in r.launches)
        wall = sum(L.wall_s for r in rs for L in r.launches)
        scen[s] = {"label": SCENARIO_LABELS[s], "launches": n,
                   "median_steps": _median(ok), "success_rate": len(ok) / n if n else 0.0,
                   "mean_steps": float(np.mean(ok)) if ok else None,
                   "median_of_set_medians": _median(set_medians),
                   "median_steps_all": _median(lengths), "decisions": dec, "wall_s": wall,
                   "decisions_per_s": dec / wall if wall > 0 else None}
    return {"grid": [hil.model.grid.rows, hil.model.grid.cols], "start": start, "goal": goal,
            "step_limit": hil.model.grid.max_steps, "sets": sets, "launches": launches,
            "seed": seed, "scenarios": scen, "per_set": per_set,
            "launch_rows": [dict(scenario=r.scenario, set=r.set_index, **L.to_dict())
                            for r in results for L in r.launches],
            "acceptance": acceptance(scen)}


def acceptance(scen: dict[str, Any]) -> dict[str, Any]:
    """The issue's checks: astrocytes shorten the median (sw and hw); hw within +-20 % of sw.

    On the median of the successful launches (``median_steps``, the project's convention) and,
    suffixed ``_all``, on the median of all launches with a failure counted at the step limit
    (``median_steps_all``)."""
    out: dict[str, Any] = {}
    for key, suffix in (("median_steps", ""), ("median_steps_all", "_all")):
        def med(s: str, key: str = key) -> Any:
            return scen.get(s, {}).get(key)
        for impl in ("sw", "hw"):
            a, b = med(f"{impl}_astro"), med(f"{impl}_noastro")
            out[f"{impl}_astro_shortens{suffix}"] = None if a is None or b is None else a < b
        for astro in ("noastro", "astro"):
            sw, hw = med(f"sw_{astro}"), med(f"hw_{astro}")
            ok = sw is not None and hw is not None and sw > 0
            out[f"hw_vs_sw_{astro}{suffix}"] = hw / sw - 1.0 if ok else None
            out[f"hw_within_20pct_{astro}{suffix}"] = (abs(hw / sw - 1.0) <= HW_TOLERANCE
                                                       if ok else None)
    return out


# ---- outputs -------------------------------------------------------------------------------
def _csv(rows: list[dict], columns: list[str]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({c: ("" if r.get(c) is None else r.get(c)) for c in columns})
    return buf.getvalue()


LAUNCH_COLUMNS = ["scenario", "set", "launch", "trial", "steps", "success", "decisions",
                  "spikes", "requests", "virtual_us", "wire_us", "energy_j", "wall_s"]
SUMMARY_COLUMNS = ["scenario", "set", "seed", "launches", "median_steps", "success_rate",
                   "fingerprint", "mode"]
SPEED_COLUMNS = ["implementation", "source", "time_per_decision_us", "energy_per_decision_j",
                 "area_mm2", "norm_speed_per_us_mm2", "speed_vs_cpu", "energy_gain_vs_cpu",
                 "method"]


def write_outputs(results: dict[str, Any], out_dir: str | os.PathLike, *,
                  figure: bool = True) -> dict[str, str]:
    """Write the result files (atomically); returns {kind: path}."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths: dict[str, str] = {}
    paths["launches_csv"] = str(atomic_write_text(out / "launches.csv",
                                                  _csv(results["launch_rows"], LAUNCH_COLUMNS)))
    paths["summary_csv"] = str(atomic_write_text(out / "summary.csv",
                                                 _csv(results["per_set"], SUMMARY_COLUMNS)))
    paths["speed_energy_csv"] = str(atomic_write_text(
        out / "speed_energy.csv", _csv(results["speed_energy"]["rows"], SPEED_COLUMNS)))
    if figure:
        from snan_hil.host.hil.figure import plot_compare
        paths["figure"] = str(plot_compare(results, out / "fig10c.png"))
    paths["json"] = str(out / "compare.json")
    results["files"] = dict(paths)
    atomic_write_json(out / "compare.json", results, indent=1, allow_nan=False)
    return paths
