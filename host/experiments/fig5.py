"""Fig. 5 (section 3.3): random mazes, wall fraction 0–90 %, with and without astrocytes,
500 trials per point, step limit 1000, a new maze every trial (rule: see
:mod:`snan_hil.host.experiments.mazes`)."""

from __future__ import annotations

from snan_hil.host.experiments.common import (EXAMPLE_WALLS, RANGE_NOTE, Figure, Results,
                                              RunOptions, astro, command_line, condition_tasks,
                                              maze_walls as walls, md_table, num, num_ci, pct,
                                              pct_ci, preset, provenance, range_ci, range_inside,
                                              report_head, save_plot, stats,
                                              wall_examples_figure)
from snan_hil.host.intervals import format_interval, inside_text, paper_inside

NAME = "fig5"
TITLE = "Fig. 5 — navigation in random mazes"
TRIALS = 500
PAPER_TEXT = ("with astrocytes 97.0–100 % success at every density, median peaking at 40 % "
              "walls (103.5 steps); without astrocytes 5.0–16.6 % success")
PAPER_MEDIAN = {0.4: 103.5}
#: success over every wall density the paper states (Fig. 5C), with / without astrocytes
PAPER_SUCCESS = {True: (0.97, 1.0), False: (0.05, 0.166)}


def base(opts: RunOptions, on: bool):
    return astro(preset("snan-10x10", opts), on)


def tasks(opts: RunOptions):
    n = opts.n(TRIALS)
    out = []
    for on in (False, True):
        for f in walls(opts):
            p = {"walls": f, "maze_rule": opts.maze_rule, "goals": 1,
                 "plasticity": opts.plasticity_params()}
            out += condition_tasks(NAME, (on, f), base(opts, on), p, n, opts.chunk,
                                   keep=range(1) if f in EXAMPLE_WALLS else (),
                                   seed_cond=(f,))  # same mazes with and without
    return out


def analyse(opts: RunOptions, res: Results) -> Figure:
    rows, ex = [], {}
    for on in (False, True):
        for f in walls(opts):
            steps, ok, e = res.trials(NAME, on, f)
            rows.append({"astro": on, "wall_fraction": f, **stats(steps, ok, seed=opts.seed),
                         "paper_median_steps": PAPER_MEDIAN.get(f) if on else None})
            if e and on:
                ex[f] = e[0]
    by = {(r["astro"], r["wall_fraction"]): r for r in rows}
    data = {"figure": NAME, "paper": PAPER_TEXT, "rows": rows,
            "examples": {str(f): e for f, e in ex.items()},
            **provenance(opts, {f"astro={on}": base(opts, on) for on in (False, True)},
                         res.seeds)}
    rep = report_head(TITLE, opts, command_line(NAME, opts),
                      f"Maze rule `{opts.maze_rule}` (docs/experiments.md): exactly "
                      "round(f x 180) walls, "
                      + ("start and goal in the same connected piece. "
                         if opts.maze_rule == "component" else
                         "a random spanning tree kept open (0-40 % only). ")
                      + f"Paper: {PAPER_TEXT}.")
    ok_a = [by[(True, f)]["success_rate"] for f in walls(opts)]
    ok_n = [by[(False, f)]["success_rate"] for f in walls(opts)]
    m40 = by.get((True, 0.4), {})
    rep += md_table(["quantity", "paper", "ours", "ours: 95 % CI", "paper inside"], [
        ["success with astrocytes (range over densities)", "97.0–100 %",
         f"{pct(min(ok_a))}–{pct(max(ok_a))}", range_ci(by, True, walls(opts)),
         range_inside(PAPER_SUCCESS[True], by, True, walls(opts))],
        ["median with astrocytes at 40 % walls", "103.5", num(m40.get("median_steps")),
         format_interval(m40.get("median_steps_ci")),
         inside_text(paper_inside(103.5, m40.get("median_steps_ci")))],
        ["success without astrocytes (range)", "5.0–16.6 %",
         f"{pct(min(ok_n))}–{pct(max(ok_n))}", range_ci(by, False, walls(opts)),
         range_inside(PAPER_SUCCESS[False], by, False, walls(opts))],
    ])
    rep += "\n"
    rep += md_table(["walls", "success (astro) [95 % CI]", "median (astro) [95 % CI]",
                     "success (no astro) [95 % CI]", "median (no astro) [95 % CI]"],
                    [[f"{100 * f:.0f} %", pct_ci(by[(True, f)]), num_ci(by[(True, f)]),
                      pct_ci(by[(False, f)]), num_ci(by[(False, f)])] for f in walls(opts)])
    rep += RANGE_NOTE

    def plot(path):
        plt, fig, gs = wall_examples_figure(ex, (11, 6.4), 3)
        x = [100 * f for f in walls(opts)]
        ax = fig.add_subplot(gs[1, 0:2])
        for on, color in ((True, "tab:blue"), (False, "tab:red")):
            ax.plot(x, [by[(on, f)]["median_steps"] or float("nan") for f in walls(opts)], "o-",
                    color=color, label="with astrocytes" if on else "without")
        ax.plot([40], [103.5], "x", color="k", ms=9, label="paper (40 %)")
        ax.set_xlabel("wall fraction (%)", fontsize=8)
        ax.set_ylabel("median route length (steps)", fontsize=8)
        ax.set_title("B: median route (successful trials)", fontsize=8)
        ax.legend(fontsize=7)
        ax = fig.add_subplot(gs[1, 2])
        for on, color in ((True, "tab:blue"), (False, "tab:red")):
            ax.plot(x, [100 * by[(on, f)]["success_rate"] for f in walls(opts)], "o-", color=color)
        ax.axhspan(97, 100, color="tab:blue", alpha=0.12, label="paper, astro")
        ax.axhspan(5, 16.6, color="tab:red", alpha=0.12, label="paper, no astro")
        ax.set_ylim(0, 105)
        ax.set_xlabel("wall fraction (%)", fontsize=8)
        ax.set_ylabel("completed routes (%)", fontsize=8)
        ax.set_title("C: success", fontsize=8)
        ax.legend(fontsize=7)
        save_plot(plt, fig, path, TITLE)

    return Figure(NAME, TITLE, data, rows, plot, rep)
