"""Figures of device characterisation and learning on the chip (needs matplotlib).

* :func:`plot_device_fit` — ``characterize --png``: ΔG per pulse against G, SET and RESET, the
  measured points, the fitted chip-level curve and the spread of the cells' own curves, the
  weight map's window shaded;
* :func:`plot_learning` — ``learn --png``: the learning curves of the arms (median route and
  success per cycle with 95 % intervals), the paper's Fig. 7 values beside, and the pulse
  ledger (pulses per cycle, SET vs RESET; the per-cell wear histogram);
* :func:`plot_lifetime` — ``bench/bench_lifetime.py``: a chip's life of learning sessions
  (success, pulses per cell, predicted against the emulated chip's wear).

Written like every bench figure (:mod:`snan_hil.tools.bench_figures`): atomically, with the
PNG text tag of its format.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from snan_hil.common.polarity import Polarity
from snan_hil.tools.bench_figures import PAPER_BLUE, PAPER_ORANGE, _pyplot, _save

__all__ = ["DEVICE_FIT_PNG_FORMAT", "LEARN_PNG_FORMAT", "LIFETIME_PNG_FORMAT",
           "plot_device_fit", "plot_learning", "plot_lifetime"]

DEVICE_FIT_PNG_FORMAT = "snan-hil-device-fit/1"
LEARN_PNG_FORMAT = "snan-hil-learn-figure/1"


def plot_device_fit(model: Any, samples: Sequence[Any], path: str | os.PathLike[str], *,
                    title: str, window_s: tuple[float, float] | None = None,
                    max_points: int = 4000, seed: int = 0) -> Path:
    """ΔG (uS) of one pulse against the G read before it (uS), one panel per polarity."""
    plt = _pyplot()
    rng = np.random.default_rng(seed)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.4))
    lo = min((s.g_before_s for s in samples), default=1e-5)
    hi = max((s.g_before_s for s in samples), default=1e-3)
    grid = np.geomspace(max(lo, 1e-7), hi, 200)
    for ax, pol, color in ((axes[0], Polarity.SET, PAPER_BLUE),
                           (axes[1], Polarity.RESET, PAPER_ORANGE)):
        pts = [(s.g_before_s, s.g_after_s - s.g_before_s) for s in samples
               if s.polarity == pol]
        if len(pts) > max_points:
            pts = [pts[i] for i in rng.choice(len(pts), max_points, replace=False)]
        if pts:
            g, d = np.array(pts).T
            ax.plot(g * 1e6, d * 1e6, ".", ms=2, color=color, alpha=0.35,
                    label=f"measured pulses ({sum(1 for s in samples if s.polarity == pol)})")
        cells = [c for c in model.cells if c.ok]
        if cells:
            curves = np.array([grid * np.expm1(c.mean_dx(pol, grid)) for c in cells]) * 1e6
            ax.fill_between(grid * 1e6, np.percentile(curves, 10, axis=0),
                            np.percentile(curves, 90, axis=0), color="grey", alpha=0.3,
                            label=f"cells' fits, 10-90 % ({len(cells)} cells)")
        ax.plot(grid * 1e6, model.mean_step_s(pol, grid) * 1e6, "-", color="black", lw=1.6,
                label="chip-level fit")
        if window_s is not None:
            ax.axvspan(window_s[0] * 1e6, window_s[1] * 1e6, color="green", alpha=0.07,
                       label="weight map window")
        ax.axhline(0, color="black", lw=0.5)
        ax.set_xscale("log")
        ax.set_xlabel("cell conductance before the pulse (uS)")
        ax.set_ylabel("conductance change of one pulse (uS)")
        amp = model.pulse.amplitude(pol)
        ax.set_title(f"{pol.name} {amp:g} V, {model.pulse.width_us} us", fontsize=9)
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
        ax.legend(fontsize=7, loc="best")
    fig.suptitle(f"{title}\ndw_min {model.dw_min:.4f} (ln G) at {model.g_ref_s * 1e6:.0f} uS, "
                 f"up_down {model.up_down:+.3f}, dw_min_dtod {model.dw_min_dtod:.3f}, "
                 f"dw_min_std {model.dw_min_std:.3f}, G bounds {model.g_min_s * 1e6:.1f}.."
                 f"{model.g_max_s * 1e6:.0f} uS", fontsize=8)
    fig.tight_layout()
    return _save(plt, fig, path, DEVICE_FIT_PNG_FORMAT)


def plot_learning(curves: Mapping[str, Mapping[str, Any]], ledger: Sequence[Mapping[str, Any]],
                  wear: Sequence[int], path: str | os.PathLike[str], *, title: str,
                  paper: Mapping[str, Any] | None = None) -> Path:
    """Three panels: median route of the successful tests per cycle (log scale, 95 %
    intervals), success rate per cycle (95 % intervals), the chip arm's pulses per cycle (SET /
    RESET stacked) with the per-cell pulse histogram as an inset. ``curves``: arm ->
    ``{median, median_ci, success, success_ci}`` per cycle; ``paper``: ``{median: {cycle:
    value}, success: {cycle: value}, label}`` drawn as crosses."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.4))
    colors = {"software": "tab:blue", "device": "tab:green", "chip": "tab:red"}
    for arm, c in curves.items():
        x = np.arange(len(c["median"]))
        col = colors.get(arm, None)
        med = np.array([np.nan if v is None else v for v in c["median"]], dtype=float)
        ci = np.array([[np.nan, np.nan] if v is None else v for v in c["median_ci"]],
                      dtype=float)
        axes[0].plot(x, med, "o-", ms=3, color=col, label=arm)
        axes[0].fill_between(x, ci[:, 0], ci[:, 1], color=col, alpha=0.15)
        suc = 100 * np.array(c["success"], dtype=float)
        sci = 100 * np.array([[np.nan, np.nan] if v is None else v for v in c["success_ci"]],
                             dtype=float)
        axes[1].plot(x, suc, "o-", ms=3, color=col, label=arm)
        axes[1].fill_between(x, sci[:, 0], sci[:, 1], color=col, alpha=0.15)
    if paper:
        for k, v in (paper.get("median") or {}).items():
            axes[0].plot([int(k)], [v], "x", color="black", ms=9)
        for k, v in (paper.get("success") or {}).items():
            axes[1].plot([int(k)], [100 * v], "x", color="black", ms=9)
        axes[0].plot([], [], "x", color="black", label=paper.get("label", "paper"))
        axes[1].plot([], [], "x", color="black", label=paper.get("label", "paper"))
    axes[0].set_yscale("log")
    _plain_log_ticks(axes[0])
    axes[0].set_ylabel("median route of successful tests (steps)")
    axes[1].set_ylabel("completed tests (%)")
    axes[1].set_ylim(0, 105)
    for ax in axes[:2]:
        ax.set_xlabel("learning cycle")
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
        ax.legend(fontsize=7)
    axes[0].set_title("A: median route (band: 95 % interval)", fontsize=8)
    axes[1].set_title("B: success rate (band: 95 % interval)", fontsize=8)
    if ledger:
        cyc = np.array([r["cycle"] for r in ledger])
        s = np.array([r["set"] for r in ledger])
        r_ = np.array([r["reset"] for r in ledger])
        axes[2].bar(cyc, s, color=PAPER_BLUE, label="SET pulses")
        axes[2].bar(cyc, r_, bottom=s, color=PAPER_ORANGE, label="RESET pulses")
        axes[2].set_xlabel("learning cycle")
        axes[2].set_ylabel("pulses applied to the chip (all sessions)")
        axes[2].legend(fontsize=7, loc="upper right")
        if len(wear):
            inset = axes[2].inset_axes([0.5, 0.45, 0.45, 0.3])
            inset.hist(np.asarray(wear), bins=20, color="grey")
            inset.set_title("pulses per cell (wear)", fontsize=6)
            inset.tick_params(labelsize=5)
    axes[2].set_title("C: the chip arm's pulse ledger", fontsize=8)
    from matplotlib.ticker import MaxNLocator
    for ax in axes:                           # cycles are whole numbers
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    fig.suptitle(title, fontsize=8)
    fig.tight_layout()
    return _save(plt, fig, path, LEARN_PNG_FORMAT)


LIFETIME_PNG_FORMAT = "snan-hil-lifetime-figure/1"


def plot_lifetime(runs: Mapping[str, Mapping[str, Any]], path: str | os.PathLike[str], *,
                  title: str, window: int = 50) -> Path:
    """A chip's life of learning sessions (``host.hil.lifetime.run_lifetime`` records, one per
    reading): A, the cycle-20 test success over the sessions (moving mean over ``window``
    sessions) and the learning pulses per session; B, per cell the cumulative pulses
    (learning and programming, sorted); C, per cell the wear the host predicts from its
    ledger (model cycles) against the emulated chip's own (device cycles)."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4))
    colors = ["tab:blue", "tab:red", "tab:green", "tab:purple"]
    for (name, run), col in zip(runs.items(), colors):
        ses = run["sessions"]
        ok = np.array([s["tests"][-1] for s in ses], dtype=float)
        k = np.arange(1, len(ok) + 1)
        win = max(1, min(window, len(ok)))
        mean = np.convolve(ok, np.ones(win) / win, mode="valid") * 100
        axes[0].plot(k[win - 1:], mean, "-", marker="." if mean.size < 5 else None,
                     color=col, label=f"{name}: success")
        cells = run["cells"]
        learn = np.array([c["learning_pulses"] for c in cells])
        prog = np.array([c["programming_pulses"] for c in cells])
        order = np.argsort(learn + prog)
        axes[1].plot(np.arange(len(cells)), (learn + prog)[order], "-", color=col,
                     label=f"{name}: all pulses")
        axes[1].plot(np.arange(len(cells)), learn[order], ":", color=col,
                     label=f"{name}: learning pulses")
        axes[2].plot([c["true_wear_cycles"] for c in cells],
                     [c["predicted_cycles"] for c in cells], ".", ms=4, color=col, label=name)
    axes[0].set_xlabel(f"session (moving mean over {window})")
    axes[0].set_ylabel("cycle-20 test success (%)")
    axes[0].axhline(90, color="grey", ls="--", lw=1, label="target 90 %")
    axes[0].set_ylim(0, 102)
    axes[0].legend(fontsize=7, loc="lower left")
    axes[0].set_title("A  success over the chip's life", loc="left", fontsize=10)
    axes[1].set_xlabel("cell (sorted by pulses)")
    axes[1].set_ylabel("cumulative pulses per cell")
    axes[1].set_yscale("log")
    axes[1].legend(fontsize=7)
    axes[1].set_title("B  pulses per cell", loc="left", fontsize=10)
    lim = max(1e-3, axes[2].get_xlim()[1], axes[2].get_ylim()[1])
    axes[2].plot([0, lim], [0, lim], color="grey", lw=1)
    axes[2].set_xlabel("emulated chip's wear per cell (device cycles)")
    axes[2].set_ylabel("host's predicted wear (model cycles)")
    axes[2].legend(fontsize=7)
    axes[2].set_title("C  wear: the host's prediction vs the chip's", loc="left", fontsize=10)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return _save(plt, fig, path, LIFETIME_PNG_FORMAT)


def _plain_log_ticks(ax: Any) -> None:
    """A log axis of step counts labelled 5, 10, 20, 50, ... as plain numbers (matplotlib's
    default labels a minor tick "6×10¹")."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter
    ax.yaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v:g}"))
    ax.yaxis.set_minor_formatter(NullFormatter())
