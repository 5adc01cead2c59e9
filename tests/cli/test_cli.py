"""The CLI skeleton: help lists sub-commands, --version, user errors are one line, a reader
that closes stdout ends a command quietly."""

import io
import subprocess
import sys

import pytest

from snan_hil import __version__
from snan_hil.tools import cli


def test_version_flag(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["--version"])
    assert exc.value.code == 0
    assert __version__ in capsys.readouterr().out


def test_help_lists_every_discovered_command(capsys):
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    out = capsys.readouterr().out
    names = [m.NAME for m in cli.discover_commands()]
    assert "version" in names
    for name in names:
        assert name in out


def test_console_script_runs():
    proc = subprocess.run([sys.executable, "-m", "snan_hil.tools.cli", "version"],
                          capture_output=True, text=True, check=False)
    assert proc.returncode == 0
    assert proc.stdout.startswith("snan-hil ")


def test_unknown_command_exits_2():
    proc = subprocess.run([sys.executable, "-m", "snan_hil.tools.cli", "no-such-command"],
                          capture_output=True, text=True, check=False)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr


class _ClosedPipe(io.StringIO):
    def write(self, s):
        raise BrokenPipeError(32, "Broken pipe")


def test_closed_stdout_ends_quietly(programmed_emu, capsys, monkeypatch):
    capsys.readouterr()
    monkeypatch.setattr(sys, "stdout", _ClosedPipe())
    assert cli.main(["history", "--port", "emu", "--json"]) == cli.EXIT_BROKEN_PIPE
    assert cli.main(["cells", "show", "--port", "emu", "--json"]) == cli.EXIT_BROKEN_PIPE
    monkeypatch.undo()
    assert "Traceback" not in capsys.readouterr().err
