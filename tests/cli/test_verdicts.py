"""The paper's claims and their tests (host/claims.py) and the verdict lines demo, compare,
experiment and learn end with (tools/verdicts.py)."""

import json

import pytest

from snan_hil.host import claims as C
from snan_hil.host.claims import Measure
from snan_hil.tools import cli


def med(v, lo, hi, paper=None):
    return Measure(v, (lo, hi), "median_steps", paper)


def rate(v, lo, hi, paper=None):
    return Measure(v, (lo, hi), "success_rate", paper)


def claim(id_):
    return next(c for c in C.CLAIMS if c.id == id_)


def test_effect_reproduced_when_shown_and_the_paper_matches():
    ms = {"10x10/no_astro/median_steps": med(355, 340, 371, 362),
          "10x10/astro/median_steps": med(57, 54, 60, 55)}
    v = C.judge(claim("astro-route-10x10"), ms)
    assert v.verdict == C.REPRODUCED and v.reproduced
    assert v.line() == ("astrocytes shorten the route (Fig. 4B, section 3.2): 10x10 median "
                        "362 -> 55 in the paper; ours 355 [340, 371] -> 57 [54, 60]: reproduced")


def test_effect_direction_only_when_a_paper_value_is_far_outside():
    ms = {"10x10/no_astro/median_steps": med(153, 138, 167, 362),
          "10x10/astro/median_steps": med(81, 78, 84, 55)}
    v = C.judge(claim("astro-route-10x10"), ms)
    assert v.verdict == C.DIRECTION_ONLY
    assert "362 and 55 lie outside" in v.note


def test_effect_not_reproduced_when_the_intervals_overlap_or_reverse():
    overlap = {"10x10/no_astro/median_steps": med(100, 80, 120, 362),
               "10x10/astro/median_steps": med(90, 70, 110, 55)}
    assert C.judge(claim("astro-route-10x10"), overlap).verdict == C.NOT_REPRODUCED
    reverse = {"10x10/no_astro/median_steps": med(50, 45, 55, 362),
               "10x10/astro/median_steps": med(90, 80, 100, 55)}
    v = C.judge(claim("astro-route-10x10"), reverse)
    assert v.verdict == C.NOT_REPRODUCED and "other way" in v.note


def test_match_uses_the_interval_or_the_project_tolerance():
    # 8 [6, 9] against 10: outside the interval, but within 25 % of 10
    assert C.matches(med(8, 6, 9, 10.0)) is True
    assert C.matches(med(7, 6, 7, 10.0)) is False          # 3 steps = 30 % away
    # rates: within 7 points of the paper's value
    assert C.matches(rate(0.94, 0.92, 0.958, (0.97, 1.0))) is True
    assert C.matches(rate(0.86, 0.84, 0.88, (0.97, 1.0))) is False
    assert C.matches(med(8, 6, 9)) is None                  # no paper value


def test_equal_is_undecided_when_the_intervals_are_too_wide():
    c = claim("hw-keeps-astro")
    wide = {"hw6x6/sw_astro/median_steps": med(17, 13, 21, 7),
            "hw6x6/hw_astro/median_steps": med(17, 13, 22, 7)}
    v = C.judge(c, wide)
    assert v.verdict == C.UNDECIDED and "not an equivalence" in v.note and "+0 %" in v.ours
    tight = {"hw6x6/sw_astro/median_steps": med(50, 49, 51, 7),
             "hw6x6/hw_astro/median_steps": med(51, 50, 52, 7)}
    assert C.judge(c, tight).verdict == C.REPRODUCED
    apart = {"hw6x6/sw_astro/median_steps": med(10, 9, 11, 7),
             "hw6x6/hw_astro/median_steps": med(20, 19, 21, 7)}
    assert C.judge(c, apart).verdict == C.NOT_REPRODUCED


def test_range_counts_the_densities_that_miss():
    ms = {f"maze{f}/astro/success_rate": rate(0.99, 0.98, 1.0, (0.97, 1.0))
          for f in (0, 20, 60)}
    assert C.judge(claim("maze-astro"), ms).verdict == C.REPRODUCED
    ms["maze40/astro/success_rate"] = rate(0.85, 0.82, 0.88, (0.97, 1.0))
    v = C.judge(claim("maze-astro"), ms)
    assert v.verdict == C.NOT_REPRODUCED and "3 of 4 densities" in v.note
    assert "40 % walls: 85.0 %" in v.note
    # the no-astrocyte family is not mixed in
    assert C.judge(claim("maze-no-astro"), ms) is None


def test_a_task_without_paper_numbers_is_judged_on_its_direction():
    c = claim("learn-chip")
    shown = {"learn/chip/first/median_steps": med(29, 15, 43),
             "learn/chip/last/median_steps": med(7, 5, 9)}
    v = C.judge(c, shown)
    assert v.verdict == C.REPRODUCED and v.paper == C.NO_NUMBER
    assert "no number in the paper for this task" in v.line()
    overlap = {"learn/chip/first/median_steps": med(7, 7, 7),
               "learn/chip/last/median_steps": med(20, 5, 33)}
    v = C.judge(c, overlap)
    assert v.verdict == C.NOT_REPRODUCED and "no number in the paper" in v.line()


def test_a_claim_without_its_measures_is_not_judged():
    assert C.verdicts("compare", {"scenarios": {}}) == []
    with pytest.raises(KeyError):
        C.measures("sim", {})


def test_demo_ends_with_one_line_per_claim_it_tests(tmp_path, capsys):
    out = tmp_path / "demo"
    assert cli.main(["demo", "--software-only", "--trials", "200", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    tail = text.strip().splitlines()[-5:]
    assert tail[0].startswith("the paper's claims this run tested: ")
    summary = json.loads((out / "demo.json").read_text())
    expected = [v.line() for v in C.verdicts("demo", summary)]
    assert [line for line in tail[1:]] == expected
    assert {v.claim.id for v in C.verdicts("demo", summary)} == {
        "astro-route-3x3", "astro-success-3x3", "astro-route-10x10", "astro-success-10x10"}
    # --json: stdout is the one JSON object, the verdict lines go to stderr
    assert cli.main(["demo", "--software-only", "--trials", "200", "--out",
                     str(tmp_path / "demo2"), "--json"]) == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out)["format"] == "snan-hil-demo/1"
    assert expected[0] in cap.err


def test_compare_software_ends_with_the_6x6_claims(cli_trained, tmp_path, capsys):
    assert cli.main(["compare", "--weights", str(cli_trained), "--scenarios",
                     "sw_noastro,sw_astro", "--launches", "3", "--out", str(tmp_path / "c"),
                     "--no-figure", "--set", "grid.max_steps=15"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-1].startswith("astrocytes halve the 6x6 route in software (Fig. 10C")
    assert "14 -> 7 in the paper; ours" in lines[-1]
    assert not any("crossbar" in line for line in lines[-2:])   # no hardware scenario ran


def test_experiment_ends_with_the_figures_claims(tmp_path, capsys):
    assert cli.main(["experiment", "fig3", "--trials", "40", "--workers", "1", "--out",
                     str(tmp_path / "e")]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-3].startswith("the paper's claims this run tested: ")
    assert lines[-2].startswith("astrocytes shorten the route (Fig. 3, section 3.1): 3x3 "
                                "median 10 -> 4 in the paper; ours ")
    assert lines[-1].startswith("astrocytes raise the success rate (Fig. 3")


def test_learn_ends_with_the_learning_claim(tmp_path, capsys):
    assert cli.main(["learn", "--arms", "software", "--sessions", "3", "--cycles", "3",
                     "--out", str(tmp_path / "l"), "--no-figure"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-2].startswith("route learning shortens the test route in software (Fig. 7a")
    assert "median (first -> last cycle)" in lines[-2]
    assert lines[-1].startswith("route learning raises the success rate in software (Fig. 7b")
