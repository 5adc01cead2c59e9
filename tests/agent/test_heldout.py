"""Held-out seeds of the tuned readings (host/heldout.py): a seed's trials are the readings
sweep's, pooling joins the seeds' trials, the single-seed range, seeds a search used are
refused."""

import dataclasses

import numpy as np
import pytest

from snan_hil.host import heldout as H
from snan_hil.host import readings as R
from snan_hil.host.experiments.executor import SerialExecutor, seed_tasks

#: the VTEAM reading at a tiny size: two route units, 10 sessions each
TINY = dataclasses.replace(H.TUNED["vteam"], tuning_trials=50, extra_seeds=(2,),
                           heldout_seeds=(101, 102))


def _run_tasks(tasks, seed, label):
    return SerialExecutor().execute(seed_tasks(tasks, seed))


@pytest.fixture(scope="module")
def doc():
    cache = R.ResultCache(None)
    return H.evaluate(TINY, _run_tasks, cache, trials=50, step=None)


def test_a_seed_runs_the_trials_of_the_readings_sweep():
    """evaluate's seed 101 is what `snan-hil readings --seed 101` runs for that reading."""
    cache = R.ResultCache(None)
    run = H.seed_conditions(TINY, 101, 50, _run_tasks, cache)
    plan = R.plan_sweep({}, R.load_targets(TINY.targets_path()), 50, 101,
                        base=list(TINY.overrides))
    tasks, _ = R.sweep_tasks(plan, cache)
    for res in SerialExecutor().execute(seed_tasks(tasks, 101)):
        for cond, data in res["conditions"].items():
            assert run.conditions[cond]["steps"] == data["steps"]
            assert run.conditions[cond]["success"] == data["success"]
    # ranges of the trial axis give the same trials as one range (prefix-stable)
    split = H.seed_conditions(TINY, 101, 50, _run_tasks, cache, step=25)
    assert split.conditions == run.conditions


def test_pooled_figures_are_the_seeds_trials_together(doc):
    cache = R.ResultCache(None)
    runs = [H.seed_conditions(TINY, s, 50, _run_tasks, cache) for s in (101, 102)]
    for cond, st in doc["heldout"]["pooled"]["conditions"].items():
        steps = np.concatenate([r.conditions[cond]["steps"] for r in runs])
        ok = np.concatenate([r.conditions[cond]["success"] for r in runs]).astype(bool)
        assert st["trials"] == steps.size == 20                  # 2 seeds x 10 sessions
        assert st["success_rate"] == pytest.approx(ok.mean())
        assert st["median_steps"] == (float(np.median(steps[ok])) if ok.any() else None)
    per = doc["heldout"]["per_seed"]
    assert set(per) == {"101", "102"} and set(doc["extra_seeds"]) == {"2"}
    # the tuning seed at the held-out count is the first trials of its longer run
    assert doc["tuning"]["trials"] == 50 and doc["tuning"]["seed"] == 1


def test_the_distance_has_an_interval_around_it(doc):
    for part in (doc["tuning"], doc["heldout"]["pooled"], *doc["heldout"]["per_seed"].values()):
        lo, hi = part["distance_ci"]
        assert lo <= hi and len(part["parts"]) == len(doc["targets"])
        assert part["distance"] == pytest.approx(sum(part["parts"]))


def test_single_seed_range_is_wider_than_the_pooled_interval():
    rng = np.random.default_rng(0)
    steps = rng.integers(20, 80, size=2000)
    ok = rng.random(2000) < 0.9
    data = {"steps": steps.tolist(), "success": ok.tolist(), "max_steps": 100, "cluster": 1}
    one = H.single_seed_range(data, 200, seed=1)
    pooled = R.condition_stats(data, seed=1)
    assert one["median_steps"][0] < pooled["median_steps_ci"][0]
    assert one["median_steps"][1] > pooled["median_steps_ci"][1]
    assert one["success_rate"][0] < 0.9 < one["success_rate"][1]


def test_clustered_conditions_resample_whole_weight_sets():
    # 10 sets of 10 launches; each set's launches equal: resampling launches would be narrow
    steps = np.repeat(np.arange(10, 30, 2), 10)
    data = {"steps": steps.tolist(), "success": [True] * 100, "max_steps": 100, "cluster": 10}
    st = H.condition_summary(data, seed=3)
    naive = R.condition_stats(dict(data, cluster=1), seed=3)
    assert st["median_steps_ci"][1] - st["median_steps_ci"][0] > \
        naive["median_steps_ci"][1] - naive["median_steps_ci"][0]
    assert "weight sets" in st["ci_method"]["median_steps"]


def test_held_out_seeds_never_include_a_seed_the_search_used():
    cache = R.ResultCache(None)
    with pytest.raises(ValueError, match="search"):
        H.evaluate(TINY, _run_tasks, cache, seeds=(1, 101), trials=10)
    with pytest.raises(ValueError, match="search"):
        H.evaluate(TINY, _run_tasks, cache, seeds=(2, 101), trials=10)
    for reading in H.TUNED.values():
        assert reading.tuning_seed not in reading.seeds()
        assert not set(reading.extra_seeds) & set(reading.seeds())
        assert len(reading.seeds()) >= 5
