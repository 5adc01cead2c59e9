"""Hardware scenarios over the legacy line protocol: synapses from mode-9 cell reads, per-spike
and per-window, on a chip programmed over the legacy protocol."""

import json

import numpy as np
import pytest

from snan_hil.calibration.weights_io import load_weight_set
from snan_hil.common.errors import UserError
from snan_hil.firmware_emu.inprocess import emulator_of
from snan_hil.host.agent import environment, synapse_tables
from snan_hil.host.hil.backend import FixedWeightsError
from snan_hil.host.hil.cell_backend import CellReadSynapses
from snan_hil.calibration.testing import session_of
from snan_hil.host.hil.compare import CompareJob, CompareRequest
from snan_hil.lab.runner import RunOptions, run_job
from snan_hil.host.hil.runner import run_scenario
from snan_hil.host.hil.synapses import check_mode, default_mode, make_synapses
from snan_hil.host.hil.testing import make_weights, program_set, small_hil_config
from snan_hil.protocol.legacy_client import LegacyClient
from snan_hil.tools import cli
from snan_hil.tools.ports import open_client


@pytest.fixture(scope="module")
def chip(tmp_path_factory):
    d = tmp_path_factory.mktemp("legacychip")
    hil = small_hil_config(max_steps=15)
    wpath = make_weights(d / "w.npz", sets=2, cycles=2, hil=hil)
    client = open_client("emu", protocol="legacy", state_file=str(d / "chip.npz"), seed=0)
    layout = program_set(client, wpath, 0, d / "layout.json")
    w, _ = load_weight_set(wpath, 0)
    env = environment(hil.model)
    nbr, _ = synapse_tables(env, hil.model)
    yield {"client": client, "layout": layout, "w": w, "wpath": wpath, "hil": hil, "nbr": nbr,
           "dir": d}
    client.close()


def _spikes(seed, p=0.15, steps=1000):
    return np.random.default_rng(seed).random(steps) < p


def test_the_legacy_board_defaults_to_per_window_and_refuses_batch(chip):
    client = chip["client"]
    assert isinstance(client, LegacyClient)
    assert default_mode(client) == "per_window" == check_mode(client, None)
    assert check_mode(client, "per_spike") == "per_spike"
    with pytest.raises(UserError, match="--mode per-window or --mode per-spike"):
        check_mode(client, "batch")
    assert isinstance(make_synapses(client, chip["layout"], chip["nbr"], "per_spike"),
                      CellReadSynapses)


@pytest.mark.parametrize("mode", ["per_spike", "per_window"])
def test_cell_reads_give_the_programmed_weights(chip, mode):
    layout, nbr, w = chip["layout"], chip["nbr"], chip["w"]
    back = CellReadSynapses(chip["client"], layout, nbr, mode=mode)
    final_w = {(s.pre, s.post): layout.weight_map.weight(s.final_s, clip=False)
               for s in layout.synapses}
    n_reads = 0
    for pre in (0, 14, 35):
        dirs = [d for d in range(4) if nbr[pre, d] >= 0]
        spikes = _spikes(pre)
        drive = back.drive(pre, dirs, spikes)
        assert drive.shape == (1000, len(dirs))
        assert np.all(drive[~spikes] == 0.0) and np.all(drive[spikes] > 0.0)
        n_reads += (int(spikes.sum()) if mode == "per_spike" else 1) * len(dirs)
        for k, d in enumerate(dirs):
            post = int(nbr[pre, d])
            reads = drive[spikes, k]
            assert np.all(np.abs(reads - final_w[(pre, post)]) < 0.03)
            assert abs(reads.mean() - w[pre, post]) < 0.04
            if mode == "per_spike":
                assert reads.std() > 0.0                   # a fresh read per spike
            else:
                assert np.all(reads == reads[0])           # one read for the window
    assert back.stats.requests == n_reads == back.stats.codes_read
    assert back.drive(3, [0, 1], np.zeros(1000, bool)).sum() == 0.0   # no spike: no read
    assert back.stats.requests == n_reads
    with pytest.raises(FixedWeightsError):
        back.apply_update(0, [0], np.zeros(1))


def test_per_spike_and_per_window_reads_agree_in_mean(chip):
    layout, nbr = chip["layout"], chip["nbr"]
    spike = CellReadSynapses(chip["client"], layout, nbr, mode="per_spike")
    window = CellReadSynapses(chip["client"], layout, nbr, mode="per_window")
    pre = 7
    dirs = [d for d in range(4) if nbr[pre, d] >= 0]
    for rep in range(40):
        s = _spikes(1000 + rep)
        spike.drive(pre, dirs, s)
        window.drive(pre, dirs, s)
    sp, sw = spike.stats.synapse_stats(), window.stats.synapse_stats()
    assert sp.keys() == sw.keys()
    for key in sp:
        (n1, m1, d1), (n2, m2, d2) = sp[key], sw[key]
        assert n2 == 40 and n1 > 40 * 100
        se = np.sqrt(d1 ** 2 / n1 + d2 ** 2 / n2)
        assert abs(m1 - m2) < 4 * se + 1e-3
        assert 0.5 < d2 / d1 < 2.0                    # one read's spread, either way


def test_launches_over_legacy_are_reproducible_and_never_pulse(chip):
    client, hil = chip["client"], chip["hil"]
    emu = emulator_of(client.transport)
    pulses = emu.board.front_end.pulses_applied
    kw = dict(launches=2, seed=3, client=client, layout=chip["layout"], baud=115200)
    a = run_scenario("hw_astro", chip["w"], hil, **kw)
    b = run_scenario("hw_astro", chip["w"], hil, **kw)
    assert a.mode == "per_window" and a.path_lengths == b.path_lengths
    assert emu.board.front_end.pulses_applied == pulses          # weights fixed: no pulse
    for r in a.launches:
        assert r.virtual_us is None and r.wire_us > 0            # no CLOCK; bytes counted
        assert r.requests <= 4 * r.decisions
    with pytest.raises(UserError, match="--protocol framed"):
        run_scenario("hw_astro", chip["w"], hil, mode="batch", **kw)


def test_compare_over_legacy_reports_the_wire_limited_rate(chip, tmp_path):
    request = CompareRequest(str(chip["wpath"]), chip["hil"], sets=(0,), launches=2, seed=1,
                             program=False, scenarios=("sw_astro", "hw_astro"))
    res = run_job(CompareJob(request), session_of(chip["client"], chip["dir"] / "layout.json"),
                  RunOptions(record="off")).result
    assert res["mode"] == "per_window"
    rows = {r["implementation"]: r for r in res["speed_energy"]["rows"]}
    wire = rows["board over the line, wire-limited"]
    hw = res["speed_energy"]["measured_inputs"]["hw"]
    expect = (hw["wire_us"] + hw["requests"] * hw["conversion_us"]) / hw["decisions"]
    assert wire["time_per_decision_us"] == pytest.approx(expect)
    assert hw["conversion_us"] == pytest.approx(61.0)        # 6 us + 11 x 5 us
    assert wire["energy_per_decision_j"] is None


def test_cli_run_hw_over_legacy(chip, tmp_path, capsys, monkeypatch):
    state = tmp_path / "c.npz"
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(state))
    wpath = str(chip["wpath"])
    assert cli.main(["program-weights", wpath, "--weight-set", "1", "--port", "emu",
                     "--protocol", "legacy", "--json"]) == 0
    capsys.readouterr()
    base = ["run", "--scenario", "hw_noastro", "--weights", wpath, "--weight-set", "1",
            "--port", "emu", "--protocol", "legacy", "--launches", "2",
            "--set", "grid.max_steps=15", "--accept-config-diff"]
    assert cli.main(base + ["--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["mode"] == "per_window" and len(out["path_lengths"]) == 2
    assert cli.main(base + ["--json", "--mode", "per-spike"]) == 0
    spike = json.loads(capsys.readouterr().out)
    assert spike["mode"] == "per_spike"
    assert spike["read_stats"]["requests"] > 20 * out["read_stats"]["requests"]
    assert cli.main(base + ["--mode", "batch"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--mode per-window" in err


def test_cli_run_json_over_legacy_records_version_protocol_board_and_wire_rate(
        chip, tmp_path, capsys, monkeypatch):
    from snan_hil import __version__
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "c.npz"))
    wpath = str(chip["wpath"])
    assert cli.main(["program-weights", wpath, "--weight-set", "0", "--port", "emu",
                     "--protocol", "legacy", "--json"]) == 0
    capsys.readouterr()
    assert cli.main(["run", "--scenario", "hw_astro", "--weights", wpath, "--port", "emu",
                     "--protocol", "legacy", "--launches", "2", "--set", "grid.max_steps=15",
                     "--accept-config-diff", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["snan_hil_version"] == __version__ and out["protocol"] == "legacy"
    assert out["baud"] == 115200 and out["mode"] == "per_window"
    board = out["board"]
    assert board["board_id"].startswith("EMU-") and "legacy" in board["firmware_version"]
    assert board["virtual_us_per_decision"] is None          # no CLOCK over legacy
    stats = out["read_stats"]
    dec = board["decisions"]
    assert dec == sum(L["decisions"] for L in out["launch_details"]) > 0
    # the wire-limited time as compare.json's speed table computes it: line time + 61 us of
    # documented conversion time per mode-9 read
    expect_us = board["wire_us_per_decision"] + board["reads_per_decision"] * 61.0
    assert board["wire_limited_us_per_decision"] == pytest.approx(expect_us)
    assert board["wire_limited_decisions_per_s"] == pytest.approx(1e6 / expect_us)
    assert board["reads_per_decision"] * dec == stats["requests"]
    rows = {r["implementation"] for r in out["speed_energy"]["rows"]}
    assert "board over the line, wire-limited" in rows


def test_the_program_it_first_hint_of_a_legacy_run_works_as_given(chip, tmp_path, capsys,
                                                                 monkeypatch):
    """The hint names --protocol legacy (a framed program-weights fails on a legacy board):
    running the suggested command makes the refused run work."""
    import shlex
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "c.npz"))
    wpath = str(chip["wpath"])
    assert cli.main(["program-weights", wpath, "--weight-set", "0", "--port", "emu",
                     "--protocol", "legacy", "--json"]) == 0
    capsys.readouterr()
    run = ["run", "--scenario", "hw_noastro", "--weights", wpath, "--weight-set", "1",
           "--port", "emu", "--protocol", "legacy", "--launches", "1",
           "--set", "grid.max_steps=15", "--accept-config-diff", "--json"]
    assert cli.main(run) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "holds other weights" in err, err
    hint = err.split("program it first: snan-hil ", 1)[1]
    argv = shlex.split(hint)
    assert argv[:2] == ["program-weights", wpath] and "--protocol" in argv
    assert argv[argv.index("--protocol") + 1] == "legacy"
    assert cli.main(argv + ["--json"]) == 0
    capsys.readouterr()
    assert cli.main(run) == 0


def test_batch_mode_over_legacy_is_refused_before_any_work(tmp_path, monkeypatch, capsys):
    """demo/compare: --mode batch over --protocol legacy is one line, before the software
    comparison or training starts, and nothing is written."""
    import time
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "user-chip.npz"))
    out = tmp_path / "demo"
    t0 = time.perf_counter()
    assert cli.main(["demo", "--trials", "3", "--sets", "1", "--launches", "1",
                     "--protocol", "legacy", "--mode", "batch", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--mode per-window" in err, err
    assert not out.exists() and not (tmp_path / "user-chip.npz").exists()
    assert time.perf_counter() - t0 < 10            # no software comparison ran (~30 s)
    wpath = make_weights(tmp_path / "w.npz", sets=1, cycles=1, hil=small_hil_config(15))
    cmp_out = tmp_path / "cmp"
    assert cli.main(["compare", "--weights", str(wpath), "--port", "emu", "--protocol",
                     "legacy", "--mode", "batch", "--out", str(cmp_out), "--launches", "1",
                     "--accept-config-diff"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--mode per-window" in err, err
    assert not cmp_out.exists() and not (tmp_path / "user-chip.npz").exists()


def test_demo_runs_the_hardware_chain_over_legacy(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "user-chip.npz"))
    out = tmp_path / "demo"
    assert cli.main(["demo", "--trials", "3", "--sets", "1", "--launches", "1",
                     "--protocol", "legacy", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "wire-limited" in text
    res = json.loads((out / "compare.json").read_text())
    assert res["mode"] == "per_window" and "legacy" in res["board"]["firmware_version"]
    assert all(p["all_ok"] for p in res["programming"].values())
    assert not (tmp_path / "user-chip.npz").exists()
    # the demo's comparison is one run of its chip's history, a launches event per launch
    from snan_hil.records.history import History
    with History.open(out / "chip.history.sqlite", create=False) as db:
        [run] = db.runs(kind="hil")
        events = [d["data"] for _i, n, d in db.documents(run.id) if n == "event"]
    launched = [e for e in events if "calcium_final" in e]
    assert len(launched) == len(res["launch_rows"]) == 4          # 4 scenarios x 1 launch
    assert {e["scenario"] for e in launched} == set(res["scenarios"])
