"""The raw console (``snan-hil console``, :mod:`snan_hil.calibration.console`) with bad lines
and at a terminal (issue 38, items 7 and 13): a bad line is one refused reply and the next
lines run; a script fed from a pipe exits 1 when lines were refused; an over-long line is
refused unparsed; ``column`` converts its reading; a terminal gets line editing and history."""

from __future__ import annotations

import json
import os
import select
import subprocess
import sys
import time

import pytest

from snan_hil.records import history as H

PY = [sys.executable, "-m", "snan_hil.tools.cli"]


def _env(folder):
    return dict(os.environ, SNAN_HIL_EMU_STATE=str(folder / "chip.npz"),
                XDG_DATA_HOME=str(folder / "data"), SNAN_HIL_PORT="")


def _console(folder, lines: str, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([*PY, "console", "--port", "emu", *extra], input=lines,
                          capture_output=True, text=True, timeout=120, env=_env(folder))


def test_an_unclosed_quote_is_one_refused_line_and_the_rest_still_runs(tmp_path):
    proc = _console(tmp_path, 'read "0,0\nread 1,1 abc\nread 1,1\n')
    assert "Traceback" not in proc.stderr
    out = proc.stdout.splitlines()
    assert out[0] == "refused: No closing quotation in 'read \"0,0'; nothing sent"
    assert out[1].startswith("refused: read R,C [CODE]: CODE 'abc' is not an integer")
    assert out[2].startswith("cell (1,1): ADC ")
    assert proc.returncode == 1
    assert proc.stderr.strip() == "snan-hil console: 2 of 3 commands refused or failed"


def test_a_clean_script_exits_0(tmp_path):
    proc = _console(tmp_path, "# a comment\nread 1,1\n\ninfo\n")
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr


def test_a_multi_megabyte_line_is_refused_unparsed_and_recorded_short(tmp_path):
    big = "9," + "1" * 8_000_000
    proc = _console(tmp_path, f"{big}\nread 1,1\n", "--json")
    out = [json.loads(x) for x in proc.stdout.splitlines()]
    assert out[0]["ok"] is False and out[0]["reply"] == \
        "refused: a line of 8000002 characters; at most 4096 (nothing sent)"
    assert len(out[0]["command"]) < 100 and out[1]["ok"] is True
    with H.History.open(tmp_path / "chip.history.sqlite", create=False) as db:
        [run] = db.runs(kind="console")
        size = db.conn.execute("SELECT max(length(doc_json)) FROM documents WHERE run_id = ?",
                               (run.id,)).fetchone()[0]
    assert size < 5000                    # the line is not copied into the run's record


def test_column_gives_the_current_and_the_one_driven_cells_conductance(tmp_path):
    proc = _console(tmp_path, "read 1,2\ncolumn 2 0 245\ncolumn 2 50 50 50\n", "--json")
    read, one, three = (json.loads(x) for x in proc.stdout.splitlines())
    assert one["ok"] and "I = " in one["reply"] and "G(1,2) = " in one["reply"]
    assert one["g_s"] == pytest.approx(read["g_s"], rel=0.03)     # cell path vs column path
    assert three["ok"] and "3 rows at code 50: sum of G" in three["reply"]


def _read_until(fd: int, needle: bytes, timeout_s: float = 60.0) -> bytes:
    got = b""
    deadline = time.monotonic() + timeout_s
    while needle not in got:
        left = deadline - time.monotonic()
        assert left > 0, got
        ready, _, _ = select.select([fd], [], [], left)
        if ready:
            try:
                chunk = os.read(fd, 4096)
            except OSError:
                break
            if not chunk:
                break
            got += chunk
    return got


def test_a_terminal_gets_line_editing_and_history(tmp_path):
    import pty
    pid, fd = pty.fork()
    if pid == 0:                                             # the console on a terminal
        os.execve(sys.executable, [*PY, "console", "--port", "emu"], _env(tmp_path))
    try:
        _read_until(fd, b"snan-hil> ")
        os.write(fd, b"read 1,1\r")
        first = _read_until(fd, b"snan-hil> ")
        os.write(fd, b"\x1b[A\r")                            # arrow up: the last line again
        again = _read_until(fd, b"snan-hil> ")
        os.write(fd, b"read 1,3\x1b[D\x1b[D\x7f2\r")       # edit: left, left, erase, type
        edited = _read_until(fd, b"snan-hil> ")
        os.write(fd, b"quit\r")
        _read_until(fd, b"", 5)
    finally:
        _pid, status = os.waitpid(pid, 0)
    assert b"cell (1,1): ADC" in first and b"cell (1,1): ADC" in again
    assert b"^[[A" not in again
    assert b"cell (2,3): ADC" in edited
    assert os.waitstatus_to_exitcode(status) == 0
    history = (tmp_path / "data" / "snan-hil" / "console-history").read_text()
    assert "read 1,1" in history and "read 2,3" in history
