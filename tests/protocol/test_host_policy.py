"""Host policy against board behaviour: the host's limits (reads <= 0.3 V, writes <=
--max-write-v) hold on both protocols before anything is sent; the framed firmware's interlock
stays; the existing firmware (legacy) applies what the host lets out."""

import pytest

from snan_hil.firmware_emu.inprocess import emulator_of
from snan_hil.common.polarity import Polarity
from snan_hil.protocol.board import MEMRICORE
from snan_hil.protocol.safety import HostSafetyError
from snan_hil.tools import cli
from snan_hil.tools.ports import open_client


@pytest.fixture
def chip_env(tmp_path, monkeypatch):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    return tmp_path


@pytest.mark.parametrize("protocol", ["framed", "legacy"])
def test_the_host_refuses_writes_above_its_limit_before_sending(chip_env, protocol):
    client = open_client("emu", protocol=protocol)
    try:
        emu = emulator_of(client.transport)
        assert client.limits.max_write_code == MEMRICORE.max_write_code == 1146
        with pytest.raises(HostSafetyError, match=r"1\.4 V.*--max-write-v.*not sent"):
            client.write_pulse(0, 0, Polarity.RESET, 1147, 100)
        with pytest.raises(HostSafetyError, match=r"read limit 0\.3 V.*not sent"):
            client.read_cell(0, 0, 246)
        assert emu.board.front_end.pulses_applied == 0
    finally:
        client.close()


@pytest.mark.parametrize("protocol", ["framed", "legacy"])
def test_the_host_limit_lowers_the_boards_and_never_raises_it(chip_env, protocol):
    """One rule on both protocols (issue 32): --max-write-v lowers the board's declared
    write limit; above it, it is refused before anything is sent (the legacy firmware has no
    interlock of its own, so this is the only guard there)."""
    raised = open_client("emu", protocol=protocol, max_write_v=1.7,
                         state_file=str(chip_env / f"{protocol}-r.npz"))
    try:
        with pytest.raises(HostSafetyError, match=r"--max-write-v 1\.7: above the board's "
                                                  r"declared write limit 1\.4 V"):
            raised.write_pulse(0, 0, Polarity.RESET, 1300, 100)
        assert emulator_of(raised.transport).board.front_end.pulses_applied == 0
    finally:
        raised.close()
    lowered = open_client("emu", protocol=protocol, max_write_v=1.0,
                          state_file=str(chip_env / f"{protocol}-l.npz"))
    try:
        assert lowered.limits.max_write_v == 1.0
        top = lowered.limits.max_write_code
        lowered.write_pulse(0, 0, Polarity.RESET, top, 100)          # at the limit: sent
        with pytest.raises(HostSafetyError, match=r"1 V"):
            lowered.write_pulse(0, 0, Polarity.RESET, top + 1, 100)   # above: not sent
        assert emulator_of(lowered.transport).board.front_end.pulses_applied == 1
    finally:
        lowered.close()


@pytest.mark.parametrize("value", ["9", "0", "-1", "nan"])
def test_a_bad_write_limit_is_one_line_naming_the_option(chip_env, capsys, value):
    assert cli.main(["info", "--port", "emu", "--max-write-v", value]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--max-write-v" in err


def test_programming_is_checked_against_the_host_limit_first(chip_env, capsys, tmp_path):
    from snan_hil.host.hil.testing import make_weights, small_hil_config
    w = make_weights(tmp_path / "w.npz", sets=1, cycles=1, hil=small_hil_config())
    assert cli.main(["program-weights", str(w), "--port", "emu", "--protocol", "legacy",
                     "--v-max", "1.4", "--max-write-v", "1.0"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--max-write-v" in err and "--v-max" in err
    assert not (tmp_path / "chip.layout.json").exists()            # refused before any work
    assert not (tmp_path / "chip.program-report.json").exists()


def test_info_over_legacy_marks_host_defaults_and_policy_not_as_board_facts(chip_env, capsys):
    """Finding 9: the existing firmware reports no write limit, compliance or read voltage;
    `info --protocol legacy` names where each such value comes from."""
    import json
    assert cli.main(["info", "--port", "emu", "--protocol", "legacy", "--max-write-v", "1.2",
                     "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    src = data["info_sources"]
    assert set(src) >= {"max_write_v", "compliance_a", "v_read_v", "board_id"}
    assert src["board_id"].startswith("board") and src["rows"].startswith("board")
    for name in ("max_write_v", "max_read_v", "v_read_v", "read_code"):
        assert src[name].startswith("host policy"), (name, src[name])
    for name in ("compliance_a", "r_load_ohm", "gain"):
        assert src[name].startswith("assumed"), (name, src[name])
    limits = data["host_limits"]
    assert limits["max_write_v"] == 1.2 and limits["max_write_code"] < 1146
    assert cli.main(["info", "--port", "emu", "--protocol", "legacy"]) == 0
    text = capsys.readouterr().out
    assert "host policy" in text and "assumed" in text
    # the framed board reports these itself: no source column
    assert cli.main(["info", "--port", "emu", "--json"]) == 0
    assert "info_sources" not in json.loads(capsys.readouterr().out)


def test_the_existing_firmwares_mode_100_text_carries_only_id_and_version():
    from snan_hil.protocol.legacy_codec import info_sources, reported_info_fields
    theirs = reported_info_fields(b"MemriCore v2 build 7\n")
    assert theirs == ("board_id", "firmware_version")
    src = info_sources(theirs)
    assert src["rows"].startswith("assumed") and src["firmware_version"].startswith("board")
    ours = reported_info_fields(b"EMU-4D430001/AB,memricore-emu-legacy 1.0.0,32,8,12,14\n")
    assert "rows" in ours and "max_write_v" not in ours
