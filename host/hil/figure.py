"""The comparison figure in the style of the paper's Fig. 10C: per weight set four bars (median
path length of the launches in each scenario, launches as dots, failed launches as crosses),
per scenario its overall median as a horizontal line (dashed: without astrocytes, dotted:
with; scenarios with the same median side by side, named in the legend), and the paper's
medians (14 steps without, 7 with astrocytes) as grey lines; every line and marker is in the
legend. Needs matplotlib."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from snan_hil.files.atomicio import atomic_path
from snan_hil.files.outputs import png_metadata
from snan_hil.host.hil.config import PAPER_MEDIANS, SCENARIO_LABELS, SCENARIOS
from snan_hil.host.plots import pyplot

COLORS = {"sw_noastro": "#9ecae1", "sw_astro": "#3182bd",
          "hw_noastro": "#fdae6b", "hw_astro": "#e6550d"}


LOG_SCALE_ABOVE = 200
"""Step limits above this get a log axis (bars then start at 1 step, said in the label);
at or below it the axis is linear from 0, so bars start at zero."""

EQUAL_LINE_OFFSET = 0.25
"""Steps between the overall-median lines of scenarios with the same median (linear axis;
2 % of the value on a log axis): equal lines side by side instead of on top of each other."""

FIGURE_FORMAT = "snan-hil-compare-figure/1"
"""Marker of ``fig10c.png`` (PNG text chunk, :func:`snan_hil.files.outputs.png_metadata`)."""


def plot_compare(results: dict[str, Any], out: str | os.PathLike) -> Path:
    """Write the figure (PNG) atomically; ``results`` is :func:`run_compare`'s dict."""
    plt = pyplot("the figure needs matplotlib")
    out = Path(out)
    fig = compare_figure(results)
    try:
        with atomic_path(out, suffix=".png") as tmp:
            fig.savefig(tmp, format="png", metadata=png_metadata(FIGURE_FORMAT))
    finally:
        plt.close(fig)
    return out


def compare_figure(results: dict[str, Any]) -> Any:
    """The matplotlib figure of :func:`plot_compare` (the caller closes it)."""
    plt = pyplot("the figure needs matplotlib")
    sets = results["sets"]
    scen = [s for s in SCENARIOS if s in results["scenarios"]]
    per = {(r["scenario"], r["set"]): r for r in results["per_set"]}
    from matplotlib.lines import Line2D    # matplotlib (the plots extra): when drawing
    fig, ax = plt.subplots(figsize=(max(7.5, 1.1 * len(sets) + 2), 6.2), dpi=120)
    width = 0.8 / max(1, len(scen))
    x = np.arange(len(sets))
    handles: list[Any] = []
    for j, s in enumerate(scen):
        xs = x - 0.4 + width * (j + 0.5)
        med = [per[(s, k)]["median_steps"] if per[(s, k)]["median_steps"] is not None
               else np.nan for k in sets]
        handles.append(ax.bar(xs, med, width * 0.92, color=COLORS[s],
                              label=f"{SCENARIO_LABELS[s]}: median of a set",
                              edgecolor="black", linewidth=0.4))
        lo, hi = _interval_bars(med, [per[(s, k)].get("median_steps_ci") for k in sets])
        ax.errorbar(xs, med, yerr=[lo, hi], fmt="none", ecolor="black", elinewidth=0.7,
                    capsize=2, zorder=4)
        for xi, k in zip(xs, sets):
            r = per[(s, k)]
            ok = [p for p, good in zip(r["path_lengths"], r["success"]) if good]
            bad = [p for p, good in zip(r["path_lengths"], r["success"]) if not good]
            ax.scatter(np.full(len(ok), xi), ok, s=6, color="black", zorder=3, linewidths=0)
            if bad:
                ax.scatter(np.full(len(bad), xi), bad, s=14, marker="x", color="red", zorder=3,
                           linewidths=0.8)
    # each scenario's overall median as a line; lines of equal value are drawn side by side
    # (offset by a fraction of a step, in their order) so that none hides another
    overall = {s: results["scenarios"][s]["median_steps"] for s in scen}
    same: dict[float, list[str]] = {}
    for s in scen:
        if overall[s] is not None:
            same.setdefault(float(overall[s]), []).append(s)
    lim0 = results.get("step_limit") or 100
    step = EQUAL_LINE_OFFSET * (1.0 if lim0 <= LOG_SCALE_ABOVE else 0.0)
    for value, group in same.items():
        for m, s in enumerate(group):
            y = value + step * (m - (len(group) - 1) / 2) if step else \
                value * (1.0 + 0.02 * (m - (len(group) - 1) / 2))
            style = ":" if s.endswith("_astro") else "--"
            ax.axhline(y, color=COLORS[s], linewidth=1.8, linestyle=style)
            ci = results["scenarios"][s].get("median_steps_ci")
            band = ""
            if ci and None not in ci:
                ax.axhspan(float(ci[0]), float(ci[1]), color=COLORS[s], alpha=0.15, lw=0,
                           zorder=0)
                band = f" [{ci[0]:g}, {ci[1]:g}]"
            shared = f" (= {', '.join(SCENARIO_LABELS[o] for o in group if o != s)})" \
                if len(group) > 1 else ""
            handles.append(Line2D([], [], color=COLORS[s], lw=1.8, ls=style,
                                  label=f"{SCENARIO_LABELS[s]}: all sets, {value:g}{band}"
                                        f"{shared}"))
    for astro_on, value in PAPER_MEDIANS.items():
        dashes: Any = (0, (6, 2, 1, 2)) if not astro_on else (0, (1, 1))
        ax.axhline(value, color="black", linewidth=2.2, linestyle=dashes, alpha=0.55, zorder=1)
        handles.append(Line2D([], [], color="black", lw=2.2, ls=dashes, alpha=0.55,
                              label=f"paper: {value:g} steps {'with' if astro_on else 'without'}"
                                    " astrocytes"))
    from matplotlib.patches import Patch
    if any(results["scenarios"][s].get("median_steps_ci") for s in scen):
        handles.append(Patch(color="grey", alpha=0.3, label="band, [a, b]: 95 % interval of "
                                                             "a scenario's overall median"))
    if any(r.get("median_steps_ci") for r in results["per_set"]):
        handles.append(Line2D([], [], color="black", lw=0.7, marker="_", ms=6,
                              label="error bar: 95 % interval of a set's median"))
    handles += [Line2D([], [], ls="", marker="o", ms=3, color="black",
                       label="one launch (reached the goal)"),
                Line2D([], [], ls="", marker="x", ms=5, color="red",
                       label="one launch (failed at the step limit)")]
    ax.set_xticks(x)
    ax.set_xticklabels([str(k) for k in sets])
    ax.set_xlabel("weight set")
    lim = results.get("step_limit")
    if lim and lim > LOG_SCALE_ABOVE:
        ax.set_yscale("log")
        ax.set_ylabel("path length (steps, log scale; bars from 1)")
        ax.set_ylim(bottom=1, top=lim * 1.4)
    else:
        ax.set_ylabel("path length (steps)")
        ax.set_ylim(0, (lim or ax.get_ylim()[1]) * 1.05)
    ax.set_title(f"{results['grid'][0]}x{results['grid'][1]} field, cell {results['start']} -> "
                 f"{results['goal']}: median of {results['launches']} launches per bar "
                 f"(step limit {lim})\n{_where_when(results)}", fontsize=9)
    # the legend in its own band below the axes, inside the figure with a margin all round
    fig.legend(handles=handles, fontsize=7, ncol=2, loc="lower center",
               bbox_to_anchor=(0.5, 0.015), frameon=False)
    fig.tight_layout(rect=(0.02, 0.21, 0.98, 1.0))
    return fig


def _interval_bars(medians: list[float], intervals: list[Any]) -> tuple[list[float],
                                                                         list[float]]:
    """Lower and upper error-bar lengths of the medians from their 95 % intervals ``[lo,
    hi]`` (0 where a set has none)."""
    lo, hi = [], []
    for m, ci in zip(medians, intervals):
        ok = ci is not None and None not in ci and np.isfinite(m)
        lo.append(max(0.0, m - float(ci[0])) if ok else 0.0)
        hi.append(max(0.0, float(ci[1]) - m) if ok else 0.0)
    return lo, hi


def _where_when(results: dict[str, Any]) -> str:
    """``board <id>, port <port>, <YYYY-MM-DD HH:MM> UTC`` of a comparison (software only:
    no board; the date when the results were made)."""
    board = (results.get("board") or {}).get("board_id")
    parts = [f"board {board}" if board else "software only (no board)"]
    if board and results.get("port"):
        parts.append(f"port {results['port']}")
    created = str(results.get("created") or "")
    if created:
        parts.append(created[:16].replace("T", " ") + " UTC")
    return ", ".join(parts)
