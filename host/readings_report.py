"""Outputs of a readings sweep (:mod:`snan_hil.host.readings`): the ranked CSV, the Markdown
table and the heat map of the distance over two keys. Pure functions of the result document
except :func:`heatmap_figure` (matplotlib)."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from typing import Any

from snan_hil.host.plots import pyplot
from snan_hil.files.outputs import png_metadata

HEATMAP_FORMAT = "snan-hil-readings-heatmap/1"
#: rows of the Markdown table
MD_ROWS = 20


def _pct(v: float | None) -> str:
    return "-" if v is None else f"{100 * v:.1f}"


def _num(v: float | None) -> str:
    return "-" if v is None else f"{v:g}"


TIE_NOTE = ("rank: readings whose 95 % distance intervals overlap share a rank (tied, not "
            "ranked); 'dropped @N': a racing round at N trials found the reading clearly worse "
            "than that round's best (paired bootstrap interval of the difference above 0).")


def csv_header(doc: dict[str, Any]) -> list[str]:
    keys = list(doc["vary"])
    labels = [f"{t['condition']} {t['quantity']}" for t in doc["targets"]]
    return (["rank", "distance", "distance_ci_low", "distance_ci_high", "trials", "status",
             *keys] + [f"d {x}" for x in labels] + [f"ours {x}" for x in labels])


def _rank(r: dict[str, Any]) -> str:
    return "-" if r.get("rank") is None else str(r["rank"])


def _status(r: dict[str, Any]) -> str:
    if r.get("status") == "dropped":
        return f"dropped @{r['trials']}"
    return "tied with best" if r.get("tied_with_best") else "finalist"


def _dci(r: dict[str, Any]) -> str:
    ci = r.get("distance_ci")
    return "" if not ci else f"[{ci[0]:.1f}, {ci[1]:.1f}]"


def csv_text(doc: dict[str, Any]) -> str:
    """One row per reading: rank (tied readings share one; empty for a dropped reading),
    distance with its 95 % interval, the trials it reached and its status, the varied keys'
    values, per-target distance and our value (success as a fraction)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(csv_header(doc))
    keys = list(doc["vary"])
    for r in doc["rows"]:
        ours = [r["conditions"][t["condition"]][t["quantity"]] for t in doc["targets"]]
        ci = r.get("distance_ci") or [None, None]
        w.writerow(["" if r.get("rank") is None else r["rank"], f"{r['distance']:.4f}",
                    *["" if v is None else f"{v:.4f}" for v in ci], r.get("trials", ""),
                    r.get("status", ""), *[r["reading"].get(k) for k in keys],
                    *[f"{p:.4f}" for p in r["parts"]],
                    *["" if v is None else f"{v:.6g}" for v in ours]])
    return buf.getvalue()


def rich_table(doc: dict[str, Any], top: int = MD_ROWS) -> Any:
    """The ranking as a rich table (the CLI prints it)."""
    from rich.table import Table
    t = Table(title=f"readings ranked by distance to the paper (up to {doc['trials']} trials, "
                    f"seed {doc['seed']})")
    for col in ("rank", "reading", "distance [95 % CI]", "trials", "status"):
        t.add_column(col, justify="left" if col in ("reading", "status") else "right")
    for r in doc["rows"][:top]:
        t.add_row(_rank(r), r["label"], f"{r['distance']:.2f} {_dci(r)}", str(r.get("trials")),
                  _status(r))
    if len(doc["rows"]) > top:
        t.add_row("...", f"{len(doc['rows']) - top} more in readings.csv", "", "", "")
    return t


def _interval(st: dict[str, Any], qty: str) -> str:
    ci = st.get("success_rate_ci" if qty == "success_rate" else "median_steps_ci")
    if not ci:
        return ""
    if qty == "success_rate":
        return f" [{100 * ci[0]:.1f}, {100 * ci[1]:.1f}]"
    return f" [{ci[0]:g}, {ci[1]:g}]"


def markdown(doc: dict[str, Any], top: int = MD_ROWS) -> str:
    """The ranking (best ``top`` readings) and, for the best reading, every target with our
    value, its 95 % interval and whether the paper lies inside."""
    lines = [f"# Readings sweep ({doc['trials']} trials per condition, seed {doc['seed']})", "",
             f"Command: `{doc['command']}`  ", f"snan-hil {doc['version']}, model "
             f"{doc['model_fingerprint']}; distance: {doc['distance']}.", "",
             TIE_NOTE, "",
             "| rank | reading | distance [95 % CI] | trials | status |", "|---|---|---|---|---|"]
    for r in doc["rows"][:top]:
        lines.append(f"| {_rank(r)} | {r['label']} | {r['distance']:.2f} {_dci(r)} | "
                     f"{r.get('trials', '')} | {_status(r)} |")
    if len(doc["rows"]) > top:
        lines.append(f"| ... | {len(doc['rows']) - top} more in readings.csv | | | |")
    if doc.get("rounds"):
        lines += ["", "| round | trials | readings | run / cached tasks | dropped | best "
                  "| wall s |", "|---|---|---|---|---|---|---|"]
        for x in doc["rounds"]:
            lines.append(f"| {x['round']} | {x['trials']} | {x['readings']} | "
                         f"{x['tasks_run']} / {x['tasks_cached']} | {x['dropped']} | "
                         f"{x['best']} ({x['best_distance']:.2f}) | {x['wall_s']:.0f} |")
    best = doc["rows"][0]
    lines += ["", f"## Best reading: {best['label']}", "",
              "| condition | quantity | ours [95 % interval] | paper | paper inside | distance |",
              "|---|---|---|---|---|---|"]
    from snan_hil.host.intervals import paper_inside
    for t, part in zip(doc["targets"], best["parts"]):
        st = best["conditions"][t["condition"]]
        qty = t["quantity"]
        v = st[qty]
        ci = st.get("success_rate_ci" if qty == "success_rate" else "median_steps_ci")
        paper = t["paper"]
        if qty == "success_rate":
            ours = _pct(v) + " %" + _interval(st, qty)
            ptxt = (f"{100 * paper[0]:.1f}–{100 * paper[1]:.1f} %" if isinstance(paper, list)
                    else f"{100 * paper:.1f} %")
        else:
            ours = _num(v) + _interval(st, qty)
            ptxt = f"{paper[0]:g}–{paper[1]:g}" if isinstance(paper, list) else f"{paper:g}"
        inside = paper_inside(paper, ci)
        lines.append(f"| {t['condition']} | {qty.replace('_', ' ')} | {ours} | {ptxt} | "
                     f"{'-' if inside is None else ('yes' if inside else 'no')} | "
                     f"{part:.2f} |")
    lines += ["", f"Intervals: {doc['ci_method']['success_rate']} (rates); "
              f"{doc['ci_method']['median_steps']} (medians)."]
    return "\n".join(lines) + "\n"


def heat_grid(doc: dict[str, Any], x_key: str, y_key: str
              ) -> tuple[list[Any], list[Any], list[list[float]]]:
    """(x values, y values, distance[y][x]): the best (lowest) distance over the other keys."""
    xs, ys = list(doc["vary"][x_key]), list(doc["vary"][y_key])
    grid = [[math.inf] * len(xs) for _ in ys]
    for r in doc["rows"]:
        if x_key not in r["reading"] or y_key not in r["reading"]:
            continue
        i = ys.index(r["reading"][y_key])
        j = xs.index(r["reading"][x_key])
        grid[i][j] = min(grid[i][j], r["distance"])
    return xs, ys, grid


def heatmap_figure(doc: dict[str, Any], keys: Sequence[str], path: Any) -> None:
    """PNG of the distance over two keys (``keys``: x, y; the minimum over the other keys);
    one key: a bar chart of the distance per value. ``path``: a file name or a binary
    file object."""
    plt = pyplot("the readings heat map needs matplotlib")
    import numpy as np
    fig, ax = plt.subplots(figsize=(7, 5))
    if len(keys) >= 2:
        xs, ys, grid = heat_grid(doc, keys[0], keys[1])
        data = np.array(grid, dtype=float)
        im = ax.imshow(data, cmap="viridis_r", origin="lower", aspect="auto")
        finite = data[np.isfinite(data)]
        lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
        for i in range(len(ys)):
            for j in range(len(xs)):
                v = data[i, j]
                # dark text on the light (low, close) end of viridis_r, light text elsewhere
                light = np.isfinite(v) and (v - lo) <= 0.5 * (hi - lo)
                ax.text(j, i, "-" if not np.isfinite(v) else f"{v:.1f}", ha="center",
                        va="center", fontsize=8, color="black" if light else "white")
        ax.set_xticks(range(len(xs)), [str(v) for v in xs])
        ax.set_yticks(range(len(ys)), [str(v) for v in ys])
        ax.set_xlabel(keys[0])
        ax.set_ylabel(keys[1])
        fig.colorbar(im, ax=ax, label="distance to the paper (lower is closer)")
        others = [k for k in doc["vary"] if k not in keys[:2]]
        sub = f"best over {', '.join(others)}" if others else ""
    else:
        key = keys[0] if keys else None
        if key is None:
            vals = ["defaults"]
            dist = [doc["rows"][0]["distance"]]
        else:
            vals = list(doc["vary"][key])
            dist = [min(r["distance"] for r in doc["rows"] if r["reading"].get(key) == v)
                    for v in vals]
        ax.bar(range(len(vals)), dist)
        ax.set_xticks(range(len(vals)), [str(v) for v in vals])
        ax.set_xlabel(key or "reading")
        ax.set_ylabel("distance to the paper (lower is closer)")
        sub = ""
    ax.set_title(f"readings sweep: distance to the paper, {doc['trials']} trials/condition"
                 + (f"\n({sub})" if sub else ""), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110, format="png", metadata=png_metadata(HEATMAP_FORMAT))
    plt.close(fig)
