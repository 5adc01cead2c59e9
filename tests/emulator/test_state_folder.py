"""File options need an existing folder (docs/outputs.md): a chip state file given with
``--state`` or ``$SNAN_HIL_EMU_STATE`` in a missing folder is refused in one line and no folder
is created; only the default chip in the user's data folder gets its folder made."""

import os
import subprocess
import sys

import pytest

from snan_hil.tools import cli

PY = [sys.executable, "-m", "snan_hil.tools.cli"]


@pytest.mark.parametrize("how", ["option", "env"])
def test_emu_refuses_a_state_file_in_a_missing_folder(tmp_path, how):
    env = dict(os.environ, XDG_DATA_HOME=str(tmp_path / "xdg"))
    argv = [*PY, "emu", "--socket", "127.0.0.1:0"]
    if how == "option":
        argv += ["--state", "nope/c.npz"]
        env.pop("SNAN_HIL_EMU_STATE", None)
    else:
        env["SNAN_HIL_EMU_STATE"] = str(tmp_path / "nope" / "c.npz")
    done = subprocess.run(argv, cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=60)
    err = done.stderr.strip()
    assert done.returncode == 2 and "nope does not exist" in err and "\n" not in err, err
    assert not (tmp_path / "nope").exists()


@pytest.mark.parametrize("command", [["info"], ["ping"]])
def test_port_emu_commands_refuse_a_missing_state_folder(tmp_path, monkeypatch, capsys,
                                                         command):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "nope" / "c.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    assert cli.main([*command, "--port", "emu"]) == 2
    err = capsys.readouterr().err.strip()
    assert "nope does not exist" in err and "\n" not in err
    assert not (tmp_path / "nope").exists()


def test_the_default_chip_gets_its_user_data_folder(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("SNAN_HIL_EMU_STATE", raising=False)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    assert cli.main(["info", "--port", "emu"]) == 0
    assert (tmp_path / "xdg" / "snan-hil" / "emu-chip.npz").is_file()
