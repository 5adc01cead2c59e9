"""The docs' result tables are generated (tools/doc_tables.py, docs/tables/make_tables.py):
every marked block equals the rendering of its stored fixed-seed run, and a cheap subset of
those runs, recomputed here with today's code, equals the stored data — so a doc number
cannot go stale silently."""

import re

import pytest

from snan_hil.host import heldout as H
from snan_hil.host import readings as R
from snan_hil.host.experiments.executor import SerialExecutor, seed_tasks
from snan_hil.tools import doc_tables as T

DOCS = sorted((T.ROOT / "docs").glob("*.md"))


def test_every_generated_block_equals_its_stored_data():
    bad = T.check()
    assert bad == [], ("blocks differ from docs/tables/data (run "
                       f"docs/tables/make_tables.py): {bad}")


def test_every_marked_block_belongs_to_a_source_with_data():
    owners = {block: (doc, s.name) for s in T.SOURCES.values() for block, doc in s.docs.items()}
    found = {}
    for path in DOCS:
        for name in re.findall(r"<!-- table: ([a-z0-9-]+) ", path.read_text()):
            assert name not in found, f"block {name} twice ({found.get(name)}, {path.name})"
            found[name] = path.relative_to(T.ROOT).as_posix()
    assert set(found) == set(owners), "a block without a source or a source without a block"
    for name, (doc, source) in owners.items():
        assert found[name] == doc
        assert T.data_path(source).is_file(), f"no stored run of {source}"


def test_replace_block_rewrites_one_block_only():
    text = ("a\n<!-- table: x (old) -->\nold body\n<!-- /table: x -->\nb\n"
            "<!-- table: x-note (n) -->\nnote\n<!-- /table: x-note -->\n")
    new = T.replace_block(text, "x", "src", "new body\n")
    assert T.blocks_of(new) == {"x": "new body\n", "x-note": "note\n"}
    assert "docs/tables/data/src.json" in new.splitlines()[1]
    with pytest.raises(ValueError):
        T.replace_block(text, "y", "src", "")


def _same(fresh, stored, keys):
    for k in keys:
        assert fresh[k] == pytest.approx(stored[k]), k


def test_the_3x3_software_rows_recomputed_equal_the_docs():
    """docs/model.md's 3x3 rows, recomputed (5000 trials, seed 1: a few seconds)."""
    stored = [r for r in T.load_data("software")["readings"]["scored"]["rows"]
              if r["grid"] == "3x3"]
    fresh = T.software_rows("scored", presets=("snan-3x3",))
    assert len(fresh) == len(stored) == 2
    for f, s in zip(fresh, stored):
        _same(f, s, ("trials", "success_rate", "median_steps", "success_rate_ci",
                     "median_steps_ci", "paper_success_rate", "paper_median_steps"))


def test_the_vteam_3x3_route_learning_recomputed_equals_the_docs():
    """docs/learning.md §5.1's 3x3 rows of the tuning seed, recomputed through the readings
    sweep (200 sessions: a few seconds)."""
    doc = T.load_data("heldout-vteam")
    reading = H.TUNED["vteam"]
    n = doc["heldout"]["trials_per_seed"]
    targets = [t for t in R.load_targets(reading.targets_path())
               if t.condition.startswith("route3/")]
    plan = R.plan_sweep({}, targets, n, reading.tuning_seed, base=list(reading.overrides))
    tasks, _ = R.sweep_tasks(plan, R.ResultCache(None))
    (res,) = SerialExecutor().execute(seed_tasks(tasks, reading.tuning_seed))
    stored = doc["tuning"]["at_heldout_trials"]["conditions"]
    for cond, data in res["conditions"].items():
        fresh = H.condition_summary(data, reading.tuning_seed)
        _same(fresh, stored[cond], ("trials", "success_rate", "median_steps",
                                    "success_rate_ci", "median_steps_ci"))


def test_the_first_weight_set_of_the_6x6_comparison_recomputed_equals_the_docs(tmp_path,
                                                                               monkeypatch):
    """docs/hil.md's comparison, its first weight set recomputed on a fresh emulated chip
    (train set 0 alone, program it, 4 scenarios x 10 launches): the launches the stored run
    gave. This is what caught the stale memristor-with-astrocytes median (issue 35)."""
    import json

    from snan_hil.tools import cli
    stored = T.load_data("hil-compare")
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    w = tmp_path / "w.npz"
    assert cli.main(["train", "--sets", "1", "--seed", str(stored["runs"][0]["train_seed"]),
                     "-o", str(w), "--json"]) == 0
    assert cli.main(["compare", "--weights", str(w), "--weight-set", "0", "--port", "emu",
                     "--seed", str(stored["seed"]), "--out", str(tmp_path / "out"),
                     "--no-figure", "--json"]) == 0
    rows = json.loads((tmp_path / "out" / "compare.json").read_text())["launch_rows"]
    fresh = {s: [int(r["steps"]) for r in rows if r["scenario"] == s]
             for s in stored["runs"][0]["set0_steps"]}
    assert fresh == stored["runs"][0]["set0_steps"]
