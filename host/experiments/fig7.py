"""Fig. 7 (section 3.5): route learning. Sessions of 20 training cycles without weight
reset (astrocytes and STDP on) on 3x3, 5x5 and 10x10, each cycle followed by a test without
astrocytes (see :mod:`snan_hil.host.experiments.route`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from snan_hil.host.experiments.calcium import calcium_event, family_config, level_for_duration
from snan_hil.host.experiments.common import (Figure, Results, RunOptions, command_line,
                                              md_table, num, pct, preset, provenance, pyplot,
                                              report_head, save_plot)
from snan_hil.host.experiments.common import CI_NOTE
from snan_hil.host.intervals import (METHOD, format_interval, inside_text, interval_fields,
                                     paper_inside)
from snan_hil.host.experiments.executor import Task
from snan_hil.host.experiments.route import route_batch

NAME = "fig7"
TITLE = "Fig. 7 — route learning over 20 cycles (tests without astrocytes)"
CYCLES = 20
SIZES = (3, 5, 10)
SESSIONS = {3: 769, 5: 606, 10: 198}
LIMITS = {3: 100, 5: 300, 10: 1000}
#: 5x5 astrocytes (not given in the paper): the 10x10 family at this duration (decisions)
DURATION_5X5 = 25.0
#: paper: (median cycle 0, median cycle 20, success cycle 0, success cycle 20)
PAPER = {3: (10.0, 4.0, 0.580, 0.978), 5: (73.0, 9.0, 0.446, 0.955),
         10: (389.0, 38.0, 0.404, 0.990)}
SESSIONS_PER_TASK = 8
FIELDS = ("test_steps", "test_success", "train_steps", "train_success", "saturated")


def size_config(opts: RunOptions, size: int):
    if size == 3:
        return preset("snan-3x3", opts)
    if size == 10:
        return preset("snan-10x10", opts)
    cfg = preset("snan-10x10", opts, f"grid.rows={size}", f"grid.cols={size}",
                 f"grid.max_steps={LIMITS[size]}")
    return family_config(cfg, level_for_duration(cfg, DURATION_5X5))


def variants(opts: RunOptions) -> list[tuple[str, int, dict]]:
    """(label, size, plasticity params): the main reading per size, the other target, and
    (3x3) the other plasticity rule."""
    alt_target = "all" if opts.route_target != "all" else "chosen"
    alt_rule = "vteam" if opts.plasticity == "additive" else "additive"
    out = [("main", s, {"rule": opts.plasticity, "target": opts.route_target})
           for s in SIZES]
    out += [(f"target={alt_target}", s, {"rule": opts.plasticity, "target": alt_target})
            for s in SIZES]
    out.append((f"rule={alt_rule}", 3, {"rule": alt_rule, "target": opts.route_target}))
    return out


def tasks(opts: RunOptions):
    out = []
    proto = {"cycles": CYCLES, "task": opts.route_task,
             "train_astro": opts.route_train_astro}
    for label, size, plast in variants(opts):
        n = opts.n(SESSIONS[size])
        cfg = size_config(opts, size)
        cond = (NAME, label, size)
        for lo in range(0, n, SESSIONS_PER_TASK):
            hi = min(n, lo + SESSIONS_PER_TASK)
            # every variant of a size sees the same sessions (start/goal, weights, spikes)
            out.append(Task(key=(*cond, lo), fn=route_batch, config=cfg,
                            params={"sessions": [lo, hi], "protocol": proto,
                                    "plasticity": plast},
                            weight=(hi - lo) * (2 * CYCLES + 1), seed_key=(NAME, size)))
    return out


def curves(d: dict[str, np.ndarray], seed: int = 0) -> dict[str, Any]:
    """Per cycle of the tests: median of the successful tests and success rate, with their
    95 % intervals (``median_ci`` bootstrap seeded by ``seed``, ``success_ci`` Wilson)."""
    ts, ok = d["test_steps"], d["test_success"].astype(bool)
    med = [float(np.median(ts[ok[:, c], c])) if ok[:, c].any() else None
           for c in range(ts.shape[1])]
    ci = [interval_fields(ts[:, c], ok[:, c], seed=seed) for c in range(ts.shape[1])]
    return {"median": med, "success": [float(v) for v in ok.mean(axis=0)],
            "median_ci": [f["median_steps_ci"] for f in ci],
            "success_ci": [f["success_rate_ci"] for f in ci],
            "train_median": [float(v) for v in np.median(d["train_steps"], axis=0)],
            "saturated": [float(v) for v in d["saturated"].mean(axis=0)],
            "sessions": int(ts.shape[0])}


def ci_cells(c: dict[str, Any], paper: tuple) -> list[str]:
    """Report cells: our 95 % intervals at cycle 0 and the last cycle, and whether the
    paper's values (median 0, median 20, success 0, success 20) lie inside."""
    def both(key: str, percent: bool) -> str:
        return (f"{format_interval(c[key][0], percent)} → "
                f"{format_interval(c[key][-1], percent)}")

    def inside(key: str, p0: float, p1: float) -> str:
        return (f"{inside_text(paper_inside(p0, c[key][0]))} / "
                f"{inside_text(paper_inside(p1, c[key][-1]))}")
    return [both("median_ci", False), inside("median_ci", paper[0], paper[1]),
            both("success_ci", True), inside("success_ci", paper[2], paper[3])]


def analyse(opts: RunOptions, res: Results) -> Figure:
    cur: dict[tuple[str, int], dict[str, Any]] = {}
    for label, size, plast in variants(opts):
        cur[(label, size)] = dict(curves(res.stacked(NAME, label, size, fields=FIELDS),
                                         seed=opts.seed), plasticity=plast)
    rows = []
    for (label, size), c in cur.items():
        for cyc in range(CYCLES + 1):
            rows.append({"variant": label, "grid": f"{size}x{size}", "cycle": cyc,
                         "rule": c["plasticity"]["rule"], "target": c["plasticity"]["target"],
                         "sessions": c["sessions"], "test_success_rate": c["success"][cyc],
                         "test_median_steps": c["median"][cyc],
                         "test_success_rate_ci": c["success_ci"][cyc],
                         "test_median_steps_ci": c["median_ci"][cyc], "ci_method": METHOD,
                         "train_median_steps": c["train_median"][cyc - 1] if cyc else None,
                         "saturated_fraction": c["saturated"][cyc - 1] if cyc else None})
    cfgs = {f"{s}x{s}": size_config(opts, s) for s in SIZES}
    ev5 = calcium_event(cfgs["5x5"])
    data = {"figure": NAME, "paper": {f"{s}x{s}": PAPER[s] for s in SIZES},
            "curves": {f"{label} {s}x{s}": c for (label, s), c in cur.items()}, "rows": rows,
            "protocol": {"cycles": CYCLES, "task": opts.route_task,
                         "train_astro": opts.route_train_astro,
                         "test_astro": False, "test_plasticity": "off"},
            **provenance(opts, cfgs, res.seeds)}
    rep = report_head(
        TITLE, opts, command_line(NAME, opts),
        f"Protocol: per session fresh weights, start/goal `{opts.route_task}` across the "
        f"cycles; each cycle = one training trial (astrocytes "
        f"{'on' if opts.route_train_astro else 'off'}, STDP "
        f"`{cfgs['3x3'].stdp.mode}`, plasticity `{opts.plasticity}`, change applied to "
        f"`{opts.route_target}` synapses) then one test (astrocytes off, weights frozen). "
        f"Step limits 100 / 300 / 1000. 5x5 astrocytes: tau_Ca = "
        f"{cfgs['5x5'].astro.tau_ca_s:.3g} s, A = {cfgs['5x5'].astro.a:.3g} "
        f"({ev5.duration:.1f} decisions; not given in the paper). Median = successful tests.")
    rep += md_table(["grid", "sessions", "paper median 0 → 20", "ours",
                     "paper success 0 → 20", "ours", "ours: median 95 % CI 0 → 20",
                     "paper inside", "ours: success 95 % CI 0 → 20", "paper inside"],
                    [[f"{s}x{s}", cur[("main", s)]["sessions"],
                      f"{num(PAPER[s][0])} → {num(PAPER[s][1])}",
                      f"{num(cur[('main', s)]['median'][0])} → "
                      f"{num(cur[('main', s)]['median'][-1])}",
                      f"{pct(PAPER[s][2])} → {pct(PAPER[s][3])}",
                      f"{pct(cur[('main', s)]['success'][0])} → "
                      f"{pct(cur[('main', s)]['success'][-1])}",
                      *ci_cells(cur[("main", s)], PAPER[s])] for s in SIZES])
    rep += (f"\n{CI_NOTE} Paper inside: whether the paper's value at cycle 0 / cycle 20 lies "
            "inside our interval.\n")
    rep += "\n## Other readings (same sessions and seeds)\n\n"
    rep += md_table(["variant", "grid", "median 0 → 5 → 20", "success 0 → 5 → 20",
                     "saturated synapses after 20"],
                    [[label, f"{s}x{s}",
                      " → ".join(num(c["median"][k]) for k in (0, 5, CYCLES)),
                      " → ".join(pct(c["success"][k]) for k in (0, 5, CYCLES)),
                      pct(c["saturated"][-1])] for (label, s), c in cur.items()])

    def plot(path):
        plt = pyplot()
        fig, axes = plt.subplots(1, 2, figsize=(11, 4.3))
        colors = {3: "tab:blue", 5: "tab:green", 10: "tab:red"}
        x = np.arange(CYCLES + 1)
        for s in SIZES:
            c = cur[("main", s)]
            axes[0].plot(x, [m if m is not None else np.nan for m in c["median"]], "o-",
                         color=colors[s], ms=3, label=f"{s}x{s}")
            axes[0].plot([0, CYCLES], PAPER[s][:2], "x", color=colors[s], ms=9)
            axes[1].plot(x, [100 * v for v in c["success"]], "o-", color=colors[s], ms=3,
                         label=f"{s}x{s}")
            axes[1].plot([0, CYCLES], [100 * PAPER[s][2], 100 * PAPER[s][3]], "x",
                         color=colors[s], ms=9)
        axes[0].set_yscale("log")
        axes[0].set_ylabel("median route length (steps)", fontsize=8)
        axes[0].set_title("A: median route in the tests (x: paper)", fontsize=8)
        axes[1].set_ylim(0, 105)
        axes[1].set_ylabel("completed routes (%)", fontsize=8)
        axes[1].set_title("B: fraction of completed routes in the tests", fontsize=8)
        for ax in axes:
            ax.set_xlabel("learning cycle", fontsize=8)
            ax.set_xticks(range(0, CYCLES + 1, 2))      # whole cycles
            ax.set_xlim(-0.5, CYCLES + 0.5)
            ax.legend(fontsize=7, loc="upper right" if ax is axes[0] else "lower right")
        save_plot(plt, fig, path, TITLE)

    return Figure(NAME, TITLE, data, rows, plot, rep)
