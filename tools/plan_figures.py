"""The figure of a plan run (``snan-hil plan run --png``; needs matplotlib).

One row per cell (up to :data:`MAX_CELLS`): the conductance read after every pulse and read
against its number on the cell (SET, RESET and reads marked apart; log scale when it spans more
than a factor 5), the amplitude of every pulse against the same number (RESET drawn negative,
so the two branches of a sweep read apart; reads at their read voltage), and -- when the plan
read at voltages of its own (the ``iv-curve`` preset) -- the current the board measured
against the voltage across the cell, one curve per step. Written like every bench figure
(:mod:`snan_hil.tools.bench_figures`): atomically, with the PNG text tag of its format.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from snan_hil.tools.bench_figures import PAPER_BLUE, PAPER_ORANGE, _pyplot, _save, \
    conductance_axis

__all__ = ["PLAN_PNG_FORMAT", "MAX_CELLS", "plot_plan_run"]

PLAN_PNG_FORMAT = "snan-hil-plan-figure/1"
MAX_CELLS = 6
"""Cells drawn (the first ones of the run; the title says how many there were)."""
READ_GREY = "#7f7f7f"


def plot_plan_run(results: Sequence[Any], path: str | os.PathLike[str], *, title: str,
                  step_names: Sequence[str | None] = ()) -> Path:
    """Draw ``results`` (:class:`~snan_hil.calibration.plans.CellPlanResult`, in run order)
    into ``path`` under ``title`` (the plan, board, port, date: :mod:`snan_hil.tools.titles`);
    ``step_names``: the plan's steps' names (1-based step numbers index it from 0), used to
    label the I-V curves."""
    plt = _pyplot()
    shown = list(results)[:MAX_CELLS]
    iv = any(_measured(r) for r in shown)
    cols = 3 if iv else 2
    fig, axes = plt.subplots(max(1, len(shown)), cols, figsize=(5.2 * cols, 3.1 * max(1,
                                                                                    len(shown))),
                             squeeze=False)
    for k, res in enumerate(shown):
        _conductance(axes[k][0], res)
        _amplitudes(axes[k][1], res)
        if iv:
            _iv(axes[k][2], res, step_names)
    more = f" (the first {len(shown)} of {len(results)} cells)" if len(results) > len(shown) \
        else ""
    fig.suptitle(f"{title}{more}", fontsize=9)
    fig.tight_layout()
    return _save(plt, fig, path, PLAN_PNG_FORMAT)


def _measured(res: Any) -> list[Any]:
    """The reads of ``res`` at a voltage of their own, with a measured current."""
    return [r for r in res.records if r.action == "read" and r.width_us == 0
            and r.amplitude_v > 0 and r.current_a is not None and r.cell_v is not None]


def _conductance(ax: Any, res: Any) -> None:
    recs = res.records
    n = np.array([r.n for r in recs], dtype=float)
    g = np.array([r.g_after_s for r in recs], dtype=float) * 1e6
    ax.plot([0, *n], [res.initial_s * 1e6, *g], "-", color="black", lw=0.5, alpha=0.5)
    ax.plot([0], [res.initial_s * 1e6], "s", color="black", ms=4, label="read before")
    for action, style, color, label in (("set", "o", PAPER_BLUE, "after a SET pulse"),
                                        ("reset", "v", PAPER_ORANGE, "after a RESET pulse"),
                                        ("read", ".", READ_GREY, "read step")):
        pick = [i for i, r in enumerate(recs) if r.action == action]
        if pick:
            ax.plot(n[pick], g[pick], style, color=color, ms=3.5, label=label)
    conductance_axis(ax, [res.initial_s * 1e6, *g])
    ax.set_xlabel("pulse or read on this cell")
    ax.set_title(f"cell ({res.row},{res.col}): {res.pulses} pulses; {res.stopped}",
                 fontsize=8)
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    ax.legend(fontsize=6, loc="best")
    _whole_numbers(ax)


def _amplitudes(ax: Any, res: Any) -> None:
    recs = res.records
    for action, sign, style, color, label in (
            ("set", 1.0, "o", PAPER_BLUE, "SET amplitude"),
            ("reset", -1.0, "v", PAPER_ORANGE, "RESET amplitude (drawn negative)"),
            ("read", 1.0, ".", READ_GREY, "read voltage")):
        pick = [r for r in recs if r.action == action]
        if not pick:
            continue
        volts = [sign * (r.amplitude_v if action != "read" or r.amplitude_v > 0
                         else (r.read_v or 0.0)) for r in pick]
        ax.plot([r.n for r in pick], volts, style, color=color, ms=3.5, label=label)
    ax.axhline(0, color="black", lw=0.5)
    ax.set_xlabel("pulse or read on this cell")
    ax.set_ylabel("applied voltage (V)")
    ax.set_title("amplitude of each pulse (the write DAC's, as applied)", fontsize=8)
    ax.grid(True, lw=0.3, alpha=0.5)
    ax.legend(fontsize=6, loc="best")
    _whole_numbers(ax)


def _iv(ax: Any, res: Any, step_names: Sequence[str | None]) -> None:
    reads = _measured(res)
    groups: dict[str, list[Any]] = {}
    for r in reads:
        name = step_names[r.step - 1] if 0 < r.step <= len(step_names) else None
        groups.setdefault(name or f"step {r.step}", []).append(r)
    for name, rs in groups.items():
        ax.plot([r.cell_v for r in rs], [r.current_a * 1e6 for r in rs], "o-", ms=3, lw=1,
                label=name)
    ax.set_xlabel("voltage across the cell during the read (V)")
    ax.set_ylabel("current measured by the ADC (uA)")
    ax.set_title("I-V in the read range (the board measures no current during a pulse)",
                 fontsize=8)
    ax.grid(True, lw=0.3, alpha=0.5)
    if groups:
        ax.legend(fontsize=6, loc="best")


def _whole_numbers(ax: Any) -> None:
    from matplotlib.ticker import MaxNLocator
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
