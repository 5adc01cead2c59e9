"""Figures of the bench commands (needs matplotlib, the ``plots`` extra; its modules are imported
inside each figure function, after :func:`snan_hil.host.plots.pyplot` has checked the extra is
installed, and not at every start of the CLI).

Every figure names the board, port and date in its title (:mod:`snan_hil.tools.titles`), puts
every marker and line in its legend, and uses the paper's colours where the paper has the
figure (Fig. 10B: measured points blue, the reference orange). Written atomically with a PNG
text tag (:func:`snan_hil.files.outputs.png_metadata`) so a later run recognises its own file.

* :func:`plot_program_trace` — ``program-weights --trace`` (Fig. 10A, the box): conductance of
  sample cells against pulse number, the stage-1 window and the stage-2 target;
* :func:`plot_retention` — ``retention --png`` (Fig. 10A): weights held over the reads, the
  read-noise band;
* :func:`plot_mac` — ``mac`` (Fig. 10B): measured against reference with the identity line,
  and the error histogram;
* :func:`plot_cell_classes` — ``cells test --png``: the array coloured by class;
* :func:`plot_ticket` — ``pulse --png``: a pulse ticket's conductance trace and amplitudes;
* :func:`plot_cell_life` — ``history --cell R,C --png``: a cell's conductance and pulse count
  over its recorded life.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from snan_hil.files.atomicio import atomic_path
from snan_hil.files.outputs import png_metadata

__all__ = ["CRITERIA_PNG_FORMAT", "plot_criteria",
           "PROGRAM_TRACE_FORMAT", "RETENTION_PNG_FORMAT", "MAC_PNG_FORMAT", "CELLS_PNG_FORMAT",
           "TICKET_PNG_FORMAT", "CELL_LIFE_PNG_FORMAT", "plot_program_trace", "plot_retention",
           "plot_mac", "plot_cell_classes", "plot_ticket", "plot_cell_life", "pick_spread",
           "CLASS_COLORS"]

PROGRAM_TRACE_FORMAT = "snan-hil-program-trace/1"
RETENTION_PNG_FORMAT = "snan-hil-retention-figure/1"
MAC_PNG_FORMAT = "snan-hil-mac-figure/1"
CELLS_PNG_FORMAT = "snan-hil-cells-figure/1"
TICKET_PNG_FORMAT = "snan-hil-pulse-figure/1"
CELL_LIFE_PNG_FORMAT = "snan-hil-cell-life/1"

PAPER_BLUE = "#1f77b4"
PAPER_ORANGE = "#ff7f0e"
CLASS_COLORS = {"good": "#2ca02c", "stuck_high": "#d62728", "stuck_low": "#1f3b73",
                "noisy": "#ff7f0e", "unresponsive": "#9467bd", "untested": "#d9d9d9"}


def _pyplot() -> Any:
    from snan_hil.host.plots import pyplot      # on first use: a command's start stays light
    return pyplot("figures need matplotlib")


def _save(plt: Any, fig: Any, path: str | os.PathLike[str], fmt: str, dpi: int = 110) -> Path:
    out = Path(path)
    try:
        with atomic_path(out, suffix=".png") as tmp:
            fig.savefig(tmp, format="png", dpi=dpi, metadata=png_metadata(fmt))
    finally:
        plt.close(fig)
    return out


def conductance_axis(ax: Any, values_us: Any, label: str = "cell conductance (uS)") -> None:
    """Log scale when the values span more than a factor 5 (else linear, so the bars of a
    narrow trace do not start at an arbitrary baseline); plain numbers as tick labels."""
    from matplotlib.ticker import FuncFormatter, LogLocator
    v = np.asarray(values_us, dtype=float)
    v = v[np.isfinite(v) & (v > 0)]
    fmt = FuncFormatter(lambda x, _pos: f"{x:g}")
    if v.size and v.max() / v.min() > 5:
        ax.set_yscale("log")
        ax.yaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
        ax.yaxis.set_minor_formatter(FuncFormatter(lambda x, _pos: ""))
        ax.set_ylabel(f"{label}, log scale")
    else:
        ax.set_ylabel(label)
    ax.yaxis.set_major_formatter(fmt)


def pick_spread(values: Sequence[float], n: int) -> list[int]:
    """Indices of up to ``n`` entries of ``values`` spread evenly over their sorted range."""
    if not values or n < 1:
        return []
    order = sorted(range(len(values)), key=lambda i: values[i])
    if len(order) <= n:
        return order
    picks = [order[round(k * (len(order) - 1) / (n - 1))] for k in range(n)] if n > 1 \
        else [order[len(order) // 2]]
    return list(dict.fromkeys(picks))


# ------------------------------------------------------------------------- Fig. 10A (box)
def plot_program_trace(collector: Any, path: str | os.PathLike[str], *, tolerance: float,
                       title: str, n_cells: int = 6) -> Path:
    """Conductance (uS, log scale) against pulse number for up to ``n_cells`` programmed cells
    whose targets span the weight range; per cell its ±tolerance window (band) and target
    (dashed); stage-1 pulses as circles, stage-2 pulses as triangles."""
    plt = _pyplot()
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    traces = [t for t in collector.traces.values() if t.target_s and t.pulses]
    if not traces:
        traces = [t for t in collector.traces.values() if t.target_s]
    chosen = [traces[i] for i in pick_spread([t.target_s for t in traces], n_cells)]
    chosen.sort(key=lambda t: t.target_s)
    fig, ax = plt.subplots(figsize=(8.5, 4.6))
    cmap = plt.get_cmap("viridis")
    handles: list[Any] = []
    longest = 1
    for j, t in enumerate(chosen):
        color = cmap(0.1 + 0.8 * j / max(1, len(chosen) - 1))
        g = [t.initial_s] + [p.g_after_s for p in t.pulses]
        n = np.arange(len(g))
        longest = max(longest, len(g) - 1)
        tgt = t.target_s * 1e6
        ax.axhspan(tgt * (1 - tolerance), tgt * (1 + tolerance), color=color, alpha=0.12, lw=0)
        ax.axhline(tgt, color=color, ls="--", lw=0.9)
        ax.plot(n, np.array(g, dtype=float) * 1e6, "-", color=color, lw=1.0)
        ax.plot([0], [g[0] * 1e6], "s", color=color, ms=5)
        for stage, marker in (("1", "o"), ("2", "^")):
            idx = [k + 1 for k, p in enumerate(t.pulses) if p.stage == stage]
            if idx:
                ax.plot(idx, np.array([g[k] for k in idx]) * 1e6, marker, color=color, ms=4,
                        mec="black", mew=0.3)
        w = "" if t.weight is None else f", w = {t.weight:.2f}"
        handles.append(Line2D([], [], color=color, lw=1.5,
                              label=f"cell ({t.row},{t.col}){w}: {tgt:.0f} uS, {t.outcome}"))
    handles += [Line2D([], [], ls="", marker="s", color="gray", label="read before pulse 1"),
                Line2D([], [], ls="", marker="o", color="gray", mec="black", mew=0.3,
                       label="stage 1 (W&V into the window)"),
                Line2D([], [], ls="", marker="^", color="gray", mec="black", mew=0.3,
                       label="stage 2 (fine tuning to the target)"),
                Patch(color="gray", alpha=0.25, label=f"stage-1 window ±{tolerance:.0%}"),
                Line2D([], [], ls="--", color="gray", label="stage-2 target")]
    every = [v for t in chosen for v in [t.initial_s or np.nan] + [p.g_after_s for p in t.pulses]]
    conductance_axis(ax, np.array(every, dtype=float) * 1e6)
    ax.set_xlabel("pulse number (0 = before the first pulse)")
    ax.set_xlim(-0.5, longest + 0.5)
    from matplotlib.ticker import MaxNLocator
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    fig.suptitle(title, fontsize=9)
    ax.legend(handles=handles, fontsize=7, loc="center left", bbox_to_anchor=(1.01, 0.5),
              frameon=False)
    fig.tight_layout()
    return _save(plt, fig, path, PROGRAM_TRACE_FORMAT)


# ------------------------------------------------------------------------- Fig. 10A
def plot_retention(weights: np.ndarray, targets: Sequence[float | None], labels: Sequence[str],
                   path: str | os.PathLike[str], *, title: str, n_cells: int = 8) -> Path:
    """Weights (0..1) read ``weights[n_reads, n_cells]`` times against read number, for up to
    ``n_cells`` cells spanning the range. Top: each cell's reads (markers drawn over its
    programmed weight, dashed) on the full 0..1 scale. Bottom: each read minus the cell's
    programmed weight (its mean when none is recorded) on a scale where the read noise shows,
    with each cell's ±1 sigma band around its mean. Read cycles have integer ticks."""
    plt = _pyplot()
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch
    from matplotlib.ticker import MaxNLocator
    w = np.asarray(weights, dtype=float)
    means = list(w.mean(axis=0))
    idx = pick_spread(means, n_cells)
    idx.sort(key=lambda i: means[i])
    n = w.shape[0]
    step = max(1, n // 2000)               # at most ~2000 points a line
    x = np.arange(1, n + 1)[::step]
    fig, (ax, axd) = plt.subplots(2, 1, figsize=(8.5, 6.4), sharex=True,
                                  gridspec_kw={"height_ratios": [3, 2]})
    cmap = plt.get_cmap("viridis")
    handles: list[Any] = []
    ms = 3.0 if len(x) <= 200 else 1.8
    for j, i in enumerate(idx):
        color = cmap(0.05 + 0.8 * j / max(1, len(idx) - 1))
        m, sd = float(w[:, i].mean()), float(w[:, i].std(ddof=1)) if n > 1 else 0.0
        tgt = targets[i]
        ref = m if tgt is None else float(tgt)
        if tgt is not None:
            ax.axhline(tgt, color=color, ls="--", lw=0.7, zorder=1)
        ax.plot(x, w[::step, i], "o", color=color, ms=ms, mew=0, alpha=0.9, zorder=3)
        dev = w[::step, i] - ref
        axd.fill_between([1, max(2, n)], m - ref - sd, m - ref + sd, color=color, alpha=0.25,
                         lw=0, zorder=1)
        axd.plot(x, dev, "o", color=color, ms=ms * 0.8, mew=0, alpha=0.8, zorder=3)
        handles.append(Line2D([], [], ls="", marker="o", color=color,
                              label=f"{labels[i]}: mean {m:.3f}, noise ±{sd:.4f}"))
    handles += [Patch(color="gray", alpha=0.35, label="±1 sigma read noise (single read)"),
                Line2D([], [], ls="--", color="gray", label="programmed weight")]
    axd.axhline(0.0, color="gray", ls="--", lw=0.8, zorder=2)
    ax.set_xlim(0.5, max(2, n) + 0.5)
    ax.set_ylim(-0.05, 1.05)
    ax.set_ylabel("weight (0..1, from the read\nconductance)")
    axd.set_ylabel("read - programmed weight")
    axd.set_xlabel(f"read cycle (of {n})")
    axd.xaxis.set_major_locator(MaxNLocator(integer=True))
    for a in (ax, axd):
        a.grid(True, lw=0.3, alpha=0.5)
    fig.suptitle(title, fontsize=9)
    ax.legend(handles=handles, fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0),
              frameon=False)
    fig.tight_layout()
    return _save(plt, fig, path, RETENTION_PNG_FORMAT)


# ------------------------------------------------------------------------- Fig. 10B
def plot_mac(result: Any, path: str | os.PathLike[str], *, title: str) -> Path:
    """Left: measured column current against the numpy reference (uA), identity line; right:
    histogram of the error in % of full scale with its RMS and max."""
    plt = _pyplot()
    from matplotlib.ticker import MaxNLocator
    a = result.arrays()
    err = result.errors_pct("reference")
    s = result.summary()
    fig, (ax, axh) = plt.subplots(1, 2, figsize=(10, 4.4), gridspec_kw={"width_ratios": [1.2, 1]})
    ref, meas = a["reference"] * 1e6, a["measured"] * 1e6
    ax.plot(ref, meas, "o", color=PAPER_BLUE, ms=3, alpha=0.7,
            label=f"measured ({len(ref)} column multiplies)")
    top = float(max(ref.max(initial=0), meas.max(initial=0))) * 1.05 or 1.0
    ax.plot([0, top], [0, top], "-", color=PAPER_ORANGE, lw=1.5, label="reference (numpy) = "
            "identity")
    ax.set_xlim(0, top)
    ax.set_ylim(0, top)
    ax.set_aspect("equal")
    ax.set_xlabel("reference sum V_i G_i (uA, target conductances)")
    ax.set_ylabel("measured column current (uA)")
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title(result.method, fontsize=8)
    lim = max(float(np.max(np.abs(err), initial=0.0)) * 1.1, 0.05)
    bins = np.linspace(-lim, lim, 31)
    axh.hist(err, bins=bins, color=PAPER_BLUE, edgecolor="black", lw=0.3,
             label="multiplies")
    axh.axvline(0, color=PAPER_ORANGE, lw=1.5, label="no error")
    rms, mx, mean = s["rms_error_pct_fs"], s["max_error_pct_fs"], s["mean_error_pct_fs"]
    axh.axvline(mean, color="black", ls=":", lw=1, label=f"mean {mean:+.3f} %")
    axh.set_xlim(-lim, lim)
    axh.yaxis.set_major_locator(MaxNLocator(integer=True))
    axh.set_xlabel(f"error (% of full scale {result.full_scale_a * 1e3:.3f} mA)")
    axh.set_ylabel("column multiplies")
    axh.set_title(f"RMS {rms:.3f} %, max {mx:.3f} % of full scale", fontsize=8)
    axh.legend(fontsize=7, loc="upper right")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return _save(plt, fig, path, MAC_PNG_FORMAT)


# ------------------------------------------------------------------------- cell classes
def plot_cell_classes(classes: dict[tuple[int, int], str], shape: tuple[int, int],
                      path: str | os.PathLike[str], *, title: str) -> Path:
    """The array (rows = bit lines down, columns = word lines across), each cell coloured by
    its class (grey: not tested), counts in the legend."""
    plt = _pyplot()
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch
    names = list(CLASS_COLORS)
    grid = np.full(shape, names.index("untested"))
    for (r, c), cls in classes.items():
        grid[r, c] = names.index(cls) if cls in names else names.index("untested")
    fig, ax = plt.subplots(figsize=(4.6, 8.2))
    ax.imshow(grid, cmap=ListedColormap([CLASS_COLORS[n] for n in names]), vmin=-0.5,
              vmax=len(names) - 0.5, aspect="auto", interpolation="nearest")
    ax.set_xticks(range(shape[1]))
    ax.set_yticks(range(0, shape[0], 2))
    ax.set_xticks(np.arange(-0.5, shape[1]), minor=True)
    ax.set_yticks(np.arange(-0.5, shape[0]), minor=True)
    ax.grid(which="minor", color="white", lw=0.6)
    ax.tick_params(which="minor", length=0)
    ax.set_xlabel("word line (column)")
    ax.set_ylabel("bit line (row)")
    counts = {n: sum(1 for v in classes.values() if v == n) for n in names[:-1]}
    counts["untested"] = shape[0] * shape[1] - len(classes)
    ax.legend(handles=[Patch(color=CLASS_COLORS[n], label=f"{n.replace('_', ' ')}: {k}")
                       for n, k in counts.items()], fontsize=7, loc="upper center",
              bbox_to_anchor=(0.5, -0.06), ncol=2, frameon=False)
    ax.set_title(title, fontsize=8, wrap=True)
    fig.tight_layout()
    return _save(plt, fig, path, CELLS_PNG_FORMAT)


CRITERIA_PNG_FORMAT = "snan-hil-criteria-figure/1"


def plot_criteria(results: Any, shape: tuple[int, int], path: str | os.PathLike[str], *,
                  title: str, criteria: Any) -> Path:
    """Heat map of the user's screening: each tested cell coloured by the R_max/R_min of its
    switching window (full ramps; log colour scale), failing cells crossed, untested grey; the
    criteria (one a line) and the per-cent good in a caption below, inside the figure."""
    plt = _pyplot()
    from matplotlib.colors import LogNorm
    ratio = np.full(shape, np.nan)
    bad_r, bad_c = [], []
    good = 0
    for res in results:
        if res.ratio is not None and np.isfinite(res.ratio):
            ratio[res.row, res.col] = res.ratio
        if res.verdict == "bad":
            bad_r.append(res.row)
            bad_c.append(res.col)
        elif res.verdict == "good":
            good += 1
    fig, ax = plt.subplots(figsize=(4.6, 8.2))
    ax.set_facecolor("#d0d0d0")
    finite = ratio[np.isfinite(ratio)]
    v0, v1 = (max(float(finite.min()), 1.0001), max(float(finite.max()), 1.001)) \
        if finite.size else (1.0, 10.0)
    norm = LogNorm(vmin=v0, vmax=v1) if finite.size else None
    im = ax.imshow(np.ma.masked_invalid(ratio), cmap="viridis", norm=norm, aspect="auto",
                   interpolation="nearest")
    ax.scatter(bad_c, bad_r, marker="x", color="red", s=28, lw=1.4,
               label=f"bad: {len(bad_r)}")
    ax.scatter([], [], marker="s", color="#d0d0d0", label="no window (not responsive) / "
                                                           "untested")
    ax.set_xticks(range(shape[1]))
    ax.set_yticks(range(0, shape[0], 2))
    ax.set_xlabel("word line (column)")
    ax.set_ylabel("bit line (row)")
    crit = []
    if criteria.rmin_below_ohm is not None:
        crit.append(f"R_min < {criteria.rmin_below_ohm:g} Ohm")
    if criteria.rmax_above_ohm is not None:
        crit.append(f"R_max > {criteria.rmax_above_ohm:g} Ohm")
    if criteria.ratio_above is not None:
        crit.append(f"R_max/R_min > {criteria.ratio_above:g}")
    judged = good + len(bad_r)
    pct = 100.0 * good / judged if judged else 0.0
    # the caption, one criterion a line, in a band of its own below the axes (one line of
    # three criteria ran past the figure's edge)
    caption = "\n".join([f"good {good} of {judged} ({pct:.0f} %), pass when:", *crit])
    legend = fig.legend(*ax.get_legend_handles_labels(), fontsize=7, loc="lower center",
                        bbox_to_anchor=(0.5, 0.01), ncol=2, frameon=False, title=caption,
                        title_fontsize=7)
    legend.get_title().set_multialignment("center")
    if norm is not None:
        bar = fig.colorbar(im, ax=ax, label="R_max / R_min of the switching window (full "
                                            "SET and RESET ramps, log)")
        ratio_bar_ticks(bar.ax.yaxis, v0, v1)
    ax.set_title(title, fontsize=8, wrap=True)
    fig.canvas.draw()
    band = legend.get_window_extent().height / fig.bbox.height
    fig.tight_layout(rect=(0.0, band + 0.02, 1.0, 1.0))
    return _save(plt, fig, path, CRITERIA_PNG_FORMAT)


def ratio_bar_ticks(axis: Any, vmin: float, vmax: float) -> None:
    """Ticks of a log colour bar from ``vmin`` to ``vmax`` (the R_max/R_min of a screening:
    often 1.1..1.5) labelled once each: less than a decade, up to 6 round steps
    (``MaxNLocator``: 1.1, 1.2, ...); wider, 1-2-5 per decade (``LogLocator``); no minor
    labels. (Two-digit labels of the log locator's minor ticks repeated: 1.2, 1.2, 1.2.)"""
    from matplotlib.ticker import LogLocator, MaxNLocator, NullFormatter, StrMethodFormatter
    if vmax / vmin < 10:
        axis.set_major_locator(MaxNLocator(nbins=6, steps=[1, 2, 2.5, 5, 10]))
    else:
        axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(StrMethodFormatter("{x:g}"))
    axis.set_minor_formatter(NullFormatter())


# ------------------------------------------------------------------------- pulse tickets
def plot_ticket(result: Any, path: str | os.PathLike[str], *, title: str) -> Path:
    """A ticket's conductance after each pulse (log scale) and its amplitudes (right axis),
    with the stop condition drawn."""
    plt = _pyplot()
    from matplotlib.ticker import MaxNLocator
    t = result.ticket
    g = [result.initial_s] + [s.g_after_s for s in result.steps]
    n = np.arange(len(g))
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    ax.plot(n, np.array(g) * 1e6, "o-", color=PAPER_BLUE, ms=3, lw=1,
            label="conductance read after each pulse (0: before)")
    if t.until_g_s is not None:
        ax.axhline(t.until_g_s * 1e6, color="black", ls="--", lw=1,
                   label=f"stop condition {t.condition()}")
    if t.window is not None:
        gw, p = t.window
        ax.axhspan(gw * (1 - p) * 1e6, gw * (1 + p) * 1e6, color="green", alpha=0.15,
                   label=f"stop window {gw * 1e6:g} uS ±{p:.0%}")
    shown = list(g) + [x for x in (t.until_g_s,) if x is not None]
    if t.window is not None:
        shown += [t.window[0] * (1 - t.window[1]), t.window[0] * (1 + t.window[1])]
    conductance_axis(ax, np.array(shown, dtype=float) * 1e6)
    ax.set_xlabel("pulse number")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    handles, labels = ax.get_legend_handles_labels()
    if result.steps:
        ax2 = ax.twinx()
        ax2.step([s.n for s in result.steps], [s.amplitude_v for s in result.steps],
                 where="mid", color=PAPER_ORANGE, lw=1,
                 label=f"{t.polarity.name} pulse amplitude ({t.width_us} us)")
        ax2.set_ylabel("pulse amplitude (V)")
        ax2.set_ylim(0, max(s.amplitude_v for s in result.steps) * 1.15)
        h2, l2 = ax2.get_legend_handles_labels()
        handles, labels = handles + h2, labels + l2
    ax.legend(handles, labels, fontsize=7, loc="best")
    ax.set_title(f"{title}\n{result.stopped}", fontsize=8)
    fig.tight_layout()
    return _save(plt, fig, path, TICKET_PNG_FORMAT)


# ------------------------------------------------------------------------- a cell's life
def plot_cell_life(events: Sequence[Any], path: str | os.PathLike[str], *, title: str) -> Path:
    """Top: conductance after every recorded event (pulses: dots coloured by polarity; run
    results: diamonds) against the event's number; bottom: the running pulse count. Vertical
    lines separate runs (labelled with their kind)."""
    plt = _pyplot()
    from matplotlib.ticker import MaxNLocator
    fig, (ax, axc) = plt.subplots(2, 1, figsize=(8, 5.2), sharex=True,
                                  gridspec_kw={"height_ratios": [2, 1]})
    x = np.arange(1, len(events) + 1)
    g = np.array([np.nan if e.g_s is None else e.g_s * 1e6 for e in events], dtype=float)
    styles = {"SET": ("^", "#d62728", "SET pulse"), "RESET": ("v", "#1f77b4", "RESET pulse")}
    for pol, (marker, color, label) in styles.items():
        sel = np.array([e.event == "pulse" and e.polarity == pol for e in events], dtype=bool)
        if sel.any():
            ax.plot(x[sel], g[sel], marker, color=color, ms=3, ls="", label=label)
    res = np.array([e.event == "result" for e in events], dtype=bool)
    if res.any():
        ax.plot(x[res], g[res], "D", color="black", ms=4, ls="", label="run result / read")
    conductance_axis(ax, g, "conductance (uS)")
    axc.step(x, [e.pulses_total for e in events], where="post", color="black", lw=1,
             label="pulses applied so far")
    axc.set_ylim(0, max(1, max((e.pulses_total for e in events), default=0)) * 1.05)
    axc.yaxis.set_major_locator(MaxNLocator(integer=True))
    axc.xaxis.set_major_locator(MaxNLocator(integer=True))
    axc.set_ylabel("pulses")
    axc.set_xlabel("recorded event")
    # run boundaries: a dotted line each; labels above the plot, slanted, leaving out a
    # label that would overlap the previous one (its line stays)
    last, labelled, skipped = None, float("-inf"), 0
    gap = max(1.0, len(events) / 22)
    for xi, e in zip(x, events):
        if e.run_id != last:
            for a in (ax, axc):
                a.axvline(xi - 0.5, color="gray", lw=0.5, ls=":")
            if xi - labelled >= gap:
                ax.annotate(f"run {e.run_id} {e.kind}", (xi - 0.5, 1.01),
                            xycoords=("data", "axes fraction"), fontsize=6, rotation=35,
                            va="bottom", ha="left", color="dimgray", annotation_clip=False)
                labelled = float(xi)
            else:
                skipped += 1
            last = e.run_id
    if skipped:
        ax.text(1.0, -0.02, f"{skipped} run label(s) left out (too close)", fontsize=6,
                color="dimgray", transform=ax.transAxes, ha="right", va="top")
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    axc.grid(True, lw=0.3, alpha=0.5)
    ax.legend(fontsize=7, loc="best")
    axc.legend(fontsize=7, loc="upper left")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    return _save(plt, fig, path, CELL_LIFE_PNG_FORMAT)
