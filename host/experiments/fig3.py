"""Fig. 3 (section 3.1): 3x3 grid, 500 trials, step limit 100, with and without astrocytes;
plus the memristive-plasticity check (VTEAM lookup vs additive STDP on 3x3)."""

from __future__ import annotations

import numpy as np

from snan_hil.host.experiments.common import (Figure, Results, RunOptions, astro, astro_table,
                                              command_line, condition_tasks, draw_route_hist,
                                              draw_trajectory, main_series, md_table, num_ci,
                                              paper_fields, pct_ci, preset, provenance, pyplot,
                                              report_head, save_plot, stats, trial_outcome)

NAME = "fig3"
TITLE = "Fig. 3 — 3x3 grid with and without astrocytes"
TRIALS = 500
PAPER = {False: (0.631, 10.0), True: (1.0, 4.0)}
#: plasticity check: (rule, stdp.mode) x astro; "trial_end" = the paper's protocol (weights
#: reset every trial), "window" = the change acts inside the trial
PLAST_ROWS = [("additive", "trial_end"), ("vteam", "trial_end"), ("additive", "window"),
              ("vteam", "window")]


def _cfg(opts: RunOptions, on: bool, mode: str | None = None):
    cfg = astro(preset("snan-3x3", opts), on)
    return cfg if mode is None else cfg.replace(**{"stdp.mode": mode})


def tasks(opts: RunOptions):
    n = opts.n(TRIALS)
    out = []
    for on in (False, True):
        out += condition_tasks(NAME, ("main", on), _cfg(opts, on),
                               {"plasticity": opts.plasticity_params()}, n, opts.chunk,
                               keep=range(3))
        for rule, mode in PLAST_ROWS:  # paired: same trials for both rules
            out += condition_tasks(NAME, ("plasticity", rule, mode, on), _cfg(opts, on, mode),
                                   {"plasticity": {"rule": rule}}, n, opts.chunk,
                                   seed_cond=("plasticity", mode, on))
    return out


def analyse(opts: RunOptions, res: Results) -> Figure:
    main = res.by_astro(NAME, "main")
    plast = []
    for rule, mode in PLAST_ROWS:
        for on in (False, True):
            steps, ok, _ = res.trials(NAME, "plasticity", rule, mode, on)
            plast.append({"rule": rule, "stdp_mode": mode, "astro": on,
                          **stats(steps, ok, seed=opts.seed)})
    rows = []
    for on in (False, True):
        s = main[on]["stats"]
        rows.append({"part": "main", "astro": on, "rule": opts.plasticity,
                     "stdp_mode": _cfg(opts, on).stdp.mode, **s, **paper_fields(PAPER, on)})
    rows += [{"part": "plasticity", **p} for p in plast]
    configs = {f"astro={on}": _cfg(opts, on) for on in (False, True)}
    data = {"figure": NAME, "paper": {str(k): v for k, v in PAPER.items()},
            "rows": rows, **main_series(main), **provenance(opts, configs, res.seeds)}
    cmd = command_line(NAME, opts)
    rep = report_head(TITLE, opts, cmd, "Paper protocol: random start != goal, fresh weights "
                      "every trial, trial ends on the goal or after 100 steps. Median = "
                      "successful trials only.")
    rep += astro_table(main, PAPER)
    rep += ("\n## Memristive plasticity (VTEAM lookup) vs additive STDP\n\n"
            "Paper: the memristive network performs like the additive one on 3x3. "
            "`trial_end` is the paper's protocol (weights reset every trial, so plasticity "
            "cannot change a trial); `window` lets each window's change act within the "
            "trial, where the two rules differ.\n\n")
    rep += md_table(["rule", "stdp.mode", "astrocytes", "success [95 % CI]",
                     "median [95 % CI]"],
                    [[p["rule"], p["stdp_mode"], "with" if p["astro"] else "without",
                      pct_ci(p), num_ci(p)] for p in plast])

    def plot(path):
        plt = pyplot()
        fig, axes = plt.subplots(2, 3, figsize=(10, 6.2))
        for r, on in enumerate((False, True)):
            ex = main[on]["examples"]
            for k in range(2):
                e = ex[k] if k < len(ex) else None
                label = f"{'A2' if on else 'A1'}: {'with' if on else 'without'} astrocytes, " \
                        f"trial {e['trial']}, {trial_outcome(e)}" if e else ""
                draw_trajectory(axes[r, k], 3, 3, e, label)
            ax = axes[r, 2]
            draw_route_hist(ax, main, on, np.arange(0, 101) - 0.5, PAPER,
                            f"{'C2' if on else 'D1'}: {'with' if on else 'without'} "
                            "astrocytes: ", sep="\n")
            ax.set_xlim(-0.5, 40)
        save_plot(plt, fig, path, TITLE)

    return Figure(NAME, TITLE, data, rows, plot, rep)
