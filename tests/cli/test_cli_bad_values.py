"""Bad option values that used to end in a library's message or a numpy warning: one line
naming the value and what to give, exit code 2 (issue 13, smaller kinds); bad input is refused
before any work, and a bench command's before the board is opened (the chip, its history and
the folder left as they were)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from snan_hil.calibration.testing import grid_weights
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


def _files(folder) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("argv,needle", [
    (["pulse", "--cell", "3,5", "--polarity", "set", "--amplitude", "0.5",
      "--max-write-v", "0.4"], "0.4 V (the board's, lowered by --max-write-v)"),
    (["pulse", "--protocol", "legacy", "--cell", "3,5", "--polarity", "set",
      "--amplitude", "1.6"], "--max-write-v can only lower it"),
    (["retention", "--protocol", "legacy"], "--path cell"),
    (["cells", "test", "--cells", "0,0", "--v-max", "1.0", "--max-write-v", "0.5"],
     "--max-write-v"),
    (["program-weights", "w.npy", "--v-max", "1.0", "--max-write-v", "0.8"],
     "(--max-write-v)"),
])
def test_refusals_leave_chip_and_history_alone(programmed_emu, one_line, capsys, monkeypatch, argv,
                                               needle):
    monkeypatch.chdir(programmed_emu)
    before = _files(programmed_emu)
    assert cli.main([argv[0], *(["test"] if argv[0] == "cells" else []), "--port", "emu",
                     *argv[2 if argv[0] == "cells" else 1:]]) == 2
    assert needle in one_line()
    assert _files(programmed_emu) == before            # no chip state, no history row


@pytest.mark.parametrize("argv,needle", [
    (["mac", "--port", "emu", "--v-max", "0.0001"], "below one DAC step (1.22 mV)"),
    (["program-weights", "w.npy", "--port", "emu", "--trace", "trace.jpg"], "ending in .png"),
    (["pulse", "--port", "emu", "--cell", "3,3", "--polarity", "set", "--amplitude", "0.5",
      "--png", "x.pdf"], "ending in .png"),
    (["sim", "--grid", "3", "--trials", "2", "--plot", "x.svg"], "ending in .png"),
    (["sim", "--grid", "3", "--trials", "2", "--animate-trial", "1"], "give --animate"),
    (["cells", "test", "--port", "emu", "--cells", "-1,0"], "outside the 32x8 array"),
    (["pulse", "--port", "emu", "--cell", "-1,0", "--polarity", "set", "--amplitude", "0.5"],
     "outside the 32x8 array"),
    (["cells", "test", "--port", "emu", "--cells", "0,0", "--v-max", "0.1"], "--v-max 0.1"),
    (["cells", "test", "--port", "emu", "--cells", "0,0", "--max-probe-pulses", "0"],
     "--max-probe-pulses 0"),
])
def test_bad_options_one_line_nothing_written(emu, one_line, capsys, monkeypatch, argv, needle):
    monkeypatch.chdir(emu)
    np.save(emu / "w.npy", grid_weights(3, 3, seed=4))
    before = _files(emu)
    assert cli.main(argv) == 2
    assert needle in one_line()
    assert _files(emu) == before


@pytest.mark.parametrize("argv, needle", [
    (["learn", "--port", "emu", "--arms", "software,software", "--out", "L"],
     "names an arm twice"),
    (["history", "--port", "emu", "--export", "runs", "--kind", "learn"],
     "--kind filters the list of runs"),
    (["plan", "run", "parking", "--cells", "3,5", "--baud", "-5", "--dry-run"],
     "--baud must be positive"),
    (["learn", "--port", "emu", "--arms", "device", "--model", "notes.txt", "--out", "L"],
     "not JSON"),
    # a seed past SQLite's INTEGER pulsed the chip, then failed to be recorded (traceback)
    (["learn", "--port", "emu", "--arms", "chip", "--seed", str(2**70), "--out", "L"],
     "at most 9223372036854775807"),
    (["demo", "--software-only", "--seed", str(2**64), "--out", "L"],
     "at most 9223372036854775807"),
    # without a terminal (pytest's stdin is none) watch said nothing useful, then hung
    (["watch", "--port", "emu", "--run", "1"], "give --screenshot FILE.svg"),
])
def test_one_line_exit_2(emu, one_line, monkeypatch, argv, needle):
    monkeypatch.chdir(emu)
    (emu / "notes.txt").write_text("hello\n")
    assert cli.main(argv) == 2
    assert needle in one_line()
    assert not (emu / "L").exists()


@pytest.mark.parametrize("argv", [["sim", "--grid", "3", "--trials", "10"],
                                  ["mac", "--vectors", "2", "--out", "macout"],
                                  ["demo", "--out", "d9", "--software-only", "--trials", "10"],
                                  ["experiment", "fig3", "--trials", "5", "--out", "e9"],
                                  ["train", "-o", "w.npz"]])
def test_a_negative_seed_is_one_line_and_creates_nothing(argv, tmp_path, monkeypatch, capsys):
    # found by a new user: --seed -1 was a numpy traceback (exit 1) and left a checkpoint that
    # refused the corrected command; --seed above 2**63 - 1 was already one line
    monkeypatch.chdir(tmp_path)
    for seed in ("-1", str(2**63)):
        assert cli.main([*argv, "--seed", seed]) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and "--seed" in err and seed in err, err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("extra, words", [(["--conversions", "11"], "--conversions 11: give 0"),
                                          (["--conversions", "-1"], "--conversions -1: give 0"),
                                          (["--conversions", "2", "--protocol", "legacy"],
                                           "legacy line protocol has no such window"),
                                          (["--conversions", "2", "--mode", "batch"],
                                           "--mode batch reads the synapses from the host")])
@pytest.mark.parametrize("command", [["compare", "--weights", "w.npz", "--out", "cmp"],
                                     ["run", "--scenario", "hw_astro", "--weights", "w.npz"],
                                     ["learn", "--out", "lrn"]])
def test_conversions_are_checked_before_any_board_or_file(command, extra, words, tmp_path,
                                                          monkeypatch, capsys):
    # found by a new user: compare programmed the chip (69 pulses) before refusing
    # --conversions 11, and over legacy or --mode batch any N was taken and ignored
    monkeypatch.chdir(tmp_path)
    assert cli.main([*command, "--port", f"emu://?state={tmp_path / 'c.npz'}", *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and "\n" not in err, err
    assert list(tmp_path.iterdir()) == []                   # no chip, no folder, no pulse
