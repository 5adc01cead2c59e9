"""The comparison figure in the style of the paper's Fig. 10C: per weight set four bars (median
path length of the launches in each scenario, launches as dots), and per scenario its overall
median as a horizontal line (dashed: without astrocytes, dotted: with). Needs matplotlib."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from snan_hil.atomicio import atomic_path
from snan_hil.outputs import png_metadata
from snan_hil.host.hil.config import SCENARIO_LABELS, SCENARIOS
from snan_hil.host.plots import pyplot

COLORS = {"sw_noastro": "#9ecae1", "sw_astro": "#3182bd",
          "hw_noastro": "#fdae6b", "hw_astro": "#e6550d"}


FIGURE_FORMAT = "snan-hil-compare-figure/1"
"""Marker of ``fig10c.png`` (PNG text chunk, :func:`snan_hil.outputs.png_metadata`)."""


def plot_compare(results: dict[str, Any], out: str | os.PathLike) -> Path:
    """Write the figure (PNG) atomically; ``results`` is :func:`run_compare`'s dict."""
    plt = pyplot("the figure needs matplotlib")
    out = Path(out)
    sets = results["sets"]
    scen = [s for s in SCENARIOS if s in results["scenarios"]]
    per = {(r["scenario"], r["set"]): r for r in results["per_set"]}
    fig, ax = plt.subplots(figsize=(max(6.0, 1.1 * len(sets) + 2), 4.2), dpi=120)
    width = 0.8 / max(1, len(scen))
    x = np.arange(len(sets))
    for j, s in enumerate(scen):
        xs = x - 0.4 + width * (j + 0.5)
        med = [per[(s, k)]["median_steps"] if per[(s, k)]["median_steps"] is not None
               else np.nan for k in sets]
        ax.bar(xs, med, width * 0.92, color=COLORS[s], label=SCENARIO_LABELS[s],
               edgecolor="black", linewidth=0.4)
        for xi, k in zip(xs, sets):
            r = per[(s, k)]
            ok = [p for p, good in zip(r["path_lengths"], r["success"]) if good]
            bad = [p for p, good in zip(r["path_lengths"], r["success"]) if not good]
            ax.scatter(np.full(len(ok), xi), ok, s=6, color="black", zorder=3, linewidths=0)
            if bad:
                ax.scatter(np.full(len(bad), xi), bad, s=14, marker="x", color="red", zorder=3,
                           linewidths=0.8)
        overall = results["scenarios"][s]["median_steps"]
        if overall is not None:
            ax.axhline(overall, color=COLORS[s], linewidth=1.6,
                       linestyle=":" if s.endswith("_astro") else "--")
    ax.set_xticks(x)
    ax.set_xticklabels([str(k) for k in sets])
    ax.set_xlabel("weight set (lines: overall median of each scenario, dashed without, "
                  "dotted with astrocytes)", fontsize=8)
    ax.set_ylabel("path length (steps)")
    ax.set_yscale("log")
    lim = results.get("step_limit")
    ax.set_title(f"{results['grid'][0]}x{results['grid'][1]} field, cell {results['start']} -> "
                 f"{results['goal']}: median of {results['launches']} launches per bar "
                 f"(x: failed at {lim} steps)", fontsize=9)
    if lim:
        ax.set_ylim(top=lim * 1.4)
    ax.legend(fontsize=7, ncol=4, loc="upper center", bbox_to_anchor=(0.5, -0.14),
              frameon=False)
    fig.tight_layout()
    try:
        with atomic_path(out, suffix=".png") as tmp:
            fig.savefig(tmp, format="png", metadata=png_metadata(FIGURE_FORMAT))
    finally:
        plt.close(fig)
    return out
