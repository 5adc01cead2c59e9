"""The four-scenario comparison of the paper's Fig. 10C, and its speed/energy report (Fig. 10D).

:func:`run_compare`: for each weight set of a trained ``.npz``: the software launches (weights as
numbers), then the set is programmed into the chip (two-stage write-and-verify; cells already
inside their window get no stage-1 pulse) and launched on the crossbar, without and with
astrocytes. :func:`write_outputs` writes ``compare.json`` (everything: launches, seeds, config,
programming summaries, acceptance checks, speed/energy), ``launches.csv`` (one row per launch),
``summary.csv`` (one row per scenario and set), ``speed_energy.csv`` and ``fig10c.png``, each
atomically (temporary file + rename).
"""

from __future__ import annotations

import contextlib
import csv
import datetime as _dt
import io
import json
import os
import shutil
import statistics
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Protocol

import numpy as np

from snan_hil import __version__
from snan_hil.files.atomicio import (atomic_write_bytes, atomic_write_json, atomic_write_text,
                               json_default)
from snan_hil.calibration.observer import CellObserver
from snan_hil.calibration.programmer import ProgramConfig, program_weights
from snan_hil.calibration.weights_io import load_weight_set
from snan_hil.common.errors import UserError
from snan_hil.host.checkpoint import CHECKPOINT_DIR, RunFolder
from snan_hil.host.hil.config import SCENARIO_LABELS, SCENARIOS, HilConfig, paper_median
from snan_hil.host.intervals import (METHOD, flat_intervals, median_interval, paper_check,
                                     rate_interval)
from snan_hil.host.hil.report import measure_spike_geometry, speed_energy_table
from snan_hil.host.hil.runner import (ScenarioResult, check_layout, require_hardware,
                                      run_scenario)
from snan_hil.common.progress import ProgressCallback, track
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.messages import Info

RESULTS_FORMAT = "snan-hil-compare/1"
HW_TOLERANCE = 0.20          #: acceptance: hardware median within +-20 % of software


def _median(values: Sequence[float]) -> float | None:
    return float(statistics.median(values)) if values else None


def task_of(meta: dict, hil: HilConfig) -> tuple[int, int]:
    """(start, goal): from the weights file if it records them, else the HIL config."""
    return int(meta.get("start", hil.task.start)), int(meta.get("goal", hil.task.goal))


def check_weights_grid(meta: dict, hil: HilConfig, path: str) -> None:
    grid = tuple(meta["grid"])
    cfg_grid = (hil.model.grid.rows, hil.model.grid.cols)
    if grid != cfg_grid:
        raise UserError(f"{path} holds {grid[0]}x{grid[1]} weights but the config is for "
                        f"{cfg_grid[0]}x{cfg_grid[1]}; pass a matching --config")


class BoardSnapshots(Protocol):
    """What a board holds at a boundary of a run, saved and put back (the emulated chip; a
    real chip cannot be put back, so real boards have none)."""

    def save(self, dest: Path) -> None: ...

    def check(self, src: Path) -> None:
        """UserError (one line naming ``src``) unless ``src`` can be put back; changes
        nothing."""

    def restore(self, src: Path) -> None: ...


def run_compare(weights_path: str | os.PathLike, hil: HilConfig, *,
                client: BoardClient | None = None, port: str = "emu",
                layout_path: str | os.PathLike | None = None,
                sets: list[int] | None = None, launches: int = 10, seed: int = 1,
                mode: str | None = None, baud: int | None = None, program: bool = True,
                program_config: ProgramConfig | None = None,
                report_dir: str | os.PathLike | None = None,
                scenarios: tuple[str, ...] = SCENARIOS,
                progress: ProgressCallback | None = None,
                program_observer: CellObserver | None = None,
                connect: Callable[[], BoardClient] | None = None,
                checkpoint: RunFolder | None = None,
                board_snapshots: BoardSnapshots | None = None,
                protocol: str | None = None,
                board_options: str | None = None) -> dict[str, Any]:
    """Run the comparison; returns the results dict (see module doc).

    The board: ``client``, a connected client used for every set, or ``connect``, which opens
    a connected client for each set's hardware part (and the final spike measurement) and is
    closed after it — so every set starts from what the board holds, nothing else (on the
    in-process emulator: a fresh boot of the saved chip). ``layout_path`` is the chip's layout
    file; ``report_dir`` receives one programming report per set; ``program_observer`` sees
    every programming pulse and cell (:mod:`snan_hil.calibration.observer`; the chip history).
    ``mode``: how the hardware scenarios read the synapses (None: the board's default,
    :mod:`.synapses`). ``progress`` gets the task "launches" (one unit per launch, all sets and
    scenarios; sets taken from a checkpoint count as done) and each set's "programming"
    (:func:`~snan_hil.calibration.programmer.program_weights`).

    ``checkpoint`` (:func:`snan_hil.host.checkpoint.open_run`): each set is committed when it
    is finished (its launches, programming summary, software time) and taken from there when
    the run is resumed. With ``board_snapshots`` (and ``connect``) the chip and its layout are
    saved at every set boundary and put back before a resumed set is redone, so a resumed run
    gives the results of an uninterrupted one (wall times aside).

    ``protocol`` (``framed``/``legacy``, as the caller opened the board) is recorded in the
    results; ``board_options`` (the command-line options that reach the board, e.g.
    ``--port /dev/ttyUSB0 --protocol legacy``; default ``--port PORT``) go into the
    "program it first" hint of a chip that does not hold a set.
    """
    t_wall = time.perf_counter()
    weights_path = str(weights_path)
    _w0, meta0 = load_weight_set(weights_path, 0)
    n_sets = int(meta0["n_sets"])
    sets = list(range(n_sets)) if sets is None else [int(k) for k in sets]
    data = {}
    for k in sets:                                   # validate every set before any I/O
        w, meta = load_weight_set(weights_path, k)
        check_weights_grid(meta, hil, weights_path)
        data[k] = (w, meta)
    start, goal = task_of(meta0, hil)
    hw_scen = [s for s in scenarios if s.startswith("hw_")]
    sw_scen = [s for s in scenarios if s.startswith("sw_")]
    hw_mode: str | None = None
    if hw_scen:
        if (client is None and connect is None) or layout_path is None:
            raise UserError("hw scenarios need a board (--port) and a layout path")
        if client is not None:
            hw_mode = require_hardware(client, mode, hil.launch_config(False))
    if board_snapshots is not None and (checkpoint is None or connect is None):
        raise ValueError("board_snapshots need a checkpoint and connect")
    info = getattr(client, "info", None)
    results: list[ScenarioResult] = []
    programming: dict[int, dict] = {}
    bar = track(progress, "launches", len(sets) * launches * len(scenarios))
    boundary = _Boundaries(checkpoint, board_snapshots,
                           Path(layout_path) if layout_path is not None else None)

    @contextlib.contextmanager
    def board() -> Iterator[BoardClient]:
        nonlocal hw_mode
        if connect is None:
            assert client is not None
            yield client
            return
        opened = connect()
        try:
            hw_mode = require_hardware(opened, mode, hil.launch_config(False))
            yield opened
        finally:
            opened.close()

    done = {k: checkpoint.done(f"set-{k}") if checkpoint is not None else None for k in sets}
    pending = [k for k in sets if done[k] is None]
    geometry_done = checkpoint.done("geometry") if checkpoint is not None and hw_scen else None
    if hw_scen and checkpoint is not None:
        finished = [k for k in sets if done[k] is not None]
        if not checkpoint.resumed or not finished and not boundary.saved("start"):
            boundary.save("start")
        elif pending or geometry_done is None:
            # redo from the last boundary: the chip and layout as the last finished set left
            boundary.restore(f"set-{finished[-1]}" if finished else "start")
    if sw_scen and pending:          # load the compiled kernels before timing the software
        run_scenario(sw_scen[0], data[sets[0]][0], hil, launches=1, seed=seed, start=start,
                     goal=goal)
    sw_wall = 0.0
    unit_walls = 0.0
    previous = "start"
    for k in sets:
        w, meta = data[k]
        record = done[k]
        if record is not None:                       # finished before: from the checkpoint
            results += [ScenarioResult.from_dict(r) for r in record["results"]]
            if record.get("programming") is not None:
                programming[k] = record["programming"]
            sw_wall += record["sw_wall_s"]
            unit_walls += record["wall_s"]
            info_dict = record.get("board")
            bar.advance(launches * len(scenarios), f"set {k}: from the checkpoint")
            previous = f"set-{k}"
            if info_dict is not None and info is None:
                info = _InfoView(info_dict)
            if hw_mode is None and record.get("mode") is not None:
                hw_mode = record["mode"]
            continue
        t_set = time.perf_counter()
        set_results: list[ScenarioResult] = []
        for s in sw_scen:
            set_results.append(run_scenario(s, w, hil, set_index=k, launches=launches,
                                            seed=seed, start=start, goal=goal,
                                            progress=bar.nested(f"set {k} {s} ")))
        set_sw = time.perf_counter() - t_set
        summ = None
        if hw_scen:
            from snan_hil.calibration.layout import Layout
            assert layout_path is not None                 # checked above
            with board() as c:
                info = c.info or info
                if program:
                    bar.advance(0, f"programming set {k}")
                    report_path = (Path(report_dir) / f"program-set{k}.json") if report_dir \
                        else None
                    pr = program_weights(c, w, meta, layout_path=layout_path,
                                         config=program_config, port=port,
                                         report_path=report_path, progress=progress,
                                         observer=program_observer)
                    layout = pr.layout
                    summ = dict(pr.report["summary"])
                    summ["all_ok"] = pr.all_ok
                    programming[k] = summ
                else:
                    layout = Layout.load(layout_path)
                check_layout(layout, w, tuple(meta["grid"]), port=port,
                             weights_path=weights_path, set_index=k,
                             board_options=board_options)
                for s in hw_scen:
                    set_results.append(run_scenario(s, w, hil, set_index=k, launches=launches,
                                                    seed=seed, start=start, goal=goal, client=c,
                                                    layout=layout, mode=hw_mode, baud=baud,
                                                    progress=bar.nested(f"set {k} {s} ")))
        results += set_results
        sw_wall += set_sw
        wall = time.perf_counter() - t_set
        unit_walls += wall
        if checkpoint is not None:
            if hw_scen:
                boundary.save(f"set-{k}")
            checkpoint.commit(f"set-{k}", {
                "results": [r.to_dict() for r in set_results], "programming": summ,
                "sw_wall_s": set_sw, "wall_s": wall,
                "board": _info_dict(info) if hw_scen else None,
                "mode": hw_mode if hw_scen else None})
            if hw_scen:
                boundary.drop(previous)
            previous = f"set-{k}"
    geometry = None
    if hw_scen:
        if geometry_done is not None:
            geometry = geometry_done.get("geometry")
        else:
            t_geo = time.perf_counter()
            with board() as c:
                info = c.info or info
                row_code = (c.info or Info()).read_code
                if layout_path is not None and Path(layout_path).is_file():
                    from snan_hil.calibration.layout import Layout
                    chain = Layout.load(layout_path).read_chain
                    row_code = chain.read_code if chain is not None else row_code
                geometry = measure_spike_geometry(c, row_code=row_code, baud=baud)
            unit_walls += time.perf_counter() - t_geo
            if checkpoint is not None:
                checkpoint.commit("geometry", {"geometry": geometry})
    out = summarize(results, hil, sets=sets, launches=launches, seed=seed, start=start,
                    goal=goal, scenarios=scenarios)
    sw_dec = sum(r.decisions for sr in results if sr.scenario.startswith("sw_")
                 for r in sr.launches)
    hw_stats = hw_totals(results, baud)
    if hw_stats and info is not None:
        hw_stats["conversion_us"] = float(info.conversion_us)
    out["speed_energy"] = speed_energy_table(
        hil.model.n_cells, hw=hw_stats or None, geometry=geometry,
        sw={"decisions": sw_dec, "wall_s": sw_wall} if sw_dec else None)
    out.update({
        "format": RESULTS_FORMAT, "snan_hil_version": __version__,
        "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "weights": {"path": weights_path, "n_sets": n_sets,
                    "set_seeds": meta0.get("seeds"), "cycles": meta0.get("cycles"),
                    "fingerprints": {str(k): r.fingerprint for r in results
                                     for k in [r.set_index]}},
        "port": port if hw_scen else None, "protocol": protocol if hw_scen else None,
        "mode": hw_mode if hw_scen else None,
        "baud": baud if hw_scen else None,
        "board": ({"board_id": info.board_id, "firmware_version": info.firmware_version}
                  if info is not None and hw_scen else None),
        "programming": {str(k): v for k, v in programming.items()},
        "config": hil.to_dict(),
        "wall_s": (unit_walls if checkpoint is not None and checkpoint.resumed
                   else time.perf_counter() - t_wall),
        "resumed": bool(checkpoint is not None and checkpoint.resumed),
    })
    return out


def check_snapshots(out: Path, board: BoardSnapshots | None) -> None:
    """Check every chip and layout snapshot of the checkpoint in ``out`` (a resumed run puts
    one of them back) before the board is opened: UserError (one line naming the damaged
    file) changes nothing."""
    folder = Path(out) / CHECKPOINT_DIR
    if not folder.is_dir():
        return
    for path in sorted(folder.glob("board-*")):
        if board is not None and not path.name.startswith("."):
            board.check(path)
    for path in sorted(folder.glob("layout-*.json")):
        _check_layout_snapshot(path)


def _check_layout_snapshot(path: Path) -> None:
    """UserError (one line naming ``path``) unless it holds a valid layout."""
    from snan_hil.calibration.layout import Layout, LayoutError
    try:
        Layout.from_dict(json.loads(path.read_text(encoding="utf-8")), "snapshot")
    except (OSError, ValueError, AttributeError, LayoutError) as exc:
        reason = str(exc) if isinstance(exc, LayoutError) else f"{type(exc).__name__}: {exc}"
        raise UserError(f"--resume: the layout snapshot {path} in the checkpoint is damaged "
                        f"({reason}); the live layout was left untouched; start the run again "
                        "in a new --out") from None


@dataclass(frozen=True)
class _InfoView:
    """board_id / firmware_version of a board recorded in a checkpoint."""

    d: dict

    @property
    def board_id(self) -> str:
        return str(self.d.get("board_id", ""))

    @property
    def firmware_version(self) -> str:
        return str(self.d.get("firmware_version", ""))

    @property
    def conversion_us(self) -> float:
        return float(self.d.get("conversion_us") or Info().conversion_us)


def _info_dict(info: Any) -> dict[str, str] | None:
    if info is None:
        return None
    return {"board_id": info.board_id, "firmware_version": info.firmware_version,
            "conversion_us": float(info.conversion_us)}


class _Boundaries:
    """Snapshots of the board and the layout file at the set boundaries of a checkpointed run
    (``board-<tag>`` via :class:`BoardSnapshots`, ``layout-<tag>.json`` a copy of the layout,
    ``layout-<tag>.absent`` when there was none)."""

    def __init__(self, checkpoint: RunFolder | None, board: BoardSnapshots | None,
                 layout_path: Path | None):
        self.checkpoint, self.board, self.layout_path = checkpoint, board, layout_path

    def _paths(self, tag: str) -> tuple[Path, Path, Path]:
        assert self.checkpoint is not None
        cp = self.checkpoint
        return cp.path(f"board-{tag}"), cp.path(f"layout-{tag}.json"), \
            cp.path(f"layout-{tag}.absent")

    def saved(self, tag: str) -> bool:
        if self.checkpoint is None:
            return False
        _b, layout, absent = self._paths(tag)
        return layout.exists() or absent.exists()

    def save(self, tag: str) -> None:
        if self.checkpoint is None:
            return
        board, layout, absent = self._paths(tag)
        if self.board is not None:
            self.board.save(board)
        if self.layout_path is not None and self.layout_path.is_file():
            atomic_write_bytes(layout, self.layout_path.read_bytes())
            absent.unlink(missing_ok=True)
        else:
            atomic_write_text(absent, "no layout at this boundary\n")
            layout.unlink(missing_ok=True)

    def restore(self, tag: str) -> None:
        if self.checkpoint is None:
            return
        board, layout, absent = self._paths(tag)
        if not (layout.exists() or absent.exists()):
            raise UserError(f"--resume: the checkpoint in {self.checkpoint.out} lacks the "
                            f"layout snapshot {layout.name}; start a new run in another --out")
        # every snapshot is checked before anything is put back: a damaged checkpoint
        # leaves the live chip and layout as they are
        if self.board is not None:
            self.board.check(board)
        if self.layout_path is not None and layout.exists():
            _check_layout_snapshot(layout)
        if self.board is not None:
            self.board.restore(board)
        if self.layout_path is not None:
            if layout.exists():
                atomic_write_bytes(self.layout_path, layout.read_bytes())
            else:
                self.layout_path.unlink(missing_ok=True)

    def drop(self, tag: str) -> None:
        if self.checkpoint is None:
            return
        for p in self._paths(tag):
            if p.is_dir():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink(missing_ok=True)


WALL_TIME_KEYS = ("wall_s", "decisions_per_s")
"""Keys of measured wall time (anywhere in the results): they differ from run to run."""


def without_wall_times(results: dict[str, Any]) -> dict[str, Any]:
    """The results without what measures this computer's wall time (every ``wall_s`` and
    ``decisions_per_s``, the speed rows measured on this machine) or when and how the run
    happened (``created``, ``resumed``, ``files``): what two runs with the same seed on equal
    chips must give identically (board times and energy included)."""
    def strip(v: Any) -> Any:
        if isinstance(v, dict):
            return {k: strip(x) for k, x in v.items() if k not in WALL_TIME_KEYS}
        if isinstance(v, list):
            return [strip(x) for x in v]
        return v
    out = strip(json.loads(json.dumps(results, default=json_default)))
    for key in ("created", "resumed", "files"):
        out.pop(key, None)
    se = out.get("speed_energy")
    if se:
        se["rows"] = [r for r in se["rows"] if r.get("source") != "measured (this machine)"]
        se.get("measured_inputs", {}).pop("sw", None)
    return out


def hw_totals(results: list[ScenarioResult], baud: int | None) -> dict[str, Any]:
    """Totals of the hardware launches of ``results`` (decisions, spikes, requests, wall_s,
    virtual_us, wire_us, energy_j; the time and energy ones None unless every launch has
    them) at line rate ``baud``: the ``hw`` input of
    :func:`~snan_hil.host.hil.report.speed_energy_table`. Empty without hardware launches."""
    launches = [r for sr in results if sr.scenario.startswith("hw_") for r in sr.launches]
    if not launches:
        return {}
    have_clock = all(r.virtual_us is not None for r in launches)
    have_wire = all(r.wire_us is not None for r in launches)
    return {"decisions": sum(r.decisions for r in launches),
            "spikes": sum(r.spikes for r in launches),
            "requests": sum(r.requests for r in launches),
            "wall_s": sum(r.wall_s for r in launches),
            "virtual_us": sum(r.virtual_us for r in launches) if have_clock else None,
            "wire_us": sum(r.wire_us for r in launches) if have_wire else None,
            "energy_j": sum(r.energy_j for r in launches) if have_clock else None,
            "baud": baud,
            "mode": next((sr.mode for sr in results if sr.scenario.startswith("hw_") and sr.mode),
                         None)}


def summarize(results: list[ScenarioResult], hil: HilConfig, *, sets: list[int], launches: int,
              seed: int, start: int, goal: int,
              scenarios: tuple[str, ...] = SCENARIOS) -> dict[str, Any]:
    """Per scenario (all sets pooled) and per scenario x set: medians (of successful launches)
    and success rates with their 95 % intervals (``success_rate_ci`` Wilson,
    ``median_steps_ci`` / ``median_steps_all_ci`` bootstrap seeded by ``seed``,
    ``ci_method``), the paper's median (14 / 7 steps) and whether it lies inside
    (``paper_inside``, ``paper_distance`` in steps); the acceptance checks."""
    per_set = [r.summary() for r in results]
    scen: dict[str, Any] = {}
    for s in scenarios:
        rs = [r for r in results if r.scenario == s]
        lengths = [L.steps for r in rs for L in r.launches]
        ok = [L.steps for r in rs for L in r.launches if L.success]
        n = len(lengths)
        set_medians = [r.median_steps for r in rs if r.median_steps is not None]
        dec = sum(L.decisions for r in rs for L in r.launches)
        wall = sum(L.wall_s for r in rs for L in r.launches)
        med_ci = median_interval(ok, seed=seed)
        scen[s] = {"label": SCENARIO_LABELS[s], "launches": n,
                   "median_steps": _median(ok), "success_rate": len(ok) / n if n else 0.0,
                   "success_rate_ci": rate_interval(len(ok), n),
                   "median_steps_ci": list(med_ci) if med_ci else None,
                   "median_steps_all_ci": _ci(median_interval(lengths, seed=seed)),
                   "ci_method": METHOD, "paper_median_steps": paper_median(s),
                   **paper_check(paper_median(s), med_ci),
                   "mean_steps": float(np.mean(ok)) if ok else None,
                   "median_of_set_medians": _median(set_medians),
                   "median_steps_all": _median(lengths), "decisions": dec, "wall_s": wall,
                   "decisions_per_s": dec / wall if wall > 0 else None}
    return {"grid": [hil.model.grid.rows, hil.model.grid.cols], "start": start, "goal": goal,
            "step_limit": hil.model.grid.max_steps, "sets": sets, "launches": launches,
            "seed": seed, "scenarios": scen, "per_set": per_set,
            "launch_rows": [dict(scenario=r.scenario, set=r.set_index, **L.to_dict())
                            for r in results for L in r.launches],
            "acceptance": acceptance(scen)}


def _ci(interval: tuple[float, float] | None) -> list[float] | None:
    return list(interval) if interval else None


def acceptance(scen: dict[str, Any]) -> dict[str, Any]:
    """The issue's checks: astrocytes shorten the median (sw and hw); hw within +-20 % of sw.

    On the median of the successful launches (``median_steps``, the project's convention) and,
    suffixed ``_all``, on the median of all launches with a failure counted at the step limit
    (``median_steps_all``). ``<impl>_astro_shortens_ci<suffix>``: the shortening is beyond
    the 95 % intervals (the interval with astrocytes lies wholly below the one without; None
    without intervals). ``paper_inside_<scenario>``: the paper's median (14 / 7 steps) lies
    inside that scenario's 95 % interval of the median of successful launches."""
    out: dict[str, Any] = {}
    for key, suffix in (("median_steps", ""), ("median_steps_all", "_all")):
        def med(s: str, key: str = key) -> Any:
            return scen.get(s, {}).get(key)
        for impl in ("sw", "hw"):
            a, b = med(f"{impl}_astro"), med(f"{impl}_noastro")
            out[f"{impl}_astro_shortens{suffix}"] = None if a is None or b is None else a < b
            ca, cb = med(f"{impl}_astro", f"{key}_ci"), med(f"{impl}_noastro", f"{key}_ci")
            out[f"{impl}_astro_shortens_ci{suffix}"] = (None if ca is None or cb is None
                                                        else ca[1] < cb[0])
        for astro in ("noastro", "astro"):
            sw, hw = med(f"sw_{astro}"), med(f"hw_{astro}")
            ok = sw is not None and hw is not None and sw > 0
            out[f"hw_vs_sw_{astro}{suffix}"] = hw / sw - 1.0 if ok else None
            out[f"hw_within_20pct_{astro}{suffix}"] = (abs(hw / sw - 1.0) <= HW_TOLERANCE
                                                       if ok else None)
    for s, v in scen.items():
        if "paper_inside" in v:
            out[f"paper_inside_{s}"] = v["paper_inside"]
    return out


# ---- outputs -------------------------------------------------------------------------------
def _csv(rows: list[dict], columns: list[str]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({c: ("" if r.get(c) is None else r.get(c)) for c in columns})
    return buf.getvalue()


LAUNCH_COLUMNS = ["scenario", "set", "launch", "trial", "steps", "success", "decisions",
                  "spikes", "requests", "virtual_us", "wire_us", "energy_j", "wall_s"]
#: summary.csv columns before the 95 % intervals were added (still recognised as ours)
SUMMARY_COLUMNS_V1 = ["scenario", "set", "seed", "launches", "median_steps", "success_rate",
                      "fingerprint", "mode"]
SUMMARY_COLUMNS = [*SUMMARY_COLUMNS_V1, "success_rate_ci_low", "success_rate_ci_high",
                   "median_steps_ci_low", "median_steps_ci_high", "ci_method"]
SPEED_COLUMNS = ["implementation", "source", "time_per_decision_us", "energy_per_decision_j",
                 "area_mm2", "norm_speed_per_us_mm2", "speed_vs_cpu", "energy_gain_vs_cpu",
                 "method"]


def write_outputs(results: dict[str, Any], out_dir: str | os.PathLike, *,
                  figure: bool = True) -> dict[str, str]:
    """Write the result files (atomically); returns {kind: path}."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths: dict[str, str] = {}
    paths["launches_csv"] = str(atomic_write_text(out / "launches.csv",
                                                  _csv(results["launch_rows"], LAUNCH_COLUMNS)))
    paths["summary_csv"] = str(atomic_write_text(
        out / "summary.csv", _csv([flat_intervals(r) for r in results["per_set"]],
                                  SUMMARY_COLUMNS)))
    paths["speed_energy_csv"] = str(atomic_write_text(
        out / "speed_energy.csv", _csv(results["speed_energy"]["rows"], SPEED_COLUMNS)))
    if figure:
        from snan_hil.host.hil.figure import plot_compare
        paths["figure"] = str(plot_compare(results, out / "fig10c.png"))
    paths["json"] = str(out / "compare.json")
    results["files"] = dict(paths)
    atomic_write_json(out / "compare.json", results, indent=1, allow_nan=False)
    return paths
