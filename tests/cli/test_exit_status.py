"""The exit status says whose the failure is (docs/outputs.md, "Exit status"): 2 a user
mistake, 3 the board or its link failed, with one line naming the port and what to check (and,
for a run that can be continued, the command that continues it)."""

import argparse
import json
from pathlib import Path

import numpy as np
import pytest
import serial

from snan_hil.calibration.testing import grid_weights
from snan_hil.common.errors import BoardLinkError, UserError
from snan_hil.firmware_emu import protocol_emu
from snan_hil.protocol import errors as E
from snan_hil.protocol.transport import open_pty_pair
from snan_hil.tools import cli

UNPLUGGED = ("device reports readiness to read but returned no data (device disconnected or "
             "multiple access on port?)")           # pyserial's words for a pulled adapter


def unplug_when(monkeypatch, condition):
    """The in-process emulator's port fails as an unplugged USB adapter does, from the first
    write at which ``condition()`` holds on."""
    real = protocol_emu.Serial.write
    gone = []

    def write(self, data):
        if gone or condition():
            gone.append(True)
            raise serial.SerialException(UNPLUGGED)
        return real(self, data)
    monkeypatch.setattr(protocol_emu.Serial, "write", write)


def after_writes(n):
    count = [0]

    def condition():
        count[0] += 1
        return count[0] > n
    return condition


def lines(capsys):
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err, err
    return err.splitlines()


def test_a_board_that_never_answers_is_a_board_or_link_failure(capsys):
    pair = open_pty_pair()                  # a port that opens, with nothing behind it
    try:
        code = cli.main(["info", "--port", pair.slave_path, "--timeout", "0.05"])
    finally:
        pair.close()
    assert code == cli.EXIT_BOARD_OR_LINK == 3
    [line] = lines(capsys)
    assert line.startswith("snan-hil info: board or link failed: ")
    assert pair.slave_path in line and "no answer" in line and "check power, cable" in line


def test_a_port_that_cannot_be_opened_is_the_users_mistake(capsys):
    assert cli.main(["info", "--port", "/dev/ttyNOPE9"]) == cli.EXIT_USER_ERROR == 2
    [line] = lines(capsys)
    assert line.startswith("snan-hil info: error: cannot open port /dev/ttyNOPE9")


def test_a_board_gone_mid_programming_exits_3_with_the_report_kept(emu, capsys, monkeypatch):
    np.save(emu / "w.npy", grid_weights(3, 3, seed=2))
    report = emu / "r.json"
    unplug_when(monkeypatch, after_writes(500))          # of 718: some synapses, not all 24
    code = cli.main(["program-weights", str(emu / "w.npy"), "--port", "emu", "--report",
                     str(report)])
    assert code == cli.EXIT_BOARD_OR_LINK
    [line] = lines(capsys)                               # nothing to resume: one line
    assert line.startswith("snan-hil program-weights: board or link failed: write to emu://")
    assert "the board or emulator went away" in line and "check cable and power" in line
    rep = json.loads(report.read_text())
    assert rep["complete"] is False and "went away" in rep["error"]
    assert 0 < sum(c["ok"] for c in rep["cells"]) < 24


def test_a_link_lost_mid_compare_names_the_command_that_continues_it(
        cli_trained, emu, capsys, monkeypatch):
    out = emu / "out"
    argv = ["compare", "--weights", str(cli_trained), "--port", "emu", "--out", str(out),
            "--launches", "2", "--seed", "4", "--json", "--no-figure", "--set",
            "grid.max_steps=15"]
    first = out / "checkpoint" / "unit-set-0.json"
    unplug_when(monkeypatch, first.exists)               # into set 1, the line goes
    assert cli.main(argv) == cli.EXIT_BOARD_OR_LINK
    *progress, failure, hint = lines(capsys)              # progress lines, then the end
    assert all(not line.startswith("snan-hil") for line in progress), progress
    assert failure.startswith("snan-hil compare: board or link failed: ") and "emu://" in failure
    assert hint == "snan-hil compare: to continue where it stopped: snan-hil " + " ".join(
        [*argv, "--resume"])
    assert first.exists() and not (out / "compare.json").exists()
    monkeypatch.undo()                                   # the adapter plugged in again
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(emu / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(emu / "data"))
    monkeypatch.delenv("SNAN_HIL_PORT", raising=False)
    assert cli.main([*argv, "--resume"]) == 0
    assert json.loads((out / "compare.json").read_text())["resumed"] is True


def test_the_exit_statuses_are_documented_as_the_cli_gives_them():
    root = Path(__file__).resolve().parents[2]
    text = (root / "docs" / "outputs.md").read_text()
    section = text.split("## Exit status", 1)[1].split("\n## ", 1)[0]
    rows = {int(line.split("|")[1]): line for line in section.splitlines()
            if line.startswith("| ") and line.split("|")[1].strip().isdigit()}
    assert sorted(rows) == [0, 1, cli.EXIT_USER_ERROR, cli.EXIT_BOARD_OR_LINK, 130,
                            cli.EXIT_BROKEN_PIPE]
    assert "user mistake" in rows[2] and "board or its link failed" in rows[3]
    readme = " ".join((root / "README.md").read_text().split())
    assert "2 a user mistake" in readme and "3 the board or its link failed" in readme


@pytest.mark.parametrize("exc, wanted, unwanted", [
    (E.BoardResetError("board on /dev/ttyUSB0 was reset (boot nonce 0x1 -> 0x2): it was reset; "
                       "call hello() to resynchronise and re-check its state"),
     ["check its power supply, then run the command again"], ["(--port"]),
    (E.board_error(E.ErrorCode.INTERNAL, "firmware fault"),
     ["(--port /dev/ttyUSB0): firmware fault", "power the board off and on"], []),
    (E.VersionMismatchError("board on /dev/ttyUSB0 speaks protocol version 3, this host speaks "
                            "1; update the board firmware or snan-hil"), [], ["power"]),
    (E.LinkTimeoutError("the line went silent; check cable", "stalled"), ["(--port "], ["power"]),
    (E.TransportError("read from /dev/ttyUSB0 failed"), ["check the board's power, cable and "
                                                         "port"], ["(--port"]),
])
def test_the_line_names_the_port_and_what_to_check(exc, wanted, unwanted):
    assert isinstance(exc, BoardLinkError)
    line = cli.board_or_link_line(argparse.Namespace(command="map", port="/dev/ttyUSB0"), exc)
    assert line.startswith("snan-hil map: board or link failed") and "\n" not in line
    assert "/dev/ttyUSB0" in line
    for text in wanted:
        assert text in line, line
    for text in unwanted:
        assert text not in line, line


@pytest.mark.parametrize("exc", [E.UnsupportedError("SPIKE_BATCH needs the framed protocol"),
                                 E.SafetyLimitError("write above the limit"),
                                 E.FieldRangeError("row 300 does not fit")])
def test_a_refused_request_stays_a_user_mistake(exc):
    assert isinstance(exc, UserError) and not isinstance(exc, BoardLinkError)
