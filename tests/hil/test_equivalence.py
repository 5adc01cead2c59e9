"""Is learning on the chip equivalent to software (issue 35 point 3; docs/learning.md §12): the
TOST of paired log routes, the success difference, the power, the cross-chip transfer
(``snan-hil transfer``) and the analysis command (``snan-hil equivalence``) with its
refusals."""

import json
import math

import numpy as np
import pytest

from snan_hil.common.errors import UserError
from snan_hil.host.hil.equivalence import (analyse, margin_allowed, paired_at, route_tost,
                                           sessions_needed, success_difference,
                                           transfer_summary)
from snan_hil.records.history import History
from snan_hil.tools import cli


def learn_doc(sw_steps, sw_ok, chip_steps, chip_ok, seed=1, cycles=2):
    """A learn.json with the given last-cycle tests (earlier cycles: failures)."""
    def arm(steps, ok):
        return {"sessions": [{"test_steps": [30] * cycles + [int(s)],
                              "test_success": [False] * cycles + [bool(o)]}
                             for s, o in zip(steps, ok)]}
    return {"format": "snan-hil-learn/1", "config": {"cycles": cycles, "seed": seed,
                                                     "sessions": len(sw_steps)},
            "arms": {"software": arm(sw_steps, sw_ok), "chip": arm(chip_steps, chip_ok)}}


def test_the_route_tost_is_computed_from_the_paired_log_differences():
    rng = np.random.default_rng(0)
    sw = rng.integers(5, 60, 40)
    chip = np.round(sw * np.exp(rng.normal(0.0, 0.05, 40))).astype(int)
    ok_sw = np.ones(40, bool)
    ok_chip = ok_sw.copy()
    ok_chip[:4] = False                       # no route pair: left out of the route test
    p = paired_at(learn_doc(sw, ok_sw, chip, ok_chip), chip="x")
    t = route_tost(p, margin=0.15)
    d = np.log(chip[4:]) - np.log(sw[4:])
    assert t.n == 36
    assert t.mean_log == pytest.approx(d.mean()) and t.sd_log == pytest.approx(d.std(ddof=1))
    assert t.ratio == pytest.approx(math.exp(d.mean()))
    assert t.equivalent and t.ratio_ci[0] > 1 / 1.15 and t.ratio_ci[1] < 1.15
    # unpaired, the same values are far noisier: the test is of the pairs, not the arms
    shuffled = paired_at(learn_doc(sw, ok_sw, np.roll(chip, 7), ok_chip), chip="x")
    t2 = route_tost(shuffled, margin=0.15)
    assert t2.sd_log > 5 * t.sd_log and not t2.equivalent
    # a chip whose routes are 40 % longer is not equivalent, whatever the sample size
    longer = paired_at(learn_doc(sw, ok_sw, np.round(sw * 1.4).astype(int), ok_sw), chip="x")
    t3 = route_tost(longer, margin=0.15)
    assert not t3.equivalent and t3.ratio_ci[0] > 1.15


def test_the_success_difference_counts_the_discordant_sessions():
    sw_ok = np.array([1, 1, 1, 1, 0, 0, 1, 1, 1, 1], bool)
    chip_ok = np.array([1, 0, 0, 1, 1, 0, 1, 1, 1, 1], bool)
    p = paired_at(learn_doc([10] * 10, sw_ok, [10] * 10, chip_ok), chip="x")
    s = success_difference(p)
    assert (s["chip_only"], s["software_only"]) == (1, 2)
    assert s["difference"] == pytest.approx(-0.1)
    assert s["ci"][0] < -0.1 < s["ci"][1] and s["confidence"] == pytest.approx(0.9)


def test_the_power_calculation_agrees_with_simulated_tosts():
    from statsmodels.stats.weightstats import ttost_paired
    sd, margin = 0.3, 0.15
    n = sessions_needed(sd, margin)
    assert margin_allowed(sd, n) <= margin + 1e-9 < margin_allowed(sd, n - 1)
    assert sessions_needed(sd, 0.3) < n                     # a wider margin needs fewer
    rng = np.random.default_rng(1)
    hits = 0
    trials = 1000
    for _ in range(trials):
        d = rng.normal(0.0, sd, n)
        hits += ttost_paired(d, np.zeros(n), -math.log1p(margin), math.log1p(margin))[0] < 0.05
    assert 0.75 <= hits / trials <= 0.88                    # planned for 80 %


def test_runs_with_the_same_seed_are_not_pooled():
    a = paired_at(learn_doc([10] * 5, [True] * 5, [10] * 5, [True] * 5, seed=3), chip="a")
    b = paired_at(learn_doc([10] * 5, [True] * 5, [10] * 5, [True] * 5, seed=3), chip="b")
    with pytest.raises(UserError, match="same --seed 3"):
        analyse([a, b])


def test_the_transfer_keeps_a_share_of_the_source_success():
    s = transfer_summary([True] * 10, [True] * 8 + [False] * 2)
    assert s["kept"] == pytest.approx(0.8) and not s["met"] and s["lost"] == 2
    assert transfer_summary([True, False] * 5, [True, False] * 5)["met"]


# -- the commands on emulated chips ------------------------------------------------------------

@pytest.fixture(scope="module")
def two_chips(tmp_path_factory):
    """Two emulated chips of different seed and spread, each characterised on 6 cells and
    learnt on (software and chip arms, 2 sessions x 2 cycles, each its own seed)."""
    d = tmp_path_factory.mktemp("equivalence")
    mp = pytest.MonkeyPatch()
    mp.setenv("XDG_DATA_HOME", str(d / "data"))
    for name, seed, spread, learn_seed in (("a", 1, "1", 11), ("b", 2, "2", 12)):
        state = d / name / "chip.npz"
        state.parent.mkdir()
        assert cli.main(["emu", "--state", str(state), "--reset-chip", "--seed", str(seed),
                         "--spread", spread]) == 0
        mp.setenv("SNAN_HIL_EMU_STATE", str(state))
        assert cli.main(["characterize", "--port", "emu", "--cells",
                         "0,0;0,1;1,2;2,3;3,4;4,5", "--repeats", "1", "--json", "--model",
                         str(d / name / "model.json")]) == 0
        assert cli.main(["learn", "--port", "emu", "--arms", "software,chip", "--sessions",
                         "2", "--cycles", "2", "--seed", str(learn_seed), "--out",
                         str(d / f"run-{name}"), "--set", "grid.max_steps=30", "--json",
                         "--no-figure"]) == 0
    yield d, mp
    mp.undo()


def test_a_chips_learnt_weights_are_tested_on_another_chip(two_chips, capsys):
    d, mp = two_chips
    mp.setenv("SNAN_HIL_EMU_STATE", str(d / "b" / "chip.npz"))
    capsys.readouterr()
    out = d / "a-on-b.json"
    assert cli.main(["transfer", str(d / "run-a"), "--port", "emu", "-o", str(out),
                     "--json"]) == 0
    t = json.loads(out.read_text())
    src = json.loads((d / "run-a" / "learn.json").read_text())
    own = [(s["test_steps"][2], s["test_success"][2]) for s in src["arms"]["chip"]["sessions"]]
    assert [(r["own_steps"], r["own_success"]) for r in t["sessions"]] == own
    assert all(r["program"]["ok"] > 0 for r in t["sessions"])     # written by write-and-verify
    assert t["seed"] == 11 and t["version"] and t["config"]["learn"]["seed"] == 11
    with History.open(d / "b" / "chip.history.sqlite", create=False) as db:
        run = db.runs("transfer")[0]
    assert run.pulses > 0 and run.status == "complete"
    # the analysis pairs the runs' sessions and names the transfer's chips
    capsys.readouterr()
    eq = d / "eq.json"
    assert cli.main(["equivalence", str(d / "run-a"), str(d / "run-b"), "--transfer",
                     str(out), "-o", str(eq), "--json"]) == 0
    res = json.loads(eq.read_text())
    b = json.loads((d / "run-b" / "learn.json").read_text())
    for name, doc in (("run-a", src), ("run-b", b)):
        ok = {arm: sum(s["test_success"][2] for s in doc["arms"][arm]["sessions"]) / 2
              for arm in ("software", "chip")}
        row = res["chips"][name]["success"]
        assert (row["software"], row["chip"]) == (ok["software"], ok["chip"])
    assert res["chips"]["pooled"]["sessions"] == 4
    assert res["transfer"][0]["source"] == "run-a" and res["transfer"][0]["target"] == "run-b"
    assert res["runs"]["run-a"]["seed"] == 11 and res["version"]


@pytest.mark.parametrize("args, words", [
    (["--margin", "1.5"], "--margin must be between 0 and 1"),
    (["--alpha", "0.7"], "--alpha must be between 0 and 0.5"),
    (["--sessions", "9"], "--sessions 9: the run has 2 paired sessions"),
    (["--cycle", "5"], "cycle 5 is outside the run's 0..2"),
])
def test_bad_equivalence_options_are_one_line(two_chips, capsys, args, words):
    d, _mp = two_chips
    assert cli.main(["equivalence", str(d / "run-a"), *args]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and len(err.splitlines()) == 1


def test_bad_inputs_are_refused_in_one_line(two_chips, tmp_path, capsys):
    d, mp = two_chips
    cases = [(["equivalence", str(d / "run-a"), str(d / "run-a")], "given twice"),
             (["equivalence", str(tmp_path)], "no learn.json there"),
             (["equivalence", str(d / "run-a"), "--transfer", str(d / "run-a" / "learn.json")],
              "not a finished 'snan-hil transfer' result"),
             (["equivalence", str(d / "run-a"), "-o", str(d / "run-a" / "learn.json"),
               "--force"], "is also an input"),
             (["transfer", str(d / "a" / "model.json"), "--port", "emu"],
              "not a 'snan-hil learn' result")]
    sw_only = tmp_path / "sw"
    sw_only.mkdir()
    doc = json.loads((d / "run-a" / "learn.json").read_text())
    del doc["arms"]["chip"]
    (sw_only / "learn.json").write_text(json.dumps(doc))
    cases.append((["equivalence", str(sw_only)], "has no chip arm"))
    for args, words in cases:
        capsys.readouterr()
        assert cli.main(args) == 2, args
        err = capsys.readouterr().err.strip()
        assert words in err and len(err.splitlines()) == 1, err
    assert cli.main(["emu", "--state", str(tmp_path / "x.npz"), "--spread", "2"]) == 2
    assert "give it with --reset-chip" in capsys.readouterr().err


def test_a_transfer_onto_the_chip_the_run_learnt_on_is_not_counted_as_cross_chip(
        two_chips, capsys):
    """The transfer claim is about *another* chip: a run's weights written back onto its own
    chip (``transfer run-a`` on chip a) would count as a cross-chip pair; refused in one line,
    no -o written."""
    d, mp = two_chips
    mp.setenv("SNAN_HIL_EMU_STATE", str(d / "a" / "chip.npz"))
    out = d / "a-on-a.json"
    assert cli.main(["transfer", str(d / "run-a"), "--port", "emu", "-o", str(out),
                     "--json"]) == 0
    capsys.readouterr()
    eq = d / "eq-self.json"
    assert cli.main(["equivalence", str(d / "run-a"), str(d / "run-b"), "--transfer",
                     str(out), "-o", str(eq)]) == 2
    err = capsys.readouterr().err.strip()
    assert "tested on the chip run-a learnt on, not on another chip" in err, err
    assert len(err.splitlines()) == 1 and not eq.exists()


def test_one_transfer_per_ordered_pair_of_chips(two_chips, capsys):
    """The same transfer given twice (or two transfers of one ordered pair) would count one
    pair twice in the transfer verdict ('N ordered pairs'); refused in one line."""
    d, mp = two_chips
    mp.setenv("SNAN_HIL_EMU_STATE", str(d / "b" / "chip.npz"))
    out = d / "a-on-b-twice.json"
    assert cli.main(["transfer", str(d / "run-a"), "--port", "emu", "-o", str(out),
                     "--json"]) == 0
    capsys.readouterr()
    assert cli.main(["equivalence", str(d / "run-a"), str(d / "run-b"), "--transfer",
                     str(out), str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "run-a -> run-b is also --transfer" in err and len(err.splitlines()) == 1, err
