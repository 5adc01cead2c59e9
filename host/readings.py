"""Paper fidelity by search: the readings of the model's open points, run on every headline
condition of the paper and ranked by one distance to all of the paper's numbers at once
(``snan-hil readings``, docs/model.md "Readings sweep").

A *reading* is a set of config overrides (dotted keys of :class:`SnanConfig`, plus the
pseudo-key ``astro.tau_ca_unit`` = ``s`` | ``ms``: the condition's own τ_Ca read in seconds,
or the same number read in milliseconds). ``--vary KEY=V1,V2`` gives the values of a key; the
sweep is the cross product of all keys.

Every reading runs on the *units* of :data:`UNITS`, each a piece of the paper's work that
yields one or more *conditions* (the 3x3 and 10x10 open grids with and without astrocytes,
Fig. 3/4; 10x10 mazes at 20/40/60 % walls with and without, Fig. 5; route learning on 10x10,
tests at cycles 0 and 20, Fig. 7; the 6x6 hardware task's software scenarios, Fig. 10C).
A condition's numbers are its success rate and the median path of its successful trials,
each with a 95 % interval (:mod:`snan_hil.host.intervals`).

The paper's numbers are the *targets* (``configs/paper-targets.yaml``). The distance of a
reading is (:func:`distance`)::

    D = sum over success-rate targets of |success - paper| / 0.07
      + sum over median targets of |ln(median / paper)| / ln(1.25)

(7 points of success rate, or a factor 1.25 in median path, count 1; a paper range counts 0
inside it; a condition where no trial succeeded counts its median at the step limit).

Results are cached by (unit, resolved config, trials, seed, model fingerprint)
(:class:`ResultCache`, SQLite), so an extended sweep reuses what was run and a change of the
model's code or of a default reruns what it affects.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import logging
import math
import sqlite3
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from snan_hil.common.version import __version__
from snan_hil.config import loader as configio
from snan_hil.config.loader import ConfigError
from snan_hil.common.errors import UserError
from snan_hil.host import intervals
from snan_hil.host.config import RENAMED, SnanConfig, apply_overrides, load_config
from snan_hil.host.experiments.executor import Task
from snan_hil.host.hil.config import HilConfig, load_hil_config
from snan_hil.host import readings_stats as stats
# the units live in readings_units (the model fingerprint covers it); these names stay here
from snan_hil.host.readings_units import (  # noqa: F401 (re-exported)
    HIL_LAUNCHES_PER_SEED, ROUTE_SESSIONS_PER_TRIAL, UNITS, Unit, cluster_size, hil_base_seeds,
    merge_results, route_sessions, run_unit)

log = logging.getLogger(__name__)

RESULTS_FORMAT = "snan-hil-readings/1"
#: pseudo-key: the unit of τ_Ca (the condition's value read in s, or the same number in ms)
TAU_UNIT_KEY = "astro.tau_ca_unit"
TAU_UNITS = ("s", "ms")
#: keys a reading may not set: they define the conditions the paper's numbers belong to
#: (grid size and step limit, astrocytes on/off per condition, walls, the task)
FIXED_KEYS = ("grid.", "astro.enabled", "name")
#: combinations a sweep may have without ``--yes``
MAX_COMBINATIONS = 64
#: success-rate points (fraction) and median factor that count one unit of distance
SUCCESS_SCALE = 0.07
MEDIAN_SCALE = math.log(1.25)
DEFAULT_TARGETS = Path(__file__).resolve().parent.parent / "configs" / "paper-targets.yaml"
#: the files whose contents define the model's results (a change invalidates the cache)
#: (the scoring, racing and reports are not among them: changing those reruns nothing)
_MODEL_FILES = ("host/snan_kernel.py", "host/kernel_params.py", "host/experiments/trials.py",
                "host/experiments/route.py", "host/experiments/mazes.py", "host/state.py",
                "host/rng.py", "host/grid.py", "host/agent.py", "host/hil/train.py",
                "host/hil/runner.py", "host/hil/study.py", "host/config.py",
                "host/readings_units.py", "crossbar_model/vteam.py",
                "crossbar_model/vteam_stdp.py")


# ---- units and conditions: host/readings_units.py (UNITS, Unit, run_unit, ... re-exported) ---


# ---- targets ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class Target:
    """One of the paper's numbers: ``quantity`` (``success_rate`` as a fraction, or
    ``median_steps``) of ``condition``; ``paper`` a value or a ``[low, high]`` range the
    paper states; ``source`` where the paper says it."""

    condition: str
    quantity: str
    paper: float | tuple[float, float]
    source: str = ""


def load_targets(path: str | Path | None = None) -> list[Target]:
    """Targets of ``path`` (default ``configs/paper-targets.yaml``). Raises
    :class:`ConfigError` (one line) for an unreadable file, an unknown condition or
    quantity, or a malformed value."""
    p = Path(path) if path is not None else DEFAULT_TARGETS
    data = configio.read_yaml(p)
    if not isinstance(data, dict) or not isinstance(data.get("targets"), list):
        raise ConfigError(f"targets file {p}: needs a 'targets:' list (see {DEFAULT_TARGETS})")
    known = {c for u in UNITS.values() for c in u.conditions}
    out: list[Target] = []
    for i, t in enumerate(data["targets"]):
        where = f"targets file {p}: entry {i + 1}"
        if not isinstance(t, dict) or set(t) - {"condition", "quantity", "paper", "source"}:
            raise ConfigError(f"{where}: needs condition, quantity, paper (and source) only")
        cond, qty, paper = t.get("condition"), t.get("quantity"), t.get("paper")
        if cond not in known:
            raise ConfigError(f"{where}: unknown condition {cond!r}; known: "
                              f"{', '.join(sorted(known))}")
        if qty not in ("success_rate", "median_steps"):
            raise ConfigError(f"{where}: quantity must be success_rate or median_steps")
        value: float | tuple[float, float]
        if isinstance(paper, (int, float)) and not isinstance(paper, bool):
            value = float(paper)
        elif (isinstance(paper, list) and len(paper) == 2
              and all(isinstance(v, (int, float)) for v in paper) and paper[0] <= paper[1]):
            value = (float(paper[0]), float(paper[1]))
        else:
            raise ConfigError(f"{where}: paper must be a number or [low, high]")
        vals = value if isinstance(value, tuple) else (value,)
        if not all(math.isfinite(v) for v in vals):
            raise ConfigError(f"{where}: paper must be a finite number")
        if qty == "median_steps" and min(vals) <= 0:
            raise ConfigError(f"{where}: a median must be > 0")
        if qty == "success_rate" and not all(0.0 <= v <= 1.0 for v in vals):
            raise ConfigError(f"{where}: a success rate is a fraction 0..1 (63.1 % = 0.631)")
        if any(o.condition == cond and o.quantity == qty for o in out):
            raise ConfigError(f"{where}: {cond} {qty} is already a target; give each once")
        out.append(Target(cond, qty, value, str(t.get("source", ""))))
    if not out:
        raise ConfigError(f"targets file {p}: no targets")
    return out


def units_for(targets: Sequence[Target]) -> list[Unit]:
    """The units whose conditions the targets name, in :data:`UNITS` order."""
    wanted = {t.condition for t in targets}
    return [u for u in UNITS.values() if wanted & set(u.conditions)]


# ---- readings ---------------------------------------------------------------------------------
Reading = dict[str, Any]


def parse_vary(texts: Sequence[str]) -> dict[str, list[Any]]:
    """``["KEY=V1,V2", ...]`` -> ``{key: [typed values]}``; each value checked against the
    config (type, allowed values) through a 3x3 and a 10x10 preset. Raises
    :class:`UserError` (one line): malformed text, unknown key or value, a key twice, a
    value twice, an empty value list."""
    out: dict[str, list[Any]] = {}
    for text in texts:
        key, sep, values = text.partition("=")
        key = key.strip()
        if not sep or not key:
            raise UserError(f"--vary {text!r}: write KEY=V1,V2,... (e.g. synapse.w_inh=5,10,50)")
        if key in out:
            raise UserError(f"--vary names {key} twice: give all its values in one --vary")
        check_reading_key(key, "--vary")
        raw = [v.strip() for v in values.split(",")]
        if not raw or any(v == "" for v in raw):
            raise UserError(f"--vary {text!r}: empty value; write KEY=V1,V2,...")
        if key == TAU_UNIT_KEY:
            bad = [v for v in raw if v not in TAU_UNITS]
            if bad:
                raise UserError(f"--vary {key}: unknown value {bad[0]!r}; choose s or ms")
            _once(key, raw, raw)
            out[key] = raw
            continue
        typed = []
        for v in raw:
            try:
                parsed = configio.parse_assignments(SnanConfig, [f"{key}={v}"],
                                                    option="--vary", renamed=RENAMED)
                for preset in ("snan-3x3", "snan-10x10"):
                    load_config(preset=preset, overrides=parsed)
            except (ConfigError, UserError) as exc:
                text = str(exc)
                prefix = f"--vary {key}={v}: "
                raise UserError(text if text.startswith(prefix) else prefix + text) from None
            (k2, val), = parsed.items()
            key = k2
            typed.append(val)
        _once(key, raw, typed)
        out[key] = typed
    return out


def _once(key: str, raw: Sequence[str], typed: Sequence[Any]) -> None:
    """UserError (one line) when two values of one ``--vary`` are the same value (``20,20``,
    ``20,2e1``): the sweep would run that reading twice."""
    for i, v in enumerate(typed):
        for j in range(i):
            if typed[j] == v:
                same = "" if raw[i] == raw[j] else f" (as {raw[i]!r})"
                raise UserError(f"--vary {key}: the value {raw[j]} is given twice{same}; give "
                                "each value once")


def best_of(docs: Sequence[tuple[str, Mapping[str, Any]]], n: int) -> list[Reading]:
    """The ``n`` best readings (lowest distance) over earlier sweeps' result documents
    (``[(path, document)]``), each with its sweep's ``--set`` values folded in (the varied
    keys win), duplicates kept once. Raises :class:`UserError` for a document that is not a
    readings result, or when the documents were scored against different targets, trial
    counts or seeds (their distances would not compare)."""
    if n < 1:
        raise UserError(f"--best must be >= 1, got {n}")
    rows: list[tuple[float, Reading]] = []
    basis = None
    for path, doc in docs:
        if not isinstance(doc, Mapping) or doc.get("format") != RESULTS_FORMAT:
            raise UserError(f"--from {path}: not a 'snan-hil readings' result "
                            "(readings.json of an earlier sweep)")
        b = (json.dumps(doc.get("targets"), sort_keys=True), doc.get("trials"), doc.get("seed"))
        if basis is not None and b != basis:
            raise UserError(f"--from {path}: scored against other targets, trials or seed "
                            "than the first --from; give sweeps that compare")
        basis = b
        base = configio.parse_assignments(SnanConfig, doc.get("set") or [], renamed=RENAMED)
        for r in doc.get("rows", []):
            rows.append((float(r["distance"]), {**base, **r["reading"]}))
    rows.sort(key=lambda dr: dr[0])
    out: list[Reading] = []
    seen: set[str] = set()
    for _d, reading in rows:
        same = _resolved(reading)     # readings that spell the same configs run once
        if same not in seen:
            seen.add(same)
            out.append(reading)
        if len(out) == n:
            break
    return out


def _resolved(reading: Reading) -> str:
    """Text of the configs ``reading`` gives every unit (equal text = the same reading)."""
    return json.dumps([_config_dict(unit_config(u, reading)) for u in UNITS.values()],
                      sort_keys=True, default=str)


def varied_keys(readings: Sequence[Reading]) -> dict[str, list[Any]]:
    """Every key of ``readings`` with its values in first-seen order (the ``vary`` of an
    explicit list of readings)."""
    out: dict[str, list[Any]] = {}
    for r in readings:
        for k, v in r.items():
            vals = out.setdefault(k, [])
            if v not in vals:
                vals.append(v)
    return out


def check_reading_key(key: str, option: str) -> None:
    """UserError when ``key`` defines a condition rather than a reading (:data:`FIXED_KEYS`:
    the grid, the astrocyte switch the conditions set, the preset name)."""
    if any(key == k or (k.endswith(".") and key.startswith(k)) for k in FIXED_KEYS):
        raise UserError(f"{option} {key}: defines the conditions the paper's numbers belong to "
                        "(grid size, step limit, walls, astrocytes on/off, name), so it cannot be "
                        "a reading; vary a model option instead")


def combinations(vary: Mapping[str, Sequence[Any]]) -> list[Reading]:
    """The cross product of ``vary`` in order (the first key varies slowest); ``[{}]`` (the
    defaults alone) when nothing varies."""
    keys = list(vary)
    return [dict(zip(keys, vals)) for vals in itertools.product(*(vary[k] for k in keys))]


def reading_label(reading: Reading) -> str:
    """``key=value, ...`` (``defaults`` for the empty reading)."""
    return ", ".join(f"{k}={_fmt(v)}" for k, v in reading.items()) or "defaults"


def _fmt(v: Any) -> str:
    if isinstance(v, bool):
        return str(v).lower()
    return str(v)


def _split(reading: Reading) -> tuple[dict[str, Any], str]:
    sets = {k: v for k, v in reading.items() if k != TAU_UNIT_KEY}
    return sets, str(reading.get(TAU_UNIT_KEY, "s"))


def unit_config(unit: Unit, reading: Reading) -> SnanConfig | HilConfig:
    """The config ``unit`` runs under ``reading`` (astrocytes as the unit says; for the 6x6
    task the HIL config with the reading applied to its model). Raises ConfigError."""
    sets, tau_unit = _split(reading)
    if unit.kind == "hil":
        hil = load_hil_config(overrides=sets)
        if tau_unit == "ms":
            model = apply_overrides(hil.model,
                                    {"astro.tau_ca_s": hil.model.astro.tau_ca_s / 1000.0})
            hil = dataclasses.replace(hil, model=model)
        return hil
    cfg = load_config(preset=unit.preset, overrides=sets)
    if tau_unit == "ms":
        cfg = apply_overrides(cfg, {"astro.tau_ca_s": cfg.astro.tau_ca_s / 1000.0})
    cfg = cfg.replace(**{"astro.enabled": unit.astro})
    if unit.kind == "nav" and cfg.stdp.mode == "trial_end":
        # independent trials discard their learned weights: a trial_end update never acts
        # (trials.prepare(learn=False) runs them with STDP off), so pairing and target cannot
        # change a result; one canonical config lets such readings share a cached result
        cfg = cfg.replace(**{"stdp.mode": "off", "stdp.pairing": "all_to_all",
                             "stdp.target": "all"})
    if unit.kind == "nav" and not unit.astro:
        cfg = _canonical_without_astrocytes(cfg, load_config(preset=unit.preset))
    return cfg


def _canonical_without_astrocytes(cfg: SnanConfig, preset: SnanConfig) -> SnanConfig:
    """The same trials under one config, so readings that cannot differ share a result:

    * astrocytes off: no astrocyte parameter is read (the kernel skips the astrocytes and the
      interneuron threshold stays ``v_thr*``), so the astrocyte section is the preset's;
    * and membrane potentials reset every window: a candidate's interneuron then only sees its
      bias from ``v_rest`` on, which never crosses ``v_thr*`` when
      ``v_rest + R*I_bias/(1 - alpha) <= v_thr*`` (3.01 < 7 in Table tab_1); the occupied
      cell's interneuron inhibits the occupied cell's own motor neuron, never a candidate, and
      is reset before that cell can become one. So ``w_inh`` cannot act: it is the preset's.

    ``tests/agent/test_readings.py`` checks both on trials."""
    cfg = cfg.replace(**{f"astro.{k}": v for k, v in dataclasses.asdict(preset.astro).items()
                         if k != "enabled"})
    n = cfg.neuron
    alpha = math.exp(-cfg.input.dt_ms / n.tau_m_ms)
    bias_limit = n.v_rest + n.r_m * n.i_bias / (1.0 - alpha)
    if n.reset_each_window and bias_limit <= n.v_thr_inter:
        cfg = cfg.replace(**{"synapse.w_inh": preset.synapse.w_inh})
    return cfg


def _config_dict(cfg: SnanConfig | HilConfig) -> dict[str, Any]:
    d = cfg.to_dict()
    if isinstance(cfg, HilConfig):
        d.pop("source", None)       # where it was read from
        d.pop("overrides", None)    # how it was spelled: the model holds their effect
    return d


def model_fingerprint() -> str:
    """SHA-256 (16 hex) of the package version and the source of the files that define the
    model's results (:data:`_MODEL_FILES`)."""
    h = hashlib.sha256(__version__.encode())
    root = Path(__file__).resolve().parent.parent
    for name in _MODEL_FILES:
        p = root / name
        h.update(name.encode())
        h.update(p.read_bytes() if p.is_file() else b"-")
    return h.hexdigest()[:16]


def cache_key(unit: Unit, cfg: SnanConfig | HilConfig, trials: int, seed: int,
              fingerprint: str, lo: int = 0) -> str:
    """Key of a unit's result over the trials ``[lo, trials)``: (unit, resolved config,
    trial range, seed, model fingerprint)."""
    text = json.dumps({"unit": unit.name, "config": _config_dict(cfg),
                       "trials": [int(lo), int(trials)], "seed": int(seed),
                       "model": fingerprint}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


# ---- scoring ----------------------------------------------------------------------------------
def condition_stats(data: Mapping[str, Any], seed: int = 0) -> dict[str, Any]:
    """Success rate, median of successful paths (None if none), trials, and their 95 %
    intervals (:func:`snan_hil.host.intervals.interval_fields`)."""
    steps = np.asarray(data["steps"], dtype=np.int64)
    ok = np.asarray(data["success"], dtype=bool)
    med = float(np.median(steps[ok])) if ok.any() else None
    return {"trials": int(ok.size), "success_rate": float(ok.mean()) if ok.size else 0.0,
            "median_steps": med, "max_steps": int(data.get("max_steps", 0)),
            **intervals.interval_fields(steps, ok, seed=seed)}


def target_distance(t: Target, st: Mapping[str, Any]) -> float:
    """Distance of one condition's statistics to one target (module doc)."""
    if t.quantity == "success_rate":
        v = float(st["success_rate"])
        lo, hi = t.paper if isinstance(t.paper, tuple) else (t.paper, t.paper)
        gap = lo - v if v < lo else (v - hi if v > hi else 0.0)
        return gap / SUCCESS_SCALE
    med = st["median_steps"]
    if med is None:
        med = float(max(st.get("max_steps") or 1, 1))
    lo, hi = t.paper if isinstance(t.paper, tuple) else (t.paper, t.paper)
    if lo <= med <= hi:
        return 0.0
    ref = lo if med < lo else hi
    return abs(math.log(float(med) / ref)) / MEDIAN_SCALE


def distance(targets: Sequence[Target], stats: Mapping[str, Mapping[str, Any]]
             ) -> tuple[float, list[float]]:
    """(total distance, per-target distances in ``targets`` order)."""
    parts = [target_distance(t, stats[t.condition]) for t in targets]
    return float(sum(parts)), parts


# ---- cache ------------------------------------------------------------------------------------
class ResultCache:
    """Unit results by :func:`cache_key` in an SQLite file (WAL; safe for one writer and
    readers). ``path`` None: no cache (every unit runs)."""

    def __init__(self, path: str | Path | None) -> None:
        self.path = Path(path) if path is not None else None
        self._db: sqlite3.Connection | None = None
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            try:
                self._db = sqlite3.connect(self.path)
                self._db.execute("PRAGMA journal_mode=WAL")
                self._db.execute("CREATE TABLE IF NOT EXISTS unit_results (key TEXT PRIMARY KEY,"
                                 " unit TEXT, reading TEXT, trials INTEGER, seed INTEGER,"
                                 " model TEXT, created REAL, result TEXT)")
                self._db.commit()
                problem = [line for r in self._db.execute("PRAGMA quick_check(1)")
                           for line in str(r[0]).splitlines()
                           if line.strip() and line != "ok" and not line.startswith("***")]
                if problem:
                    raise sqlite3.DatabaseError(problem[0])
            except sqlite3.DatabaseError as exc:
                self.close()
                raise self._damaged(exc) from None

    def _damaged(self, exc: sqlite3.DatabaseError) -> UserError:
        """One line for a cache SQLite cannot use (damaged, not a cache)."""
        return UserError(f"--cache {self.path}: the readings cache cannot be used (SQLite: "
                         f"{exc}); it holds only results that can be computed again: delete "
                         "it or give another --cache FILE (or --no-cache)")

    @staticmethod
    def owns(path: Path) -> bool:
        """True when ``path`` is an SQLite file holding this cache's table."""
        try:
            with path.open("rb") as f:
                if f.read(16) != b"SQLite format 3\x00":
                    return False
            db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
            try:
                row = db.execute("SELECT name FROM sqlite_master WHERE type='table' AND "
                                 "name='unit_results'").fetchone()
            finally:
                db.close()
            return row is not None
        except (OSError, sqlite3.Error):
            return False

    def get(self, key: str) -> dict | None:
        if self._db is None:
            return None
        try:
            row = self._db.execute("SELECT result FROM unit_results WHERE key=?",
                                   (key,)).fetchone()
        except sqlite3.DatabaseError as exc:    # damaged after the check: one line, too
            raise self._damaged(exc) from None
        return json.loads(row[0]) if row else None

    def put(self, key: str, unit: str, reading: Reading, trials: int, seed: int, model: str,
            result: dict) -> None:
        if self._db is None:
            return
        try:
            with self._db:
                self._db.execute("INSERT OR REPLACE INTO unit_results VALUES "
                                 "(?,?,?,?,?,?,?,?)",
                                 (key, unit, json.dumps(reading, default=str), int(trials),
                                  int(seed), model, time.time(), json.dumps(result)))
        except sqlite3.OperationalError as exc:
            if "locked" in str(exc).lower() or "busy" in str(exc).lower():
                log.warning("--cache %s is locked (%s): this result is not cached", self.path,
                            exc)
                return
            raise self._damaged(exc) from None
        except sqlite3.DatabaseError as exc:
            raise self._damaged(exc) from None

    def close(self) -> None:
        if self._db is not None:
            self._db.close()
            self._db = None


# ---- the sweep --------------------------------------------------------------------------------
@dataclass
class SweepPlan:
    """What a sweep runs: readings x units at up to ``trials`` trials per condition."""

    readings: list[Reading]
    units: list[Unit]
    targets: list[Target]
    trials: int
    seed: int
    fingerprint: str
    #: (reading index, unit name) -> (config, cache key of the trials [0, trials))
    jobs: dict[tuple[int, str], tuple[Any, str]]

    def key(self, i: int, unit: str, lo: int, hi: int) -> str:
        """Cache key of reading ``i`` on ``unit`` over the trials ``[lo, hi)``."""
        return cache_key(UNITS[unit], self.jobs[(i, unit)][0], hi, self.seed, self.fingerprint,
                         lo=lo)


def plan_sweep(vary: Mapping[str, Sequence[Any]], targets: Sequence[Target], trials: int,
               seed: int, *, base: Sequence[str] = (),
               readings: Sequence[Reading] | None = None) -> SweepPlan:
    """Resolve every (reading, unit) config and its cache key. ``base``: ``--set`` texts
    applied under every reading; ``readings``: an explicit list instead of the cross
    product of ``vary``. Raises :class:`UserError` for a reading a unit rejects."""
    if trials < 1:
        raise UserError(f"--trials must be >= 1, got {trials}")
    readings = list(readings) if readings is not None else combinations(vary)
    base_sets = configio.parse_assignments(SnanConfig, base, renamed=RENAMED) if base else {}
    for key in base_sets:
        check_reading_key(key, "--set")
    both = sorted(set(base_sets) & {k for r in readings for k in r})
    if both:
        raise UserError(f"--set and the readings both give {both[0]}: give it in one place "
                        "(--vary to vary it, --set to fix it)")
    units = units_for(targets)
    fp = model_fingerprint()
    jobs: dict[tuple[int, str], tuple[Any, str]] = {}
    for i, reading in enumerate(readings):
        full = {**base_sets, **reading}
        for u in units:
            try:
                cfg = unit_config(u, full)
            except (ConfigError, UserError) as exc:
                raise UserError(f"reading {reading_label(reading)} on {u.name}: {exc}") from None
            jobs[(i, u.name)] = (cfg, cache_key(u, cfg, trials, seed, fp))
    return SweepPlan(readings, units, list(targets), trials, seed, fp, jobs)


def sweep_tasks(plan: SweepPlan, cache: ResultCache, *, lo: int = 0, hi: int | None = None,
                readings: Sequence[int] | None = None) -> tuple[list[Task], dict[str, dict]]:
    """Tasks of the (reading, unit) pairs over the trials ``[lo, hi)`` (default: all
    readings, ``[0, plan.trials)``) that are not in ``cache`` (one per distinct cache key:
    readings that resolve to the same config run once), and the cached results by key."""
    hi = plan.trials if hi is None else hi
    wanted = set(range(len(plan.readings)) if readings is None else readings)
    tasks: list[Task] = []
    cached: dict[str, dict] = {}
    seen: set[str] = set()
    for (i, name), (cfg, _key) in plan.jobs.items():
        if i not in wanted:
            continue
        key = plan.key(i, name, lo, hi)
        if key in seen or key in cached:
            continue
        hit = cache.get(key)
        if hit is not None:
            cached[key] = hit
            continue
        seen.add(key)
        unit = UNITS[name]
        params = {"unit": name, "trials": [lo, hi],
                  "reading": reading_label(plan.readings[i])}     # for the cache's records
        weight = max(1, round((hi - lo) * unit.cost))
        tasks.append(Task(key=(key,), fn=run_unit, config=cfg, params=params, weight=weight,
                          seed_key=("readings", name)))
    return tasks, cached


def _unit_trials(unit: Unit, trials: int) -> int:
    """Trials each condition of ``unit`` has at ``trials`` sweep trials."""
    if unit.kind == "route":
        return route_sessions(trials)
    if unit.kind == "hil":
        return HIL_LAUNCHES_PER_SEED * hil_base_seeds(trials)
    return trials


def resample_plan(plan: SweepPlan, trials: int) -> dict[str, np.ndarray]:
    """Condition -> bootstrap counts (:func:`snan_hil.host.readings_stats.resample_counts`)
    at ``trials`` sweep trials: one resample per unit, shared by its conditions and by every
    reading (paired)."""
    out: dict[str, np.ndarray] = {}
    for u in plan.units:
        counts = stats.resample_counts(_unit_trials(u, trials), cluster_size(u),
                                       stats.unit_rng(plan.seed, u.name, trials))
        for c in u.conditions:
            out[c] = counts
    return out


def score_reading(plan: SweepPlan, i: int, data: Mapping[str, Mapping[str, Any]],
                  counts: Mapping[str, np.ndarray]) -> tuple[dict[str, Any], np.ndarray]:
    """(row, bootstrap distances) of reading ``i`` from its conditions' ``data``."""
    st = {c: condition_stats(d, seed=plan.seed) for c, d in data.items()}
    total, parts = distance(plan.targets, st)
    boot = stats.bootstrap_distances(plan.targets, data, counts)
    row = {"reading": plan.readings[i], "label": reading_label(plan.readings[i]),
           "distance": total, "distance_ci": stats.percentile_interval(boot),
           "parts": parts, "conditions": st}
    return row, boot


def _conditions(plan: SweepPlan, i: int, by_unit: Mapping[str, Mapping[str, Any]]
                ) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for u in plan.units:
        out.update(by_unit[u.name]["conditions"])
    return out


def rank_rows(rows: list[dict[str, Any]], boots: Sequence[np.ndarray]) -> list[dict[str, Any]]:
    """Rank finalist rows by the tie rule (:func:`snan_hil.host.readings_stats.tie_ranks`):
    readings whose distance intervals overlap share a rank; each row gets ``rank``,
    ``tied_with_best`` and ``delta_vs_best_ci`` (paired interval of its distance minus the
    best reading's). Returns the rows sorted by distance."""
    order = sorted(range(len(rows)), key=lambda k: rows[k]["distance"])
    ranks = stats.tie_ranks([r["distance_ci"] for r in rows])
    best = order[0]
    for k, r in enumerate(rows):
        r["rank"] = ranks[k]
        r["tied_with_best"] = ranks[k] == 1
        r["delta_vs_best_ci"] = (stats.paired_interval(boots[k], boots[best]) if k != best
                                 else [0.0, 0.0])
    return [rows[k] for k in order]


def score(plan: SweepPlan, results: Mapping[str, dict]) -> list[dict[str, Any]]:
    """One row per reading at ``plan.trials`` (every reading run to the end), ranked:
    ``rank`` (ties share one, :func:`rank_rows`), ``reading``, ``label``, ``distance``,
    ``distance_ci``, ``parts`` (per target), ``conditions`` (statistics), ``trials``,
    ``status`` "finalist"; ``results`` by the keys of ``plan.jobs``."""
    counts = resample_plan(plan, plan.trials)
    rows, boots = [], []
    for i in range(len(plan.readings)):
        by_unit = {u.name: results[plan.jobs[(i, u.name)][1]] for u in plan.units}
        row, boot = score_reading(plan, i, _conditions(plan, i, by_unit), counts)
        row.update(trials=plan.trials, status="finalist")
        rows.append(row)
        boots.append(boot)
    return rank_rows(rows, boots)


#: trials of a racing sweep's first round
RACE_START = 250


def race_rounds(trials: int, start: int = RACE_START) -> list[int]:
    """Trial counts of a racing sweep: ``start``, doubling, ending at ``trials``
    (``[trials]`` when ``start >= trials``)."""
    if start < 1:
        raise UserError(f"--race-start must be >= 1, got {start}")
    out = []
    n = start
    while n < trials:
        out.append(n)
        n *= 2
    if out and trials < 1.5 * out[-1]:     # no last round of less than half the trials
        out[-1] = trials
    else:
        out.append(trials)
    return out


RunTasks = Any   #: ``(tasks, label) -> list of results`` (runs and caches one round's tasks)


#: readings a racing round never drops: the best ones by point distance (a guard against the
#: false drops of many paired tests at once; they cost little, sharing most conditions)
RACE_KEEP = 6


def race(plan: SweepPlan, cache: ResultCache, rounds: Sequence[int], run_tasks: RunTasks,
         keep: int = RACE_KEEP) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The racing sweep: every reading at ``rounds[0]`` trials; after each round the readings
    *clearly worse* than that round's best are dropped (the paired bootstrap interval of their
    distance minus the best's lies above 0), the others get the trials up to the next round
    (the ranges add up: :mod:`snan_hil.host.readings_units`); the ``keep`` best of a round by
    point distance are never dropped, so at least that many reach the end. The last round is
    ``plan.trials``. Rounds only read results (seeded by task keys), so a sweep gives the same
    rows on any executor.

    ``run_tasks(tasks, label)`` runs one round's tasks (and caches them); returns
    (rows, rounds summary). Finalists (alive after the last round) are ranked by the tie
    rule (:func:`rank_rows`); dropped readings carry ``status`` "dropped", the ``trials`` they
    reached, the best reading of that round (``dropped_vs``) and ``delta_vs_best_ci``."""
    rounds = list(rounds)
    if not rounds or rounds[-1] != plan.trials or sorted(set(rounds)) != rounds:
        raise ValueError(f"rounds {rounds} must rise to the plan's {plan.trials} trials")
    alive = list(range(len(plan.readings)))
    parts: dict[tuple[int, str], list[dict]] = {}
    dropped: list[dict[str, Any]] = []
    summary: list[dict[str, Any]] = []
    prev = 0
    rows: dict[int, dict[str, Any]] = {}
    boots: dict[int, np.ndarray] = {}
    for r, n in enumerate(rounds):
        tasks, cached = sweep_tasks(plan, cache, lo=prev, hi=n, readings=alive)
        t0 = time.perf_counter()
        results = run_tasks(tasks, f"round {r + 1}/{len(rounds)}: {len(alive)} readings to "
                                   f"{n} trials")
        by_key = dict(cached)
        by_key.update({t.key[0]: res for t, res in zip(tasks, results)})
        counts = resample_plan(plan, n)
        rows, boots = {}, {}
        for i in alive:
            by_unit = {}
            for u in plan.units:
                parts.setdefault((i, u.name), []).append(by_key[plan.key(i, u.name, prev, n)])
                by_unit[u.name] = merge_results(parts[(i, u.name)])
            rows[i], boots[i] = score_reading(plan, i, _conditions(plan, i, by_unit), counts)
            rows[i].update(trials=n, status="finalist")
        best = min(alive, key=lambda k: rows[k]["distance"])
        drop = []
        kept = set(sorted(alive, key=lambda k: rows[k]["distance"])[:max(1, keep)])
        if r < len(rounds) - 1:
            for i in alive:
                if i in kept:
                    continue
                delta = stats.paired_interval(boots[i], boots[best])
                if delta[0] > 0:
                    rows[i].update(status="dropped", dropped_vs=rows[best]["label"],
                                   delta_vs_best_ci=delta, rank=None, tied_with_best=False)
                    dropped.append(rows[i])
                    drop.append(i)
        summary.append({"round": r + 1, "trials": n, "readings": len(alive),
                        "tasks_run": len(tasks), "tasks_cached": len(cached),
                        "dropped": len(drop), "best": rows[best]["label"],
                        "best_distance": rows[best]["distance"],
                        "best_distance_ci": rows[best]["distance_ci"],
                        "wall_s": time.perf_counter() - t0})
        log.info("readings race round %d: %d readings at %d trials, %d dropped", r + 1,
                 len(alive), n, len(drop))
        alive = [i for i in alive if i not in drop]
        prev = n
    finalists = rank_rows([rows[i] for i in alive], [boots[i] for i in alive])
    dropped.sort(key=lambda x: (-x["trials"], x["distance"]))
    return finalists + dropped, summary


def result_document(plan: SweepPlan, rows: list[dict[str, Any]], *, vary: Mapping[str, Any],
                    base: Sequence[str], targets_path: str, command: str,
                    rounds: Sequence[dict[str, Any]] | None = None) -> dict[str, Any]:
    """The JSON document of a sweep (format :data:`RESULTS_FORMAT`)."""
    return {"format": RESULTS_FORMAT, "version": __version__, "command": command,
            "seed": plan.seed, "trials": plan.trials, "model_fingerprint": plan.fingerprint,
            "vary": {k: list(v) for k, v in vary.items()}, "set": list(base),
            "targets_file": targets_path,
            "targets": [{"condition": t.condition, "quantity": t.quantity,
                         "paper": list(t.paper) if isinstance(t.paper, tuple) else t.paper,
                         "source": t.source} for t in plan.targets],
            "distance": ("sum over targets: |success - paper| / 0.07 (success rates) + "
                         "|ln(median / paper)| / ln(1.25) (medians); 0 inside a paper range; "
                         "no success = median at the step limit"),
            "distance_ci_method": stats.METHOD,
            "ranking": ("readings whose distance intervals overlap share a rank (rank = 1 + "
                        "the readings whose whole interval lies below); a racing sweep drops "
                        "a reading when the paired bootstrap interval of its distance minus "
                        "the round's best lies above 0"),
            "rounds": list(rounds or []),
            "units": {u.name: {"kind": u.kind, "preset": u.preset, "source": u.source,
                               "conditions": list(u.conditions)} for u in plan.units},
            "route_sessions": route_sessions(plan.trials),
            "hil_launches": 100 * hil_base_seeds(plan.trials),
            "ci_method": intervals.METHOD, "rows": rows}
