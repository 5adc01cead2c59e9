"""``snan-hil watch``: the view's state from documents, the Textual app driven headless with
its pilot (following a running run in the history, pause / resume / stop reaching the job's
control channel), a snapshot test of the drawn view, and the --screenshot command."""

from __future__ import annotations

import asyncio
import itertools
import json

import pytest

from snan_hil.calibration.observer import CellEvent, PulseEvent
from snan_hil.common.polarity import Polarity
from snan_hil.records import history as H
from snan_hil.records.control import RunControl, StopRequested
from snan_hil.records.documents import DocumentCollector, RunMetadata, RunPublisher
from snan_hil.tools import cli
from snan_hil.tools.watch_app import WatchApp, heat_map, hil_grid
from snan_hil.tools.watch_state import HistorySource, ReplaySource, RunView


def _fixed_run() -> list[tuple[str, dict]]:
    """A deterministic run: a few pulses and results, progress, and two hardware launches."""
    clock = itertools.count(1_800_000_000)
    ids = (f"00000000-0000-4000-8000-{k:012d}" for k in itertools.count())
    pub = RunPublisher(RunMetadata("chip A", "ana", "snapshot", ("demo",),
                                   uid="11111111-2222-4333-8444-555555555555"),
                       kind="program", command="snan-hil program-weights w.npz --port emu",
                       clock=lambda: float(next(clock)), monotonic=lambda: float(next(clock)),
                       uid=lambda: next(ids), board_id="EMU-4D430001/0000", port="emu")
    col = DocumentCollector()
    pub.subscribe(col)
    from snan_hil.common.progress import ProgressEvent
    g = 50e-6
    for r, c in [(0, 0), (0, 1), (1, 0), (3, 5), (7, 7)]:
        for k in range(4):
            pub.on_pulses([PulseEvent(r, c, Polarity.SET, 0.5 + 0.1 * k, 100, g, g * 1.3,
                                      "1")])
            g *= 1.3
        pub.on_cell(CellEvent(r, c, "ok", g, target_s=g, pulses=4))
        pub.progress(ProgressEvent("programming", [(0, 0), (0, 1), (1, 0), (3, 5),
                                                   (7, 7)].index((r, c)) + 1, 8))
        g = 50e-6 + 20e-6 * r
    for launch, (steps, ok) in enumerate([(9, True), (15, False), (7, True)]):
        path = [18, 19, 13, 7, 1, 0][: 6 if ok else 4]
        pub.event("launches", {"scenario": "hw_astro", "set_index": 0, "launch": launch,
                               "steps": steps, "success": ok, "path": path,
                               "calcium_final": [0.05 * (i % 7) for i in range(36)],
                               "grid_rows": 6, "grid_cols": 6, "ca_thr": 0.2})
    pub.stop("complete")
    return col.docs


def test_run_view_follows_the_documents():
    view = RunView()
    view.feed(_fixed_run())
    assert view.kind == "program" and view.status == "finished: success"
    assert view.total_pulses == 20 and view.pulses[(3, 5)] == 4
    assert view.outcome_counts() == {"ok": 5}
    assert view.g[(0, 0)] == pytest.approx(50e-6 * 1.3 ** 4)
    assert view.medians() == {"hw_astro": (8.0, 2, 3)}            # median of 9 and 7
    assert "*" in heat_map(view).plain and "hw_astro launch 2" in hil_grid(view).plain
    assert view.progress["programming"]["done"] == 5


def _running(tmp_path):
    path = tmp_path / "h.sqlite"
    rec = H.Recorder(path, "pulse", command="snan-hil pulse ...",
                     metadata=RunMetadata(sample="w9"))
    rec.on_pulses([PulseEvent(2, 3, Polarity.SET, 0.8, 100, 1e-4, 1.2e-4, "ticket")])
    rec.flush()
    return path, rec


def test_pilot_follows_a_running_run_and_controls_it(tmp_path):
    path, rec = _running(tmp_path)
    source = HistorySource(path)                  # the newest (running) run
    app = WatchApp(source, poll_s=60)             # the test drives the polls itself

    async def drive() -> list[str]:
        async with app.run_test(size=(130, 44)) as pilot:
            await pilot.pause()
            assert app.view.status == "running" and app.view.start["sample"] == "w9"
            assert "120*" in app.query_one("#map").render().plain
            rec.on_pulses([PulseEvent(2, 3, Polarity.SET, 0.9, 100, 1.2e-4, 1.5e-4, "ticket")])
            rec.on_cell(CellEvent(2, 3, "condition met", 1.5e-4, pulses=2))   # flushed
            app.refresh_view()
            await pilot.pause()
            assert app.view.total_pulses == 2 and app._logged == 2
            await pilot.press("p")
            await pilot.press("p")
            await pilot.press("s")
            await pilot.pause()
            return [a for _i, a in source.db.controls(rec.uid)]
    actions = asyncio.run(drive())
    assert actions == ["pause", "resume", "stop"]
    # the job's side: its control channel sees the stop before its next pulse
    ctl = RunControl(path, rec.uid, db=rec.db, poll_s=0)
    with pytest.raises(StopRequested):
        ctl.check()
    rec.finish("interrupted", reason="stop requested")
    source.close()


def test_a_replay_cannot_be_controlled(tmp_path):
    app = WatchApp(ReplaySource(_fixed_run(), per_poll=10), poll_s=60)

    async def drive() -> tuple[int, int]:
        async with app.run_test(size=(130, 44)) as pilot:
            await pilot.pause()
            first = app.view.events
            await pilot.press("s")                # a notification, no error, nothing sent
            app.refresh_view()
            await pilot.pause()
            return first, app.view.events
    first, later = asyncio.run(drive())
    assert first < later


def test_snapshot_of_the_view(snap_compare):
    app = WatchApp(ReplaySource(_fixed_run()), poll_s=60)
    assert snap_compare(app, terminal_size=(130, 44))


def test_screenshot_command_writes_svg(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    assert cli.main(["plan", "run", "set", "--cells", "1,1", "--port", "emu", "--json"]) == 0
    uid = json.loads(capsys.readouterr().out)["run"]["uid"]
    shot = tmp_path / "w.svg"
    assert cli.main(["watch", "--port", "emu", "--run", uid[:8], "--screenshot",
                     str(shot)]) == 0
    svg = shot.read_text()
    assert svg.lstrip().startswith("<svg") and "finished:" in svg and "set" in svg
    assert cli.main(["watch", "--port", "emu", "--run", "nope-nope", "--screenshot",
                     str(shot)]) == 2
    assert "no run nope-nope" in capsys.readouterr().err
    # our own screenshot is replaced; any other SVG (a user's drawing) only with --force
    assert cli.main(["watch", "--port", "emu", "--run", uid, "--screenshot", str(shot)]) == 0
    theirs = tmp_path / "drawing.svg"
    mine = '<svg xmlns="http://www.w3.org/2000/svg"><circle r="4"/></svg>\n'
    theirs.write_text(mine)
    capsys.readouterr()
    assert cli.main(["watch", "--port", "emu", "--run", uid, "--screenshot",
                     str(theirs)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "is not a 'snan-hil watch' screenshot" in err and "--force" in err
    assert theirs.read_text() == mine
    assert cli.main(["watch", "--port", "emu", "--run", uid, "--screenshot", str(theirs),
                     "--force"]) == 0
    assert "finished:" in theirs.read_text()


def test_watch_a_pty_finds_the_served_chips_history_without_board(tmp_path, monkeypatch,
                                                                   capsys):
    # issue 38 item 13: watch --port /dev/pts/N was refused until --board ID, although that
    # chip keeps its history beside its state file
    import os
    import re
    import signal
    import subprocess
    import sys
    env = dict(os.environ, XDG_DATA_HOME=str(tmp_path / "data"), SNAN_HIL_PORT="")
    py = [sys.executable, "-m", "snan_hil.tools.cli"]
    emu = subprocess.Popen([*py, "emu", "--state", str(tmp_path / "served.npz")],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        match = re.search(r"serving on (\S+)", emu.stdout.readline())
        assert match, emu.stderr.read()
        pty = match.group(1)
        done = subprocess.run([*py, "read-cell", "--cell", "1,1", "--port", pty, "--json"],
                              capture_output=True, text=True, env=env, timeout=120)
        assert done.returncode == 0, done.stderr
        assert (tmp_path / "served.history.sqlite").is_file()
        monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
        monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "other-chip.npz"))
        shot = tmp_path / "w.svg"               # while the emulator serves the chip there
        assert cli.main(["watch", "--port", pty, "--screenshot", str(shot)]) == 0, \
            capsys.readouterr().err
        assert "read" in shot.read_text()
        capsys.readouterr()
        assert cli.main(["history", "--port", pty, "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["history"] == str(
            tmp_path / "served.history.sqlite")
    finally:
        emu.send_signal(signal.SIGINT)
        emu.communicate(timeout=60)
    # the emulator has stopped: the pty may serve something else now, the port names no chip
    assert cli.main(["history", "--port", pty]) == 2
    assert "--board" in capsys.readouterr().err


def test_the_running_cells_conductance_trace(tmp_path, monkeypatch, capsys):
    # issue 38 item 10: watch showed the map, counts and a pulse log, not the running cell's
    # conductance trace (MemriBoard's live plot)
    from snan_hil.tools.watch_app import cell_trace
    view = RunView()
    view.feed(_fixed_run())
    assert view.trace_cell == (7, 7) and len(view.trace) == 4        # the last cell only
    assert [w for _g, w in view.trace] == ["SET"] * 4
    text = cell_trace(view, width=40, height=6).plain
    assert text.startswith("cell (7,7): 4 pulses and reads in this run") and "█" in text
    pub = RunPublisher(RunMetadata(), kind="plan")
    col = DocumentCollector()
    pub.subscribe(col)
    g = 30e-6
    for _k in range(30):                                 # a ramp over two decades, reads too
        g *= 1.2
        pub.on_pulses([PulseEvent(4, 2, Polarity.SET, 0.5, 100, g / 1.2, g, "plan step 1")])
        pub.event("reads", {"row": 4, "col": 2, "adc": 1, "read_code": 245, "read_v": 0.3,
                            "g_s": g, "step": "plan step 2"})
    view = RunView()
    view.feed(col.docs)
    shown = cell_trace(view, width=20, height=4)
    assert "(log)" in shown.plain and "last 20 shown" in shown.plain
    styles = {str(span.style) for span in shown.spans}
    assert any("31,119,180" in st for st in styles) and "grey62" in styles   # SET and reads
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    assert cli.main(["plan", "run", "set", "--cells", "1,1", "--port", "emu"]) == 0
    shot = tmp_path / "w.svg"
    assert cli.main(["watch", "--port", "emu", "--screenshot", str(shot)]) == 0
    assert "conductance&#160;of&#160;the&#160;running&#160;cell" in shot.read_text() or \
        "conductance of the running cell" in shot.read_text()
