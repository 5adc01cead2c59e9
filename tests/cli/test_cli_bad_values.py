"""Bad option values that used to end in a library's message or a numpy warning: one line
naming the value and what to give, exit code 2 (issue 13, smaller kinds)."""

from __future__ import annotations

import warnings

import pytest

from snan_hil.tools import cli


@pytest.fixture(autouse=True)
def emu_state(tmp_path, monkeypatch):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))


@pytest.mark.parametrize("url,needle", [
    ("socket://127.0.0.1:99999", "port 99999 is outside 1..65535"),
    ("socket://127.0.0.1:0", "port 0 is outside 1..65535"),
    ("socket://127.0.0.1:-5", "not a number"),
    ("socket://localhost", "no port in the URL"),
    ("socket://:5000", "no host in the URL"),
    ("socket://host:50x0", "'50x0' is not a number"),
    ("rfc2217://127.0.0.1:70000", "port 70000 is outside 1..65535"),
    ("socket://[::1]:123456", "port 123456 is outside"),
])
@pytest.mark.parametrize("command", [["info"], ["ping"], ["map"]])
def test_bad_network_urls(capsys, url, needle, command):
    assert cli.main([*command, "--port", url]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err and f"--port {url}" in err
    assert "debug|info" not in err and "NoneType" not in err


@pytest.mark.parametrize("code,needle", [
    ("-1", "--read-code -1: a read needs a DAC code of at least 1"),
    ("0", "--read-code 0: a read needs a DAC code of at least 1"),
    ("246", "--read-code 246 is above the board's read limit 245 (0.299 V"),
    ("70000", "--read-code 70000 is above the board's read limit"),
])
def test_map_read_code_out_of_range(tmp_path, capsys, code, needle):
    with warnings.catch_warnings():
        warnings.simplefilter("error")                  # no numpy warning on the way
        assert cli.main(["map", "--port", "emu", "--read-code", code]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err and "wire format" not in err


def test_map_lowest_read_code_works_without_warnings(capsys):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert cli.main(["map", "--port", "emu", "--read-code", "1"]) == 0
    assert "readable cells" in capsys.readouterr().out


@pytest.mark.parametrize("option,value,needle", [
    ("--timeout", "1e308", "--timeout (seconds): must be <= 3600.0, got 1e+308"),
    ("--timeout", "inf", "--timeout (seconds): expected a finite number, got inf"),
    ("--timeout", "0", "--timeout (seconds): must be > 0.0, got 0.0"),
    ("--stall-budget", "1e9", "--stall-budget (seconds): must be <= 86400.0, got 1000000000.0"),
    ("--wait", "-1", "--wait (seconds): must be >= 0.0, got -1.0"),
])
def test_link_time_options_outside_their_bounds_are_one_line_before_any_io(
        tmp_path, capsys, option, value, needle):
    assert cli.main(["info", "--port", "emu", option, value]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.rstrip().endswith(needle)
    assert not (tmp_path / "chip.npz").exists()             # the board was never opened


def test_link_time_bounds_are_the_documented_ones_and_a_bound_is_accepted(capsys):
    from snan_hil.config import loader as configio
    from snan_hil.protocol.link import MAX_TIMEOUT_S, LinkTimes
    assert configio._bounds(configio.field_type(LinkTimes, "timeout_s")) == [
        ("gt", 0), ("le", MAX_TIMEOUT_S)]
    parser = cli.build_parser()
    with pytest.raises(SystemExit):
        parser.parse_args(["info", "--help"])
    assert f"at most {MAX_TIMEOUT_S:g}" in " ".join(capsys.readouterr().out.split())
    assert cli.main(["info", "--port", "emu", "--timeout", f"{MAX_TIMEOUT_S:g}"]) == 0
