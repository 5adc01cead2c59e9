"""Figures of a simulation batch (the paper's Fig. 3/4 style): histogram of path lengths
and a few trajectories. Needs matplotlib (the ``plots`` extra)."""

from __future__ import annotations

import math
import os
import pathlib
from typing import Any

import numpy as np

from snan_hil.files.atomicio import atomic_path
from snan_hil.common.errors import UserError
from snan_hil.files.outputs import png_metadata
from snan_hil.host.simulate import SimResult, paper_result


def pyplot(need: str = "plotting needs matplotlib") -> Any:
    """``matplotlib.pyplot`` on the non-interactive Agg back-end — the one place the project
    imports it; without matplotlib a :class:`UserError` "<need>: pip install
    'snan-hil[plots]'". Every figure is a file, so the shell's ``MPLBACKEND`` (which
    matplotlib reads on import, and refuses with a traceback when it names no back-end) is
    set aside while matplotlib is imported, then put back."""
    saved = os.environ.pop("MPLBACKEND", None)
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:  # pragma: no cover - depends on the installation
        raise UserError(f"{need}: pip install 'snan-hil[plots]'") from None
    finally:
        if saved is not None:
            os.environ["MPLBACKEND"] = saved
    return plt


SIM_PLOT_FORMAT = "snan-hil-sim-plot/1"
"""Marker of a ``sim --plot`` PNG (text chunk, :func:`snan_hil.files.outputs.png_metadata`)."""


def plot_sim(result: SimResult, out: str | pathlib.Path, n_traj: int = 4) -> pathlib.Path:
    """Write a PNG with the path-length histogram and ``n_traj`` trajectories
    (:func:`sim_figure`)."""
    out = pathlib.Path(out)
    if out.parent and not out.parent.exists():
        raise UserError(f"cannot write plot: folder {out.parent} does not exist")
    plt = pyplot()
    fig = sim_figure(result, n_traj)
    fmt = pathlib.Path(out).suffix.lstrip(".").lower() or "png"
    try:
        with atomic_path(out) as tmp:
            fig.savefig(tmp, dpi=110, format=fmt,
                        metadata=png_metadata(SIM_PLOT_FORMAT) if fmt == "png" else None)
    finally:
        plt.close(fig)
    return out


def sim_figure(result: SimResult, n_traj: int = 4) -> Any:
    """The histogram of successful path lengths (integer counts, x range to the longest path
    or the paper's median, whichever is further) with our median and the paper's median and
    success rate for this grid (3x3 and 10x10, paper sections 3.1-3.2), and ``n_traj``
    trajectories with start and goal labelled. The caller closes the figure."""
    plt = pyplot()
    from matplotlib.lines import Line2D    # matplotlib (the plots extra): when drawing
    from matplotlib.ticker import MaxNLocator
    cfg = result.config
    rows, cols = cfg.grid.rows, cfg.grid.cols
    n_traj = max(0, min(n_traj, result.trials))
    fig = plt.figure(figsize=(4.4 + 3 * max(n_traj, 1), 3.9))
    grid = fig.add_gridspec(1, 1 + max(n_traj, 1), width_ratios=[1.7] + [1] * max(n_traj, 1))
    ax = fig.add_subplot(grid[0, 0])
    ok = result.steps[result.success]
    limit = cfg.grid.max_steps
    s = result.summary()
    med = s["median_steps"]
    paper = paper_result(cfg)
    top = int(ok.max()) if ok.size else 1
    if paper is not None:
        top = max(top, int(math.ceil(paper[1])))
    top = min(limit, top + max(1, top // 20))
    if top <= 60:
        bins = np.arange(0, top + 2) - 0.5            # one bar per step count
    else:
        width = int(math.ceil((top + 1) / 50))
        bins = np.arange(0, top + width + 1, width) - 0.5
    ax.hist(ok, bins=bins, color="tab:blue", alpha=0.8,
            label=f"successful trials ({s['successes']} of {s['trials']})")
    if med is not None:
        ax.axvline(med, color="tab:blue", lw=1.6, ls="--", label=f"median, ours: {med:g}")
    if paper is not None:
        ax.axvline(paper[1], color="black", lw=1.6, ls=":",
                   label=f"median, paper: {paper[1]:g}")
    # room right of the last bar and of both median lines, so no line sits on the border
    right = max([top] + ([med] if med is not None else []) + ([paper[1]] if paper else []))
    ax.set_xlim(-0.5, right + max(1.5, 0.06 * right))
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    astro = "with" if s["astro"] else "without"
    ours = f"success {100 * s['success_rate']:.1f} %"
    theirs = (f" (paper {100 * paper[0]:.1f} %)" if paper is not None
              else " (no paper value for this grid)")
    ax.set_title(f"{s['grid']} {astro} astrocytes, step limit {limit}:\n{ours}{theirs}",
                 fontsize=9)
    ax.set_xlabel("path length of successful trials (steps)")
    ax.set_ylabel("trials")
    ax.legend(fontsize=7, loc="upper right")
    for k in range(n_traj):
        axt = fig.add_subplot(grid[0, 1 + k])
        path = result.path(k)
        r, c = np.divmod(path, cols)
        rng = np.random.default_rng(k)
        jit = 0.12 * (rng.random((2, path.size)) - 0.5)
        axt.plot(c + jit[0], r + jit[1], "-", color="tab:gray", lw=0.8, alpha=0.7)
        axt.plot(c[0], r[0], "s", color="tab:green", ms=9)
        axt.annotate("start", (c[0], r[0]), textcoords="offset points", xytext=(0, 7),
                     ha="center", fontsize=7, color="tab:green", fontweight="bold")
        g = int(result.goals[k])
        axt.plot(g % cols, g // cols, "*", color="gold", mec="k", ms=13)
        axt.annotate("goal", (g % cols, g // cols), textcoords="offset points",
                     xytext=(0, -12), ha="center", fontsize=7, fontweight="bold")
        axt.set_xlim(-0.5, cols - 0.5)
        axt.set_ylim(rows - 0.5, -0.5)
        axt.set_xticks(range(cols))
        axt.set_yticks(range(rows))
        axt.tick_params(labelsize=6)
        axt.grid(True, lw=0.3)
        axt.set_aspect("equal")
        status = "reached the goal" if result.success[k] else "failed"
        axt.set_title(f"trial {k}: {result.steps[k]} steps ({status})", fontsize=8)
    if n_traj:
        fig.legend(handles=[
            Line2D([], [], ls="", marker="s", color="tab:green", ms=7, label="start cell"),
            Line2D([], [], ls="", marker="*", color="gold", mec="k", ms=10, label="goal cell"),
            Line2D([], [], color="tab:gray", lw=0.8,
                   label="path (jittered so repeated moves show)")],
            fontsize=7, loc="lower center", bbox_to_anchor=(0.62, 0.0), ncol=3, frameon=False)
        fig.tight_layout(rect=(0, 0.07, 1, 1))
    else:
        fig.tight_layout()
    return fig
