"""The bench commands on the in-process emulator, framed and legacy protocol: pulse, cells,
mac, history, retention --png, program-weights --trace, map --json; their bad input (one line,
exit 2, nothing written) and the history database's failure policy."""

from __future__ import annotations

import csv
import json
import sqlite3

import numpy as np
import pytest

from snan_hil.calibration.layout import Layout
from snan_hil.calibration.testing import grid_weights
from snan_hil.crossbar_model.array import CrossbarArray
from snan_hil.records.history import History
from snan_hil.files.outputs import PNG_KEY
from snan_hil.tools import cli

PROTOCOLS = ("framed", "legacy")


def _png_tag(path) -> str:
    from PIL import Image
    with Image.open(path) as im:
        return str(im.text.get(PNG_KEY, ""))


def _files(folder) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


@pytest.fixture
def emu(tmp_path, monkeypatch):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    monkeypatch.delenv("SNAN_HIL_PORT", raising=False)
    return tmp_path


@pytest.fixture(scope="module")
def programmed(tmp_path_factory):
    """A chip with a 3x3 weight set programmed (framed), its folder."""
    d = tmp_path_factory.mktemp("programmed")
    np.save(d / "w.npy", grid_weights(3, 3, seed=4))
    mp = pytest.MonkeyPatch()
    mp.setenv("SNAN_HIL_EMU_STATE", str(d / "chip.npz"))
    try:
        assert cli.main(["program-weights", str(d / "w.npy"), "--port", "emu", "--json",
                         "--trace", str(d / "trace.png")]) == 0
    finally:
        mp.undo()
    return d


def _use(monkeypatch, folder):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(folder / "chip.npz"))
    monkeypatch.delenv("SNAN_HIL_PORT", raising=False)


# ------------------------------------------------------------------ program-weights
def test_program_weights_trace_and_history(programmed, monkeypatch, capsys):
    d = programmed
    assert _png_tag(d / "trace.png").startswith("snan-hil-program-trace/")
    report = json.loads((d / "chip.program-report.json").read_text())
    with History.open(d / "chip.history.sqlite", create=False) as db:
        runs = db.runs(kind="program")
        assert runs[-1].status == "complete" and runs[-1].record_level == "pulses"
        assert runs[-1].pulses == report["summary"]["host_pulses"]
        assert runs[-1].summary["ok"] == report["summary"]["ok"]
        cell = report["cells"][0]
        life = db.cell_life(cell["row"], cell["col"])
        pulses = [e for e in life if e.event == "pulse"]
        assert len(pulses) == cell["pulses_total"]
        assert {e.stage for e in pulses} <= {"1", "2"}
        ok = [e for e in life if e.event == "result" and e.outcome == "ok"]
        assert ok and ok[-1].g_s == pytest.approx(cell["final_s"], rel=1e-6)


# ------------------------------------------------------------------ pulse
@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_pulse_ticket_stops_at_condition(emu, capsys, protocol):
    d = emu
    argv = ["pulse", "--port", "emu", "--protocol", protocol, "--cell", "30,6", "--polarity",
            "set", "--amplitude", "0.4:1.4:0.05", "--until-g", "0.6mS", "--png",
            str(d / "t.png"), "--csv", str(d / "t.csv"), "--json"]
    assert cli.main(argv) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["condition_met"] and res["final_s"] >= 6e-4
    assert all(s["g_after_s"] < 6e-4 for s in res["steps"][:-1])
    assert res["ticket"]["polarity"] == "SET"
    rows = list(csv.DictReader(open(d / "t.csv")))
    assert len(rows) == res["pulses"] > 0
    # the applied amplitudes: the write DAC code's voltage, at most one step below the plan
    planned = [0.4 + 0.05 * k for k in range(len(rows))]
    applied = [float(r["amplitude_v"]) for r in rows]
    assert all(p - 5.0 / 4095 - 1e-9 <= a <= p + 1e-9 for a, p in zip(applied, planned))
    assert applied == pytest.approx([s["amplitude_v"] for s in res["steps"]], abs=1e-6)
    assert (res["ticket"]["start_v"], res["ticket"]["step_v"]) == (0.4, 0.05)
    assert _png_tag(d / "t.png").startswith("snan-hil-pulse-figure/")
    with History.open(d / "chip.history.sqlite", create=False) as db:
        run = db.runs()[0]
        assert (run.kind, run.protocol, run.pulses) == ("pulse", protocol, res["pulses"])
        life = db.cell_life(30, 6)
        assert [e.stage for e in life if e.event == "pulse"] == ["ticket"] * res["pulses"]
        # the amplitudes recorded are the DAC code's voltages, at most the planned ones
        assert [e.amplitude_v for e in life if e.event == "pulse"] == pytest.approx(applied,
                                                                                     abs=1e-6)
    # RESET back with a window; --record cells: no pulse rows
    assert cli.main(["pulse", "--port", "emu", "--protocol", protocol, "--cell", "30,6",
                     "--polarity", "reset", "--amplitude", "0.8", "--count", "40", "--window",
                     "300+-8%", "--record", "cells", "--json"]) == 0
    res2 = json.loads(capsys.readouterr().out)
    assert res2["condition_met"] and abs(res2["final_s"] / 3e-4 - 1) <= 0.08
    with History.open(d / "chip.history.sqlite", create=False) as db:
        assert db.runs()[0].pulses == 0 and db.runs()[0].cells == 1


@pytest.mark.parametrize("argv,needle", [
    (["--cell", "32,0"], "outside the 32x8 array"),
    (["--cell", "0,8"], "outside the 32x8 array"),
    (["--cell", "-1,2"], "outside"),
    (["--amplitude", "1.5"], "above the host's write limit"),
    (["--amplitude", "0.3:1.7:0.1"], "above the host's write limit"),
    (["--amplitude", "0.3:1.2:0"], "never ends"),
    (["--amplitude", "0.3:1.2:-0.1"], "never ends"),
    (["--until-g", "lots"], "--until-g"),
    (["--window", "500"], "G±P"),
    (["--width-us", "0"], "--width-us"),
    (["--count", "0"], "--count"),
])
def test_pulse_bad_input_one_line_nothing_written(emu, capsys, argv, needle):
    base = {"--cell": "3,3", "--amplitude": "0.5"}
    for k, v in zip(argv[::2], argv[1::2]):
        base[k] = v
    args = ["pulse", "--port", "emu", "--polarity", "set", "--png", str(emu / "x.png")]
    args += [f"{k}={v}" for k, v in base.items()]
    assert cli.main(args) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1 and "Traceback" not in err
    assert _files(emu) == {}                     # no chip, no history, no figure


# ------------------------------------------------------------------ cells
@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_cells_test_finds_stuck_cells_and_layout_uses_them(emu, capsys, protocol):
    d = emu
    chip = CrossbarArray.from_yaml(None, seed=0)           # the emulator's chip for seed 0
    stuck = [tuple(map(int, c)) for c in np.argwhere(chip.stuck_mask)]
    assert stuck
    healthy = [(0, 0), (1, 1)]
    cells = [f"{r},{c}" for r, c in stuck + healthy]
    np.save(d / "w.npy", grid_weights(6, 6, seed=1))
    assert cli.main(["cells", "test", "--port", "emu", "--protocol", protocol, "--cells",
                     *cells, "--png", str(d / "c.png"), "-o", str(d / "c.json"),
                     "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    by = {(c["row"], c["col"]): c["class"] for c in res["cells"]}
    for r, c in stuck:
        assert by[(r, c)] == ("stuck_high" if chip.stuck_high[r, c] else "stuck_low")
    assert all(by[c] == "good" for c in healthy)
    assert res["summary"]["good"] == 2
    assert max(c["pulses"] for c in res["cells"]) <= \
        2 * res["config"]["max_probe_pulses"] + res["config"]["max_restore_pulses"]
    assert json.loads((d / "c.json").read_text())["format"].startswith("snan-hil-cells/")
    assert _png_tag(d / "c.png").startswith("snan-hil-cells-figure/")
    # cells show: the same classes from the database, no board
    assert cli.main(["cells", "show", "--port", "emu", "--json"]) == 0
    shown = {(c["row"], c["col"]): c["class"] for c in json.loads(capsys.readouterr().out)
             ["cells"]}
    assert shown == by
    # program-weights (framed) keeps synapses off the bad cells found by the test
    assert cli.main(["program-weights", str(d / "w.npy"), "--port", "emu", "--no-screen",
                     "--json"]) == 0
    layout = Layout.load(d / "chip.layout.json")
    used = layout.used_cells()
    assert not used & set(stuck)
    assert all("cell test" in layout.bad_cells[c] for c in stuck)


def test_cells_bad_input(emu, capsys):
    for argv, needle in ((["--cells"], "empty cell list"), ([], "--cells R,C"),
                         (["--cells", "3,9"], "outside the 32x8"),
                         (["--cells", "3;4"], "ROW,COL"),
                         (["--all", "--v-max", "1.6"], "write limit")):
        assert cli.main(["cells", "test", "--port", "emu", *argv]) == 2
        err = capsys.readouterr().err
        assert needle in err and err.count("\n") == 1
    assert _files(emu) == {}


# ------------------------------------------------------------------ mac
@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_mac_against_numpy(programmed, tmp_path, monkeypatch, capsys, protocol):
    _use(monkeypatch, programmed)
    out = tmp_path / f"mac-{protocol}"
    assert cli.main(["mac", "--port", "emu", "--protocol", protocol, "--vectors", "12",
                     "--seed", "3", "--out", str(out), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)["summary"]
    assert res["method"].startswith("READ_COLUMN" if protocol == "framed" else "sum of single")
    assert res["samples"] == 12 * len(res["columns"]) and res["cells"] == 24
    # the programmed targets are within +-10 %: the multiply is within a few % of full scale
    assert 0 < res["rms_error_pct_fs"] < 2.0 and res["max_error_pct_fs"] < 5.0
    assert res["saturated"] == 0
    data = json.loads((out / "mac.json").read_text())
    assert data["format"] == "snan-hil-mac/1" and data["board"]["protocol"] == protocol
    # the CSV's errors are the JSON's samples recomputed: measured - numpy(V . G_target)
    rows = list(csv.DictReader(open(out / "mac.csv")))
    assert len(rows) == res["samples"]
    err = np.array([float(r["error_pct_fs"]) for r in rows])
    recomputed = 100 * np.array([(s["measured_a"] - s["reference_a"]) / res["full_scale_a"]
                                 for s in data["samples"]])
    assert err == pytest.approx(recomputed, abs=1e-4)
    assert np.sqrt(np.mean(err ** 2)) == pytest.approx(res["rms_error_pct_fs"], abs=1e-3)
    assert _png_tag(out / "mac.png").startswith("snan-hil-mac-figure/")
    # the reference is a real dot product: references spread over the output range
    ref = np.array([s["reference_a"] for s in data["samples"]])
    assert ref.min() < 0.3 * ref.max()


def test_mac_programs_random_weights_and_refuses_bad_input(emu, capsys):
    d = emu
    assert cli.main(["mac", "--port", "emu", "--vectors", "3"]) == 2
    assert "program weights first" in capsys.readouterr().err
    assert cli.main(["mac", "--port", "emu", "--v-max", "0.5", "--weights", "random"]) == 2
    assert "read limit" in capsys.readouterr().err
    assert cli.main(["mac", "--port", "emu", "--vectors", "0", "--weights", "random"]) == 2
    assert "--vectors" in capsys.readouterr().err
    assert _files(d) == {}
    assert cli.main(["mac", "--port", "emu", "--weights", "random", "--grid", "2",
                     "--vectors", "5", "--out", str(d / "m"), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)["summary"]
    assert res["cells"] == 8 and res["rms_error_pct_fs"] < 2.0
    with History.open(d / "chip.history.sqlite", create=False) as db:
        assert [r.kind for r in db.runs()] == ["mac", "program"]


# ------------------------------------------------------------------ retention, map, history
def test_retention_png_and_map_json(programmed, tmp_path, monkeypatch, capsys):
    _use(monkeypatch, programmed)
    assert cli.main(["retention", "--port", "emu", "--reads", "30", "--png",
                     str(tmp_path / "r.png"), "--json"]) == 0
    ret = json.loads(capsys.readouterr().out)
    assert _png_tag(tmp_path / "r.png").startswith("snan-hil-retention-figure/")
    assert cli.main(["map", "--port", "emu", "--json"]) == 0
    m = json.loads(capsys.readouterr().out)
    assert m["rows"] == 32 and m["cols"] == 8 and len(m["conductance_s"]) == 32
    assert "board EMU-" in m["title"] and "port emu" in m["title"]
    layout = Layout.load(programmed / "chip.layout.json")
    s = layout.synapses[0]
    assert m["conductance_s"][s.row][s.col] == pytest.approx(s.final_s, rel=0.05)
    with History.open(programmed / "chip.history.sqlite", create=False) as db:
        runs = {r.kind: r for r in db.runs()}
        assert runs["retention"].cells == ret["summary"]["cells"]
        assert runs["map"].cells == 256 and runs["map"].record_level == "cells"


def test_history_command(programmed, tmp_path, monkeypatch, capsys):
    _use(monkeypatch, programmed)
    assert cli.main(["history", "--port", "emu", "--json"]) == 0
    runs = json.loads(capsys.readouterr().out)["runs"]
    assert runs and runs[-1]["kind"] == "program"
    report = json.loads((programmed / "chip.program-report.json").read_text())
    cell = report["cells"][1]
    assert cli.main(["history", "--port", "emu", "--cell", f"{cell['row']},{cell['col']}",
                     "--png", str(tmp_path / "life.png"), "--json"]) == 0
    life = json.loads(capsys.readouterr().out)["events"]
    assert sum(e["event"] == "pulse" for e in life) >= cell["pulses_total"]
    assert _png_tag(tmp_path / "life.png").startswith("snan-hil-cell-life/")
    assert cli.main(["history", "--port", "emu", "--export", "pulses", "-o",
                     str(tmp_path / "p.csv")]) == 0
    rows = list(csv.DictReader(open(tmp_path / "p.csv")))
    with History.open(programmed / "chip.history.sqlite", create=False) as db:
        assert len(rows) == sum(r.pulses for r in db.runs())
    # bad input
    for argv, needle in ((["--cell", "40,0"], "outside"), (["--png", "x.png"], "--cell"),
                         (["-o", "x.csv"], "--export"),
                         (["--history", str(tmp_path / "none.sqlite")], "no history database")):
        assert cli.main(["history", "--port", "emu", *argv]) == 2
        err = capsys.readouterr().err
        assert needle in err and err.count("\n") == 1


# ------------------------------------------------------------------ history failure policy
def test_foreign_history_file_refused_before_any_work(emu, capsys):
    d = emu
    foreign = d / "notes.sqlite"
    foreign.write_text("my notes\n")
    other = d / "other.sqlite"
    conn = sqlite3.connect(other)
    conn.execute("CREATE TABLE x (y)")
    conn.commit()
    conn.close()
    before = _files(d)
    for path in (foreign, other):
        for argv in (["pulse", "--port", "emu", "--cell", "3,3", "--polarity", "set",
                      "--amplitude", "0.5"],
                     ["map", "--port", "emu"],
                     ["history", "--port", "emu"],
                     ["cells", "show", "--port", "emu"]):
            assert cli.main([*argv, "--history", str(path), "--force"]) == 2, argv
            err = capsys.readouterr().err
            assert "not a snan-hil history database" in err and err.count("\n") == 1
    assert _files(d) == before                       # nothing written, nothing replaced


def test_damaged_history_is_refused_before_programming_and_left_alone(emu, capsys):
    d = emu
    np.save(d / "w.npy", grid_weights(2, 2, seed=1))
    assert cli.main(["map", "--port", "emu", "--json"]) == 0     # creates the database
    capsys.readouterr()
    db = d / "chip.history.sqlite"
    data = bytearray(db.read_bytes())
    for k in range(4096, len(data), 5):
        data[k] ^= 0xA5
    db.write_bytes(bytes(data))
    chip = (d / "chip.npz").read_bytes()
    assert cli.main(["program-weights", str(d / "w.npy"), "--port", "emu", "--json"]) == 2
    cap = capsys.readouterr()
    assert cap.out == "" and cap.err.count("\n") == 1 and "Traceback" not in cap.err
    assert "damaged" in cap.err and "history recover" in cap.err
    assert db.read_bytes() == bytes(data)              # not added to, silently or otherwise
    assert (d / "chip.npz").read_bytes() == chip       # no pulse before the refusal


def test_locked_history_delays_the_records_of_programming_and_loses_none(emu, capsys,
                                                                          monkeypatch):
    import snan_hil.records.history as H
    d = emu
    np.save(d / "w.npy", grid_weights(2, 2, seed=1))
    assert cli.main(["map", "--port", "emu", "--json"]) == 0
    capsys.readouterr()
    monkeypatch.setattr(H, "BUSY_TIMEOUT_S", 0.05)
    monkeypatch.setattr(H, "FINISH_WAIT_S", 0.2)
    other = sqlite3.connect(d / "chip.history.sqlite", isolation_level=None)
    other.execute("BEGIN EXCLUSIVE")                   # held for the whole run
    try:
        assert cli.main(["program-weights", str(d / "w.npy"), "--port", "emu", "--json"]) == 0
        cap = capsys.readouterr()
    finally:
        other.execute("ROLLBACK")
        other.close()
    report = json.loads(cap.out)
    assert report["summary"]["ok"] == 8
    warned = [line for line in cap.err.splitlines() if "locked" in line]
    assert len(warned) == 1 and warned[0].startswith("warning: history")
    assert "go into the database the next time" in warned[0]
    with History.open(d / "chip.history.sqlite") as db:   # the pending records go in
        run = db.runs(kind="program")[0]
        assert run.status == "complete"
        assert run.pulses == report["summary"]["host_pulses"] > 0
    assert not (d / "chip.history.sqlite.pending").exists()
