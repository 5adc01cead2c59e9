"""``snan-hil readings``: parsing of --vary, the distance, the cache, executors giving identical
results, the output files and one-line refusals of bad input (snan_hil.host.readings)."""

from __future__ import annotations

import json
import math
import sqlite3

import pytest

from snan_hil.common.errors import UserError
from snan_hil.host import readings as R
from snan_hil.host.experiments.executor import SerialExecutor, seed_tasks
from snan_hil.tools.cli import main

#: only the cheap 3x3 units: the sweep machinery is the same for every unit
TARGETS_3X3 = """targets:
  - {condition: 3x3/no_astro, quantity: success_rate, paper: 0.631}
  - {condition: 3x3/no_astro, quantity: median_steps, paper: 10}
  - {condition: 3x3/astro, quantity: success_rate, paper: [0.9, 1.0]}
  - {condition: 3x3/astro, quantity: median_steps, paper: 4}
"""


@pytest.fixture
def targets_file(tmp_path):
    p = tmp_path / "targets.yaml"
    p.write_text(TARGETS_3X3)
    return p


def test_parse_vary_types_values_and_refuses_bad_keys():
    v = R.parse_vary(["synapse.w_inh=5,10", "neuron.reset_each_window=true,false",
                      "astro.tau_ca_unit=s,ms"])
    assert v == {"synapse.w_inh": [5.0, 10.0], "neuron.reset_each_window": [True, False],
                 "astro.tau_ca_unit": ["s", "ms"]}
    assert len(R.combinations(v)) == 8
    assert R.combinations({}) == [{}]
    for bad, words in ((["synapse.nope=1"], "synapse.nope"), (["stdp.mode=sometimes"], "mode"),
                       (["synapse.w_inh"], "KEY=V1"), (["synapse.w_inh=1,"], "empty"),
                       (["astro.tau_ca_unit=h"], "s or ms"),
                       (["synapse.w_inh=1", "synapse.w_inh=2"], "twice"),
                       (["synapse.w_inh=5,10,5"], "the value 5 is given twice")):
        with pytest.raises(UserError, match=words):
            R.parse_vary(bad)


def test_tau_unit_reads_each_conditions_tau_in_ms():
    u3, u10 = R.UNITS["3x3/astro"], R.UNITS["10x10/astro"]
    s3, ms3 = (R.unit_config(u3, {"astro.tau_ca_unit": x}) for x in ("s", "ms"))
    ms10 = R.unit_config(u10, {"astro.tau_ca_unit": "ms"})
    assert ms3.astro.tau_ca_s == pytest.approx(s3.astro.tau_ca_s / 1000)
    assert ms10.astro.tau_ca_s == pytest.approx(R.unit_config(u10, {}).astro.tau_ca_s / 1000)
    hil = R.unit_config(R.UNITS["hw6x6"], {"astro.tau_ca_unit": "ms"})
    assert hil.model.astro.tau_ca_s == pytest.approx(
        R.unit_config(R.UNITS["hw6x6"], {}).model.astro.tau_ca_s / 1000)


def test_distance_follows_the_documented_formula():
    rate = R.Target("3x3/no_astro", "success_rate", 0.631)
    rng = R.Target("3x3/no_astro", "success_rate", (0.05, 0.166))
    med = R.Target("3x3/no_astro", "median_steps", 10.0)
    st = {"success_rate": 0.701, "median_steps": 12.5, "max_steps": 100}
    assert R.target_distance(rate, st) == pytest.approx(0.07 / 0.07)
    assert R.target_distance(rng, {**st, "success_rate": 0.1}) == 0.0
    assert R.target_distance(rng, st) == pytest.approx((0.701 - 0.166) / 0.07)
    assert R.target_distance(med, st) == pytest.approx(1.0)      # 12.5 / 10 = 1.25
    assert R.target_distance(med, {**st, "median_steps": 8.0}) == pytest.approx(1.0)
    # no success: the median counts at the step limit
    assert R.target_distance(med, {**st, "median_steps": None}) == pytest.approx(
        math.log(10) / math.log(1.25))
    total, parts = R.distance([rate, med], {"3x3/no_astro": st})
    assert total == pytest.approx(sum(parts)) and parts == pytest.approx([1.0, 1.0])


def test_targets_file_is_checked(tmp_path):
    assert {t.condition for t in R.load_targets()} >= {"10x10/astro", "route10/cycle20",
                                                        "hw6x6/sw_astro", "maze40/no_astro"}
    bad = tmp_path / "t.yaml"
    for text, words in (("targets: []", "no targets"),
                        ("targets:\n  - {condition: 4x4/astro, quantity: success_rate, "
                         "paper: 1}", "unknown condition"),
                        ("targets:\n  - {condition: 3x3/astro, quantity: speed, paper: 1}",
                         "quantity"),
                        ("targets:\n  - {condition: 3x3/astro, quantity: median_steps, "
                         "paper: [5, 2]}", "number or"),
                        ("nothing: 1", "targets")):
        bad.write_text(text)
        with pytest.raises(UserError, match=words):
            R.load_targets(bad)


def test_trial_end_readings_share_navigation_results():
    """pairing/target of a trial_end update cannot act in independent trials: one config."""
    u = R.UNITS["3x3/no_astro"]
    a = R.unit_config(u, {"stdp.pairing": "nearest", "stdp.target": "chosen"})
    b = R.unit_config(u, {})
    assert a == b
    w = R.unit_config(u, {"stdp.mode": "window", "stdp.pairing": "nearest"})
    assert w != R.unit_config(u, {"stdp.mode": "window"})


def _run_plan(plan, executor, cache):
    tasks, cached = R.sweep_tasks(plan, cache)
    tasks = seed_tasks(tasks, plan.seed)
    res = executor.execute(tasks)
    for t, r in zip(tasks, res):
        cache.put(t.key[0], t.params["unit"], {}, plan.trials, plan.seed, plan.fingerprint, r)
    return len(tasks), {**cached, **{t.key[0]: r for t, r in zip(tasks, res)}}


def test_cache_reuses_results_and_keys_by_config_trials_seed(tmp_path, targets_file):
    targets = R.load_targets(targets_file)
    cache = R.ResultCache(tmp_path / "c.sqlite")
    plan = R.plan_sweep(R.parse_vary(["synapse.w_inh=5,50"]), targets, 6, 3)
    ran, first = _run_plan(plan, SerialExecutor(), cache)
    # 2 readings x 2 units, but without astrocytes (potentials reset each window) w_inh cannot
    # act: both readings share that unit's config
    assert ran == 3
    ran2, again = _run_plan(plan, SerialExecutor(), cache)
    assert ran2 == 0 and again == first
    assert {k: v["conditions"] for k, v in again.items()} == \
        {k: v["conditions"] for k, v in first.items()}
    # an extended sweep runs only the new values; another seed or trial count runs anew
    ext = R.plan_sweep(R.parse_vary(["synapse.w_inh=5,50,20"]), targets, 6, 3)
    assert _run_plan(ext, SerialExecutor(), cache)[0] == 1
    assert _run_plan(R.plan_sweep({}, targets, 6, 4), SerialExecutor(), cache)[0] == 2
    assert _run_plan(R.plan_sweep({}, targets, 7, 3), SerialExecutor(), cache)[0] == 2
    rows = R.score(plan, first)
    assert rows[0]["rank"] == 1 and rows[1]["rank"] in (1, 2)
    assert rows[0]["distance"] <= rows[1]["distance"]
    assert all(r["distance_ci"][0] <= r["distance"] + 1e-9 or r["distance_ci"][0] <=
               r["distance_ci"][1] for r in rows)
    assert all(len(r["parts"]) == 4 for r in rows)
    cache.close()
    assert R.ResultCache.owns(tmp_path / "c.sqlite")
    (tmp_path / "x.sqlite").write_text("not a database")
    assert not R.ResultCache.owns(tmp_path / "x.sqlite")


def test_dask_and_processes_give_identical_results(tmp_path, targets_file):
    distributed = pytest.importorskip("distributed")
    from snan_hil.host.experiments.executor import DaskExecutor, ProcessExecutor
    targets = R.load_targets(targets_file)
    plan = R.plan_sweep(R.parse_vary(["synapse.w_inh=5,50"]), targets, 5, 2)
    _, local = _run_plan(plan, ProcessExecutor(2), R.ResultCache(None))
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        _, dask = _run_plan(plan, DaskExecutor(client=client), R.ResultCache(None))
    assert {k: v["conditions"] for k, v in dask.items()} == \
        {k: v["conditions"] for k, v in local.items()}


def test_cli_writes_outputs_and_reuses_the_cache(tmp_path, targets_file, capsys):
    out, cache = tmp_path / "sweep", tmp_path / "cache.sqlite"
    args = ["readings", "--vary", "synapse.w_inh=5,50", "--vary",
            "neuron.reset_each_window=true,false", "--targets", str(targets_file),
            "--trials", "5", "--workers", "1", "--cache", str(cache), "--out", str(out)]
    assert main(args) == 0
    doc = json.loads((out / "readings.json").read_text())
    assert doc["format"] == R.RESULTS_FORMAT and doc["seed"] == 1 and doc["trials"] == 5
    assert len(doc["rows"]) == 4 and doc["model_fingerprint"] == R.model_fingerprint()
    st = doc["rows"][0]["conditions"]["3x3/astro"]
    assert st["trials"] == 5 and len(st["success_rate_ci"]) == 2
    assert (out / "readings.csv").read_text().startswith(
        "rank,distance,distance_ci_low,distance_ci_high,trials,status,synapse.w_inh,")
    assert "| rank | reading | distance [95 % CI] | trials | status |" in \
        (out / "readings.md").read_text()
    assert (out / "readings.png").stat().st_size > 1000
    capsys.readouterr()
    assert main([*args, "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert [r["distance"] for r in again["rows"]] == [r["distance"] for r in doc["rows"]]
    with sqlite3.connect(cache) as db:     # 3x3/no_astro with reset potentials: one result
        assert db.execute("SELECT COUNT(*) FROM unit_results").fetchone()[0] == 7


@pytest.mark.parametrize("extra, words", [
    (["--vary", "synapse.bogus=1,2"], "synapse.bogus"),
    (["--vary", "stdp.mode=trial_end,sometimes"], "sometimes"),
    (["--vary", "synapse.w_inh="], "empty"),
    (["--vary", "synapse.w_inh=20,20"], "the value 20 is given twice"),
    (["--vary", "synapse.w_inh=20,2e1"], "the value 20 is given twice (as '2e1')"),
    (["--vary", "synapse.w_inh=1,2,3,4,5,6,7,8,9", "--vary", "stdp.k=1,2,3,4,5,6,7,8"],
     "--yes"),
    (["--vary", "synapse.w_inh=1,2", "--heatmap", "synapse.w_inh,stdp.k"], "--heatmap"),
    (["--targets", "no-such-targets.yaml"], "--targets"),
    (["--trials", "0"], "--trials"),
    (["--race-start", "3"], "--race-start 3 must be below --trials 3"),
    (["--race-start", "100", "--trials", "20"], "--race-start 100 must be below --trials 20"),
    (["--dask", "tcp://127.0.0.1:9"], "Dask scheduler"),
])
def test_bad_input_is_one_line_exit_2_before_any_work(tmp_path, capsys, extra, words):
    out = tmp_path / "out"
    trials = [] if "--trials" in extra else ["--trials", "3"]    # an option is given once
    rc = main(["readings", *trials, "--cache", str(tmp_path / "c.sqlite"),
               "--out", str(out), *extra])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert words in err and "Traceback" not in err and len(err.splitlines()) == 1
    assert not (out / "readings.json").exists()


def test_from_reruns_the_best_readings_of_earlier_sweeps(tmp_path, targets_file, capsys):
    cache = tmp_path / "c.sqlite"
    common = ["--targets", str(targets_file), "--trials", "4", "--workers", "1",
              "--cache", str(cache)]
    assert main(["readings", "--vary", "synapse.w_inh=1,5,50", "--set", "synapse.init=truncate",
                 *common, "--out", str(tmp_path / "a")]) == 0
    assert main(["readings", "--vary", "neuron.refractory=clamp,integrate", *common,
                 "--out", str(tmp_path / "b")]) == 0
    a = json.loads((tmp_path / "a" / "readings.json").read_text())
    b = json.loads((tmp_path / "b" / "readings.json").read_text())
    pool = sorted([(r["distance"], {"synapse.init": "truncate", **r["reading"]})
                   for r in a["rows"]] + [(r["distance"], r["reading"]) for r in b["rows"]],
                  key=lambda dr: dr[0])
    best = R.best_of([("a", a), ("b", b)], 3)
    assert best == [r for _d, r in pool[:3]]
    capsys.readouterr()
    assert main(["readings", "--from", str(tmp_path / "a" / "readings.json"), "--from",
                 str(tmp_path / "b" / "readings.json"), "--best", "3",
                 *[c if c != "4" else "6" for c in common], "--out", str(tmp_path / "c"),
                 "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["trials"] == 6 and sorted(map(json.dumps, (r["reading"] for r in doc["rows"]))) \
        == sorted(map(json.dumps, best))
    # refusals: not a result, --vary together with --from, sweeps that do not compare
    (tmp_path / "x.json").write_text("{}")
    for argv, words in ((["--from", str(tmp_path / "x.json")], "not a 'snan-hil readings'"),
                        (["--from", str(tmp_path / "a" / "readings.json"), "--vary",
                          "synapse.w_inh=1"], "exclude"),
                        (["--from", str(tmp_path / "a" / "readings.json"), "--from",
                          str(tmp_path / "c" / "readings.json")], "compare"),
                        (["--from", str(tmp_path / "nope.json")], "no such file")):
        assert main(["readings", *argv, *common, "--out", str(tmp_path / "d")]) == 2
        err = capsys.readouterr().err.strip()
        assert words in err and len(err.splitlines()) == 1


def test_best_of_keeps_readings_that_spell_the_same_config_once():
    doc = {"format": R.RESULTS_FORMAT, "targets": [], "trials": 5, "seed": 1, "set": [],
           "rows": [{"distance": 1.0, "reading": {"synapse.w_inh": 50.0}},
                    {"distance": 2.0, "reading": {"synapse.w_inh": 50.0,
                                                  "neuron.refractory": "clamp"}},
                    {"distance": 3.0, "reading": {"synapse.w_inh": 5.0}}]}
    assert R.best_of([("a", doc)], 2) == [{"synapse.w_inh": 50.0}, {"synapse.w_inh": 5.0}]


def test_refusals_found_by_a_fresh_user(tmp_path, targets_file, capsys):
    """Each: one line, exit 2, before any work, nothing written."""
    common = ["--targets", str(targets_file), "--trials", "3",
              "--cache", str(tmp_path / "c.sqlite")]
    assert main(["readings", *common, "--workers", "1", "--out", str(tmp_path / "a")]) == 0
    src = tmp_path / "a" / "readings.json"
    before = src.read_bytes()
    db = tmp_path / "other.sqlite"
    with sqlite3.connect(db) as con:
        con.execute("CREATE TABLE theirs (x)")
    bad = tmp_path / "bad.yaml"
    capsys.readouterr()
    cases = [
        (["--from", str(src), "--out", str(tmp_path / "a")], "input"),        # own input
        (["--seed", "-1"], "--seed"),
        (["--vary", "grid.rows=3,5"], "defines the conditions"),
        (["--vary", "astro.enabled=true,false"], "defines the conditions"),
        (["--set", "grid.max_steps=5"], "defines the conditions"),
        (["--vary", "synapse.w_inh=5", "--set", "synapse.w_inh=20"], "one place"),
        (["--best", "3"], "--from"),
        (["--dask", "nonsense"], "Dask scheduler"),
    ]
    for argv, words in cases:
        out = [] if "--out" in argv else ["--out", str(tmp_path / "x")]   # given once
        assert main(["readings", *common, *out, *argv]) == 2, argv
        err = capsys.readouterr().err.strip()
        assert words in err and len(err.splitlines()) == 1 and "Traceback" not in err, err
        assert not (tmp_path / "x").exists()
    assert src.read_bytes() == before
    for extra in ([], ["--force"]):
        assert main(["readings", "--targets", str(targets_file), "--trials", "3", "--cache",
                     str(db), "--out", str(tmp_path / "x"), *extra]) == 2
        assert "not a readings cache" in capsys.readouterr().err
    with sqlite3.connect(db) as con:
        assert [r[0] for r in con.execute("SELECT name FROM sqlite_master")] == ["theirs"]
    for text, words in (("  - {condition: 3x3/astro, quantity: success_rate, paper: 63.1}",
                         "fraction"),
                        ("  - {condition: 3x3/astro, quantity: median_steps, paper: .nan}",
                         "finite"),
                        ("  - {condition: 3x3/astro, quantity: median_steps, paper: .inf}",
                         "finite"),
                        ("  - {condition: 3x3/astro, quantity: median_steps, paper: 4}\n"
                         "  - {condition: 3x3/astro, quantity: median_steps, paper: 5}", "once")):
        bad.write_text("targets:\n" + text + "\n")
        assert main(["readings", "--targets", str(bad), "--trials", "3", "--no-cache",
                     "--out", str(tmp_path / "x")]) == 2
        err = capsys.readouterr().err.strip()
        assert words in err and len(err.splitlines()) == 1, err


def test_readings_that_cannot_differ_share_a_config_and_give_the_same_trials():
    """Without astrocytes (potentials reset each window) w_inh and the astrocyte parameters
    cannot act: the sweep runs them once, and running them separately gives the same trials."""
    from snan_hil.host.config import load_config
    from snan_hil.host.experiments.trials import nav_batch
    u = R.UNITS["3x3/no_astro"]
    assert R.unit_config(u, {"synapse.w_inh": 5.0}) == R.unit_config(u, {})
    assert R.unit_config(u, {"astro.tau_ca_unit": "ms"}) == R.unit_config(u, {})
    assert R.unit_config(u, {"synapse.w_inh": 5.0, "neuron.reset_each_window": False}) != \
        R.unit_config(u, {"neuron.reset_each_window": False})
    assert R.unit_config(R.UNITS["3x3/astro"], {"synapse.w_inh": 5.0}) != \
        R.unit_config(R.UNITS["3x3/astro"], {})
    base = load_config(preset="snan-3x3").replace(**{"astro.enabled": False})
    runs = [nav_batch(base.replace(**sets), {"trials": [0, 40]}, 7)["steps"]
            for sets in ({}, {"synapse.w_inh": 1.0}, {"astro.tau_ca_s": 0.0012, "astro.a": 3.0})]
    assert runs[0] == runs[1] == runs[2]


@pytest.mark.parametrize("unit, cut, end", [("3x3/astro", 7, 15), ("route10", 50, 100),
                                            ("hw6x6", 100, 200)])
def test_trial_ranges_add_up_to_the_whole_run(unit, cut, end):
    """A racing round adds trials [n1, n2) to [0, n1): the same as one run of [0, n2)."""
    from snan_hil.host.readings_units import merge_results, run_unit
    cfg = R.unit_config(R.UNITS[unit], {})
    whole = run_unit(cfg, {"unit": unit, "trials": [0, end]}, 11)
    parts = merge_results([run_unit(cfg, {"unit": unit, "trials": [0, cut]}, 11),
                           run_unit(cfg, {"unit": unit, "trials": [cut, end]}, 11)])
    assert parts["conditions"] == whole["conditions"]
    n = len(next(iter(whole["conditions"].values()))["steps"])
    assert n == {"3x3/astro": 15, "route10": 20, "hw6x6": 200}[unit]


def test_bootstrap_of_rates_and_medians_equals_materialised_resamples():
    import numpy as np
    from snan_hil.host import readings_stats as S
    rng = np.random.default_rng(3)
    steps = rng.integers(1, 40, size=30)
    ok = rng.random(30) < 0.6
    counts = S.resample_counts(30, 3, np.random.default_rng(5), n_resamples=200)
    assert counts.shape == (200, 30) and (counts.sum(axis=1) == 30).all()
    assert (counts[:, 0::3] == counts[:, 1::3]).all()          # clusters of 3 move together
    rate, med = S.resampled_stats(steps, ok, counts, max_steps=100)
    for b in range(200):
        idx = np.repeat(np.arange(30), counts[b])
        assert rate[b] == pytest.approx(ok[idx].mean())
        good = steps[idx][ok[idx]]
        assert med[b] == (np.median(good) if good.size else 100)
    assert S.tie_ranks([[1, 3], [2, 4], [5, 6], [3.5, 5.5]]) == [1, 1, 3, 2]


def _race(executor, targets, rounds, vary):
    plan = R.plan_sweep(R.parse_vary(vary), targets, rounds[-1], 2)
    cache = R.ResultCache(None)
    return R.race(plan, cache, rounds, lambda tasks, label: executor.execute(
        seed_tasks(tasks, plan.seed)), keep=1)


def test_race_drops_the_clearly_worse_and_gives_the_same_rows_on_dask(tmp_path):
    """The same racing sweep, serial and on a Dask cluster: identical rows; the in-trial
    reading that traps the 3x3 agent is dropped after the first round, the other reaches the
    last round and equals a plain sweep at that count."""
    distributed = pytest.importorskip("distributed")
    from snan_hil.host.experiments.executor import DaskExecutor
    p = tmp_path / "t.yaml"
    p.write_text("targets:\n  - {condition: 3x3/no_astro, quantity: success_rate, paper: 0.78}\n"
                 "  - {condition: 3x3/no_astro, quantity: median_steps, paper: 6}\n")
    targets = R.load_targets(p)
    vary = ["stdp.mode=trial_end,window"]
    rows, rounds = _race(SerialExecutor(), targets, [60, 120], vary)
    assert [r["status"] for r in rows] == ["finalist", "dropped"]
    assert rows[0]["reading"] == {"stdp.mode": "trial_end"} and rows[0]["trials"] == 120
    assert rows[1]["trials"] == 60 and rows[1]["delta_vs_best_ci"][0] > 0
    assert [x["readings"] for x in rounds] == [2, 1]
    plain = R.plan_sweep(R.parse_vary(vary), targets, 120, 2)
    tasks = seed_tasks(R.sweep_tasks(plain, R.ResultCache(None))[0], 2)
    res = SerialExecutor().execute(tasks)
    flat = R.score(plain, {t.key[0]: r for t, r in zip(tasks, res)})
    assert flat[0]["conditions"] == rows[0]["conditions"]
    assert flat[0]["distance_ci"] == rows[0]["distance_ci"]
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        on_dask, _ = _race(DaskExecutor(client=client), targets, [60, 120], vary)
    assert json.dumps(on_dask, sort_keys=True) == json.dumps(rows, sort_keys=True)


def test_race_rounds_double_up_to_the_trials():
    assert R.race_rounds(5000, 500) == [500, 1000, 2000, 5000]
    assert R.race_rounds(200, 500) == [200]
    assert R.race_rounds(1100, 500) == [500, 1100]
    with pytest.raises(UserError, match="race-start"):
        R.race_rounds(100, 0)


def test_tradeoff_front_and_table(tmp_path):
    from snan_hil.host import readings_report as rep
    assert rep.pareto_front([(60, 0.9), (80, 0.5), (70, 0.95), (100, 0.4), (90, 0.6)]) == \
        [0, 1, 3]

    def row(label, reading, x, astro, s10, s3):
        return {"label": label, "reading": reading, "trials": 10, "conditions": {
            "10x10/astro": {"median_steps": x, "median_steps_ci": [x - 1, x + 1],
                            "success_rate": astro},
            "10x10/no_astro": {"success_rate": s10, "success_rate_ci": [s10 - .01, s10 + .01]},
            "3x3/no_astro": {"success_rate": s3, "success_rate_ci": [s3 - .01, s3 + .01]}}}
    lit = {"synapse.w_inh": 50.0, "neuron.reset_each_window": False, "stdp.mode": "window",
           "stdp.pairing": "all_to_all", "stdp.target": "all"}
    doc = {"trials": 10, "seed": 1, "rows": [
        row("a", lit, 57.0, 1.0, 1.0, 1.0), row("b", {}, 84.0, 1.0, 0.47, 0.78),
        row("c", {"stdp.mode": "window"}, 50.0, 0.5, 0.05, 0.3)]}
    assert rep.has_tradeoff(doc)
    rows = {r["label"]: r for r in rep.tradeoff_rows(doc)}
    assert rows["a"]["named"] == "paper-literal" and rows["b"]["named"] == "scored"
    assert rows["a"]["front_10x10/no_astro"] and rows["b"]["front_10x10/no_astro"]
    assert not rows["c"]["eligible"] and not rows["c"]["front_3x3/no_astro"]
    md = rep.tradeoff_markdown(doc)
    assert "(**paper-literal**)" in md and md.count("\n| ") == 4      # header + 3 readings
    rep.tradeoff_figure(doc, tmp_path / "t.png")
    assert (tmp_path / "t.png").stat().st_size > 5000


def test_a_damaged_cache_is_one_line_before_any_unit_runs(tmp_path, capsys):
    path = tmp_path / "c.sqlite"
    cache = R.ResultCache(path)
    for k in range(400):                                  # a few pages of results
        cache.put(f"k{k}", "u", {"r": k}, 3, 1, "m", {"x": "y" * 200})
    cache.close()
    data = bytearray(path.read_bytes())
    for k in range(4096, len(data), 7):                  # header intact, pages broken
        data[k] = (data[k] + 0x5A) & 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(UserError, match="readings cache cannot be used .*--no-cache"):
        R.ResultCache(path)
    out = tmp_path / "out"
    assert main(["readings", "--trials", "3", "--vary", "synapse.w_inh=10,20",
                 "--cache", str(path), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1 and "--cache" in err
    assert not out.exists() and path.read_bytes() == bytes(data)
