"""Figures read at a glance: the paper's values on sim --plot and fig10c, integer count ticks,
every line and marker in a legend, start/goal labels, scales; the retention figure's reads,
band and cycles; the calcium trace behind sim/run --animate and the animation itself."""

from __future__ import annotations

import json

import matplotlib
import numpy as np
import pytest

from snan_hil.host.agent import environment, run_trial
from snan_hil.host.calcium_trace import astro_window, calcium_trace
from snan_hil.host.config import load_config
from snan_hil.host.hil.figure import compare_figure
from snan_hil.host.plots import sim_figure
from snan_hil.host.simulate import simulate
from snan_hil.host.snan_reference import reference_window
from snan_hil.host.state import NetworkState
from snan_hil.tools import cli

matplotlib.use("Agg")


def _legend_texts(ax_or_fig) -> list[str]:
    legends = [ax_or_fig.get_legend()] if hasattr(ax_or_fig, "get_legend") else []
    legends += list(getattr(ax_or_fig, "legends", []))
    return [t.get_text() for lg in legends if lg is not None for t in lg.get_texts()]


# ------------------------------------------------------------------ sim --plot
@pytest.mark.parametrize("grid,astro,paper", [(3, True, (1.0, 4)), (3, False, (0.631, 10)),
                                              (10, True, (1.0, 55))])
def test_sim_plot_shows_the_paper_values(grid, astro, paper):
    import matplotlib.pyplot as plt
    cfg = load_config(preset=f"snan-{grid}x{grid}",
                      overrides=[f"astro.enabled={str(astro).lower()}"])
    res = simulate(cfg, 12 if grid == 3 else 3, seed=2)
    fig = sim_figure(res, n_traj=2)
    try:
        hist = fig.axes[0]
        texts = _legend_texts(hist)
        assert f"median, paper: {paper[1]:g}" in texts
        assert any(t.startswith("median, ours") for t in texts) or res.summary()[
            "median_steps"] is None
        assert f"(paper {100 * paper[0]:.1f} %)" in hist.get_title()
        ticks = [t for t in hist.get_yticks() if t >= 0]
        assert all(float(t).is_integer() for t in ticks)          # counts: integer ticks
        assert all(float(t).is_integer() for t in hist.get_xticks())
        lo, hi = hist.get_xlim()
        assert lo < 0 and hi >= paper[1] + 1 and hi <= 1.1 * cfg.grid.max_steps + 2
        med = res.summary()["median_steps"]      # no median line on the right border
        assert med is None or hi >= med + 1
        for traj in fig.axes[1:]:
            labels = [t.get_text() for t in traj.texts]
            assert "start" in labels and "goal" in labels
        assert {"start cell", "goal cell"} <= set(_legend_texts(fig))
    finally:
        plt.close(fig)


def test_sim_plot_says_when_the_paper_has_no_value():
    import matplotlib.pyplot as plt
    cfg = load_config(preset="snan-10x10", overrides=["grid.rows=4", "grid.cols=4",
                                                      "grid.max_steps=50"])
    fig = sim_figure(simulate(cfg, 5, seed=1), n_traj=1)
    try:
        assert "no paper value for this grid" in fig.axes[0].get_title()
        assert not any("paper" in t for t in _legend_texts(fig.axes[0]))
    finally:
        plt.close(fig)


# ------------------------------------------------------------------ fig10c
def _compare_results(limit: int) -> dict:
    rng = np.random.default_rng(0)
    scen = ["sw_noastro", "sw_astro", "hw_noastro", "hw_astro"]
    per, summary = [], {}
    for s in scen:
        everything = []
        for k in range(3):
            pl = [int(x) for x in rng.integers(5, 20, 6)]
            ok = [x < 18 for x in pl]
            pl = [x if o else limit for x, o in zip(pl, ok)]
            good = [x for x, o in zip(pl, ok) if o]
            per.append({"scenario": s, "set": k, "path_lengths": pl, "success": ok,
                        "median_steps": float(np.median(good))})
            everything += good
        summary[s] = {"median_steps": float(np.median(everything))}
    return {"sets": [0, 1, 2], "scenarios": summary, "per_set": per, "grid": [6, 6],
            "start": 18, "goal": 0, "launches": 6, "step_limit": limit}


def test_fig10c_shows_the_paper_medians_and_a_full_legend():
    import matplotlib.pyplot as plt
    fig = compare_figure(_compare_results(100))
    try:
        ax = fig.axes[0]
        texts = _legend_texts(fig)
        assert "paper: 14 steps without astrocytes" in texts
        assert "paper: 7 steps with astrocytes" in texts
        assert sum("all sets" in t for t in texts) == 4            # the four median lines
        assert sum("median of a set" in t for t in texts) == 4     # the four bar colours
        assert any("failed" in t for t in texts) and any("reached" in t for t in texts)
        assert ax.get_yscale() == "linear" and ax.get_ylim()[0] == 0   # bars start at 0
        lines = {round(line.get_ydata()[0], 6) for line in ax.get_lines()
                 if len(set(line.get_ydata())) == 1}
        assert {14.0, 7.0} <= lines
        # the legend lies inside the figure with a margin, clear of the axes
        fig.canvas.draw()
        box = fig.legends[0].get_window_extent(fig.canvas.get_renderer())
        fb = fig.bbox
        assert fb.x0 + 5 < box.x0 and box.x1 < fb.x1 - 5 and fb.y0 < box.y0
        assert box.y1 < ax.get_tightbbox(fig.canvas.get_renderer()).y0   # below the labels
    finally:
        plt.close(fig)
    fig = compare_figure(_compare_results(1000))
    try:
        assert fig.axes[0].get_yscale() == "log" and "log" in fig.axes[0].get_ylabel()
    finally:
        plt.close(fig)


def test_fig10c_shows_intervals_the_board_and_the_date():
    # issue 38 item 13: fig10c had no intervals, board or date
    import matplotlib.pyplot as plt
    from matplotlib.container import ErrorbarContainer
    res = _compare_results(100)
    for r in res["per_set"]:
        r["median_steps_ci"] = [r["median_steps"] - 1.0, r["median_steps"] + 2.0]
    for s in res["scenarios"].values():
        s["median_steps_ci"] = [s["median_steps"] - 1.5, s["median_steps"] + 1.5]
    res.update(board={"board_id": "MC-4D430001_8B29"}, port="/dev/ttyUSB0",
               created="2026-03-04T05:06:07+00:00")
    fig = compare_figure(res)
    try:
        ax = fig.axes[0]
        assert "board MC-4D430001_8B29, port /dev/ttyUSB0, 2026-03-04 05:06 UTC" in \
            ax.get_title()
        bars = [c for c in ax.containers if isinstance(c, ErrorbarContainer)]
        assert len(bars) == 4                                    # one per scenario
        spans = [p for p in ax.patches if p.get_alpha() == 0.15]
        assert len(spans) == 4                                   # each median's interval
        texts = _legend_texts(fig)
        assert any("95 % interval of a set's median" in t for t in texts)
        m = res["scenarios"]["hw_astro"]["median_steps"]
        assert any(f"[{m - 1.5:g}, {m + 1.5:g}]" in t for t in texts)
    finally:
        plt.close(fig)
    sw = {k: v for k, v in res.items() if k not in ("board", "port")}
    fig = compare_figure(sw)
    try:
        assert "software only (no board), 2026-03-04 05:06 UTC" in fig.axes[0].get_title()
    finally:
        plt.close(fig)


# ------------------------------------------------------------------ calcium trace
def test_astro_window_equals_the_reference():
    cfg = load_config(preset="snan-3x3")
    rng = np.random.default_rng(5)
    st = NetworkState.fresh(cfg)
    n = cfg.n_cells
    g, ca, y = np.zeros(n), np.zeros(n), np.zeros(n)
    for cell in [0, 1, 4, 4, 5, 8, 0]:
        spikes = rng.random(cfg.window_steps) < cfg.input.p
        reference_window(st, cfg, cell, [], spikes, np.zeros((cfg.window_steps, 0)))
        astro_window(cfg, g, ca, y, cell, spikes)
        assert np.array_equal(ca, st.ca) and np.array_equal(y, st.y) and np.array_equal(g, st.g)
    assert ca.max() > cfg.astro.ca_thr                 # the visits did raise calcium



def test_compiled_astro_window_gives_the_references_floats():
    """calcium_trace's compiled window (snan_kernel.astro_window_all) = astro_window, bit for
    bit, on a 6 x 6 grid with long stays (calcium above threshold) and moves."""
    from snan_hil.host.snan_kernel import astro_window_all
    cfg = load_config(overrides=["grid.rows=6", "grid.cols=6"])
    ast = cfg.astro
    rng = np.random.default_rng(11)
    n = cfg.n_cells
    ref = [np.zeros(n) for _ in range(3)]
    fast = [np.zeros(n) for _ in range(3)]
    for cell in [0, 0, 0, 1, 7, 7, 35, 20, 0, 0]:
        spikes = rng.random(cfg.window_steps) < cfg.input.p
        astro_window(cfg, *ref, cell, spikes)
        astro_window_all(cfg.input.dt_ms, ast.alpha_n_per_ms, ast.k_n, ast.g_thr, ast.a,
                         ast.tau_ca_ms, cell, spikes, *fast)
        for a, b in zip(ref, fast):
            assert np.array_equal(a, b)
    assert ref[1].max() > ast.ca_thr

@pytest.mark.parametrize("astro", [True, False])
def test_calcium_trace_uses_the_trials_own_spike_trains(astro):
    cfg = load_config(preset="snan-3x3", overrides=[f"astro.enabled={str(astro).lower()}"])
    env = environment(cfg)
    r = run_trial(env, cfg, 0, 8, seed=7, trial=3, engine="reference", record=True)
    fast = run_trial(env, cfg, 0, 8, seed=7, trial=3)
    assert list(fast.path) == list(r.path)             # the engines agree on the trial
    tr = calcium_trace(cfg, fast.path, seed=7, trial=3)
    assert list(tr.spikes) == [len(w.input_spikes) for w in r.windows]
    assert tr.ca.shape == (len(fast.path), cfg.n_cells) and np.all(tr.ca[0] == 0)
    visited = set(int(c) for c in fast.path[:-1])
    never = [i for i in range(cfg.n_cells) if i not in visited]
    assert np.all(tr.ca[:, never] == 0)                # calcium only where the agent was
    if astro:
        assert tr.ca[:, sorted(visited)].max() > 0
    else:
        assert np.all(tr.ca == 0)


# ------------------------------------------------------------------ animations
def _gif(path):
    from PIL import Image
    with Image.open(path) as im:
        return im.n_frames, im.info.get("comment", b"")


def test_sim_animate_writes_a_marked_gif(tmp_path, capsys):
    out = tmp_path / "a.gif"
    assert cli.main(["sim", "--grid", "3", "--trials", "4", "--seed", "2", "--animate",
                     str(out), "--animate-trial", "1", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    frames, comment = _gif(out)
    assert res["animation"] == str(out) and comment.startswith(b"snan-hil-animation/")
    cfg = load_config(preset="snan-3x3")
    r = run_trial(environment(cfg), cfg, *_task(cfg, 2, 1), seed=2, trial=1)
    assert frames == r.steps + 1                       # one frame per decision, and the start
    assert cli.main(["sim", "--grid", "3", "--trials", "4", "--animate", str(out)]) == 0
    capsys.readouterr()
    for argv, needle in ((["--animate", str(tmp_path / "a.png")], ".gif"),
                         (["--animate", str(out), "--animate-trial", "4"], "0..3")):
        assert cli.main(["sim", "--grid", "3", "--trials", "4", *argv]) == 2
        err = capsys.readouterr().err
        assert needle in err and err.count("\n") == 1
    (tmp_path / "mine.gif").write_bytes(b"GIF89a not ours")
    assert cli.main(["sim", "--grid", "3", "--trials", "2", "--animate",
                     str(tmp_path / "mine.gif")]) == 2
    assert "--force" in capsys.readouterr().err
    assert (tmp_path / "mine.gif").read_bytes() == b"GIF89a not ours"


def _task(cfg, seed, trial):
    from snan_hil.host.simulate import trial_setup
    env = environment(cfg)
    from snan_hil.host.agent import synapse_tables
    nbr, _ = synapse_tables(env, cfg)
    start, goal, _w, _key = trial_setup(cfg, env, nbr, seed, trial)
    return start, goal


def test_run_animate_software_and_crossbar(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    short = ["--set", "grid.max_steps=15"]
    w = tmp_path / "w.npz"
    assert cli.main(["train", "--grid", "6", "--start", "18", "--goal", "0", "--sets", "1",
                     "--cycles", "1", "--seed", "3", "-o", str(w), "--json", *short]) == 0
    assert cli.main(["program-weights", str(w), "--port", "emu", "--json"]) == 0
    capsys.readouterr()
    for scenario in ("sw_astro", "hw_astro"):
        out = tmp_path / f"{scenario}.gif"
        assert cli.main(["run", "--scenario", scenario, "--weights", str(w), "--launches", "2",
                         "--seed", "2", "--animate", str(out), "--animate-launch", "1",
                         "--json", *short]) == 0
        res = json.loads(capsys.readouterr().out)
        frames, comment = _gif(out)
        launch = res["launch_details"][1]
        assert frames == launch["steps"] + 1 and comment.startswith(b"snan-hil-animation/")
        assert res["animation"] == str(out)
    assert cli.main(["run", "--scenario", "sw_astro", "--weights", str(w), "--launches", "2",
                     "--animate", str(tmp_path / "x.gif"), "--animate-launch", "2",
                     *short]) == 2
    assert "--animate-launch 2" in capsys.readouterr().err


# ------------------------------------------------------------------ experiment figures
def _figure_of(name: str, trials: int, monkeypatch):
    """The matplotlib figure ``experiment NAME --trials N`` draws (captured, not written)."""
    import importlib
    from snan_hil.host.experiments.common import RunOptions
    from snan_hil.host.experiments.executor import SerialExecutor
    from snan_hil.host.experiments.runner import execute, plan
    mod = importlib.import_module(f"snan_hil.host.experiments.{name}")
    seen = []
    monkeypatch.setattr(mod, "save_plot", lambda plt, fig, path, title: seen.append(fig))
    p = plan([name], RunOptions(seed=3, trials=trials))
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        execute(p, SerialExecutor(), d)
    assert seen, f"{name} drew no figure"
    return seen[0]


def _integer(ticks) -> bool:
    return all(float(t).is_integer() for t in ticks)


def test_fig4_panels_say_what_differs_and_name_both_axes(monkeypatch):
    import matplotlib.pyplot as plt
    fig = _figure_of("fig4", 4, monkeypatch)
    try:
        titles = [ax.get_title() for ax in fig.axes]
        assert any(t.startswith("B1: without astrocytes") for t in titles)
        assert any(t.startswith("B2: with astrocytes") for t in titles)
        assert any(t.startswith("A1: without astrocytes") for t in titles)
        hist = [ax for ax in fig.axes if ax.get_title().startswith("B")]
        assert all(_integer(ax.get_yticks()) and _integer(ax.get_xticks()) for ax in hist)
        c2 = next(ax for ax in fig.axes if ax.get_title().startswith("C2"))
        texts = _legend_texts(c2)
        assert any("(left axis)" in t for t in texts) and any("(right axis)" in t for t in texts)
        fig.canvas.draw()        # the legend sits below the axes, not over the data
        r = fig.canvas.get_renderer()
        assert c2.get_legend().get_window_extent(r).y1 < c2.get_window_extent(r).y0
    finally:
        plt.close(fig)


def test_a_failed_trial_is_marked_in_its_panel_title():
    from snan_hil.host.experiments.common import trial_outcome
    assert trial_outcome({"path": [0, 1, 2], "success": True}) == "2 steps"
    assert "FAILED" in trial_outcome({"path": [0] * 101, "success": False})


def test_fig7_learning_cycles_are_whole_numbers(monkeypatch):
    import matplotlib.pyplot as plt
    fig = _figure_of("fig7", 2, monkeypatch)
    try:
        for ax in fig.axes:
            assert _integer(ax.get_xticks()) and ax.get_xlabel() == "learning cycle"
    finally:
        plt.close(fig)


def test_learn_figure_has_whole_cycles_and_plain_step_labels(tmp_path, monkeypatch):
    # issue 38 item 13: learn.png ticked "6×10¹" and fractional cycles
    import matplotlib.pyplot as plt

    from snan_hil.tools import device_figures
    seen = []
    monkeypatch.setattr(device_figures, "_save",
                        lambda plt_, fig, path, fmt: seen.append(fig))
    curves = {arm: {"median": [62.0, 30.0, 17.0], "median_ci": [[50, 70], [25, 40], [15, 20]],
                    "success": [0.4, 0.7, 0.9], "success_ci": [[0.2, 0.6], [0.5, 0.9],
                                                               [0.7, 1.0]]}
              for arm in ("software", "chip")}
    ledger = [{"cycle": k, "set": 10 + k, "reset": 5} for k in range(3)]
    device_figures.plot_learning(curves, ledger, [3, 4, 5], tmp_path / "l.png", title="t")
    fig = seen[0]
    try:
        fig.canvas.draw()
        for ax in fig.axes[:3]:
            assert _integer(ax.get_xticks()), ax.get_xticks()
        labels = [t.get_text() for t in fig.axes[0].get_yticklabels(which="both")
                  if t.get_text()]
        assert labels and all("10^" not in t and "times" not in t and "×" not in t
                              for t in labels), labels
        assert {"20", "50"} <= set(labels)
    finally:
        plt.close(fig)


def test_fig10c_lines_of_equal_value_stay_distinguishable():
    import matplotlib.pyplot as plt
    res = _compare_results(100)
    for s in res["scenarios"].values():
        s["median_steps"] = 13.0
    fig = compare_figure(res)
    try:
        ax = fig.axes[0]
        ys = sorted(line.get_ydata()[0] for line in ax.get_lines()
                    if len(set(line.get_ydata())) == 1 and abs(line.get_ydata()[0] - 13) < 1)
        assert len(ys) == 4 and len(set(ys)) == 4 and ys[-1] - ys[0] < 1   # side by side
        texts = [t for t in _legend_texts(fig) if "all sets, 13" in t]
        assert len(texts) == 4 and all("(=" in t for t in texts)
    finally:
        plt.close(fig)


def test_a_bogus_mplbackend_in_the_shell_does_not_stop_a_figure(tmp_path):
    """Issue 27 item 11: MPLBACKEND=bogus made every figure a traceback (matplotlib refuses it
    on import). Figures are files: they are drawn with Agg whatever the shell names, and the
    variable is left as it was."""
    import os
    import subprocess
    import sys
    out = tmp_path / "p.png"
    code = ("import os, sys; from snan_hil.tools import cli; "
            "rc = cli.main(['sim', '--grid', '3', '--trials', '3', '--plot', sys.argv[1]]); "
            "assert os.environ['MPLBACKEND'] == 'bogus'; sys.exit(rc)")
    done = subprocess.run([sys.executable, "-c", code, str(out)], capture_output=True,
                          text=True, timeout=300,
                          env={**os.environ, "MPLBACKEND": "bogus"})
    assert done.returncode == 0, done.stderr[-2000:]
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_sim_animates_a_trial_with_steps_by_default(tmp_path, capsys):
    from PIL import Image

    from snan_hil.tools.commands.sim import MIN_ANIMATED_STEPS
    gif = tmp_path / "a.gif"
    assert cli.main(["sim", "--grid", "3", "--trials", "20", "--seed", "1", "--json",
                     "--animate", str(gif)]) == 0
    capsys.readouterr()
    with Image.open(gif) as im:
        assert im.n_frames >= MIN_ANIMATED_STEPS + 1


def test_retention_figure_shows_reads_band_and_integer_cycles(tmp_path, monkeypatch):
    from snan_hil.tools import bench_figures
    kept = {}
    monkeypatch.setattr(bench_figures, "_save",
                        lambda plt, fig, path, fmt: kept.setdefault("fig", fig) and path)
    rng = np.random.default_rng(0)
    targets = [0.1, 0.5, 0.9]
    w = np.array(targets) + 0.002 * rng.standard_normal((7, 3))     # 7 reads, noise 0.002
    bench_figures.plot_retention(w, targets, ["a", "b", "c"], tmp_path / "r.png", title="t")
    fig = kept["fig"]
    top, dev = fig.axes[:2]
    ticks = [t for t in dev.get_xticks() if dev.get_xlim()[0] <= t <= dev.get_xlim()[1]]
    assert ticks and all(float(t).is_integer() for t in ticks)        # read cycles
    # the read markers are drawn over the dashed programmed weight
    marks = [ln for ln in top.get_lines() if ln.get_marker() == "o"]
    dashed = [ln for ln in top.get_lines() if ln.get_linestyle() == "--"]
    assert len(marks) == 3 and min(m.get_zorder() for m in marks) > max(
        d.get_zorder() for d in dashed)
    # the deviation panel's range is of the order of the noise, so the ±1 sigma band shows
    lo, hi = dev.get_ylim()
    assert hi - lo < 0.05
    assert len(dev.collections) >= 3                                  # one band per cell
