"""An ``emu://`` URL and the command's link options: a URL without ``protocol=`` or ``mcu=``
gets the one ``--protocol`` / ``--mcu`` names, a URL naming another is refused (one line, exit
2), and ``--mcu`` applies to the in-process emulator only."""

from __future__ import annotations

import pytest

from snan_hil.common.errors import UserError
from snan_hil.lab.ports import open_transport, port_url, resolve_mcu
from snan_hil.tools.cli import main


def test_emu_url_inherits_or_refuses_the_protocol():
    assert port_url("emu://?state=c.npz", protocol="legacy") == "emu://?state=c.npz&protocol=legacy"
    assert port_url("emu://", protocol="legacy") == "emu://?protocol=legacy"
    assert port_url("emu://?state=c.npz", protocol="framed") == "emu://?state=c.npz"
    assert port_url("emu://?protocol=legacy", protocol="legacy") == "emu://?protocol=legacy"
    with pytest.raises(UserError, match="contradicts protocol=framed"):
        port_url("emu://?protocol=framed", protocol="legacy")


def test_info_over_a_legacy_emu_url_without_protocol_answers(tmp_path, capsys):
    url = f"emu://?state={tmp_path / 'chip.npz'}"
    assert main(["info", "--port", url, "--protocol", "legacy", "--json"]) == 0
    assert "legacy" in capsys.readouterr().out.lower()
    assert main(["info", "--port", url + "&protocol=framed", "--protocol", "legacy"]) == 2
    err = capsys.readouterr().err.strip()
    assert "contradicts" in err and len(err.splitlines()) == 1


def test_mcu_conflicts_with_the_port_are_refused(emu, one_line):
    assert resolve_mcu("emu://?mcu=firmware", None) == "firmware"
    assert resolve_mcu("emu", None) == "model" and resolve_mcu("/dev/ttyUSB0", None) is None
    assert main(["info", "--port", "emu://?mcu=model", "--mcu", "firmware"]) == 2
    assert "contradicts mcu=model" in one_line()
    assert main(["info", "--port", "socket://127.0.0.1:9", "--mcu", "firmware"]) == 2
    assert "--mcu only applies to the in-process emulator" in one_line()
    with pytest.raises(UserError, match="only applies"):
        open_transport("/dev/ttyUSB0", mcu="model")


def test_mcu_is_added_to_an_emu_url_without_one(emu, firmware_mcu, capsys):
    assert main(["info", "--port", f"emu://?state={emu / 'u.npz'}", "--mcu", firmware_mcu,
                 "--json"]) == 0
    assert '"MC-4D430001/' in capsys.readouterr().out


def test_a_legacy_emu_url_decides_the_protocol_when_none_is_given(tmp_path, capsys,
                                                                   monkeypatch):
    # found by a new user: the default --protocol framed was taken as given and refused
    url = f"emu://?state={tmp_path / 'chip.npz'}&protocol=legacy"
    assert main(["info", "--port", url, "--json"]) == 0
    assert "legacy" in capsys.readouterr().out.lower()
    monkeypatch.setenv("SNAN_HIL_PORT", url)
    assert main(["info", "--json"]) == 0
    assert "legacy" in capsys.readouterr().out.lower()
    assert main(["info", "--protocol", "framed"]) == 2             # given: still refused
    assert "contradicts protocol=legacy" in capsys.readouterr().err
