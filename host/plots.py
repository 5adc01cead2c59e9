"""Figures of a simulation batch (the paper's Fig. 3/4 style): histogram of path lengths
and a few trajectories. Needs matplotlib (the ``plots`` extra)."""

from __future__ import annotations

import pathlib

import numpy as np

from snan_hil.atomicio import atomic_path
from snan_hil.errors import UserError
from snan_hil.outputs import png_metadata
from snan_hil.host.simulate import SimResult


def pyplot(need: str = "plotting needs matplotlib"):
    """``matplotlib.pyplot`` on the non-interactive Agg back-end; without matplotlib a
    :class:`UserError` "<need>: pip install 'snan-hil[plots]'"."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:  # pragma: no cover - depends on the installation
        raise UserError(f"{need}: pip install 'snan-hil[plots]'") from None
    return plt


SIM_PLOT_FORMAT = "snan-hil-sim-plot/1"
"""Marker of a ``sim --plot`` PNG (text chunk, :func:`snan_hil.outputs.png_metadata`)."""


def plot_sim(result: SimResult, out: str | pathlib.Path, n_traj: int = 4) -> pathlib.Path:
    """Write a PNG with the path-length histogram and ``n_traj`` trajectories."""
    out = pathlib.Path(out)
    if out.parent and not out.parent.exists():
        raise UserError(f"cannot write plot: folder {out.parent} does not exist")
    plt = pyplot()
    cfg = result.config
    rows, cols = cfg.grid.rows, cfg.grid.cols
    n_traj = max(0, min(n_traj, result.trials))
    fig = plt.figure(figsize=(4 + 3 * max(n_traj, 1), 3.6))
    grid = fig.add_gridspec(1, 1 + max(n_traj, 1), width_ratios=[1.6] + [1] * max(n_traj, 1))
    ax = fig.add_subplot(grid[0, 0])
    ok = result.steps[result.success]
    limit = cfg.grid.max_steps
    bins = np.arange(0, limit + 2) - 0.5 if limit <= 100 else np.linspace(0, limit, 51)
    ax.hist(ok, bins=bins, color="tab:blue", alpha=0.8)
    s = result.summary()
    med = s["median_steps"]
    ax.set_title(f"{s['grid']} {'astro' if s['astro'] else 'no astro'}: "
                 f"{100 * s['success_rate']:.1f}% ok, median {med if med is not None else '-'}",
                 fontsize=9)
    ax.set_xlabel("path length of successful trials (steps)")
    ax.set_ylabel("trials")
    for k in range(n_traj):
        axt = fig.add_subplot(grid[0, 1 + k])
        path = result.path(k)
        r, c = np.divmod(path, cols)
        rng = np.random.default_rng(k)
        jit = 0.12 * (rng.random((2, path.size)) - 0.5)
        axt.plot(c + jit[0], r + jit[1], "-", color="tab:gray", lw=0.8, alpha=0.7)
        axt.plot(c[0], r[0], "s", color="tab:green", ms=9, label="start")
        g = int(result.goals[k])
        axt.plot(g % cols, g // cols, "*", color="gold", mec="k", ms=13, label="goal")
        axt.set_xlim(-0.5, cols - 0.5)
        axt.set_ylim(rows - 0.5, -0.5)
        axt.set_xticks(range(cols))
        axt.set_yticks(range(rows))
        axt.tick_params(labelsize=6)
        axt.grid(True, lw=0.3)
        axt.set_aspect("equal")
        status = "ok" if result.success[k] else "failed"
        axt.set_title(f"trial {k}: {result.steps[k]} steps ({status})", fontsize=8)
    fig.tight_layout()
    fmt = pathlib.Path(out).suffix.lstrip(".").lower() or "png"
    with atomic_path(out) as tmp:
        fig.savefig(tmp, dpi=110, format=fmt,
                    metadata=png_metadata(SIM_PLOT_FORMAT) if fmt == "png" else None)
    plt.close(fig)
    return out
