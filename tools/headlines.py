"""Headline numbers of the paper's experiments next to the paper's values (``experiment``
prints them; ``experiment --json`` gives them), taken from each figure's result rows.

A row of a figure's results that carries ``paper_<quantity>`` beside ``<quantity>`` (fig3,
fig4, fig5, fig6: success rate and median path length per condition) is a headline; fig7
gives its numbers per grid as ``(median cycle 0, median cycle 20, success cycle 0, success
cycle 20)`` and its rows per cycle (the main variant is the first).

Every headline carries our 95 % interval (``ours_ci``: the row's ``<quantity>_ci``, Wilson
for a rate, bootstrap for a median; None when no trial succeeded), whether the paper's value
lies inside it (``paper_inside``) and how far outside (``paper_distance``, 0 inside; same unit
as the quantity), and the interval's method (``ci_method``).
"""

from __future__ import annotations

from typing import Any

from snan_hil.host.intervals import METHOD, paper_distance, paper_inside

__all__ = ["headlines"]

_STATS = {"trials", "successes", "success_rate", "median_steps", "mean_steps", "p25_steps",
          "p75_steps", "sessions", "test_success_rate", "test_median_steps",
          "train_median_steps", "saturated_fraction"}


def _condition(row: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in row.items() if k not in _STATS and not k.startswith("paper_")
            and not isinstance(v, (list, dict))}


def headlines(name: str, data: dict[str, Any], rows: list[dict[str, Any]]
              ) -> list[dict[str, Any]]:
    """``[{figure, quantity, condition, ours, paper, ours_ci, paper_inside, paper_distance,
    ci_method}]`` of one figure (ours and ours_ci may be None when no trial succeeded)."""
    out: list[dict[str, Any]] = []
    if name == "fig7":
        return _fig7(data, rows)
    for row in rows:
        for key, paper in row.items():
            if not key.startswith("paper_") or paper is None:
                continue
            quantity = key[len("paper_"):]
            if quantity not in row:
                continue
            out.append(_head(name, quantity, _condition(row), row[quantity],
                             row.get(f"{quantity}_ci"), paper))
    return out


def _head(name: str, quantity: str, condition: dict[str, Any], ours: Any, ours_ci: Any,
          paper: Any) -> dict[str, Any]:
    return {"figure": name, "quantity": quantity, "condition": condition, "ours": ours,
            "paper": paper, "ours_ci": ours_ci, "paper_inside": paper_inside(paper, ours_ci),
            "paper_distance": paper_distance(paper, ours_ci),
            "ci_method": METHOD.get(quantity)}


def _fig7(data: dict[str, Any], rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    paper = data.get("paper") or {}
    if not rows:
        return []
    main = rows[0].get("variant")
    by = {(r["grid"], r["cycle"]): r for r in rows if r.get("variant") == main}
    last = max((r["cycle"] for r in rows if r.get("variant") == main), default=0)
    out = []
    for grid, values in paper.items():
        med0, med_n, ok0, ok_n = values
        for cycle, med, ok in ((0, med0, ok0), (last, med_n, ok_n)):
            r = by.get((grid, cycle))
            if r is None:
                continue
            cond = {"variant": main, "grid": grid, "cycle": cycle}
            out.append(_head("fig7", "median_steps", cond, r.get("test_median_steps"),
                             r.get("test_median_steps_ci"), med))
            out.append(_head("fig7", "success_rate", cond, r.get("test_success_rate"),
                             r.get("test_success_rate_ci"), ok))
    return out
