"""--port from SNAN_HIL_PORT, and no silent emulator: a command that falls back to the emulator
while a serial device such as /dev/ttyUSB0 exists says so and names how to use the board."""

from __future__ import annotations

import json

import pytest

from snan_hil.tools import cli, ports


@pytest.fixture
def emu(tmp_path, monkeypatch):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    monkeypatch.delenv(ports.PORT_ENV, raising=False)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    monkeypatch.setattr(ports, "SERIAL_GLOBS", (str(tmp_path / "dev" / "ttyUSB*"),
                                                str(tmp_path / "dev" / "ttyACM*")))
    (tmp_path / "dev").mkdir()
    return tmp_path


def test_port_from_environment(emu, monkeypatch, capsys):
    monkeypatch.setenv(ports.PORT_ENV, "emu")
    assert cli.main(["map", "--json", "--record", "off"]) == 0
    assert json.loads(capsys.readouterr().out)["board"]["port"] == "emu"
    missing = str(emu / "dev" / "ttyUSB7")
    monkeypatch.setenv(ports.PORT_ENV, missing)
    assert cli.main(["map", "--record", "off"]) == 2
    err = capsys.readouterr().err
    assert f"cannot open port {missing}" in err and err.count("\n") == 1
    # an explicit --port wins over the environment
    assert cli.main(["map", "--port", "emu", "--json", "--record", "off"]) == 0
    capsys.readouterr()


def test_no_silent_emulator_when_a_serial_device_exists(emu, capsys):
    assert cli.main(["map", "--json", "--record", "off"]) == 0
    assert "emulator" not in capsys.readouterr().err        # no device: nothing to say
    for name in ("ttyUSB0", "ttyACM1"):
        (emu / "dev" / name).write_text("")
    assert cli.main(["map", "--json", "--record", "off"]) == 0
    cap = capsys.readouterr()
    json.loads(cap.out)                                    # stdout stays clean JSON
    lines = [line for line in cap.err.splitlines() if "note:" in line]
    assert len(lines) == 1
    usb = str(emu / "dev" / "ttyUSB0")
    assert "using the board emulator" in lines[0] and usb in lines[0]
    assert f"--port {str(emu / 'dev' / 'ttyACM1')}" in lines[0] or f"--port {usb}" in \
        lines[0]
    assert ports.PORT_ENV in lines[0]
    # an explicit --port emu is a choice: no note
    assert cli.main(["map", "--port", "emu", "--json", "--record", "off"]) == 0
    assert "note:" not in capsys.readouterr().err


def test_history_follows_the_environment(emu, monkeypatch, capsys):
    monkeypatch.setenv(ports.PORT_ENV, "socket://127.0.0.1:9")
    assert cli.main(["history"]) == 2
    err = capsys.readouterr().err
    # the port from the environment; its history is keyed by the board's identity
    assert "socket://127.0.0.1:9" in err and "--board" in err and err.count("\n") == 1
    assert cli.main(["history", "--board", "MC-4D430001"]) == 2
    err = capsys.readouterr().err
    assert "MC-4D430001.history.sqlite" in err and err.count("\n") == 1
