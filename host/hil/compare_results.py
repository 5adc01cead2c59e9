"""The results of a comparison: summaries with their intervals, the acceptance checks, the
hardware totals of the speed/energy report, and the result files.

:func:`summarize` turns the launches of :func:`snan_hil.host.hil.compare.run_compare` into
per-scenario and per-set medians and success rates with 95 % intervals; :func:`write_outputs`
writes ``compare.json`` (everything: launches, seeds, config, programming summaries,
acceptance checks, speed/energy), ``launches.csv`` (one row per launch), ``summary.csv`` (one
row per scenario and set), ``speed_energy.csv`` and ``fig10c.png``, each atomically
(temporary file + rename).
"""

from __future__ import annotations

import csv
import io
import json
import os
import statistics
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from snan_hil.files.atomicio import atomic_write_json, atomic_write_text, json_default
from snan_hil.host.hil.config import SCENARIO_LABELS, SCENARIOS, HilConfig, paper_median
from snan_hil.host.hil.figure import plot_compare
from snan_hil.host.hil.runner import ScenarioResult
from snan_hil.host.intervals import (METHOD, flat_intervals, median_interval, paper_check,
                                     rate_interval)

__all__ = ["HW_TOLERANCE", "WALL_TIME_KEYS", "without_wall_times", "hw_totals", "summarize",
           "acceptance", "write_outputs", "LAUNCH_COLUMNS", "SUMMARY_COLUMNS_V1",
           "SUMMARY_COLUMNS", "SPEED_COLUMNS", "SPEED_COLUMNS_V1"]

HW_TOLERANCE = 0.20          #: acceptance: hardware median within +-20 % of software


def _median(values: Sequence[float]) -> float | None:
    return float(statistics.median(values)) if values else None


WALL_TIME_KEYS = ("wall_s", "decisions_per_s")
"""Keys of measured wall time (anywhere in the results): they differ from run to run."""


def without_wall_times(results: dict[str, Any]) -> dict[str, Any]:
    """The results without what measures this computer's wall time (every ``wall_s`` and
    ``decisions_per_s``, the speed rows measured on this machine) or when and how the run
    happened (``created``, ``resumed``, ``files``, ``session``: the session's provenance
    names the chip and its files; ``run``: the run's uid and history id): what two runs with
    the same seed on equal chips must give identically (board times and energy included)."""
    def strip(v: Any) -> Any:
        if isinstance(v, dict):
            return {k: strip(x) for k, x in v.items() if k not in WALL_TIME_KEYS}
        if isinstance(v, list):
            return [strip(x) for x in v]
        return v
    out = strip(json.loads(json.dumps(results, default=json_default)))
    for key in ("created", "resumed", "files", "session", "run"):
        out.pop(key, None)
    se = out.get("speed_energy")
    if se:
        se["rows"] = [r for r in se["rows"] if r.get("source") != "measured (this machine)"]
        se.get("measured_inputs", {}).pop("sw", None)
    return out


def hw_totals(results: list[ScenarioResult], baud: int | None) -> dict[str, Any]:
    """Totals of the hardware launches of ``results`` (decisions, spikes, requests, wall_s,
    virtual_us, wire_us, energy_j; the time and energy ones None unless every launch has
    them) at line rate ``baud``: the ``hw`` input of
    :func:`~snan_hil.host.hil.report.speed_energy_table`; with the on-board window also
    ``plan`` (its read stats summed: reads, settling waits, row-DAC words, request and reply
    bytes, conversions a read) for the ceiling row, and ``interleaved`` (the launches ran two at
    a time: the UART overlapped the board's work). Empty without hardware launches."""
    launches = [r for sr in results if sr.scenario.startswith("hw_") for r in sr.launches]
    if not launches:
        return {}
    have_clock = all(r.virtual_us is not None for r in launches)
    have_wire = all(r.wire_us is not None for r in launches)
    hw_stats = [sr.read_stats for sr in results if sr.scenario.startswith("hw_")]
    plan = None
    if hw_stats and all(st.get("request_bytes") for st in hw_stats):
        plan = {k: sum(st[k] for st in hw_stats)
                for k in ("decisions", "codes_read", "waits", "row_words", "request_bytes",
                          "reply_bytes")}
        plan["conversions"] = hw_stats[0]["conversions"]
        plan["averages"] = hw_stats[0].get("averages", 0)
    return {"decisions": sum(r.decisions for r in launches),
            "spikes": sum(r.spikes for r in launches),
            "requests": sum(r.requests for r in launches),
            "wall_s": sum(r.wall_s for r in launches),
            "virtual_us": sum(r.virtual_us for r in launches) if have_clock else None,
            "wire_us": sum(r.wire_us for r in launches) if have_wire else None,
            "energy_j": sum(r.energy_j for r in launches) if have_clock else None,
            "baud": baud,
            "mode": next((sr.mode for sr in results if sr.scenario.startswith("hw_") and sr.mode),
                         None),
            "interleaved": any(st.get("interleaved") for st in hw_stats),
            **({"plan": plan} if plan else {})}


def summarize(results: list[ScenarioResult], hil: HilConfig, *, sets: list[int], launches: int,
              seed: int, start: int, goal: int,
              scenarios: tuple[str, ...] = SCENARIOS) -> dict[str, Any]:
    """Per scenario (all sets pooled) and per scenario x set: medians (of successful launches)
    and success rates with their 95 % intervals (``success_rate_ci`` Wilson,
    ``median_steps_ci`` / ``median_steps_all_ci`` bootstrap seeded by ``seed``,
    ``ci_method``), the paper's median (6x6: 14 / 7 steps, 10x10: 362 / 55) and whether it
    lies inside
    (``paper_inside``, ``paper_distance`` in steps); the acceptance checks."""
    per_set = [r.summary() for r in results]
    grid = (hil.model.grid.rows, hil.model.grid.cols)
    scen: dict[str, Any] = {}
    for s in scenarios:
        rs = [r for r in results if r.scenario == s]
        lengths = [L.steps for r in rs for L in r.launches]
        ok = [L.steps for r in rs for L in r.launches if L.success]
        n = len(lengths)
        set_medians = [r.median_steps for r in rs if r.median_steps is not None]
        dec = sum(L.decisions for r in rs for L in r.launches)
        wall = sum(L.wall_s for r in rs for L in r.launches)
        med_ci = median_interval(ok, seed=seed)
        scen[s] = {"label": SCENARIO_LABELS[s], "launches": n,
                   "median_steps": _median(ok), "success_rate": len(ok) / n if n else 0.0,
                   "success_rate_ci": rate_interval(len(ok), n),
                   "median_steps_ci": list(med_ci) if med_ci else None,
                   "median_steps_all_ci": _ci(median_interval(lengths, seed=seed)),
                   "ci_method": METHOD, "paper_median_steps": paper_median(s, grid),
                   **paper_check(paper_median(s, grid), med_ci),
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


def _ci(interval: tuple[float, float] | None) -> list[float] | None:
    return list(interval) if interval else None


def acceptance(scen: dict[str, Any]) -> dict[str, Any]:
    """The issue's checks: astrocytes shorten the median (sw and hw); hw within +-20 % of sw.

    On the median of the successful launches (``median_steps``, the project's convention) and,
    suffixed ``_all``, on the median of all launches with a failure counted at the step limit
    (``median_steps_all``). ``<impl>_astro_shortens_ci<suffix>``: the shortening is beyond
    the 95 % intervals (the interval with astrocytes lies wholly below the one without; None
    without intervals). ``paper_inside_<scenario>``: the paper's median (14 / 7 steps) lies
    inside that scenario's 95 % interval of the median of successful launches."""
    out: dict[str, Any] = {}
    for key, suffix in (("median_steps", ""), ("median_steps_all", "_all")):
        def med(s: str, key: str = key) -> Any:
            return scen.get(s, {}).get(key)
        for impl in ("sw", "hw"):
            a, b = med(f"{impl}_astro"), med(f"{impl}_noastro")
            out[f"{impl}_astro_shortens{suffix}"] = None if a is None or b is None else a < b
            ca, cb = med(f"{impl}_astro", f"{key}_ci"), med(f"{impl}_noastro", f"{key}_ci")
            out[f"{impl}_astro_shortens_ci{suffix}"] = (None if ca is None or cb is None
                                                        else ca[1] < cb[0])
        for astro in ("noastro", "astro"):
            sw, hw = med(f"sw_{astro}"), med(f"hw_{astro}")
            ok = sw is not None and hw is not None and sw > 0
            out[f"hw_vs_sw_{astro}{suffix}"] = hw / sw - 1.0 if ok else None
            out[f"hw_within_20pct_{astro}{suffix}"] = (abs(hw / sw - 1.0) <= HW_TOLERANCE
                                                       if ok else None)
    for s, v in scen.items():
        if "paper_inside" in v:
            out[f"paper_inside_{s}"] = v["paper_inside"]
    return out


# ---- outputs -------------------------------------------------------------------------------
def _csv(rows: list[dict[str, Any]], columns: list[str]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({c: ("" if r.get(c) is None else r.get(c)) for c in columns})
    return buf.getvalue()


LAUNCH_COLUMNS = ["scenario", "set", "launch", "trial", "steps", "success", "decisions",
                  "spikes", "requests", "virtual_us", "wire_us", "energy_j", "wall_s"]
#: summary.csv columns before the 95 % intervals were added (still recognised as ours)
SUMMARY_COLUMNS_V1 = ["scenario", "set", "seed", "launches", "median_steps", "success_rate",
                      "fingerprint", "mode"]
SUMMARY_COLUMNS = [*SUMMARY_COLUMNS_V1, "success_rate_ci_low", "success_rate_ci_high",
                   "median_steps_ci_low", "median_steps_ci_high", "ci_method"]
SPEED_COLUMNS_V1 = ["implementation", "source", "time_per_decision_us",
                    "energy_per_decision_j", "area_mm2", "norm_speed_per_us_mm2", "speed_vs_cpu",
                    "energy_gain_vs_cpu", "method"]
SPEED_COLUMNS = [*SPEED_COLUMNS_V1, "spikes_per_decision", "time_per_spike_us"]
"""The spike columns were added at the end (issue 33): an earlier file is still ours."""


def write_outputs(results: dict[str, Any], out_dir: str | os.PathLike, *,
                  figure: bool = True) -> dict[str, str]:
    """Write the result files (atomically); returns {kind: path}."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths: dict[str, str] = {}
    paths["launches_csv"] = str(atomic_write_text(out / "launches.csv",
                                                  _csv(results["launch_rows"], LAUNCH_COLUMNS)))
    paths["summary_csv"] = str(atomic_write_text(
        out / "summary.csv", _csv([flat_intervals(r) for r in results["per_set"]],
                                  SUMMARY_COLUMNS)))
    paths["speed_energy_csv"] = str(atomic_write_text(
        out / "speed_energy.csv", _csv(results["speed_energy"]["rows"], SPEED_COLUMNS)))
    if figure:
        paths["figure"] = str(plot_compare(results, out / "fig10c.png"))
    paths["json"] = str(out / "compare.json")
    results["files"] = dict(paths)
    atomic_write_json(out / "compare.json", results, indent=1, allow_nan=False)
    return paths
