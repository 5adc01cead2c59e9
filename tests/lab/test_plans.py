"""Pulse plans (snan_hil.calibration.plans, ``snan-hil plan``): strict YAML validation, ramps,
terminators on conductance and ADC code, the host limit and compliance on every pulse, the
dry run (no board), history records with the plan, repeat from the history, the presets, and
the time estimate against the emulator's board clock; a step above the board's own write
limit is refused before the first pulse, in the line docs/bench.md quotes."""

from __future__ import annotations

import json
import math

import pytest

from snan_hil.calibration import plans as P
from snan_hil.calibration.board_io import BoardCellIO, CellLimits, PulseLedger
from snan_hil.calibration.readchain import ReadChain
from snan_hil.common.polarity import Polarity
from snan_hil.files.outputs import PNG_KEY
from snan_hil.protocol.board import MEMRICORE
from snan_hil.records.history import History
from snan_hil.tools import cli


def _plan(**over) -> dict:
    tree = {"format": P.PLAN_FORMAT, "name": "t",
            "steps": [{"action": "set", "ramp": {"start_v": 0.3, "stop_v": 0.5,
                                                 "step_v": 0.1}}]}
    tree.update(over)
    return tree


# ------------------------------------------------------------------ validation
@pytest.mark.parametrize("tree, words", [
    (_plan(steps=[{"action": "set", "amplitude_v": 0.8, "widht_us": 100}]),
     ["unknown key steps[0].widht_us", "known there:", "width_us"]),
    (_plan(extra=1), ["unknown key extra", "steps"]),
    (_plan(steps=[{"action": "set", "amplitude_v": 0.8, "count": 2.5}]),
     ["steps[0].count", "expected an integer", "2.5"]),
    (_plan(steps=[{"action": "set", "amplitude_v": 0.8, "count": "3"}]),
     ["steps[0].count", "expected an integer"]),
    (_plan(steps=[{"action": "set", "ramp": {"start_v": 0.3, "stop_v": 1, "step_v": 0}}]),
     ["steps[0].ramp.step_v", "must be > 0"]),
    (_plan(steps=[{"action": "set", "amplitude_v": 0.8, "ramp": {"start_v": 0.3,
                                                                 "stop_v": 1, "step_v": 0.1}}]),
     ["steps[0]", "exactly one of amplitude_v, ramp"]),
    (_plan(steps=[{"action": "read", "amplitude_v": 0.2, "ramp": {
        "start_v": 0.1, "stop_v": 0.2, "step_v": 0.1}}]), ["takes amplitude_v or ramp"]),
    (_plan(steps=[{"action": "zap", "amplitude_v": 0.2}]), ["steps[0].action", "set"]),
    (_plan(steps=[{"action": "set", "amplitude_v": 0.8,
                   "stop_when": {"conductance_s": {"==": 5e-4}}}]), ["give a tolerance"]),
    (_plan(steps=[{"action": "set", "amplitude_v": 0.8,
                   "stop_when": {"conductance_s": {"<": 5e-4, ">": 1e-4}}}]),
     ["exactly one of ==, <, >, in, out"]),
    (_plan(steps=[{"action": "set", "amplitude_v": 0.8,
                   "stop_when": {"adc_code": {"in": [9000, 8000]}}}]), ["low <= high"]),
    (_plan(steps=[]), ["steps", "at least 1"]),
    # a tiny step is refused by its count, before any amplitude is built (1e-12 V filled 24 GB)
    (_plan(steps=[{"action": "set", "ramp": {"start_v": 0.3, "stop_v": 1.2,
                                             "step_v": 1e-12}}]),
     ["steps[0].ramp", "9e+11 amplitudes", "at most 100000", "larger step_v"]),
    (_plan(format="snan-hil-plan/9"), ["not a pulse plan"]),
])
def test_bad_plans_are_one_line_naming_the_key(tree, words):
    with pytest.raises(P.PlanError) as err:
        P.parse_plan(tree, "plan x.yaml")
    text = str(err.value)
    assert "\n" not in text and text.startswith("plan x.yaml")
    for w in words:
        assert w in text, text


def test_yaml_file_is_read_as_yaml_1_2(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text("format: snan-hil-plan/1\nname: y\nsteps:\n  - action: set\n"
                 "    amplitude_v: 8e-1\n    width_us: 010\n")
    plan = P.load_plan(f)
    assert plan.steps[0].amplitude_v == 0.8 and plan.steps[0].width_us == 10   # not octal
    f.write_text("format: snan-hil-plan/1\nname: y\nname: z\nsteps: []\n")
    with pytest.raises(P.PlanError, match="not valid YAML"):
        P.load_plan(f)


def test_ramps_go_up_and_down_and_include_the_stop():
    up = P.Ramp(start_v=0.3, stop_v=0.6, step_v=0.1).amplitudes()
    down = P.Ramp(start_v=0.6, stop_v=0.3, step_v=0.1).amplitudes()
    assert up == (0.3, 0.4, 0.5, 0.6) and down == (0.6, 0.5, 0.4, 0.3)
    assert P.Ramp(start_v=0.3, stop_v=0.65, step_v=0.1).amplitudes()[-1] == 0.6
    plan = P.parse_plan(_plan(repeats=2, steps=[
        {"action": "set", "ramp": {"start_v": 0.3, "stop_v": 0.5, "step_v": 0.1}, "count": 2,
         "repeats": 3}, {"action": "read", "count": 4}]))
    pulses = list(P.expand(plan, MEMRICORE))
    assert len(pulses) == plan.n_pulses() == 2 * (3 * 3 * 2 + 4)
    assert [p.amplitude_v for p in pulses[:6]] == [0.3, 0.3, 0.4, 0.4, 0.5, 0.5]
    assert all(p.applied_v <= p.amplitude_v + 1e-12 for p in pulses)   # DAC floor


def test_every_preset_loads_and_fits_the_host_limits():
    names = P.preset_names()
    for kind in ("iv-curve", "switching-sweep", "endurance", "potentiation-depression",
                 "depression-potentiation",
                 "retention", "parking", "set", "reset", "programming", "measure"):
        assert kind in names
    for name in names:
        plan = P.load_preset(name)
        P.check_plan(plan, MEMRICORE)
        assert max((p.amplitude_v for p in P.expand(plan, MEMRICORE)), default=0) \
            <= MEMRICORE.max_write_v


def test_check_plan_names_the_step_above_the_limit():
    plan = P.parse_plan(_plan(steps=[{"action": "read"}, {"action": "reset", "ramp": {
        "start_v": 0.5, "stop_v": 1.7, "step_v": 0.05}}]))
    with pytest.raises(P.PlanError) as err:
        P.check_plan(plan, MEMRICORE)
    assert "step 2 (RESET ramp 0.5->1.7 V" in str(err.value) and "1.4 V" in str(err.value)
    P.check_plan(plan, MEMRICORE, max_write_v=1.8)         # the limit it is given
    with pytest.raises(P.PlanError, match="lowered by --max-write-v"):
        P.check_plan(plan, MEMRICORE, max_write_v=1.0)


def test_compliance_limit_formula():
    g = P.compliance_g_limit_s(MEMRICORE, 1.4)
    # at that conductance the predicted current is exactly the margin's current
    assert 1.4 / (1 / g + MEMRICORE.r_switch_ohm) == pytest.approx(0.95 * 2e-3)
    assert P.compliance_g_limit_s(MEMRICORE, 0.01) == math.inf


# ------------------------------------------------------------------ terminators (fake cell)
class FakeIO:
    """A cell whose G moves by a fixed factor per pulse; ADC = G in uS x 10."""

    def __init__(self, g=100e-6, factor=1.2, cap_v=10.0):
        self.g, self.factor, self.cap_v = g, factor, cap_v
        self.pulses: list[tuple[Polarity, float]] = []
        self.last_adc = None
        self.width_us = 100

    def _adc(self):
        self.last_adc = int(round(self.g * 1e7))
        return self.g

    def read(self):
        return self._adc()

    def pulse(self, pol, v):
        self.pulses.append((pol, v))
        self.g = self.g * self.factor if pol == Polarity.SET else self.g / self.factor
        return self._adc()

    def amplitude_cap(self, pol, g):
        return self.cap_v


@pytest.mark.parametrize("cond, pulses", [
    ({"conductance_s": {">": 150e-6}}, 3),            # 100 -> 120 -> 144 -> 172.8
    ({"conductance_s": {"in": [140e-6, 150e-6]}}, 2),
    ({"conductance_s": {"out": [90e-6, 130e-6]}}, 2),
    ({"adc_code": {"==": 1440}}, 2),
    ({"adc_code": {">": 2000}}, 4),                   # 207.4 uS
    ({"conductance_s": {"==": 144e-6, "tolerance": 0.01}}, 2),
])
def test_step_terminators(cond, pulses):
    plan = P.parse_plan(_plan(steps=[{"action": "set", "amplitude_v": 0.8, "count": 10,
                                      "stop_when": cond}, {"action": "read", "count": 2}]))
    io = FakeIO()
    reads = []
    [res] = P.run_plan(lambda r, c: io, [(1, 2)], plan,
                       on_read=lambda *a, **k: reads.append(a))
    assert len(io.pulses) == pulses
    assert res.steps[0]["stopped"].endswith("met") and len(reads) == 2   # the plan went on


def test_plan_terminator_ends_the_cell_and_lt_checked_before_the_first_pulse():
    plan = P.parse_plan(_plan(stop_when={"conductance_s": {"<": 60e-6}}, steps=[
        {"action": "reset", "amplitude_v": 0.8, "count": 10},
        {"action": "set", "amplitude_v": 0.8, "count": 10}]))
    io = FakeIO()
    [res] = P.run_plan(lambda r, c: io, [(0, 0)], plan)
    assert len(io.pulses) == 3 and "plan condition" in res.stopped   # 100/1.2^3 = 58 uS
    io2 = FakeIO(g=50e-6)
    [res2] = P.run_plan(lambda r, c: io2, [(0, 0)], plan)
    assert io2.pulses == [] and "already met" in res2.stopped


def test_compliance_ends_the_step_and_the_plan_goes_on():
    plan = P.parse_plan(_plan(steps=[
        {"action": "set", "ramp": {"start_v": 0.5, "stop_v": 1.0, "step_v": 0.1}},
        {"action": "reset", "amplitude_v": 0.6}]))
    io = FakeIO(cap_v=0.75)
    seen = []

    class Obs:
        def on_pulses(self, events):
            seen.extend(events)

        def on_cell(self, event):
            seen.append(event)
    [res] = P.run_plan(lambda r, c: io, [(0, 0)], plan, observer=Obs())
    assert [v for _p, v in io.pulses] == [0.5, 0.6, 0.7, 0.6]
    assert res.steps[0]["stopped"].startswith("compliance") and res.steps[1]["applied"] == 1
    # each pulse reached the observer on its own, as it was applied, then the cell's result
    assert [type(e).__name__ for e in seen] == ["PulseEvent"] * 4 + ["CellEvent"]


# ------------------------------------------------------------------ on the emulator
def test_dry_run_lists_every_pulse_and_opens_nothing(emu, capsys):
    assert cli.main(["plan", "run", "switching-sweep", "--cells", "3,5", "4,5", "--dry-run",
                     "--json", "--port", "emu"]) == 0
    data = json.loads(capsys.readouterr().out)
    plan = P.load_preset("switching-sweep")
    assert len(data["pulses"]) == plan.n_pulses() == 110
    first = data["pulses"][0]
    assert first["host_limit"] == "ok" and first["compliance"] == "G <= 63673 uS"   # 0.05 V
    top = max(data["pulses"], key=lambda r: r["amplitude_v"])
    assert top["applied_v"] <= 1.4 and top["compliance"].startswith("G <= 137")
    assert data["total_s"] == pytest.approx(2 * data["per_cell_s"])
    assert not (emu / "chip.npz").exists() and not list(emu.glob("*.sqlite"))


def test_plan_above_the_limit_is_refused_before_the_board(emu, tmp_path, capsys):
    f = tmp_path / "hot.yaml"
    f.write_text(json.dumps(_plan(steps=[{"action": "set", "amplitude_v": 0.8},
                                         {"action": "set", "amplitude_v": 1.5}])))
    assert cli.main(["plan", "run", str(f), "--cells", "3,5", "--port", "emu"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "step 2 (SET 1.5 V" in err[0] and "nothing was sent" in err[0]
    assert not (emu / "chip.npz").exists() and not list(emu.glob("*.sqlite"))
    # the dry run refuses with the same one line, and prints no table before it
    for extra in ([], ["--json"]):
        assert cli.main(["plan", "run", str(f), "--cells", "3,5", "--dry-run", *extra]) == 2
        out = capsys.readouterr()
        assert out.out == "" and len(out.err.strip().splitlines()) == 1 and "step 2" in out.err


@pytest.mark.parametrize("protocol", ["framed", "legacy"])
def test_run_records_the_plan_and_repeat_runs_it_again(emu, capsys, protocol):
    args = ["--port", "emu", "--protocol", protocol]
    assert cli.main(["plan", "run", "set", "--cells", "3,5", "4,5", *args, "--sample", "w1",
                     "--operator", "ana", "--tag", "t1", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["run"]["sample"] == "w1" and data["run"]["exit_status"] == "success"
    for cell in data["cells"]:
        ok = cell["final_s"] > 800e-6 or cell["stopped"].startswith("all")
        assert ok and cell["pulses"] == len(cell["records"]) >= 1
    with History.open(emu / "chip.history.sqlite", create=False) as db:
        [run] = db.runs(kind="plan")
        assert run.config["plan"]["name"] == "set" and run.config["cells"] == [[3, 5], [4, 5]]
        assert run.pulses == sum(c["pulses"] for c in data["cells"])
        assert (run.uid, run.sample, run.operator, run.tags) == \
            (data["run"]["uid"], "w1", "ana", ("t1",))
    assert cli.main(["plan", "repeat", data["run"]["uid"][:8], "--cells", "6,1", *args,
                     "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert [(c["row"], c["col"]) for c in again["cells"]] == [(6, 1)]
    with History.open(emu / "chip.history.sqlite", create=False) as db:
        runs = db.runs(kind="plan")
        assert len(runs) == 2 and runs[0].config["repeat_of"]["uid"] == data["run"]["uid"]
        # the repeat keeps the original run's sample and operator (issue 38 item 13)
        assert (runs[0].sample, runs[0].operator) == ("w1", "ana")
    assert again["run"]["sample"] == "w1" and again["run"]["operator"] == "ana"
    assert cli.main(["plan", "repeat", data["run"]["uid"][:8], "--cells", "6,1", *args,
                     "--sample", "w2", "--json"]) == 0       # unless the repeat says other
    assert json.loads(capsys.readouterr().out)["run"]["sample"] == "w2"
    assert cli.main(["plan", "repeat", "999", *args]) == 2
    assert "no such run" in capsys.readouterr().err


def test_repeat_refuses_a_run_that_is_not_a_plan(emu, capsys):
    assert cli.main(["map", "--port", "emu", "--json"]) == 0
    capsys.readouterr()
    assert cli.main(["plan", "repeat", "1", "--port", "emu"]) == 2
    assert "not a plan run" in capsys.readouterr().err


def test_cells_file_selects_cells(emu, tmp_path, capsys):
    f = tmp_path / "good.csv"
    f.write_text("row,col,verdict\n2,1,good\n5,7,good\n")
    assert cli.main(["plan", "run", "measure", "--cells-file", str(f), "--dry-run",
                     "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["cells"] == [[2, 1], [5, 7]]
    f.write_text("row,col\n2,9\n")
    assert cli.main(["plan", "run", "measure", "--cells-file", str(f), "--dry-run"]) == 2
    assert "line 2" in capsys.readouterr().err


def test_estimate_is_close_to_the_emulated_board_clock(tmp_path):
    """The dry run's time per pulse against the emulator's virtual clock (framed protocol):
    within 10 % of it."""
    from snan_hil.tools.ports import open_client
    plan = P.parse_plan(_plan(steps=[{"action": "set", "amplitude_v": 0.5, "count": 20,
                                      "width_us": 1000}, {"action": "read", "count": 20}]))
    client = open_client("emu", state_file=str(tmp_path / "c.npz"), seed=1)
    try:
        info = client.info
        io = BoardCellIO(client, ReadChain.nominal(info), 2, 2, CellLimits.of(client.limits, info),
                         PulseLedger())
        io.read()
        t0 = client.clock().time_us
        P.run_plan(lambda r, c: io, [(2, 2)], plan)
        took = (client.clock().time_us - t0) * 1e-6
    finally:
        client.close()
    est = sum(P.pulse_time_s(info, p) for p in P.expand(plan, info))
    est += P.pulse_time_s(info, P.PlannedPulse(0, 1, 1, 1, "read", 0, 0, 0, 0, 0))  # 1st read
    assert est == pytest.approx(took, rel=0.10), (est, took)


def test_a_steps_pulses_go_out_at_the_steps_width_and_are_recorded_so(tmp_path):
    """Found by the port onto the job runner: every pulse of a plan went out at the cell I/O's
    100 us while the history recorded the step's width."""
    import dataclasses

    from snan_hil.lab.opener import FileUse, plan_board
    from snan_hil.lab.ports import BoardAddress
    from snan_hil.lab.runner import RunOptions, run_job
    sent: list[int] = []

    class Spy:
        def __init__(self, client):
            self.client = client

        def write_pulse(self, row, col, polarity, code, width_us, read_code):
            sent.append(int(width_us))
            return self.client.write_pulse(row, col, polarity, code, width_us, read_code)

        def __getattr__(self, name):
            return getattr(self.client, name)
    plan = P.parse_plan(_plan(steps=[{"action": "set", "amplitude_v": 0.4, "count": 2,
                                      "width_us": 300},
                                     {"action": "reset", "amplitude_v": 0.4, "width_us": 40}]))
    board = plan_board(BoardAddress(f"emu://?state={tmp_path / 'c.npz'}&seed=1"),
                       FileUse(record=True))
    with board.open() as session:
        spied = dataclasses.replace(session, client=Spy(session.client))
        done = run_job(P.PlanJob(plan, [(2, 2)], source="test"), spied, RunOptions())
    assert sent == [300, 300, 40]
    with History.open(done.history, create=False) as db:
        rows = db.conn.execute("SELECT width_us, stage FROM pulses ORDER BY n").fetchall()
    assert [tuple(r) for r in rows] == [(300, "plan step 1"), (300, "plan step 1"),
                                        (40, "plan step 2")]


# ------------------------------------------------------------------ current, figures (issue 38)
def test_iv_curve_measures_the_current_in_the_read_range(emu, capsys):
    # item 11: the iv-curve preset read G at 0.3 V after each pulse and recorded no current
    out = emu / "iv.json"
    assert cli.main(["plan", "run", "iv-curve", "--cells", "3,5", "--port", "emu", "-o",
                     str(out), "--json"]) == 0
    capsys.readouterr()
    [cell] = json.loads(out.read_text())["cells"]
    plan = P.load_preset("iv-curve")
    names = [s.name for s in plan.steps]
    reads = [r for r in cell["records"] if r["action"] == "read"]
    assert len(reads) == 3 * (15 + 14) and all(r["current_a"] is not None for r in reads)
    top = MEMRICORE.write_dac_volts(MEMRICORE.max_read_code)
    assert all(0 < r["read_v"] <= top + 1e-9 for r in reads)          # within the read limit
    for r in reads:      # the current through cell and read chain, as the ADC measured it
        series = 1 / r["g_after_s"] + MEMRICORE.r_switch_ohm + MEMRICORE.r_load_ohm
        assert r["current_a"] == pytest.approx(r["read_v"] / series, rel=0.02)
        assert r["cell_v"] == pytest.approx(r["current_a"] / r["g_after_s"], rel=0.02)

    def slope(name):
        up = [r for r in reads if names[r["step"] - 1] == name][:15]
        assert all(b["current_a"] > a["current_a"] for a, b in zip(up, up[1:]))
        return up[-1]["current_a"] / up[-1]["cell_v"]
    assert slope("after SET") > 2 * slope("after RESET")   # low- vs high-resistance state
    pulses = [r for r in cell["records"] if r["action"] != "read"]
    assert pulses and all(r["read_v"] == pytest.approx(top) for r in pulses)


def test_a_read_above_the_read_limit_and_the_old_preset_names_are_refused():
    plan = P.parse_plan(_plan(steps=[{"action": "read", "ramp": {"start_v": 0.1, "stop_v": 0.5,
                                                                 "step_v": 0.1}}]))
    with pytest.raises(P.PlanError, match="a read at 0.5 V is above the board's read limit"):
        P.check_plan(plan, MEMRICORE)
    for old, new in P.RENAMED_PRESETS.items():
        with pytest.raises(P.PlanError, match=f"preset {old} is now {new}"):
            P.load_plan(old)


@pytest.mark.parametrize("preset, panels", [("iv-curve", 3), ("switching-sweep-set", 2)])
def test_plan_run_png_draws_conductance_and_amplitude_per_pulse(emu, capsys, monkeypatch,
                                                                preset, panels):
    # item 10: plan run had no figure of what it measured
    from snan_hil.tools import plan_figures
    seen = []
    real = plan_figures._save

    def spy(plt, fig, path, fmt, dpi=110):
        seen.append([ax.get_ylabel() for ax in fig.axes])
        return real(plt, fig, path, fmt, dpi)
    monkeypatch.setattr(plan_figures, "_save", spy)
    png = emu / "plan.png"
    assert cli.main(["plan", "run", preset, "--cells", "3,5", "4,5", "--port", "emu",
                     "--png", str(png)]) == 0
    assert f"wrote --png {png}" in capsys.readouterr().out
    from PIL import Image
    with Image.open(png) as im:
        assert str(im.text.get(PNG_KEY, "")).startswith("snan-hil-plan-figure/")
    [labels] = seen
    assert len(labels) == 2 * panels
    assert labels[0].startswith("cell conductance (uS)") and labels[1] == "applied voltage (V)"
    if panels == 3:
        assert labels[2] == "current measured by the ADC (uA)"
    assert cli.main(["plan", "run", preset, "--cells", "3,5", "--dry-run", "--png",
                     str(emu / "x.png")]) == 2
    assert "--png would get no result" in capsys.readouterr().err


def test_a_plan_past_the_boards_own_limit_is_refused_before_its_first_pulse(emu, one_line):
    # found by a fresh-user pass: --max-write-v 1.6 let step 1 run, the board refused step 2
    plan = emu / "hot.yaml"
    plan.write_text("format: snan-hil-plan/1\nname: hot\nsteps:\n"
                    "  - {action: set, amplitude_v: 0.8}\n  - {action: set, amplitude_v: 1.5}\n")
    assert cli.main(["plan", "run", str(plan), "--cells", "1,1", "--max-write-v", "1.6",
                     "--port", "emu"]) == 2
    # now --max-write-v cannot raise the board's limit (issue 32): refused before the plan
    assert "--max-write-v 1.6: above the board's declared write limit 1.4 V" in one_line()
    from snan_hil.records import history as H
    for db_path in emu.rglob("*.sqlite"):
        with H.History.open(db_path, create=False) as db:
            assert not db.runs(kind="plan")                        # nothing ran, nothing sent


def test_the_plan_limit_example_of_bench_md_is_the_real_line(emu, one_line, monkeypatch):
    # found by a fresh-user pass: the doc's line named the plan file, the real one does not
    import re
    from pathlib import Path
    doc = " ".join((Path(__file__).parents[2] / "docs" / "bench.md").read_text().split())
    [quoted] = re.findall(r"`(snan-hil plan: error: plan t: step 2 .*?nothing was sent)`", doc)
    monkeypatch.chdir(emu)
    (emu / "hot.yaml").write_text("format: snan-hil-plan/1\nname: t\nsteps:\n"
                                  "  - {action: set, amplitude_v: 0.8}\n"
                                  "  - {action: set, amplitude_v: 1.5}\n")
    assert cli.main(["plan", "run", "hot.yaml", "--cells", "3,5", "--port", "emu"]) == 2
    assert one_line() == quoted


def test_a_dry_run_never_raises_the_write_limit(tmp_path, capsys):
    # found by a new user: --dry-run took --max-write-v 2.0 above MemriCore's 1.4 V and listed
    # 1.6 and 1.8 V pulses as "host limit: ok"; the real run refuses the option
    plan = tmp_path / "hi.yaml"
    plan.write_text("format: snan-hil-plan/1\nname: hi\nsteps:\n  - action: set\n"
                    "    ramp: {start_v: 1.0, stop_v: 1.8, step_v: 0.2}\n    width_us: 100\n")
    assert cli.main(["plan", "run", str(plan), "--cells", "3,5", "--max-write-v", "2.0",
                     "--dry-run"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--max-write-v 2.0: above the board's declared write limit" in err
    assert cli.main(["plan", "run", str(plan), "--cells", "3,5", "--max-write-v", "1.2",
                     "--dry-run"]) == 2
    assert "1.8 V is above the host's write limit 1.2 V" in capsys.readouterr().err
