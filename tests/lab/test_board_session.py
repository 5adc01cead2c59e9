"""The board session and the opener (issue 21 points 1-3, issue 27 items 8 and 9).

* one chip, one record: the same emulated chip reached in-process and served by
  ``snan-hil emu --state`` has one layout and one history database, so a run is never
  attributed to the wrong weight set;
* finished work is never overwritten: ``program-weights --layout L`` with the layout of another
  board or chip, or of a newer format, is refused in one line and L is left as it is;
* the session: files resolved once, read retries switched on once, one provenance snapshot.
"""

from __future__ import annotations

import json
import os
import signal

import pytest

from snan_hil.board.files import BoardFiles
from snan_hil.board.identity import BoardIdentity
from snan_hil.lab.opener import FileUse, plan_board
from snan_hil.lab.ports import BoardAddress
from snan_hil.protocol.retry import RetryingClient
from snan_hil.tools import cli


@pytest.fixture
def env(chip_home):
    return chip_home


def stop(proc) -> None:
    proc.send_signal(signal.SIGTERM)
    proc.communicate(timeout=30)


# -- issue 27, item 9: one chip, one record ---------------------------------------------------
def test_a_chip_served_and_in_process_has_one_layout_and_one_history(env, capsys,
                                                                     start_emu_server, one_line):
    from snan_hil.host.hil.testing import make_weights
    weights = make_weights(env / "w.npz", sets=3, cycles=1)
    chip = env / "chip.npz"
    in_process = f"emu://?state={chip}"
    # set 1 in-process, then set 2 over a socket served from the same chip file
    assert cli.main(["program-weights", str(weights), "--weight-set", "1", "--port",
                     in_process, "--json"]) == 0
    first = json.loads(capsys.readouterr().out)
    server, url = start_emu_server(chip, env=dict(os.environ))
    try:
        assert cli.main(["program-weights", str(weights), "--weight-set", "2", "--port", url,
                         "--json"]) == 0
        served = json.loads(capsys.readouterr().out)
    finally:
        stop(server)
    assert served["layout"] == first["layout"] == str(env / "chip.layout.json")
    assert served["report"] == first["report"]
    assert not (env / "xdg" / "snan-hil" / "layouts").exists()       # no second record
    from snan_hil.records.history import History
    with History.open(env / "chip.history.sqlite") as db:            # one history: both runs
        assert [r.kind for r in db.runs()] == ["program", "program"]
    # the chip holds set 2: an in-process run of set 1 is refused, set 2 accepted
    run = ["run", "--scenario", "hw_noastro", "--weights", str(weights), "--launches", "1",
           "--set", "grid.max_steps=30",
           "--port", in_process, "--json"]
    capsys.readouterr()
    assert cli.main([*run, "--weight-set", "1"]) == 2
    assert "holds other weights" in one_line()
    assert cli.main([*run, "--weight-set", "2"]) == 0
    assert json.loads(capsys.readouterr().out)["layout"] == str(env / "chip.layout.json")


def test_served_and_in_process_sessions_resolve_the_same_files(env, start_emu_server):
    chip = env / "chip.npz"
    use = FileUse(record=True)
    with plan_board(BoardAddress(f"emu://?state={chip}"), use).open() as local:
        pass
    server, url = start_emu_server(chip, env=dict(os.environ))
    try:
        with plan_board(BoardAddress(url), use).open() as remote:
            assert remote.identity == local.identity and remote.identity.chip_id
            assert remote.files.layout == local.files.layout == env / "chip.layout.json"
            assert remote.files.history == local.files.history
            assert remote.snapshots is None and local.snapshots is not None
    finally:
        stop(server)
    # a chip this machine does not serve (a real board) is keyed by its board id
    other = BoardFiles.of_board(BoardIdentity("MC-4D430001/XYZ"), url)
    assert other.layout.name == "MC-4D430001_XYZ.json"


# -- issue 27, item 8: another board's layout, a newer format ----------------------------------
@pytest.mark.parametrize("fresh", [False, True])
def test_program_weights_refuses_another_chips_layout(env, capsys, fresh, one_line):
    layout = env / "a.layout.json"
    assert cli.main(["program-weights", str(env / "w.npy"), "--port",
                     f"emu://?state={env / 'a.npz'}", "--layout", str(layout), "--json"]) == 0
    capsys.readouterr()
    before = layout.read_bytes()
    argv = ["program-weights", str(env / "w.npy"), "--port", f"emu://?state={env / 'b.npz'}",
            "--layout", str(layout), *(["--fresh-layout"] if fresh else [])]
    assert cli.main(argv) == 2
    err = one_line()
    assert str(layout) in err and "another chip" in err and "never overwrites" in err
    assert layout.read_bytes() == before                          # finished work kept


def test_the_default_chip_is_one_board_whichever_mcu_model_runs_it(env, capsys):
    """The Python MCU model reports EMU-4D430001/<serial>, the C firmware MC-4D430001/<serial>
    (what it says on a real board): the same emulated chip, so its default layout serves
    both (it was refused as another board's with --mcu firmware); another chip stays
    refused."""
    a, b = BoardIdentity("EMU-4D430001/ABC"), BoardIdentity("MC-4D430001/ABC")
    assert a.owns(b) and b.owns(a) and a.chip_key == b.chip_key == "4D430001/ABC"
    assert not b.owns(BoardIdentity("EMU-4D430001/XYZ"))
    assert not BoardIdentity("MC-4D430001").owns(BoardIdentity("EMU-4D430001"))  # no chip named
    layout = env / "chip.layout.json"
    assert cli.main(["program-weights", str(env / "w.npy"), "--port", "emu", "--json"]) == 0
    assert json.loads(layout.read_text())["board"]["board_id"].startswith("EMU-")
    capsys.readouterr()
    assert cli.main(["read-cell", "--port", "emu", "--mcu", "firmware", "--cell", "0,0",
                     "--json"]) == 0, capsys.readouterr().err
    assert json.loads(capsys.readouterr().out)


def test_program_weights_refuses_a_layout_of_a_newer_format(env, capsys, one_line):
    layout = env / "l.json"
    assert cli.main(["program-weights", str(env / "w.npy"), "--port", "emu", "--layout",
                     str(layout), "--json"]) == 0
    capsys.readouterr()
    data = json.loads(layout.read_text())
    data["format"] = "snan-hil-layout/2"
    layout.write_text(json.dumps(data))
    before = layout.read_bytes()
    assert cli.main(["program-weights", str(env / "w.npy"), "--port", "emu", "--layout",
                     str(layout)]) == 2
    err = one_line()
    assert "snan-hil-layout/2" in err and "newer" in err
    assert layout.read_bytes() == before


# -- the session -----------------------------------------------------------------------------
def test_the_session_retries_reads_once_and_records_its_provenance(env):
    plan = plan_board(BoardAddress("emu", state_file=str(env / "c.npz"), seed=3,
                                   max_write_v=1.2), FileUse(record=True))
    assert plan.files.layout == env / "c.layout.json"          # known before HELLO
    with plan.open() as session:
        assert isinstance(session.client, RetryingClient)
        assert not isinstance(session.client.inner, RetryingClient)   # wrapped once
        assert session.limits.max_write_v == pytest.approx(1.2)
        snap = session.snapshot()
    assert snap["format"] == "snan-hil-session/1" and snap["port"] == "emu"
    assert snap["identity"]["chip_id"] == session.identity.chip_id != ""
    assert snap["host_limits"]["max_write_v"] == pytest.approx(1.2)
    assert snap["files"]["history"] == str(env / "c.history.sqlite")
    json.dumps(snap, allow_nan=False)                           # JSON-ready
    # a second open (a fresh boot, as every set of a comparison) is the same board
    with plan.open() as again:
        assert again.identity == session.identity and again.files == session.files


def test_layout_files_follow_the_rules():
    files = BoardFiles.beside_chip("/x/emu-chip.npz")
    assert files.layout.name == "emu-chip.layout.json"
    assert files.report.name == "emu-chip.program-report.json"
    assert files.previous_report.name == "emu-chip.program-report.prev.json"
    assert files.history.name == "emu-chip.history.sqlite"
    named = files.overridden(layout="/y/mine.json")
    assert named.report.name == "mine.program-report.json"
    assert named.history == files.history                       # the history is the board's
    legacy = BoardFiles.of_board(BoardIdentity("legacy"), "/dev/ttyUSB0")
    assert legacy.layout.name == "port-dev_ttyUSB0.json"
    assert BoardIdentity("EMU-1/A").resume_key("p") == {"board_id": "EMU-1/A"}
    assert not BoardIdentity("EMU-1/A").owns(BoardIdentity("EMU-1/B"))
    assert BoardIdentity("").owns(BoardIdentity("EMU-1/B"))
