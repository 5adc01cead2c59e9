"""The chip keeps its conductances across emulator restarts (state file), in-process and CLI."""

import csv
import os
import re
import signal
import subprocess
import sys

from pathlib import Path

import numpy as np
import pytest

from snan_hil.crossbar_model import CrossbarArray
from snan_hil.firmware_emu import state
from snan_hil.firmware_emu.emulator import Emulator
from snan_hil.firmware_emu.inprocess import emulator_of
from snan_hil.common.errors import UserError
from snan_hil.tools import cli
from snan_hil.tools.ports import open_client
from snan_hil.common.polarity import Polarity


@pytest.fixture
def chip_env(tmp_path, monkeypatch):
    """Point the in-process emulator's default state file into tmp (never the user's home)."""
    path = tmp_path / "emu-chip.npz"
    monkeypatch.setenv(state.STATE_ENV, str(path))
    return path


def test_default_state_path_honours_env(chip_env, monkeypatch):
    assert state.default_state_path() == chip_env
    monkeypatch.delenv(state.STATE_ENV)
    monkeypatch.setenv("XDG_DATA_HOME", str(chip_env.parent / "xdg"))
    assert state.default_state_path() == chip_env.parent / "xdg" / "snan-hil" / "emu-chip.npz"


def test_state_survives_emulator_restart(tmp_path):
    path = tmp_path / "chip.npz"
    emu = Emulator(path, seed=3, save_interval_s=3600)
    for col in range(4):
        emu.firmware.write_pulse(col, col, Polarity.SET, 1000, 500)
        emu.dispatcher.on_state_change()
    g_written = emu.array.conductance()
    journal = path.with_name(path.name + ".journal")
    assert path.exists() and journal.stat().st_size > 0   # snapshot + the writes' journal
    emu.close()
    assert path.exists()
    again = Emulator(path, seed=99)          # the seed does not matter for an existing chip
    assert np.array_equal(again.array.conductance(), g_written)
    fresh = Emulator(tmp_path / "other.npz", seed=3)
    assert not np.array_equal(fresh.array.conductance(), g_written)


def test_inprocess_port_emu_keeps_the_chip_between_commands(chip_env, mcu):
    client = open_client("emu", mcu=mcu)
    try:
        before = client.read_cell(6, 1)
        after = client.write_pulse(6, 1, Polarity.SET, 1000, 1000)
        assert after > before + 20
    finally:
        client.close()                       # saves the chip
    assert chip_env.exists()
    client = open_client("emu", mcu=mcu)     # a second "command"
    try:
        assert abs(client.read_cell(6, 1) - after) < 0.05 * after
    finally:
        client.close()
    client = open_client("emu", mcu=mcu)
    try:
        assert emulator_of(client.transport).state_file == chip_env
    finally:
        client.close()


def test_reset_chip_recreates_the_state_file(chip_env, capsys):
    emu = Emulator(chip_env, seed=0)
    emu.array.set_conductance(0, 0, 1e-3)
    emu._mark_dirty()
    emu.close()
    assert CrossbarArray.load(str(chip_env)).conductance()[0, 0] == pytest.approx(1e-3)
    assert cli.main(["emu", "--reset-chip"]) == 0
    assert "replaced" in capsys.readouterr().out
    reset = CrossbarArray.load(str(chip_env)).conductance()
    assert np.array_equal(reset, CrossbarArray.from_yaml(None, seed=0).conductance())


def test_corrupt_state_file_is_one_line_user_error(chip_env, capsys):
    chip_env.write_bytes(b"not an npz")
    assert cli.main(["map", "--port", "emu"]) == 2
    err = capsys.readouterr().err
    assert "chip" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("content", [b"", b"PK\x03\x04 truncated zip", b"not an npz"])
def test_emu_command_refuses_a_corrupt_state_file_and_keeps_it(tmp_path, capsys, content):
    path = tmp_path / "chip.npz"
    path.write_bytes(content)
    assert cli.main(["emu", "--state", str(path)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and str(path) in err
    # not recognisably a chip: the hint names another, free file, never this one
    assert "--reset-chip" not in err and str(tmp_path / "chip-2.npz") in err, err
    assert path.read_bytes() == content                # nothing was overwritten


def test_a_foreign_npz_as_state_is_never_suggested_for_overwriting(tmp_path, capsys):
    """Finding 8: `emu --state w.npz` (a weights file) must not suggest `--reset-chip --state
    w.npz`; the suggested path is free and works."""
    weights = tmp_path / "w.npz"
    np.savez(weights, w=np.zeros((3, 3)))
    before = weights.read_bytes()
    for protocol in ("framed", "legacy"):
        assert cli.main(["emu", "--protocol", protocol, "--state", str(weights)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "--reset-chip" not in err, err
        other = err.split("--state ")[-1].split()[0].rstrip(";)")
        assert other != str(weights) and not Path(other).exists()
    assert weights.read_bytes() == before
    assert cli.main(["emu", "--reset-chip", "--state", other]) == 0      # the hint works
    assert Path(other).is_file()


def test_a_damaged_chip_of_ours_is_offered_a_reset(tmp_path, capsys):
    path = tmp_path / "mine.npz"
    assert cli.main(["emu", "--reset-chip", "--state", str(path)]) == 0
    with np.load(path, allow_pickle=False) as d:
        data = {k: d[k] for k in d.files}
    data["state"] = np.full_like(data["state"], np.nan)
    np.savez(path, **data)
    capsys.readouterr()
    assert cli.main(["emu", "--state", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert f"--reset-chip --state {path}" in err and "NaN" in err, err
    assert cli.main(["emu", "--reset-chip", "--state", str(path)]) == 0


def test_map_command_reads_the_chip(chip_env, tmp_path, mcu):
    csv_path = tmp_path / "map.csv"
    assert cli.main(["map", "--port", "emu", "--mcu", mcu, "--csv", str(csv_path)]) == 0
    chip = CrossbarArray.load(str(chip_env))
    r_true = 1.0 / chip.effective_conductance(0.0)       # memristor + select transistor
    with open(csv_path) as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 32 * 8
    r_map = np.zeros((32, 8))
    for row in rows:
        r_map[int(row["row"]), int(row["col"])] = float(row["resistance_ohm"])
    ok = ~chip.stuck_mask
    assert np.allclose(r_map[ok], r_true[ok], rtol=0.05)


@pytest.mark.parametrize("stop_signal", [signal.SIGINT, signal.SIGTERM])
def test_cli_emu_serves_a_pty_and_saves_on_ctrl_c(tmp_path, stop_signal, mcu):
    path = tmp_path / "served.npz"
    env = dict(os.environ, SNAN_HIL_EMU_STATE=str(tmp_path / "unused.npz"))
    proc = subprocess.Popen([sys.executable, "-m", "snan_hil.tools.cli", "emu", "--state",
                             str(path), "--seed", "5", "--mcu", mcu], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env,
                            # Ctrl-C at a terminal: SIGINT as Python handles it, even when this
                            # run is a background job (whose children start ignoring SIGINT)
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        line = proc.stdout.readline()
        match = re.search(r"serving on (\S+)", line)
        assert match, line
        client = open_client(match.group(1), 115200, "framed", timeout=2.0)
        try:
            client.write_pulse(2, 3, Polarity.SET, 1000, 1000)
            g_served = client.read_cell(2, 3)
        finally:
            client.close()
    finally:
        proc.send_signal(stop_signal)
        out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert "client opened" in err and "Traceback" not in err
    assert "stopped after 1 connection(s)" in out
    assert path.exists() and not (tmp_path / "unused.npz").exists()
    chip = CrossbarArray.load(str(path))
    fresh = CrossbarArray.from_yaml(None, seed=5)
    assert chip.conductance()[2, 3] > fresh.conductance()[2, 3]
    assert g_served > 0


@pytest.mark.parametrize("command", ["emu", "map", "info"])
def test_help_shows_the_default_chip_file_and_how_to_reset_it(chip_env, capsys, command):
    with pytest.raises(SystemExit) as exc:
        cli.main([command, "--help"])
    assert exc.value.code == 0
    out = " ".join(capsys.readouterr().out.split())      # undo argparse's line wrapping
    assert "--reset-chip" in out
    assert str(chip_env).replace(" ", "") in out.replace(" ", "")


def test_a_chip_file_is_owned_by_one_process_at_a_time(tmp_path, capsys):
    path = tmp_path / "chip.npz"
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys; from snan_hil.firmware_emu import state; "
         f"state.acquire({str(path)!r}); print('held', flush=True); sys.stdin.read()"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(UserError, match="in use by another emulator"):
            Emulator(path, seed=0)
        for argv in (["emu", "--state", str(path)], ["emu", "--reset-chip", "--state", str(path)]):
            assert cli.main(argv) == 2
            err = capsys.readouterr().err
            assert str(holder.pid) in err and len(err.strip().splitlines()) == 1
        assert not path.exists()
    finally:
        holder.communicate("", timeout=20)
    first = Emulator(path, seed=0)            # the other process is gone: free again
    second = Emulator(path, seed=0)           # emulators in one process share the file
    first.close()
    second.close()
    Emulator(path, seed=0).close()


def test_a_directory_as_state_file_is_refused_without_side_effects(tmp_path):
    folder = tmp_path / "chips"
    folder.mkdir()
    with pytest.raises(UserError, match="directory"):
        Emulator(folder, seed=0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["chips"]
