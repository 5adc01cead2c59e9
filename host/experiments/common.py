"""What every figure module shares: run options, configurations, condition tasks, result
collection, statistics, the output files (JSON, CSV, PNG, Markdown, written atomically)
and plotting helpers."""

from __future__ import annotations

import csv
import io
import json
import math
import os
import pathlib
import shutil
import tempfile
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from snan_hil.common.version import __version__
from snan_hil.files.atomicio import new_file_mode
from snan_hil.common.errors import UserError
from snan_hil.host.config import SnanConfig, load_config
from snan_hil.host.experiments.executor import Task, key_text
from snan_hil.host.experiments.mazes import MAZE_RULES, max_connected_fraction
from snan_hil.host.snan_kernel import TARGET_CODES as TARGETS
from snan_hil.host.experiments.trials import nav_batch
from snan_hil.host.plasticity import PLASTICITY_RULES
from snan_hil.host.intervals import (METHOD_TEXT, flat_intervals, format_interval, inside_text,
                                     interval_fields, paper_inside)
from snan_hil.host.plots import pyplot as _pyplot

#: route-learning start/goal modes
ROUTE_TASKS = ("fixed", "random")


@dataclass(frozen=True)
class RunOptions:
    """Options of one ``snan-hil experiment`` run (the CLI's flags)."""

    seed: int = 1
    trials: int | None = None        #: trials per condition (fig7: sessions); None = paper's
    plasticity: str = "additive"     #: additive | vteam (the learning rule everywhere)
    overrides: tuple[str, ...] = ()  #: ``--set`` strings applied to every base preset
    maze_rule: str = "component"
    route_target: str = "chosen"     #: fig7: where the STDP change goes (stdp.target)
    route_task: str = "fixed"        #: fig7: fixed | random start/goal across cycles
    route_train_astro: bool = True   #: fig7: astrocytes during the training trials
    chunk: int = 50                  #: trials per task (progress / load balance only)

    def __post_init__(self) -> None:
        if self.trials is not None and self.trials < 1:
            raise UserError(f"--trials must be >= 1, got {self.trials}")
        if self.plasticity not in PLASTICITY_RULES:
            raise UserError(f"--plasticity {self.plasticity!r}: choose "
                            f"{' or '.join(PLASTICITY_RULES)}")
        if self.maze_rule not in MAZE_RULES:
            raise UserError(f"--maze-rule {self.maze_rule!r}: choose {' or '.join(MAZE_RULES)}")
        if self.route_target not in TARGETS:
            raise UserError(f"--route-target {self.route_target!r}: choose one of "
                            f"{', '.join(TARGETS)}")
        if self.route_task not in ROUTE_TASKS:
            raise UserError(f"--route-task {self.route_task!r}: choose fixed or random")
        if self.chunk < 1:
            raise UserError(f"chunk must be >= 1, got {self.chunk}")

    def n(self, paper: int) -> int:
        """Trials of a condition: ``--trials`` or the paper's count."""
        return self.trials if self.trials is not None else paper

    def plasticity_params(self, target: str | None = None) -> dict:
        """Plasticity of a figure's trials (target None: the config's ``stdp.target``)."""
        return {"rule": self.plasticity, "target": target}

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["overrides"] = list(self.overrides)
        return d


def preset(name: str, opts: RunOptions, *extra: str) -> SnanConfig:
    """A preset with the run's ``--set`` overrides, then ``extra`` overrides."""
    return load_config(preset=name, overrides=[*opts.overrides, *extra])


def astro(cfg: SnanConfig, on: bool) -> SnanConfig:
    return cfg.replace(**{"astro.enabled": bool(on)})


# ---- tasks and results ----------------------------------------------------------------------
def condition_tasks(fig: str, cond: Sequence[Any], cfg: SnanConfig, params: dict, n: int,
                    chunk: int, fn: Callable = nav_batch, keep: Iterable[int] = (),
                    seed_cond: Sequence[Any] | None = None) -> list[Task]:
    """Tasks running trials 0..n-1 of condition ``cond`` in chunks (task key = condition +
    first trial). All chunks share one seed, derived from ``seed_cond`` (default: the
    condition), so results do not depend on the chunk size; conditions that share a
    ``seed_cond`` see the same starts, goals, mazes, initial weights and input spikes
    (paired comparisons)."""
    tasks = []
    cond = (fig, *cond)
    skey = (fig, *(seed_cond if seed_cond is not None else cond[1:]))
    keep = sorted(int(k) for k in keep if 0 <= int(k) < n)
    for lo in range(0, n, chunk):
        hi = min(n, lo + chunk)
        p = dict(params, trials=[lo, hi], keep=[k for k in keep if lo <= k < hi])
        tasks.append(Task(key=(*cond, lo), fn=fn, config=cfg, params=p, weight=hi - lo,
                          seed_key=skey))
    return tasks


class Results:
    """Results of a sweep, collected per condition = task key without its last element
    (the chunk's first trial / session); chunks concatenated in that order."""

    def __init__(self, tasks: Sequence[Task], results: Sequence[dict]) -> None:
        self._by: dict[str, list[tuple[Task, dict]]] = {}
        for t, r in zip(tasks, results):
            self._by.setdefault(key_text(t.key[:-1]), []).append((t, r))
        self.seeds = {k: v[0][0].seed for k, v in self._by.items()}

    def parts(self, fig: str, *cond: Any) -> list[dict]:
        items = self._by.get(key_text((fig, *cond)))
        if items is None:
            raise KeyError(f"no results for condition {(fig, *cond)!r}")
        return [r for _t, r in sorted(items, key=lambda tr: tr[0].key[-1])]

    def seed(self, fig: str, *cond: Any) -> int:
        seed = self.seeds[key_text((fig, *cond))]
        if seed is None:
            raise KeyError(f"condition {(fig, *cond)!r} ran without a seed")
        return int(seed)

    def trials(self, fig: str, *cond: Any) -> tuple[np.ndarray, np.ndarray, list[dict]]:
        """(steps, success, examples) of a navigation condition."""
        parts = self.parts(fig, *cond)
        steps = np.concatenate([np.asarray(p["steps"], dtype=np.int64) for p in parts])
        ok = np.concatenate([np.asarray(p["success"], dtype=bool) for p in parts])
        ex = [e for p in parts for e in p.get("examples", [])]
        return steps, ok, ex

    def by_astro(self, fig: str, *cond: Any) -> dict[bool, dict[str, Any]]:
        """Per astro off/on (the last key element): ``{"stats", "steps", "success",
        "examples"}`` of the navigation condition ``(*cond, on)``."""
        out = {}
        for on in (False, True):
            steps, ok, ex = self.trials(fig, *cond, on)
            seed = self.seeds.get(key_text((fig, *cond, on)))
            out[on] = {"stats": stats(steps, ok, seed=int(seed or 0)), "steps": steps,
                       "success": ok, "examples": ex}
        return out

    def stacked(self, fig: str, *cond: Any, fields: Sequence[str]) -> dict[str, np.ndarray]:
        """Per-session arrays of a route-learning condition."""
        parts = self.parts(fig, *cond)
        return {f: np.concatenate([np.asarray(p[f]) for p in parts]) for f in fields}


def stats(steps: np.ndarray, ok: np.ndarray, seed: int = 0) -> dict[str, Any]:
    """Success rate (0..1) and the successful trials' path statistics (steps) of one
    condition (``steps``, ``ok``: shape (trials,)), with the 95 % intervals of the rate
    (``success_rate_ci``, Wilson) and of the median (``median_steps_ci``, bootstrap seeded by
    ``seed``) and ``ci_method`` (:func:`snan_hil.host.intervals.interval_fields`)."""
    good = steps[ok]
    q = (lambda p: float(np.percentile(good, p))) if good.size else (lambda p: None)
    return {"trials": int(ok.size), "successes": int(ok.sum()),
            "success_rate": float(ok.mean()) if ok.size else 0.0,
            "median_steps": float(np.median(good)) if good.size else None,
            "mean_steps": float(good.mean()) if good.size else None,
            "p25_steps": q(25), "p75_steps": q(75), **interval_fields(steps, ok, seed=seed)}


# ---- figures and files --------------------------------------------------------------------
@dataclass
class Figure:
    """Everything one figure writes: JSON data, CSV rows, a plot function, a report."""

    name: str
    title: str
    data: dict[str, Any]
    rows: list[dict[str, Any]]
    plot: Callable[[pathlib.Path], None]
    report: str
    files: dict[str, str] = field(default_factory=dict)


def clean(obj: Any) -> Any:
    """JSON-safe copy: numpy scalars/arrays to Python, non-finite floats to None."""
    if isinstance(obj, dict):
        return {str(k): clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [clean(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return clean(obj.tolist())
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


FIGURE_FORMAT = "snan-hil-experiment/1"
"""The ``format`` field of a figure's JSON (its folder ``<out>/<figure>/`` is replaced as a
whole when the figure is run again)."""


def provenance(opts: RunOptions, configs: dict[str, SnanConfig],
               seeds: dict[str, int | None]) -> dict[str, Any]:
    return {"format": FIGURE_FORMAT, "snan_hil_version": __version__, "master_seed": opts.seed,
            "options": opts.to_dict(), "condition_seeds": seeds,
            "configs": {k: c.to_dict() for k, c in configs.items()}}


def csv_text(rows: list[dict[str, Any]]) -> str:
    """CSV of result rows (columns in order of first appearance; 95 % intervals as
    ``<name>_ci_low`` / ``<name>_ci_high``, :func:`~snan_hil.host.intervals.flat_intervals`)."""
    rows = [flat_intervals(r) for r in rows]
    cols: list[str] = []
    for r in rows:
        for k in r:
            if k not in cols:
                cols.append(k)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if v is None else v) for k, v in clean(r).items()})
    return buf.getvalue()


def write_figure(fig: Figure, out_dir: str | pathlib.Path) -> pathlib.Path:
    """Write ``<out>/<name>/{name}.json, .csv, .png, .md`` atomically: everything goes to a
    temporary folder next to it, which then replaces the old folder by rename."""
    out = pathlib.Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"cannot create output folder {out}: {exc.strerror}") from None
    final = out / fig.name
    tmp = pathlib.Path(tempfile.mkdtemp(prefix=f".{fig.name}.", dir=out))
    try:
        (tmp / f"{fig.name}.json").write_text(json.dumps(clean(fig.data), indent=1) + "\n")
        (tmp / f"{fig.name}.csv").write_text(csv_text(fig.rows))
        (tmp / f"{fig.name}.md").write_text(fig.report)
        fig.plot(tmp / f"{fig.name}.png")
        os.chmod(tmp, new_file_mode(folder=True))      # mkdtemp made it 0700
        old = None
        if final.exists():
            old = out / f".{fig.name}.old.{os.getpid()}"
            os.rename(final, old)
        os.rename(tmp, final)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    fig.files = {ext: str(final / f"{fig.name}.{ext}") for ext in ("json", "csv", "png", "md")}
    return final


# ---- formatting -------------------------------------------------------------------------
def pct(x: float | None, nd: int = 1) -> str:
    return "–" if x is None else f"{100 * x:.{nd}f} %"


def num(x: float | None, nd: int = 1) -> str:
    if x is None:
        return "–"
    return f"{x:.0f}" if float(x).is_integer() else f"{x:.{nd}f}"


def md_table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def pct_ci(s: dict[str, Any], nd: int = 1) -> str:
    """A stats row's success rate with its 95 % interval: "78.6 % [74.8, 82.0] %"."""
    return f"{pct(s['success_rate'], nd)} {format_interval(s.get('success_rate_ci'), True, nd)}"


def num_ci(s: dict[str, Any], key: str = "median_steps") -> str:
    """A stats row's median with its 95 % interval: "8 [7, 9]" ("–" when none succeeded)."""
    if s.get(key) is None:
        return "–"
    return f"{num(s[key])} {format_interval(s.get(key + '_ci'))}"


def range_ci(by: dict, on: bool, walls: Sequence[float]) -> str:
    """The 95 % intervals of the lowest and the highest success rate over ``walls``
    (``by[(on, f)]``: stats rows), "[a, b] % … [c, d] %"."""
    lo = min(walls, key=lambda f: by[(on, f)]["success_rate"])
    hi = max(walls, key=lambda f: by[(on, f)]["success_rate"])
    return (f"{format_interval(by[(on, lo)].get('success_rate_ci'), True)} … "
            f"{format_interval(by[(on, hi)].get('success_rate_ci'), True)}")


def range_inside(paper: tuple[float, float], by: dict, on: bool, walls: Sequence[float]) -> str:
    """"yes" when the paper's success range meets every density's 95 % interval."""
    return inside_text(all(paper_inside(paper, by[(on, f)].get("success_rate_ci"))
                           for f in walls))


#: report footnote naming the intervals' method
CI_NOTE = f"95 % intervals (CI): {METHOD_TEXT}."
#: the note under a maze sweep's tables (Fig. 5, Fig. 6), whose range rows give intervals
RANGE_NOTE = (f"\n{CI_NOTE} Range rows: the intervals of the lowest and the highest rate; the "
              "paper's range is inside when every density's interval meets it.\n")

#: wall fractions of the maze sweeps (Fig. 5, Fig. 6: the paper's 0-90 %) and those drawn
MAZE_WALLS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
EXAMPLE_WALLS = (0.2, 0.4, 0.6)


def maze_walls(opts: RunOptions) -> tuple[float, ...]:
    """Wall fractions of a maze sweep on the 10x10 field (rule ``connected``: only those a
    connected maze allows)."""
    if opts.maze_rule == "connected":
        return tuple(f for f in MAZE_WALLS if f <= max_connected_fraction(10, 10) + 1e-12)
    return MAZE_WALLS


def paper_fields(paper: dict[bool, tuple], on: bool) -> dict[str, Any]:
    """The paper's (success rate, median) of the condition with (``on``) or without
    astrocytes, as a row's ``paper_*`` fields."""
    return {"paper_success_rate": paper[on][0], "paper_median_steps": paper[on][1]}


def main_series(main: dict[bool, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """``steps`` and ``examples`` of the without/with-astrocytes conditions (keys "False",
    "True") for a figure's JSON."""
    return {"steps": {str(on): main[on]["steps"] for on in (False, True)},
            "examples": {str(on): main[on]["examples"] for on in (False, True)}}


def astro_table(main: dict[bool, dict[str, Any]], paper: dict[bool, tuple]) -> str:
    """Markdown table of :meth:`Results.by_astro` without / with astrocytes next to the
    paper's ``{astro: (success rate, median steps)}``: our 95 % intervals (Wilson for the
    rate, bootstrap for the median) and whether the paper's value lies inside each."""
    rows = []
    for on in (False, True):
        s = main[on]["stats"]
        rows.append([("with" if on else "without") + " astrocytes", pct(paper[on][0]),
                     pct(s["success_rate"]), num(paper[on][1]), num(s["median_steps"]),
                     format_interval(s.get("success_rate_ci"), percent=True),
                     inside_text(paper_inside(paper[on][0], s.get("success_rate_ci"))),
                     format_interval(s.get("median_steps_ci")),
                     inside_text(paper_inside(paper[on][1], s.get("median_steps_ci"))),
                     s["trials"]])
    return md_table(["condition", "paper success", "ours", "paper median", "ours",
                     "ours: success 95 % CI", "paper inside", "ours: median 95 % CI",
                     "paper inside", "trials"], rows) + f"\n{CI_NOTE}\n"


def report_head(title: str, opts: RunOptions, command: str, notes: str = "") -> str:
    text = (f"# {title}\n\n"
            f"Command: `{command}`  \n"
            f"Master seed {opts.seed}; plasticity `{opts.plasticity}`; "
            f"overrides: {', '.join(opts.overrides) or 'none'}. Seeds and full configs of "
            f"every condition are in the JSON file next to this report.\n\n")
    return text + (notes + "\n\n" if notes else "")


def command_line(name: str, opts: RunOptions) -> str:
    parts = ["snan-hil experiment", name, f"--seed {opts.seed}"]
    if opts.trials is not None:
        parts.append(f"--trials {opts.trials}")
    if opts.plasticity != "additive":
        parts.append(f"--plasticity {opts.plasticity}")
    if opts.maze_rule != "component":
        parts.append(f"--maze-rule {opts.maze_rule}")
    if opts.route_target != "chosen":
        parts.append(f"--route-target {opts.route_target}")
    if opts.route_task != "fixed":
        parts.append(f"--route-task {opts.route_task}")
    if not opts.route_train_astro:
        parts.append("--no-route-train-astro")
    parts += [f"--set {o}" for o in opts.overrides]
    return " ".join(parts)


# ---- plotting ---------------------------------------------------------------------------
def pyplot():
    """``matplotlib.pyplot`` (Agg) for the figure modules; UserError without matplotlib."""
    return _pyplot("figures need matplotlib")


def integer_ticks(axis) -> None:
    """Ticks at whole numbers only on ``axis`` (``ax.xaxis`` / ``ax.yaxis``): for counts."""
    from matplotlib.ticker import MaxNLocator   # matplotlib (the plots extra): when drawing
    axis.set_major_locator(MaxNLocator(integer=True))


def trial_outcome(example: dict) -> str:
    """``"N steps"``, or ``"N steps, FAILED (step limit)"`` for a trial that did not arrive."""
    steps = len(example["path"]) - 1
    return f"{steps} steps" + ("" if example.get("success", True) else ", FAILED (step limit)")


def draw_trajectory(ax, rows: int, cols: int, example: dict | None, title: str) -> None:
    """Grid, walls, start (green), goals (gold stars) and the path of one trial; a failed
    trial's path is drawn in red (its title should say so: :func:`trial_outcome`)."""
    ax.set_xlim(-0.5, cols - 0.5)
    ax.set_ylim(rows - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.set_xticks([])
    ax.set_yticks([])
    for r in range(rows + 1):
        ax.plot([-0.5, cols - 0.5], [r - 0.5, r - 0.5], color="0.85", lw=0.5)
    for c in range(cols + 1):
        ax.plot([c - 0.5, c - 0.5], [-0.5, rows - 0.5], color="0.85", lw=0.5)
    ax.set_title(title, fontsize=8)
    if example is None:
        return
    for a, b in example.get("walls", []):
        (ra, ca), (rb, cb) = divmod(a, cols), divmod(b, cols)
        if ra == rb:  # vertical wall between columns
            x = max(ca, cb) - 0.5
            ax.plot([x, x], [ra - 0.5, ra + 0.5], color="k", lw=1.6)
        else:
            yv = max(ra, rb) - 0.5
            ax.plot([ca - 0.5, ca + 0.5], [yv, yv], color="k", lw=1.6)
    path = np.asarray(example["path"])
    path_r, path_c = np.divmod(path, cols)
    jit = 0.18 * (np.random.default_rng(0).random((2, path.size)) - 0.5)
    ax.plot(path_c + jit[0], path_r + jit[1], "-",
            color="tab:blue" if example.get("success", True) else "tab:red", lw=0.7, alpha=0.6)
    s = int(example["start"])
    ax.plot(s % cols, s // cols, "s", color="tab:green", ms=7)
    for g in example["goals"]:
        ax.plot(g % cols, g // cols, "*", color="gold", mec="k", ms=10)


def wall_examples_figure(examples: dict, figsize: tuple[float, float], cols: int):
    """(plt, fig, gs) of a maze figure: a 2 x ``cols`` grid whose panel row A shows one
    example trajectory on the 10x10 field per wall fraction of :data:`EXAMPLE_WALLS`, in
    ``gs[0, k]`` (``examples``: wall fraction -> example trial or missing)."""
    plt = pyplot()
    fig = plt.figure(figsize=figsize)
    gs = fig.add_gridspec(2, cols)
    for k, f in enumerate(EXAMPLE_WALLS):
        e = examples.get(f)
        draw_trajectory(fig.add_subplot(gs[0, k]), 10, 10, e,
                        f"A: {100 * f:.0f} % walls, {trial_outcome(e)}"
                        if e else f"A: {100 * f:.0f} % walls")
    return plt, fig, gs


def draw_route_hist(ax, main: dict[bool, dict[str, Any]], on: bool, bins: Any,
                    paper: dict[bool, tuple], head: str, sep: str = " ") -> None:
    """Histogram of the successful routes' lengths without/with (``on``) astrocytes, titled
    ``head`` + success rate and median, then ``sep`` and the paper's two numbers."""
    ax.hist(main[on]["steps"][main[on]["success"]], bins=bins,
            color="tab:blue" if on else "tab:red")
    s = main[on]["stats"]
    ax.set_title(f"{head}{pct(s['success_rate'])}, median {num(s['median_steps'])}{sep}"
                 f"(paper {pct(paper[on][0])}, {num(paper[on][1])})", fontsize=8)
    ax.set_xlabel("route length (steps)", fontsize=8)
    ax.set_ylabel("trials", fontsize=8)
    ax.set_xlim(float(np.min(bins)), float(np.max(bins)))
    integer_ticks(ax.xaxis)
    integer_ticks(ax.yaxis)


def save_plot(plt, fig, path, title: str) -> None:
    """Put ``title`` on top, lay out, write ``path`` (110 dpi) and close the figure."""
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
