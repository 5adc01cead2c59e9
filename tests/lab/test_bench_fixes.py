"""Findings of a fresh user's test of the lab bench (issue 15 follow-up): --board selects that
board's history, refusals happen before the board is opened (no chip change, no history row),
--max-write-v is the ticket's limit, a pulse on a programmed synapse marks it stale, a good
re-test clears cell-test marks, a closed stdout ends a command quietly."""

from __future__ import annotations

import io
import json
import sys

import numpy as np
import pytest

from snan_hil.calibration.layout import Layout
from snan_hil.calibration.testing import grid_weights
from snan_hil.records.history import History
from snan_hil.tools import cli


def _files(folder) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _one_line(capsys, needle: str) -> str:
    err = capsys.readouterr().err
    assert needle in err, err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


@pytest.fixture
def programmed(emu, capsys):
    np.save(emu / "w.npy", grid_weights(3, 3, seed=4))
    assert cli.main(["program-weights", str(emu / "w.npy"), "--port", "emu", "--json"]) == 0
    capsys.readouterr()
    return emu


def _board_id(folder) -> str:
    return str(Layout.load(folder / "chip.layout.json").board["board_id"])


# ------------------------------------------------------------------ 1: --board
def test_board_option_selects_that_boards_history(programmed, capsys):
    d = programmed
    board = _board_id(d)
    assert board.startswith("EMU-4D430001/")
    assert cli.main(["history", "--board", board, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["history"] == str(d / "chip.history.sqlite")
    # a board without a database: one line naming the boards that have one, exit 2
    for argv in (["history", "--board", "NOPE"], ["cells", "show", "--board", "NOPE"],
                 ["history", "--board", "EMU-4D430001/000000000000"]):
        assert cli.main(argv) == 2
        _one_line(capsys, board)
    # a real board's database in the layouts folder, by its id
    other = d / "data" / "snan-hil" / "layouts" / "MC-7_1.history.sqlite"
    other.parent.mkdir(parents=True)
    with History.open(other) as db:
        assert db.runs() == []
    assert cli.main(["history", "--board", "MC-7/1", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == {"history": str(other), "runs": []}


# ------------------------------------------------------------------ 2: refusals before work
@pytest.mark.parametrize("argv,needle", [
    (["pulse", "--cell", "3,5", "--polarity", "set", "--amplitude", "0.5",
      "--max-write-v", "0.4"], "0.4 V (the board's, lowered by --max-write-v)"),
    (["pulse", "--protocol", "legacy", "--cell", "3,5", "--polarity", "set",
      "--amplitude", "1.6"], "--max-write-v can only lower it"),
    (["retention", "--protocol", "legacy"], "--path cell"),
    (["cells", "test", "--cells", "0,0", "--v-max", "1.0", "--max-write-v", "0.5"],
     "--max-write-v"),
    (["program-weights", "w.npy", "--max-write-v", "0.8"], "(--max-write-v)"),
])
def test_refusals_leave_chip_and_history_alone(programmed, capsys, monkeypatch, argv,
                                               needle):
    monkeypatch.chdir(programmed)
    before = _files(programmed)
    assert cli.main([argv[0], *(["test"] if argv[0] == "cells" else []), "--port", "emu",
                     *argv[2 if argv[0] == "cells" else 1:]]) == 2
    _one_line(capsys, needle)
    assert _files(programmed) == before            # no chip state, no history row


@pytest.mark.parametrize("protocol", ("framed", "legacy"))
def test_max_write_v_above_the_boards_limit_is_refused_before_a_pulse(emu, capsys, protocol):
    """One rule (issue 32): --max-write-v may lower the board's 1.4 V, never raise it -- on
    the legacy protocol too, whose firmware has no interlock; nothing is sent."""
    assert cli.main(["pulse", "--port", "emu", "--protocol", protocol, "--cell", "3,5",
                     "--polarity", "set", "--amplitude", "1.3", "--max-write-v", "1.7",
                     "--record", "off", "--json"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "can only lower it" in err, err


# ------------------------------------------------------------------ 4: stale synapse
def test_pulse_on_programmed_synapse_marks_it_stale(programmed, capsys):
    d = programmed
    layout = Layout.load(d / "chip.layout.json")
    syn = layout.synapses[1]
    assert cli.main(["pulse", "--port", "emu", "--cell", f"{syn.row},{syn.col}", "--polarity",
                     "reset", "--amplitude", "0.8", "--count", "3", "--json"]) == 0
    cap = capsys.readouterr()
    assert f"holds synapse {syn.pre}->{syn.post}" in cap.err
    res = json.loads(cap.out)
    assert res["stale_synapse"]["pre"] == syn.pre
    after = Layout.load(d / "chip.layout.json")
    stale = after.stale_synapses()
    assert [(s.pre, s.post) for s in stale] == [(syn.pre, syn.post)]
    assert "pulse ticket RESET" in (stale[0].stale or "")
    # read-weights names it
    assert cli.main(["read-weights", "--port", "emu", "--json"]) == 0
    cap = capsys.readouterr()
    assert "changed by a pulse ticket" in cap.err
    assert json.loads(cap.out)["stale_synapses"][0]["post"] == syn.post
    # programming again clears it
    assert cli.main(["program-weights", str(d / "w.npy"), "--port", "emu", "--json"]) == 0
    capsys.readouterr()
    assert Layout.load(d / "chip.layout.json").stale_synapses() == []


def test_pulse_on_unused_cell_does_not_touch_layout(programmed, capsys):
    d = programmed
    before = (d / "chip.layout.json").read_bytes()
    assert cli.main(["pulse", "--port", "emu", "--cell", "30,7", "--polarity", "set",
                     "--amplitude", "0.6"]) == 0
    assert "warning" not in capsys.readouterr().err
    assert (d / "chip.layout.json").read_bytes() == before


# ------------------------------------------------------------------ 5: last class counts
def test_good_retest_clears_cell_test_marks(programmed, capsys):
    d = programmed
    cells = ["30,0", "30,1"]
    assert cli.main(["cells", "test", "--port", "emu", "--cells", *cells, "--noise-limit",
                     "0.001", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert {c["class"] for c in res["cells"]} == {"noisy"}
    assert sorted(map(tuple, res["layout_marked"])) == [(30, 0), (30, 1)]
    assert {(30, 0), (30, 1)} <= set(Layout.load(d / "chip.layout.json").bad_cells)
    assert cli.main(["cells", "test", "--port", "emu", "--cells", *cells, "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert {c["class"] for c in res["cells"]} == {"good"}
    assert sorted(map(tuple, res["layout_cleared"])) == [(30, 0), (30, 1)]
    assert not {(30, 0), (30, 1)} & set(Layout.load(d / "chip.layout.json").bad_cells)


def test_program_weights_drops_marks_of_cells_last_found_good(programmed, capsys):
    """A layout mark from an older cell test is dropped by program-weights when the
    database's last class of the cell is good."""
    d = programmed
    assert cli.main(["cells", "test", "--port", "emu", "--cells", "30,2", "--json"]) == 0
    capsys.readouterr()
    layout = Layout.load(d / "chip.layout.json")
    layout.mark_bad(30, 2, "cell test: noisy")
    layout.mark_bad(30, 3, "cell test: noisy")          # never tested: the mark stays
    layout.save(d / "chip.layout.json")
    assert cli.main(["program-weights", str(d / "w.npy"), "--port", "emu", "--json"]) == 0
    capsys.readouterr()
    bad = Layout.load(d / "chip.layout.json").bad_cells
    assert (30, 2) not in bad and (30, 3) in bad


# ------------------------------------------------------------------ 11: closed stdout
class _ClosedPipe(io.StringIO):
    def write(self, s):
        raise BrokenPipeError(32, "Broken pipe")


def test_closed_stdout_ends_quietly(programmed, capsys, monkeypatch):
    capsys.readouterr()
    monkeypatch.setattr(sys, "stdout", _ClosedPipe())
    assert cli.main(["history", "--port", "emu", "--json"]) == cli.EXIT_BROKEN_PIPE
    assert cli.main(["cells", "show", "--port", "emu", "--json"]) == cli.EXIT_BROKEN_PIPE
    monkeypatch.undo()
    assert "Traceback" not in capsys.readouterr().err


# ------------------------------------------------------------------ 6, 7: history
def test_history_table_keeps_run_kind_status_whole_at_80_columns(programmed, capsys,
                                                                 monkeypatch):
    from rich.console import Console

    from snan_hil.tools import console as console_mod
    from snan_hil.tools.commands import history as history_cmd
    narrow = Console(width=80, file=io.StringIO(), force_terminal=False)
    monkeypatch.setattr(history_cmd, "console", narrow)
    monkeypatch.setattr(console_mod, "console", narrow)
    for _ in range(3):
        assert cli.main(["pulse", "--port", "emu", "--cell", "31,7", "--polarity", "set",
                         "--amplitude", "0.5", "--json"]) == 0
    capsys.readouterr()
    assert cli.main(["history", "--port", "emu"]) == 0
    text = narrow.file.getvalue()
    rows = [line for line in text.splitlines() if line.startswith("│")]
    cells = [[c.strip() for c in line.strip("│").split("│")] for line in rows]
    firsts = [c for c in cells if c[0]]
    assert [c[0] for c in firsts] == ["4", "3", "2", "1"]          # run ids whole
    assert [c[1] for c in firsts] == ["pulse"] * 3 + ["program"]
    assert all(c[3] == "complete" for c in firsts)
    assert "…" not in "".join(c[0] + c[1] + c[3] for c in cells)


def test_history_export_of_a_missing_run_and_run_without_export(programmed, capsys):
    d = programmed
    assert cli.main(["history", "--port", "emu", "--export", "runs", "--run", "999", "-o",
                     str(d / "r.csv")]) == 2
    _one_line(capsys, "--run 999: no such run")
    assert not (d / "r.csv").exists()
    assert cli.main(["history", "--port", "emu", "--run", "1"]) == 2
    _one_line(capsys, "give --export")
    assert cli.main(["history", "--port", "emu", "--export", "runs", "--run", "1"]) == 0
    assert capsys.readouterr().out.count("\n") == 2              # header + run 1


# ------------------------------------------------------------------ 8, 13, 14, 15: bad input
@pytest.mark.parametrize("argv,needle", [
    (["mac", "--port", "emu", "--v-max", "0.0001"], "below one DAC step (1.22 mV)"),
    (["program-weights", "w.npy", "--port", "emu", "--trace", "trace.jpg"], "ending in .png"),
    (["pulse", "--port", "emu", "--cell", "3,3", "--polarity", "set", "--amplitude", "0.5",
      "--png", "x.pdf"], "ending in .png"),
    (["sim", "--grid", "3", "--trials", "2", "--plot", "x.svg"], "ending in .png"),
    (["sim", "--grid", "3", "--trials", "2", "--animate-trial", "1"], "give --animate"),
    (["cells", "test", "--port", "emu", "--cells", "-1,0"], "outside the 32x8 array"),
    (["pulse", "--port", "emu", "--cell", "-1,0", "--polarity", "set", "--amplitude", "0.5"],
     "outside the 32x8 array"),
    (["cells", "test", "--port", "emu", "--cells", "0,0", "--v-max", "0.1"], "--v-max 0.1"),
    (["cells", "test", "--port", "emu", "--cells", "0,0", "--max-probe-pulses", "0"],
     "--max-probe-pulses 0"),
])
def test_bad_options_one_line_nothing_written(emu, capsys, monkeypatch, argv, needle):
    monkeypatch.chdir(emu)
    np.save(emu / "w.npy", grid_weights(3, 3, seed=4))
    before = _files(emu)
    assert cli.main(argv) == 2
    _one_line(capsys, needle)
    assert _files(emu) == before


def test_noise_limit_note_shows_its_digits(emu, capsys):
    assert cli.main(["cells", "test", "--port", "emu", "--cells", "0,0", "--noise-limit",
                     "0.001", "--record", "off", "--json"]) == 0
    cell = json.loads(capsys.readouterr().out)["cells"][0]
    assert cell["class"] == "noisy" and "> 0.1%" in cell["note"]


def test_sim_animates_a_trial_with_steps_by_default(tmp_path, capsys):
    from PIL import Image

    from snan_hil.tools.commands.sim import MIN_ANIMATED_STEPS
    gif = tmp_path / "a.gif"
    assert cli.main(["sim", "--grid", "3", "--trials", "20", "--seed", "1", "--json",
                     "--animate", str(gif)]) == 0
    capsys.readouterr()
    with Image.open(gif) as im:
        assert im.n_frames >= MIN_ANIMATED_STEPS + 1


# ------------------------------------------------------------------ 10, 12: reports
def test_reports_carry_the_version(programmed, capsys):
    from snan_hil import __version__
    d = programmed
    assert json.loads((d / "chip.program-report.json").read_text())["version"] == __version__
    assert cli.main(["mac", "--port", "emu", "--weights", "random", "--grid", "3", "--seed",
                     "2", "--vectors", "5", "--out", str(d / "mac"), "--json"]) == 0
    capsys.readouterr()
    mac = json.loads((d / "mac" / "mac.json").read_text())
    assert mac["version"] == __version__
    assert mac["weights"] == {"source": "random", "weights": "random", "path": "random",
                              "grid": [3, 3], "seed": 2}
    assert cli.main(["cells", "test", "--port", "emu", "--cells", "31,0", "-o",
                     str(d / "c.json"), "--json"]) == 0
    capsys.readouterr()
    assert json.loads((d / "c.json").read_text())["version"] == __version__
    assert cli.main(["map", "--port", "emu", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["version"] == __version__


def test_ticket_reports_applied_volts_and_a_named_ramp(emu, capsys):
    assert cli.main(["pulse", "--port", "emu", "--cell", "30,5", "--polarity", "set",
                     "--amplitude", "0.6:1.0:0.1", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    t = res["ticket"]
    assert (t["start_v"], t["stop_v"], t["step_v"], t["steps"]) == (0.6, 1.0, 0.1, 5)
    assert "amplitudes_v" not in t
    lsb = 5.0 / 4095
    for s, planned in zip(res["steps"], (0.6, 0.7, 0.8, 0.9, 1.0)):
        code = round(s["amplitude_v"] / lsb)
        assert s["amplitude_v"] == pytest.approx(code * lsb)         # a DAC code's voltage
        assert planned - lsb < s["amplitude_v"] <= planned + 1e-12
    with History.open(emu / "chip.history.sqlite", create=False) as db:
        pulses = [e.amplitude_v for e in db.cell_life(30, 5) if e.event == "pulse"]
    assert pulses == pytest.approx([s["amplitude_v"] for s in res["steps"]])


# ------------------------------------------------------------------ 9: retention figure
def test_retention_figure_shows_reads_band_and_integer_cycles(tmp_path, monkeypatch):
    from snan_hil.tools import bench_figures
    kept = {}
    monkeypatch.setattr(bench_figures, "_save",
                        lambda plt, fig, path, fmt: kept.setdefault("fig", fig) and path)
    rng = np.random.default_rng(0)
    targets = [0.1, 0.5, 0.9]
    w = np.array(targets) + 0.002 * rng.standard_normal((7, 3))     # 7 reads, noise 0.002
    bench_figures.plot_retention(w, targets, ["a", "b", "c"], tmp_path / "r.png", title="t")
    fig = kept["fig"]
    top, dev = fig.axes[:2]
    ticks = [t for t in dev.get_xticks() if dev.get_xlim()[0] <= t <= dev.get_xlim()[1]]
    assert ticks and all(float(t).is_integer() for t in ticks)        # read cycles
    # the read markers are drawn over the dashed programmed weight
    marks = [ln for ln in top.get_lines() if ln.get_marker() == "o"]
    dashed = [ln for ln in top.get_lines() if ln.get_linestyle() == "--"]
    assert len(marks) == 3 and min(m.get_zorder() for m in marks) > max(
        d.get_zorder() for d in dashed)
    # the deviation panel's range is of the order of the noise, so the ±1 sigma band shows
    lo, hi = dev.get_ylim()
    assert hi - lo < 0.05
    assert len(dev.collections) >= 3                                  # one band per cell


@pytest.mark.parametrize("text", ["[1, 2]", '"layout"', "null"])
def test_a_layout_file_that_is_not_a_json_object_is_one_line(tmp_path, text):
    from snan_hil.calibration.layout import LayoutError
    path = tmp_path / "chip.layout.json"
    path.write_text(text)
    with pytest.raises(LayoutError, match="is not a layout") as err:
        Layout.load(path)
    assert "\n" not in str(err.value) and path.read_text() == text    # the file is untouched
