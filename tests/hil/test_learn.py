"""Learning with the weights on a device (``snan-hil learn``, docs/learning.md): STDP updates
as pulses with a per-synapse remainder, the three arms on paired seeds, the pulse ledger against
the chip history, resume after a kill without any pulse applied twice, and compare on the
chip's learnt state."""

import json
import math

import numpy as np
import pytest

from snan_hil.calibration.mapping import WeightMap
from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.fitted import DeviceModel, LearningPulse
from snan_hil.host.hil.learn import LearnConfig
from snan_hil.host.hil.learning import DeviceModelSynapses, PulsePlanner, synapse_index
from snan_hil.records.history import History
from snan_hil.tools import cli

WM = WeightMap()


def soft_model(up=0.04, down=0.03, std=0.0, dtod=0.0, read=0.0) -> DeviceModel:
    """A chip-level model: soft bounds in ln G at 50 uS .. 1.2 mS around the weight map's
    middle, no per-cell fits."""
    g_ref = WM.conductance(0.5)
    x_ref = math.log(g_ref)
    x_max, x_min = math.log(1.2e-3), math.log(40e-6)
    return DeviceModel(LearningPulse(), g_ref, (up + down) / 2, (up - down) / (up + down), dtod,
                       0.0, std, 40e-6, 1.2e-3, 0.0, 0.0, up / (x_max - x_ref), 0.0,
                       down / (x_ref - x_min), 0.0, read)


def planner(model=None, keys=((0, 0), (0, 1))) -> PulsePlanner:
    p = PulsePlanner(model or soft_model(), WM, {k: (i, 0) for i, k in enumerate(keys)},
                     0.001, 1.0)
    p.start({k: 0.5 for k in keys})
    return p


def test_updates_smaller_than_a_step_accumulate_in_the_remainder():
    p = planner()
    step = p.step((0, 0), Polarity.SET, 0.5)
    assert 0.01 < step < 0.05
    sent = 0
    for _ in range(40):                       # 40 updates of a tenth of a step each
        p.update((0, 0), step / 10)
        sent += sum(o.count for o in p.plan())
        assert abs(p.remainder((0, 0))) <= 0.5 * step + 1e-12
    # four (first) steps worth was asked: a few pulses were sent, none of it was lost
    assert 3 <= sent <= 8
    assert abs(p.w_int[(0, 0)] - 0.5 - 4 * step) < 1e-12
    assert abs(p.w_est[(0, 0)] - p.w_int[(0, 0)]) <= 0.6 * step


def test_a_large_update_becomes_a_train_and_stays_inside_the_window():
    p = planner()
    p.update((0, 0), +2.0)                    # far beyond w_max: clipped like the software rule
    p.update((0, 1), -2.0)
    orders = {o.key: o for o in p.plan()}
    up, down = orders[(0, 0)], orders[(0, 1)]
    assert up.polarity == Polarity.SET and down.polarity == Polarity.RESET
    assert p.w_int[(0, 0)] == 1.0 and p.w_int[(0, 1)] == 0.001
    assert p.w_est[(0, 0)] <= 1.0 + 0.5 * abs(up.steps[-1])
    assert p.w_est[(0, 1)] >= 0.001 - 0.5 * abs(down.steps[-1])
    # the model's SET steps shrink towards the top, so a train's steps decrease
    assert all(a >= b for a, b in zip(up.steps, up.steps[1:]))
    before = p.w_est[(0, 0)]
    p.not_applied((0, 0), up.steps[-3:])      # three pulses lost: the estimate moves back
    assert p.w_est[(0, 0)] == pytest.approx(before - sum(up.steps[-3:]))
    assert sum(o.count for o in p.plan([(0, 0)])) == 3


def test_the_device_arm_hits_the_intended_weights_with_an_exact_noiseless_model():
    nbr = np.array([[1, -1, 2, -1], [0, -1, -1, -1], [0, -1, -1, -1]])
    keys = synapse_index(nbr)
    model = soft_model()
    p = PulsePlanner(model, WM, {k: (i, -1) for i, k in enumerate(keys)}, 0.001, 1.0)
    dev = DeviceModelSynapses(model, WM, nbr, p, np.random.default_rng(0), program_sigma=0.0)
    start = {k: 0.6 for k in keys}
    dev.program(start)
    p.start(start, dev.true_weights())
    rng = np.random.default_rng(1)
    for _ in range(30):
        for k in keys:
            p.update(k, float(rng.normal(0, 0.05)))
        dev.apply(p.plan())
        for k in keys:
            # rounding to the nearest whole pulse in one direction: within half the larger
            # of the two steps there (no back-and-forth within a plan)
            step = max(abs(p.step(k, pol, p.w_est[k] + d)) for pol in (Polarity.SET,
                       Polarity.RESET) for d in (-0.03, 0.0, 0.03))
            assert abs(dev.true_weights()[k] - p.w_int[k]) <= 0.5 * step + 1e-9
            assert dev.true_weights()[k] == pytest.approx(p.w_est[k], abs=1e-12)
    # with cycle-to-cycle noise the same plan scatters around the intent (open loop)
    noisy = soft_model(std=0.3)
    p2 = PulsePlanner(noisy, WM, {k: (i, -1) for i, k in enumerate(keys)}, 0.001, 1.0)
    dev2 = DeviceModelSynapses(noisy, WM, nbr, p2, np.random.default_rng(0), program_sigma=0.0)
    dev2.program(start)
    p2.start(start, dev2.true_weights())
    for k in keys:
        p2.update(k, 0.3)
    dev2.apply(p2.plan())
    errors = [dev2.true_weights()[k] - p2.w_int[k] for k in keys]
    assert max(abs(e) for e in errors) > 0.005


@pytest.fixture(scope="module")
def chip_env(tmp_path_factory):
    """An emulated board (in-process, framed), characterised on 6 cells: the model file."""
    d = tmp_path_factory.mktemp("learn")
    env = {"SNAN_HIL_EMU_STATE": str(d / "chip.npz"), "XDG_DATA_HOME": str(d / "data")}
    mp = pytest.MonkeyPatch()
    for k, v in env.items():
        mp.setenv(k, v)
    assert cli.main(["characterize", "--port", "emu", "--cells", "0,0;0,1;1,2;2,3;3,4;4,5",
                     "--repeats", "1", "--json", "--model", str(d / "model.json")]) == 0
    yield d
    mp.undo()


def _run(args, capsys):
    rc = cli.main(["learn", "--port", "emu", "--json", *args])
    out = capsys.readouterr().out
    assert rc == 0, out
    return json.loads(out)


def test_three_arms_on_paired_seeds_with_the_ledger_equal_to_the_chip_history(
        chip_env, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(chip_env / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(chip_env / "data"))
    out = tmp_path / "run"
    res = _run(["--sessions", "2", "--cycles", "2", "--out", str(out), "--set",
                "grid.max_steps=30"], capsys)
    doc = json.loads((out / "learn.json").read_text())
    assert set(doc["arms"]) == {"software", "device", "chip"}
    # paired: every arm's session k starts from the same initial weights and task; the
    # software arm reproduces route learning's own session (the trial kernel)
    for arm in doc["arms"].values():
        assert len(arm["sessions"]) == 2 and len(arm["sessions"][0]["test_steps"]) == 3
    led = doc["ledger"]
    assert led["total"] == res["ledger_total"] > 0 and led["uncertain"] == 0
    assert doc["history"]["pulses_recorded"] == led["total"]
    with History.open(doc["history"]["path"], create=False) as db:
        run = db.runs("learn")[0]
    assert run.pulses == led["total"] and run.status == "complete"
    assert sum(led["per_cell"].values()) == led["total"]
    learning = [r for r in led["rows"] if r["stage"].startswith("learn")]
    assert learning and all(r["energy_j"] is not None and r["energy_j"] > 0
                            for r in learning if r["set"] + r["reset"])
    assert doc["link_summary"]["wire_s_at_115200"] > 0
    for name in ("curves.csv", "sessions.csv", "ledger.csv", "learn.png", "learnt.npz"):
        assert (out / name).is_file(), name
    # the chip's learnt state launches without reprogramming
    cmp_out = tmp_path / "cmp"
    rc = cli.main(["compare", "--weights", str(out / "learnt.npz"), "--weight-set", "1",
                   "--no-program", "--port", "emu", "--launches", "2", "--out", str(cmp_out),
                   "--scenarios", "sw_noastro,hw_noastro", "--no-figure", "--json",
                   "--set", "grid.max_steps=30"])
    assert rc == 0, capsys.readouterr()
    cmp = json.loads(capsys.readouterr().out)
    assert set(cmp["scenarios"]) == {"sw_noastro", "hw_noastro"}


def _journal(out):
    """The run's pulse journal (the job runner's, in the checkpoint): its lines."""
    return [json.loads(x) for x in
            (out / "checkpoint" / "pulses.jsonl").read_text().splitlines() if x.strip()]


def _kill_after_reply(monkeypatch, sent, kill_at, stage="learn"):
    """The board applies pulse ``kill_at["n"]`` of ``stage`` and the process dies before its
    reply reaches the host (a KeyboardInterrupt out of WRITE_PULSE); ``sent``: every pulse
    the board applied, by stage ("learn" or "other")."""
    from snan_hil.calibration import board_io
    real = board_io.BoardCellIO.pulse

    def counting(self, polarity, amplitude_v):
        mine = "learn" if self.stage == "learn" else "other"
        client = self.client

        class Cut:                                # the request goes out, the reply is lost
            def __getattr__(self, name):
                return getattr(client, name)

            def write_pulse(self, *a, **k):
                adc = client.write_pulse(*a, **k)
                sent[mine] += 1
                if mine == stage and sent[mine] == kill_at["n"]:
                    raise KeyboardInterrupt
                return adc
        self.client = Cut()
        try:
            return real(self, polarity, amplitude_v)
        finally:
            self.client = client
    monkeypatch.setattr(board_io.BoardCellIO, "pulse", counting)


@pytest.mark.parametrize("mode", [None, "batch"], ids=["on-board-default", "batch"])
def test_a_killed_run_resumes_without_applying_any_pulse_twice(chip_env, tmp_path,
                                                              monkeypatch, capsys, mode):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(chip_env / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(chip_env / "data"))
    sent = {"learn": 0, "other": 0}
    kill_at = {"n": 5}
    _kill_after_reply(monkeypatch, sent, kill_at)
    out = tmp_path / "run"
    argv = ["learn", "--port", "emu", "--json", "--sessions", "1", "--cycles", "3", "--arms",
            "chip", "--out", str(out), "--set", "grid.max_steps=30",
            *(["--mode", mode] if mode else [])]
    assert cli.main(argv) == 130                        # interrupted like Ctrl-C
    err = capsys.readouterr().err.splitlines()
    assert err[-2:] == ["snan-hil learn: interrupted", "snan-hil learn: to continue where it "
                        "stopped: snan-hil " + " ".join(argv) + " --resume"]   # how to resume
    assert _journal(out)[-1]["s"] == "sent"             # the kill came between send and reply
    kill_at["n"] = -1
    assert cli.main([*argv, "--resume"]) == 0
    capsys.readouterr()
    doc = json.loads((out / "learn.json").read_text())
    assert doc["chip_mode"] == (mode or "on_board")
    led = doc["ledger"]
    # every pulse the board applied is in the ledger once, or counted uncertain (the one in
    # flight at the kill, never resent)
    assert led["uncertain"] == 1
    assert led["total"] + led["uncertain"] == sent["learn"] + sent["other"]
    sends = [(d["r"], d["n"]) for d in _journal(out) if d["s"] == "sent"]
    assert len(sends) == len(set(sends)) == sent["learn"] + sent["other"]
    assert doc["history"]["pulses_recorded"] == led["total"]


class _Killed(BaseException):
    """The process dies here (SIGKILL): no clean-up writes anything more."""


def _mark_crashed(history_path):
    """What every reader of the history makes of a run whose process died (SIGKILL): its
    runs still 'running' are crashed (the in-process kill leaves this process alive)."""
    import sqlite3
    with sqlite3.connect(history_path) as db:
        db.execute("UPDATE runs SET status = 'crashed' WHERE status = 'running'")


def test_a_sigkilled_runs_buffered_pulses_are_recorded_at_resume(chip_env, tmp_path,
                                                                 monkeypatch, capsys):
    """A kill -9 loses what the history recorder buffered (FLUSH_INTERVAL_S); the pulses the
    journal marks done are recorded at --resume (into the killed run, stage recovered), so
    the history of the whole run (killed and resumed parts) holds every ledger pulse."""
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(chip_env / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(chip_env / "data"))
    from snan_hil.calibration import board_io
    from snan_hil.records import history
    monkeypatch.setattr(history, "FLUSH_INTERVAL_S", 1e9)   # learning pulses stay buffered
    real_pulse, real_flush = board_io.BoardCellIO.pulse, history.Recorder.flush
    state = {"learn": 0, "kill_at": 7, "dead": False}

    def pulse(self, polarity, amplitude_v):
        g = real_pulse(self, polarity, amplitude_v)
        if self.stage == "learn":
            state["learn"] += 1
            if state["learn"] == state["kill_at"]:
                state["dead"] = True
                raise _Killed
        return g

    def flush(self):
        if state["dead"]:                   # a dead process writes nothing: the buffer is lost
            self._cells, self._pulses, self._docs = [], [], []
            self._close_db()
            return
        real_flush(self)
    monkeypatch.setattr(board_io.BoardCellIO, "pulse", pulse)
    monkeypatch.setattr(history.Recorder, "flush", flush)
    monkeypatch.setattr(history.History, "end_run", lambda *a, **k: None)
    out = tmp_path / "run"
    argv = ["learn", "--port", "emu", "--json", "--sessions", "1", "--cycles", "2", "--arms",
            "chip", "--out", str(out), "--set", "grid.max_steps=30"]
    with pytest.raises(_Killed):
        cli.main(argv)
    capsys.readouterr()
    monkeypatch.setattr(history.Recorder, "flush", real_flush)
    monkeypatch.undo()
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(chip_env / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(chip_env / "data"))
    hist_path = chip_env / "chip.history.sqlite"
    _mark_crashed(hist_path)
    assert cli.main([*argv, "--resume"]) == 0
    res = json.loads(capsys.readouterr().out)
    doc = json.loads((out / "learn.json").read_text())
    led, hist = doc["ledger"], doc["history"]
    assert hist["recovered"] == state["kill_at"]           # journalled done, never written
    assert len(hist["runs"]) == 2 and res["history"]["pulses_recorded"] == led["total"]
    with History.open(hist["path"], create=False) as db:
        runs = [db.run(r) for r in hist["runs"]]
        recovered = db.conn.execute("SELECT count(*) FROM pulses WHERE run_id = ? AND stage "
                                    "= 'recovered'", (hist["runs"][0],)).fetchone()[0]
    assert sum(r.pulses for r in runs) == led["total"]     # every ledger pulse, once
    assert recovered == state["kill_at"]


def test_bad_options_are_one_line(chip_env, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(chip_env / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(chip_env / "data"))
    for argv, text in ((["--arms", "chip,robot"], "unknown robot"),
                       (["--set-v", "0.9"], "no device model of the learning pulse (SET 0.9 V"),
                       (["--grid", "10"], "360 synapses"),
                       (["--sessions", "0"], "--sessions"),
                       (["--model", str(tmp_path / "none.json")], "none.json: no such file"),
                       (["--model", str(tmp_path)], "not a device model")):
        assert cli.main(["learn", "--port", "emu", "--out", str(tmp_path / "o"), *argv]) == 2
        err = capsys.readouterr().err
        assert text in err and "Traceback" not in err, err


def test_the_chip_arm_runs_over_the_existing_firmwares_line_protocol(chip_env, tmp_path,
                                                                      monkeypatch, capsys):
    """Mode-7 pulses and single-cell (mode 9) reads: no STATUS counter, no CLOCK; the ledger
    still equals the history, and the energy is the host's estimate only."""
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(chip_env / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(chip_env / "data"))
    out = tmp_path / "legacy"
    rc = cli.main(["learn", "--port", "emu", "--protocol", "legacy", "--json", "--sessions", "1",
                   "--cycles", "2", "--arms", "chip", "--out", str(out), "--model",
                   str(chip_env / "model.json"), "--set", "grid.max_steps=20"])
    assert rc == 0
    capsys.readouterr()
    doc = json.loads((out / "learn.json").read_text())
    led = doc["ledger"]
    assert led["total"] > 0 and doc["history"]["pulses_recorded"] == led["total"]
    learning = [r for r in led["rows"] if r["stage"].startswith("learn")]
    assert all(r["energy_j"] is None for r in learning)
    assert any(r["energy_estimate_j"] > 0 for r in learning)


def _chip_copy(chip_env, dest, monkeypatch):
    """A copy of the characterised chip (state file and data folder) at ``dest``: runs on
    copies start from the same chip."""
    import shutil
    dest.mkdir(parents=True, exist_ok=True)
    for f in chip_env.glob("chip.*"):                   # state, its journal, history, layout
        shutil.copy(f, dest / f.name)
    if (chip_env / "data").is_dir():
        shutil.copytree(chip_env / "data", dest / "data")
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(dest / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(dest / "data"))


def test_the_on_board_window_learns_as_the_batch_mode_on_the_same_chip(chip_env, tmp_path,
                                                                      monkeypatch, capsys):
    """learn's default on a framed board is the on-board decision window: the board runs the
    motor neurons and answers their spike steps, the host's STDP pairs them with its input
    spikes. With the board's standard reads (--conversions 0: ten averages, as SPIKE_BATCH)
    on copies of one chip (the same reads: same SPI sequence, same noise draws) it gives the
    batch mode's (host float LIF on SPIKE_BATCH drives) routes, STDP updates (the intended
    weights of every plan), pulses and learnt weights, on fewer bytes per decision. (The lean
    read plan, the board's default, takes other reads: bench/bench_window.py measures how
    many decisions it keeps.)"""
    docs, plans = {}, {}
    for mode in ("batch", None):
        _chip_copy(chip_env, tmp_path / f"chip-{mode}", monkeypatch)
        out = tmp_path / f"run-{mode}"
        _run(["--sessions", "1", "--cycles", "2", "--arms", "chip", "--out", str(out),
              "--model", str(chip_env / "model.json"), "--set", "grid.max_steps=30",
              *(["--mode", mode] if mode else ["--conversions", "0"])], capsys)
        docs[mode] = json.loads((out / "learn.json").read_text())
        plans[mode] = [json.loads((out / "checkpoint" / f"unit-chip-s0-c{c}-plan.json")
                                  .read_text())["data"] for c in (1, 2)]
    batch, board = docs["batch"], docs[None]
    assert (batch["chip_mode"], board["chip_mode"]) == ("batch", "on_board")
    sb, so = batch["arms"]["chip"]["sessions"][0], board["arms"]["chip"]["sessions"][0]
    assert sum(sb["pulses"]) > 0                        # it learnt: STDP became pulses
    assert so == sb                                     # routes, pulses, learnt weights
    for pb, po in zip(plans["batch"], plans[None]):
        assert po["train"] == pb["train"]
        assert po["planner"] == pb["planner"]           # the same STDP updates
        assert po["orders"] == pb["orders"]
    assert _same_counts(board, batch) and board["ledger"]["total"] == batch["ledger"]["total"]
    per_b = [c["read_bytes"] / c["read_decisions"] for c in batch["link"]]
    per_o = [c["read_bytes"] / c["read_decisions"] for c in board["link"]]
    assert max(per_o) < min(per_b) / 5, (per_o, per_b)


def _same_counts(a, b) -> bool:
    """The ledgers' pulse counts per stage (their energies are the boards' own clocks)."""
    def key(d):
        return [(r["session"], r["cycle"], r["stage"], r["set"], r["reset"])
                for r in d["ledger"]["rows"]]
    return key(a) == key(b) and a["ledger"]["per_cell"] == b["ledger"]["per_cell"]


def test_learn_takes_the_on_board_window_where_the_board_has_it(tmp_path):
    """The chip arm's default is the board's (as run's): on_board with DECISION_WINDOW, batch
    on a board without it; on-board asked of a board without it is one line."""
    from snan_hil.common.errors import UserError
    from snan_hil.firmware_emu.testing import lossy_inprocess_client
    from snan_hil.host.hil.learn import LearnConfig, LearnTask
    from snan_hil.host.hil.synapses import check_mode
    from snan_hil.protocol.device import DeviceEndpoint
    from snan_hil.protocol.link import LinkClient
    from snan_hil.protocol.testing import FakeBoard
    from snan_hil.protocol.transport import CallbackTransport
    from snan_hil.tools.commands.learn import model_config
    import argparse
    cfg, start, goal = model_config(argparse.Namespace(grid=6, start=None, goal=None,
                                                       config=None, overrides=[]))
    train = LearnTask(cfg, LearnConfig(start=start, goal=goal)).train_cfg
    client, _ = lossy_inprocess_client(tmp_path / "chip.npz")
    fake = FakeBoard()
    old = LinkClient(CallbackTransport(DeviceEndpoint(fake, boot_nonce=fake.boot_nonce).feed,
                                       name="old-board"))
    try:
        client.hello()
        old.hello()
        assert check_mode(client, None, train) == "on_board"
        assert check_mode(client, "batch", train) == "batch"
        assert check_mode(old, None, train) == "batch"
        with pytest.raises(UserError, match="no DECISION_WINDOW"):
            check_mode(old, "on_board", train)
    finally:
        client.close()


def test_on_board_over_the_legacy_protocol_is_one_line(chip_env, tmp_path, monkeypatch,
                                                       capsys):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(chip_env / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(chip_env / "data"))
    out = tmp_path / "o"
    rc = cli.main(["learn", "--port", "emu", "--protocol", "legacy", "--mode", "on-board",
                   "--arms", "chip", "--out", str(out), "--model", str(chip_env / "model.json")])
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err
    lines = [x for x in err.splitlines() if x.strip()]
    assert len(lines) == 1 and "DECISION_WINDOW" in lines[0] and "--mode per-window" in lines[0]
    assert not out.exists()                             # refused before any work


def test_a_resumed_cycle_learns_from_its_journal_which_planned_pulses_ran():
    """replay_plan: each earlier attempt sends the plan's pulses it has not seen done, lost or
    uncertain, in order (an uncertain pulse ends its order: the cell is re-planned), then
    pulses outside the plan (re-planned cells, a refresh)."""
    from snan_hil.host.hil.learn_chip import replay_plan
    from snan_hil.host.hil.learning import PulseOrder
    from snan_hil.records.journal import JournalPulse
    a = PulseOrder((0, 0), 1, 0, Polarity.SET, (0.1, 0.1, 0.1))
    b = PulseOrder((0, 1), 2, 0, Polarity.RESET, (-0.1, -0.1))
    c = PulseOrder((1, 0), 3, 0, Polarity.SET, (0.1,))

    def p(run, n, order, state):
        return JournalPulse(run, n, state, "chip-s0-c1", order.row, order.col,
                            order.polarity.name, 0.8, 100, "learn")
    first = [p("r1", 0, a, "done"), p("r1", 1, a, "done"), p("r1", 2, a, "sent")]
    second = [p("r2", 0, b, "done"), p("r2", 1, b, "lost"), p("r2", 2, c, "sent")]
    got = replay_plan([a, b, c], first + second)
    assert got.states == {(0, 0): "done", (0, 1): "done", (0, 2): "sent", (1, 0): "done",
                          (1, 1): "lost", (2, 0): "sent"} and got.extra == []
    # a plan done to its end, then a refresh pulse on another cell: outside the plan
    refresh = JournalPulse("r1", 3, "done", "chip-s0-c1", 9, 9, "SET", 0.8, 100, "learn")
    whole = [p("r1", 0, c, "done"), refresh]
    got = replay_plan([c], whole)
    assert got.states == {(0, 0): "done"} and got.extra == [refresh]
    # pulses of a superseded plan are outside this one
    assert replay_plan([c], whole, frozenset({("r1", 0), ("r1", 3)})).extra == whole
    with pytest.raises(RuntimeError, match="not the committed plan's next pulse"):
        replay_plan([b], first)


def test_a_cycle_resumed_with_two_uncertain_cells_replans_both_under_their_own_keys(
        chip_env, tmp_path, monkeypatch, capsys):
    """Killed twice inside one cycle's pulses, each time between a pulse's request and its
    reply, on two cells: the third run counts both pulses uncertain (never sent again), reads
    both cells and plans them anew; every pulse of the journal has its own (run, n) (the old
    learn journal keyed both cells' re-planned pulses (10001, 0, 0)), and the ledger holds
    every pulse the board applied once, the two uncertain aside."""
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(chip_env / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(chip_env / "data"))
    sent = {"learn": 0, "other": 0}
    kill_at = {"n": 5}
    _kill_after_reply(monkeypatch, sent, kill_at)
    out = tmp_path / "run"
    argv = ["learn", "--port", "emu", "--json", "--sessions", "1", "--cycles", "2", "--arms",
            "chip", "--out", str(out), "--set", "grid.max_steps=30", "--mode", "batch"]
    assert cli.main(argv) == 130
    kill_at["n"] = sent["learn"] + 1                    # the next run's first learning pulse
    assert cli.main([*argv, "--resume"]) == 130
    kill_at["n"] = -1
    assert cli.main([*argv, "--resume"]) == 0
    capsys.readouterr()
    lines = _journal(out)
    uncertain = [d for d in lines if d["s"] == "sent"
                 and not any(e["s"] in ("done", "lost") and (e["r"], e["n"]) == (d["r"], d["n"])
                             for e in lines)]
    assert len(uncertain) == 2 and uncertain[0]["u"] == uncertain[1]["u"] == "chip-s0-c1"
    assert uncertain[0]["c"] != uncertain[1]["c"]       # two cells of one cycle
    sends = [(d["r"], d["n"]) for d in lines if d["s"] == "sent"]
    assert len(sends) == len(set(sends)) == sent["learn"] + sent["other"]
    runs = list(dict.fromkeys(d["r"] for d in lines))
    assert len(runs) == 3
    last = [d for d in lines if d["r"] == runs[-1] and d["s"] == "sent"
            and d["u"] == "chip-s0-c1"]
    for u in uncertain:                                 # each cell read and planned anew
        assert any(d["c"] == u["c"] for d in last)
    doc = json.loads((out / "learn.json").read_text())
    led = doc["ledger"]
    assert led["uncertain"] == 2
    assert led["total"] + led["uncertain"] == sent["learn"] + sent["other"]
    assert doc["history"]["pulses_recorded"] == led["total"]
    cycle1 = next(r for r in led["rows"] if r["cycle"] == 1 and r["stage"] == "learn")
    assert cycle1["uncertain"] == 2


def test_the_result_comes_from_the_units_records_also_for_an_interrupted_run():
    """LearnJob.result: the document from the records alone; "interrupted": the sessions
    that finished, the curves of those; "complete" with a session missing is an error."""
    import argparse

    from snan_hil.host.hil.learn import LearnJob, run_here
    from snan_hil.tools.commands.learn import model_config
    cfg, start, goal = model_config(argparse.Namespace(grid=3, start=None, goal=None,
                                                       config=None,
                                                       overrides=["grid.max_steps=10"]))
    lc = LearnConfig(start=start, goal=goal, sessions=2, cycles=1, arms=("software",))
    job = LearnJob(cfg, lc)
    units = job.units()
    assert [u.key for u in units] == ["software-s0", "software-s1"]
    assert all(u.group is None and not u.on_board for u in units) and job.groups() == []
    records = run_here(job, units[:1], None, None)
    doc = job.result(records, "interrupted")
    assert len(doc["arms"]["software"]["sessions"]) == 1
    assert doc["arms"]["software"]["curves"]["sessions"] == 1
    assert "ledger" not in doc
    with pytest.raises(RuntimeError, match="sessions missing"):
        job.result(records, "complete")
    whole = LearnJob(cfg, lc).result({**records, **run_here(job, units[1:], None, None)},
                                     "complete")
    assert whole["arms"]["software"]["curves"]["sessions"] == 2


def test_a_read_plan_the_board_cannot_run_is_refused_before_the_chip_is_programmed(
        chip_env, tmp_path, monkeypatch, capsys):
    """--conversions beyond the board's averages: one line naming the conversions, exit 2,
    and no pulse on the chip (the job's plan checks the on-board read plan before the chip
    arm programs its first session)."""
    import sqlite3
    _chip_copy(chip_env, tmp_path / "chip", monkeypatch)
    dbs = [p for p in (tmp_path / "chip").rglob("*") if p.is_file()
           and p.read_bytes()[:15] == b"SQLite format 3"]

    def pulses() -> int:
        total = 0
        for db in dbs:
            with sqlite3.connect(db) as c:
                if c.execute("SELECT name FROM sqlite_master WHERE name = 'pulses'").fetchone():
                    total += c.execute("SELECT COUNT(*) FROM pulses").fetchone()[0]
        return total
    before = pulses()
    assert dbs and before > 0                  # the characterisation's pulses are recorded
    rc = cli.main(["learn", "--port", "emu", "--json", "--sessions", "1", "--cycles", "1",
                   "--arms", "chip", "--out", str(tmp_path / "run"), "--model",
                   str(chip_env / "model.json"), "--set", "grid.max_steps=30",
                   "--conversions", "11"])
    err = capsys.readouterr().err
    assert rc == 2 and "conversions" in err and "Traceback" not in err
    assert pulses() == before


def test_the_report_gives_the_device_arms_prediction_with_its_paired_interval(capsys):
    """The device-model arm's cycle-C route against the chip arm's: the ratio of the medians
    and its paired-bootstrap interval over the sessions both arms finished."""
    from snan_hil.host.intervals import median_ratio_interval
    from snan_hil.tools.commands.learn import _print_prediction_and_budget
    rng = np.random.default_rng(3)
    dev = rng.integers(3, 40, 30)
    chip = np.maximum(dev + rng.integers(-6, 7, 30), 3)
    ok_d, ok_c = dev < 38, chip < 38

    def arm(steps, ok, n):
        return {"sessions": [{"test_steps": [100, int(s)], "test_success": [False, bool(k)]}
                             for s, k in zip(steps[:n], ok[:n])],
                "curves": {"median": [None, float(np.median(steps[:n][ok[:n]]))]}}
    # the chip arm was stopped after 25 sessions (one more half done): 25 pairs
    chip_arm = arm(chip, ok_c, 25)
    chip_arm["sessions"].append({"test_steps": [100], "test_success": [False]})
    doc = {"arms": {"device": arm(dev, ok_d, 30), "chip": chip_arm}, "config": {}}
    _print_prediction_and_budget(doc, 1)
    out = " ".join(capsys.readouterr().out.split())
    point, (lo, hi) = median_ratio_interval(dev[:25], ok_d[:25], chip[:25], ok_c[:25], seed=1)
    assert "the device-model arm predicts the chip's cycle-1 route" in out
    assert f"95 % interval {100 * (lo - 1):+.0f} % .. {100 * (hi - 1):+.0f} % over 25 paired " \
           "sessions" in out, out
    assert lo < hi


def test_the_device_seed_draws_another_chip_of_the_model_over_the_same_sessions():
    """``device_seed`` 0 is the default stream; another value draws other devices and noise
    from the same model: the same initial weights and task, another device's learning."""
    import argparse
    from dataclasses import replace
    from snan_hil.common.errors import UserError
    from snan_hil.host.hil.learn_arms import LearnTask, device_session
    from snan_hil.tools.commands.learn import model_config
    cfg, start, goal = model_config(argparse.Namespace(grid=3, start=None, goal=None,
                                                       config=None, overrides=[]))
    model = soft_model(std=0.3, dtod=0.3, read=0.003)
    lc = LearnConfig(start=start, goal=goal, sessions=1, cycles=3, arms=("device",))

    def run(c):
        return device_session(LearnTask(cfg, c), 0, model, WeightMap(), lambda _d: None)
    default, zero, other = run(lc), run(replace(lc, device_seed=0)), run(replace(lc,
                                                                                device_seed=1))
    assert default.to_dict() == zero.to_dict()
    assert LearnTask(cfg, lc).initial(0).tolist() == LearnTask(
        cfg, replace(lc, device_seed=1)).initial(0).tolist()
    assert other.weights != default.weights and other.w_estimate != default.w_estimate
    with pytest.raises(UserError, match="--device-seed must be >= 0"):
        replace(lc, device_seed=-1).check({"device_seed": "--device-seed"})


def test_the_device_seed_is_refused_without_the_device_arm_and_beyond_the_record():
    """``--device-seed`` draws only the device-model arm's devices: given with arms that have
    no device arm it would do nothing, so it is refused in one line; a seed the run's record
    (an SQLite INTEGER) cannot hold is refused as ``--seed`` is."""
    from dataclasses import replace
    from snan_hil.common.errors import UserError
    names = {"device_seed": "--device-seed", "arms": "--arms"}
    lc = LearnConfig(start=8, goal=0, sessions=1, cycles=1, arms=("software", "chip"))
    lc.check(names)                                                 # the default 0: fine
    with pytest.raises(UserError, match="--device-seed draws the device-model arm's devices, "
                                        "and --arms software,chip has no device arm"):
        replace(lc, device_seed=1).check(names)
    replace(lc, arms=("software", "device"), device_seed=1).check(names)
    with pytest.raises(UserError, match=r"--device-seed 9223372036854775808: at most "
                                        r"9223372036854775807"):
        replace(lc, arms=("device",), device_seed=2**63).check(names)
