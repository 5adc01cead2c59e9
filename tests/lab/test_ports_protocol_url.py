"""An ``emu://`` URL speaks the protocol ``--protocol`` names: a URL without ``protocol=`` gets
it, a URL naming another protocol is refused (one line, exit 2)."""

from __future__ import annotations

import pytest

from snan_hil.common.errors import UserError
from snan_hil.tools.cli import main
from snan_hil.lab.ports import port_url


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
