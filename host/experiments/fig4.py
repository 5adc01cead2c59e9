"""Fig. 4 (section 3.2): 10x10 grid, 500 trials, step limit 1000, with and without
astrocytes (A/B), and the calcium-duration sweep (C2): median route and success rate
against the duration of the astrocytic modulation in decisions (see
:mod:`snan_hil.host.experiments.calcium` for the definition and the (tau_Ca, A) family)."""

from __future__ import annotations

import numpy as np

from snan_hil.host.experiments.calcium import calcium_event, family_config, level_for_duration
from snan_hil.host.experiments.common import (CI_NOTE, Figure, Results, RunOptions, astro,
                                              astro_table, command_line, condition_tasks,
                                              draw_route_hist, draw_trajectory, main_series,
                                              md_table, num, num_ci, paper_fields, pct, pct_ci,
                                              preset, provenance, pyplot, report_head,
                                              save_plot, stats, trial_outcome)
from snan_hil.host.intervals import inside_text, paper_inside

NAME = "fig4"
TITLE = "Fig. 4 — 10x10 grid with and without astrocytes; calcium-duration sweep"
TRIALS = 500
PAPER = {False: (0.462, 362.0), True: (1.0, 55.0)}
#: durations of the astrocytic modulation swept in C2 (decisions)
DURATIONS = (1, 2, 5, 10, 20, 40, 60, 80, 100, 150, 200)
#: the paper's C2 statements: duration -> (success, median) where given
PAPER_C2 = {1: (0.2346, None), 10: (0.9787, None)}
PAPER_C2_TEXT = ("success 23.46 % at 1 step, 97.87 % at 10 steps, 100 % above 20 steps; "
                 "median 83–111 below 10 steps, minimum 53–55 at 60–100 steps")


def base(opts: RunOptions):
    return preset("snan-10x10", opts)


def duration_configs(opts: RunOptions):
    b = astro(base(opts), True)
    out = []
    for d in DURATIONS:
        level = level_for_duration(b, d)
        out.append((d, level, family_config(b, level)))
    return out


def tasks(opts: RunOptions):
    n = opts.n(TRIALS)
    p = {"plasticity": opts.plasticity_params()}
    out = []
    for on in (False, True):
        out += condition_tasks(NAME, ("main", on), astro(base(opts), on), p, n, opts.chunk,
                               keep=range(2), seed_cond=("trials",))
    for d, _level, cfg in duration_configs(opts):  # paired: the same trials everywhere
        out += condition_tasks(NAME, ("duration", d), cfg, p, n, opts.chunk,
                               seed_cond=("trials",))
    return out


def analyse(opts: RunOptions, res: Results) -> Figure:
    main = res.by_astro(NAME, "main")
    sweep = []
    for d, level, cfg in duration_configs(opts):
        steps, ok, _ = res.trials(NAME, "duration", d)
        ev = calcium_event(cfg)
        sweep.append({"duration_target": d, "duration_measured": ev.duration,
                      "onset": ev.onset, "level_s": level, "tau_ca_s": cfg.astro.tau_ca_s,
                      "A": cfg.astro.a, **stats(steps, ok, seed=opts.seed)})
        if d in PAPER_C2:          # the paper states the success at this duration
            sweep[-1]["paper_success_rate"] = PAPER_C2[d][0]
    preset_ev = calcium_event(astro(base(opts), True))
    rows = [{"part": "main", "astro": on, **main[on]["stats"], **paper_fields(PAPER, on)}
            for on in (False, True)]
    rows += [{"part": "duration", **s} for s in sweep]
    data = {"figure": NAME, "paper": {str(k): v for k, v in PAPER.items()},
            "paper_c2": PAPER_C2_TEXT, "rows": rows,
            "preset_calcium": {"duration": preset_ev.duration, "onset": preset_ev.onset},
            **main_series(main),
            **provenance(opts, {f"astro={on}": astro(base(opts), on) for on in (False, True)},
                         res.seeds)}
    rep = report_head(TITLE, opts, command_line(NAME, opts),
                      "Random start != goal, fresh weights every trial, step limit 1000. "
                      "Median = successful trials only.")
    rep += astro_table(main, PAPER)
    rep += (f"\nThe preset (tau_Ca = {base(opts).astro.tau_ca_s} s, A = {base(opts).astro.a}) "
            f"keeps the calcium above Ca_thr for {preset_ev.duration:.1f} decisions after one "
            f"visit (onset {preset_ev.onset:.1f} decisions after the visit starts).\n")
    rep += ("\n## C2: calcium-duration sweep (with astrocytes)\n\n"
            "Duration = decisions the calcium stays above Ca_thr after one visit, measured "
            "from the model; family tau_Ca = max(s, 1 s), A = s (docs/experiments.md). "
            f"Paper: {PAPER_C2_TEXT}.\n\n")
    rep += md_table(["duration (decisions)", "tau_Ca (s)", "A", "onset", "success [95 % CI]",
                     "paper success", "paper inside", "median [95 % CI]"],
                    [[num(s["duration_measured"], 2), f"{s['tau_ca_s']:.3g}", f"{s['A']:.3g}",
                      num(s["onset"], 1), pct_ci(s),
                      pct(PAPER_C2[s["duration_target"]][0])
                      if s["duration_target"] in PAPER_C2 else
                      ("100 %" if s["duration_target"] > 20 else "–"),
                      inside_text(paper_inside(PAPER_C2[s["duration_target"]][0],
                                               s["success_rate_ci"]))
                      if s["duration_target"] in PAPER_C2 else "–",
                      num_ci(s)] for s in sweep])
    rep += f"\n{CI_NOTE}\n"

    def plot(path):
        plt = pyplot()
        fig = plt.figure(figsize=(11, 6.4))
        gs = fig.add_gridspec(2, 3)
        for r, on in enumerate((False, True)):
            ex = main[on]["examples"]
            e = ex[0] if ex else None
            which = "with" if on else "without"
            draw_trajectory(fig.add_subplot(gs[r, 0]), 10, 10, e,
                            f"{'A2' if on else 'A1'}: {which} astrocytes, {trial_outcome(e)}"
                            if e else "")
            draw_route_hist(fig.add_subplot(gs[r, 1]), main, on, np.linspace(0, 1000, 51),
                            PAPER, f"{'B2' if on else 'B1'}: {which} astrocytes: ", sep="\n")
        ax = fig.add_subplot(gs[:, 2])
        d = [s["duration_measured"] for s in sweep]
        med = [s["median_steps"] if s["median_steps"] is not None else np.nan for s in sweep]
        h1, = ax.plot(d, med, "o-", color="tab:blue",
                      label="median route, ours (left axis)")
        h1p = ax.fill_between([60, 100], 53, 55, color="tab:blue", alpha=0.25, lw=0,
                              label="median 53-55 at 60-100, paper (left axis)")
        ax.set_xscale("log")
        ax.set_xlabel("duration of astrocytic modulation (decisions)", fontsize=8)
        ax.set_ylabel("median route length (steps): blue, circles", color="tab:blue",
                      fontsize=8)
        ax2 = ax.twinx()
        h2, = ax2.plot(d, [100 * s["success_rate"] for s in sweep], "s-", color="tab:green",
                       label="completed routes, ours (right axis)")
        h2p, = ax2.plot([1, 10], [23.46, 97.87], "x", color="k", ms=8,
                        label="completed routes, paper (right axis)")
        ax2.set_ylabel("completed routes (%): green, squares", color="tab:green", fontsize=8)
        ax2.set_ylim(0, 105)
        # below the axes: never over the data
        ax.legend(handles=[h1, h1p, h2, h2p], fontsize=7, loc="upper center",
                  bbox_to_anchor=(0.5, -0.13), ncol=1, frameon=False)
        ax.set_title("C2: calcium-duration sweep (with astrocytes)", fontsize=8)
        save_plot(plt, fig, path, TITLE)

    return Figure(NAME, TITLE, data, rows, plot, rep)
