"""``snan-hil learn`` killed and resumed: every pulse the board applied is counted once (issue
32: the ledger of a run killed while programming; issue 38 item 4: a cut line of the pulse
journal decided by the board's pulse counter)."""

import json
import os
import subprocess
import sys
import time

import pytest

from snan_hil.records.history import History
from snan_hil.records.journal import read_journal
from snan_hil.tools import cli

PY = [sys.executable, "-m", "snan_hil.tools.cli"]


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    """A device model of the learning pulse, fitted on an emulated chip of its own."""
    d = tmp_path_factory.mktemp("model")
    path = d / "model.json"
    assert cli.main(["characterize", "--port", f"emu://?state={d / 'chip.npz'}", "--cells",
                     "0,0;0,1;1,2;2,3;3,4;4,5", "--repeats", "1", "--json", "--model",
                     str(path), "--record", "off"]) == 0
    return path


def _argv(port, model, out, *extra):
    return ["learn", "--port", port, "--arms", "chip", "--sessions", "1", "--cycles", "1",
            "--model", str(model), "--out", str(out), "--no-figure", "--json", "--set",
            "grid.max_steps=30", *extra]


def _sent(journal):
    try:
        return journal.read_text(encoding="utf-8", errors="replace").count('"s":"sent"')
    except FileNotFoundError:
        return 0


def test_a_learn_killed_while_programming_keeps_those_pulses_in_its_ledger(
        model, tmp_path, monkeypatch, capsys):
    """A fresh chip, ``kill -9`` after ~60 programming pulses, --resume: the ledger holds the
    killed part's programming pulses (a row of their own), so it equals the history of the
    whole run (before: 924 in the ledger, 997 in the history, the 73 of the killed part)."""
    chip, out = tmp_path / "fresh.npz", tmp_path / "out"
    env = {"XDG_DATA_HOME": str(tmp_path / "xdg"), "SNAN_HIL_PORT": ""}
    argv = _argv(f"emu://?state={chip}&seed=3", model, out)
    proc = subprocess.Popen([*PY, *argv], env=dict(os.environ, **env),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    journal = out / "checkpoint" / "pulses.jsonl"
    deadline = time.monotonic() + 300
    while _sent(journal) < 60:
        assert proc.poll() is None, "finished before the kill: " + proc.stderr.read()
        assert time.monotonic() < deadline
        time.sleep(0.005)
    proc.kill()
    proc.communicate(timeout=60)
    assert not (out / "checkpoint" / "unit-chip-s0-c0.json").exists()   # inside programming
    killed = read_journal(journal)
    assert {p.stage for p in killed.pulses} <= {"1", "2"}      # write-and-verify stages
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    assert cli.main([*argv, "--resume"]) == 0
    capsys.readouterr()
    doc = json.loads((out / "learn.json").read_text())
    led, hist = doc["ledger"], doc["history"]
    with History.open(hist["path"], create=False) as db:
        recorded = sum(r.pulses for r in db.runs("learn"))
    assert len(hist["runs"]) == 2
    assert led["total"] == recorded == hist["pulses_recorded"]
    cut = led["rows"][0]
    assert cut["stage"] == "program (interrupted)" and cut["cycle"] == 0
    done = sum(1 for p in killed.pulses if p.state == "done")
    assert cut["set"] + cut["reset"] == done >= 59 and cut["uncertain"] <= 1
    assert [r["stage"] for r in led["rows"][1:]] == ["program", "learn"]


@pytest.mark.parametrize("cut", ["done", "sent"])
def test_a_cut_journal_line_is_decided_by_the_boards_pulse_counter(
        model, tmp_path, monkeypatch, capsys, cut):
    """A served board keeps its boot and pulse counter while learn is killed and resumed. The
    journal's last line cut mid-line, garbage after it: a cut "done" line's pulse ran (the
    counter says one more than the journal's done), a cut "sent" line's never went out; one
    line says so, and the ledger holds every pulse the board counted, none uncertain."""
    from snan_hil.calibration import board_io
    from snan_hil.firmware_emu.emulator import Emulator
    from snan_hil.firmware_emu.server import TcpServer
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    monkeypatch.delenv("SNAN_HIL_PORT", raising=False)
    emu = Emulator(tmp_path / "served.npz", seed=3)
    out = tmp_path / "out"
    real = board_io.BoardCellIO.pulse
    learnt = [0]

    def pulse(self, polarity, amplitude_v):
        if self.stage != "learn":
            return real(self, polarity, amplitude_v)
        if cut == "sent" and learnt[0] == 4:
            raise KeyboardInterrupt                 # killed while writing the "sent" line
        g = real(self, polarity, amplitude_v)
        learnt[0] += 1
        if cut == "done" and learnt[0] == 5:
            raise KeyboardInterrupt                 # killed while writing the "done" line
        return g
    with TcpServer(emu, "127.0.0.1", 0) as server:
        before = emu.board.front_end.pulses_applied
        argv = _argv(server.url, model, out, "--mode", "batch")
        monkeypatch.setattr(board_io.BoardCellIO, "pulse", pulse)
        assert cli.main(argv) == 130
        monkeypatch.setattr(board_io.BoardCellIO, "pulse", real)
        journal = out / "checkpoint" / "pulses.jsonl"
        lines = journal.read_text().splitlines()
        last = json.loads(lines[-1])
        if cut == "done":
            assert last["s"] == "done"
            text = "\n".join(lines[:-1]) + "\n" + lines[-1][:18]
        else:
            assert last["s"] == "done"
            text = "\n".join(lines) + "\n" + json.dumps(
                {"r": last["r"], "n": last["n"] + 1, "s": "sent"}, separators=(",", ":"))[:25]
        journal.write_text(text + "\x00" * 16 + "garbage")
        capsys.readouterr()
        assert cli.main([*argv, "--resume"]) == 0
        applied = emu.board.front_end.pulses_applied - before
    doc = json.loads((out / "learn.json").read_text())
    led = doc["ledger"]
    assert led["uncertain"] == 0
    assert led["total"] == applied == doc["history"]["pulses_recorded"]
    err = capsys.readouterr().err
    told = [line for line in err.splitlines() if "pulse journal" in line]
    assert len(told) == 1, err
    if cut == "done":
        assert "the board's pulse counter (same boot) says it ran: counted as applied" \
            in told[0], told
    else:
        assert "never went out" in told[0] and "the board's pulse counter agrees" in told[0]
    assert len(read_journal(journal).torn) == 1     # the resumed run wrote whole lines
