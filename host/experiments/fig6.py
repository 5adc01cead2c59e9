"""Fig. 6 (section 3.4): multi-goal navigation in mazes (three goals, any order, 5000
steps; A/B) and multi-goal navigation with return to the start (C/D: success and median
over calcium durations x wall densities)."""

from __future__ import annotations

import numpy as np

from snan_hil.host.experiments.calcium import calcium_event, family_config, level_for_duration
from snan_hil.host.experiments.common import (CI_NOTE, EXAMPLE_WALLS, RANGE_NOTE, Figure,
                                              Results, RunOptions, astro, command_line,
                                              condition_tasks, maze_walls as walls, md_table,
                                              num, num_ci, pct, pct_ci, preset, provenance,
                                              range_ci, range_inside, report_head, save_plot,
                                              stats, wall_examples_figure)
from snan_hil.host.intervals import format_interval, inside_text, paper_inside, rate_interval

NAME = "fig6"
TITLE = "Fig. 6 — multi-goal navigation in mazes (and return to start)"
TRIALS = 500
GOALS = 3
MAX_STEPS = 5000
DURATIONS = (5, 10, 20, 30, 50, 70, 100, 150)
PAPER_MEDIAN = {0.4: 253.0, 0.8: 80.0, 0.9: 56.0}
#: three goals: success with astrocytes and failure without over every density (Fig. 6B)
PAPER_SUCCESS_ASTRO = (0.976, 1.0)
PAPER_FAILURE_NO_ASTRO = (0.932, 1.0)
#: return to start without astrocytes: no success at any density (Fig. 6C/D)
PAPER_RETURN_NO_ASTRO = (0.0, 0.0)
PAPER_TEXT = ("with astrocytes 97.6–100 % success (100 % at 0–10 % and 70–90 % walls), "
              "median 253 at 40 %, 80 at 80 %, 56 at 90 %; without astrocytes 93.2–100 % "
              "failure (100 % at 40–70 %)")
PAPER_CD_TEXT = ("return to start: no success at all without astrocytes; with astrocytes "
                 "5–20 step durations fail more often (20–60 % walls), above 30 steps "
                 "98–100 % "
                 "success at most densities; median independent of the duration for 20–100 "
                 "steps, growing above 100")


def base(opts: RunOptions, on: bool):
    return astro(preset("snan-10x10", opts, f"grid.max_steps={MAX_STEPS}"), on)


def duration_configs(opts: RunOptions):
    b = base(opts, True)
    return [(d, family_config(b, level_for_duration(b, d))) for d in DURATIONS]


def tasks(opts: RunOptions):
    n = opts.n(TRIALS)
    out = []
    plast = opts.plasticity_params()
    for on in (False, True):
        for f in walls(opts):
            p = {"walls": f, "maze_rule": opts.maze_rule, "goals": GOALS, "plasticity": plast}
            out += condition_tasks(NAME, ("multi", on, f), base(opts, on), p, n, opts.chunk,
                                   keep=range(1) if on and f in EXAMPLE_WALLS else (),
                                   seed_cond=(f,))  # same mazes and tasks everywhere
            if not on:
                out += condition_tasks(NAME, ("return", False, f), base(opts, False),
                                       dict(p, return_to_start=True), n, opts.chunk,
                                       seed_cond=(f,))
    for d, cfg in duration_configs(opts):
        for f in walls(opts):
            p = {"walls": f, "maze_rule": opts.maze_rule, "goals": GOALS, "plasticity": plast,
                 "return_to_start": True}
            out += condition_tasks(NAME, ("return", d, f), cfg, p, n, opts.chunk,
                                   seed_cond=(f,))
    return out


def analyse(opts: RunOptions, res: Results) -> Figure:
    rows, ex = [], {}
    for on in (False, True):
        for f in walls(opts):
            steps, ok, e = res.trials(NAME, "multi", on, f)
            rows.append({"part": "multi", "astro": on, "duration": None, "wall_fraction": f,
                         **stats(steps, ok, seed=opts.seed),
                         "paper_median_steps": PAPER_MEDIAN.get(f) if on else None})
            if e:
                ex[f] = e[0]
    durs = duration_configs(opts)
    for f in walls(opts):
        steps, ok, _ = res.trials(NAME, "return", False, f)
        rows.append({"part": "return", "astro": False, "duration": None, "wall_fraction": f,
                     **stats(steps, ok, seed=opts.seed)})
    for d, cfg in durs:
        for f in walls(opts):
            steps, ok, _ = res.trials(NAME, "return", d, f)
            rows.append({"part": "return", "astro": True, "duration": d,
                         "duration_measured": calcium_event(cfg).duration,
                         "tau_ca_s": cfg.astro.tau_ca_s, "A": cfg.astro.a, "wall_fraction": f,
                         **stats(steps, ok, seed=opts.seed)})
    multi = {(r["astro"], r["wall_fraction"]): r for r in rows if r["part"] == "multi"}
    ret = {(r["duration"], r["wall_fraction"]): r for r in rows if r["part"] == "return"}
    data = {"figure": NAME, "paper": PAPER_TEXT, "paper_cd": PAPER_CD_TEXT, "rows": rows,
            "examples": {str(f): e for f, e in ex.items()},
            **provenance(opts, {f"astro={on}": base(opts, on) for on in (False, True)},
                         res.seeds)}
    ok_a = [multi[(True, f)]["success_rate"] for f in walls(opts)]
    fail_n = [1 - multi[(False, f)]["success_rate"] for f in walls(opts)]
    ret_n = [ret[(None, f)]["successes"] for f in walls(opts)]
    rep = report_head(TITLE, opts, command_line(NAME, opts),
                      f"Three goals, any order, step limit {MAX_STEPS}, maze rule "
                      f"`{opts.maze_rule}` ("
                      + ("all goals in the start's piece" if opts.maze_rule == "component"
                         else "connected mazes, 0-40 % only")
                      + "), a new maze "
                      f"every trial. Paper: {PAPER_TEXT}.")
    def med_row(f: float, paper: float) -> list[str]:
        s = multi.get((True, f), {})
        return [f"median at {100 * f:.0f} % walls", f"{paper:g}", num(s.get("median_steps")),
                format_interval(s.get("median_steps_ci")),
                inside_text(paper_inside(paper, s.get("median_steps_ci")))]
    ret_total = sum(ret[(None, f)]['trials'] for f in walls(opts))
    ret_ci = rate_interval(sum(ret_n), ret_total)
    fail_ci = {f: [1 - c for c in reversed(multi[(False, f)]["success_rate_ci"])]
               for f in walls(opts)}
    lo_f = min(walls(opts), key=lambda f: 1 - multi[(False, f)]["success_rate"])
    hi_f = max(walls(opts), key=lambda f: 1 - multi[(False, f)]["success_rate"])
    rep += md_table(["quantity", "paper", "ours", "ours: 95 % CI", "paper inside"], [
        ["success with astrocytes (range)", "97.6–100 %", f"{pct(min(ok_a))}–{pct(max(ok_a))}",
         range_ci(multi, True, walls(opts)),
         range_inside(PAPER_SUCCESS_ASTRO, multi, True, walls(opts))],
        *[med_row(f, p) for f, p in PAPER_MEDIAN.items()],
        ["failure without astrocytes (range)", "93.2–100 %",
         f"{pct(min(fail_n))}–{pct(max(fail_n))}",
         f"{format_interval(fail_ci[lo_f], True)} … {format_interval(fail_ci[hi_f], True)}",
         inside_text(all(paper_inside(PAPER_FAILURE_NO_ASTRO, fail_ci[f]) for f in walls(opts)))],
        ["return to start without astrocytes: successes", "0 (all densities)",
         f"{sum(ret_n)} of {ret_total}", format_interval(ret_ci, True),
         inside_text(paper_inside(0.0, ret_ci))],
    ])
    rep += "\n"
    rep += md_table(["walls", "success (astro) [95 % CI]", "median (astro) [95 % CI]",
                     "success (no astro) [95 % CI]", "median (no astro) [95 % CI]",
                     "return, no astro: success [95 % CI]"],
                    [[f"{100 * f:.0f} %", pct_ci(multi[(True, f)]), num_ci(multi[(True, f)]),
                      pct_ci(multi[(False, f)]), num_ci(multi[(False, f)]),
                      pct_ci(ret[(None, f)])] for f in walls(opts)])
    rep += RANGE_NOTE
    rep += (f"\n## C/D: return to start, success / median by calcium duration (rows, "
            f"decisions) and wall fraction (columns)\n\nPaper: {PAPER_CD_TEXT}.\n\n")
    rep += md_table(["duration"] + [f"{100 * f:.0f} %" for f in walls(opts)],
                    [[str(d)] + [f"{pct_ci(ret[(d, f)], 0)} / {num_ci(ret[(d, f)])}"
                                 for f in walls(opts)]
                     for d, _c in durs])
    rep += f"\nCells: success [95 % CI] / median [95 % CI]. {CI_NOTE}\n"

    def plot(path):
        plt, fig, gs = wall_examples_figure(ex, (12, 7.5), 4)
        x = [100 * f for f in walls(opts)]
        ax = fig.add_subplot(gs[0, 3])
        h = ax.plot(x, [multi[(True, f)]["median_steps"] or np.nan for f in walls(opts)],
                    "o-", color="tab:blue", label="median route, with astrocytes (left axis)")
        h += ax.plot(list(100 * np.array(list(PAPER_MEDIAN))), list(PAPER_MEDIAN.values()), "x",
                     color="k", ms=8, label="median route, paper (left axis)")
        ax.set_xlabel("wall fraction (%)", fontsize=8)
        ax.set_ylabel("median route (steps): blue, circles", fontsize=8, color="tab:blue")
        ax2 = ax.twinx()
        h += ax2.plot(x, [100 * multi[(True, f)]["success_rate"] for f in walls(opts)], "s-",
                      color="tab:green", label="completed, with astrocytes (right axis)")
        h += ax2.plot(x, [100 * multi[(False, f)]["success_rate"] for f in walls(opts)], "^--",
                      color="tab:red", label="completed, without astrocytes (right axis)")
        ax2.set_ylim(0, 105)
        ax2.set_ylabel("completed (%): squares / triangles", fontsize=7)
        # the legend below the panel, never over its data
        ax.legend(handles=h, fontsize=6, loc="upper center", bbox_to_anchor=(0.5, -0.2),
                  ncol=1, frameon=False)
        ax.set_title("B: three goals", fontsize=8)
        succ = np.array([[ret[(d, f)]["success_rate"] for f in walls(opts)] for d, _c in durs])
        med = np.array([[ret[(d, f)]["median_steps"] or np.nan for f in walls(opts)]
                        for d, _c in durs])
        for col, (mat, label, cmap) in enumerate(((100 * succ, "C: success (%)", "viridis"),
                                                  (med, "D: median route (steps)", "magma"))):
            ax = fig.add_subplot(gs[1, 2 * col:2 * col + 2])
            im = ax.imshow(mat, aspect="auto", origin="lower", cmap=cmap)
            ax.set_xticks(range(len(walls(opts))))
            ax.set_xticklabels([f"{100 * f:.0f}" for f in walls(opts)], fontsize=7)
            ax.set_yticks(range(len(durs)))
            ax.set_yticklabels([str(d) for d, _c in durs], fontsize=7)
            ax.set_xlabel("wall fraction (%)", fontsize=8)
            ax.set_ylabel("calcium duration (decisions)", fontsize=8)
            ax.set_title(label + ", return to start", fontsize=8)
            fig.colorbar(im, ax=ax)
        save_plot(plt, fig, path, TITLE)

    return Figure(NAME, TITLE, data, rows, plot, rep)
