"""docs/notebook.md is a working session: its Python blocks run, in order, against the
emulator in a fresh folder, and what they leave behind is what the page says."""

from __future__ import annotations

import contextlib
import io
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "notebook.md"


def blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", PAGE.read_text(encoding="utf-8"), flags=re.S)


def test_the_notebook_page_runs_as_written(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "default.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    code = blocks()
    assert len(code) >= 5
    namespace: dict[str, object] = {}
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        for block in code:
            exec(compile(block, str(PAGE), "exec"), namespace)
    text = out.getvalue()
    assert "EMU-4D430001/" in text and "synapses inside their window" in text
    prog, run = namespace["prog"], namespace["run"]
    assert prog.all_ok and prog.synapses == 120 and prog.final_s.shape == (120,)
    assert run.path_length_steps.shape == (3,) and run.board_us_per_decision > 0
    shot = namespace["shot"]
    assert shot.conductance_after_s > shot.conductance_before_s       # a SET pulse
    # the chip and its files beside it, as the page says; the default chip untouched
    assert sorted(p.name for p in tmp_path.glob("chip*")) == [
        "chip.history.sqlite", "chip.layout.json", "chip.npz", "chip.npz.journal",
        "chip.program-report.json"]
    report = json.loads((tmp_path / "chip.program-report.json").read_text())
    assert report["session"]["identity"]["board_id"] == namespace["record"]["identity"][
        "board_id"]
    assert not (tmp_path / "default.npz").exists()
    # everything the page did to the chip is in its history, as the command line's runs are
    # (issue 32): the runs and every pulse, seen by `snan-hil history`
    shown = subprocess.run([sys.executable, "-m", "snan_hil.tools.cli", "history", "--port",
                            f"emu://?state={tmp_path / 'chip.npz'}", "--json"],
                           capture_output=True, text=True, cwd=tmp_path,
                           env={**__import__("os").environ, "XDG_DATA_HOME": str(tmp_path)})
    assert shown.returncode == 0, shown.stderr
    runs = json.loads(shown.stdout)["runs"]
    kinds = sorted(r["kind"] for r in runs)
    assert "pulse" in kinds and "program" in kinds, kinds
    assert all(r["status"] == "complete" for r in runs)
    assert sum(r["pulses"] for r in runs) >= prog.pulses + 1    # programming + the pulse


def test_importing_the_package_stays_cheap():
    """``snan_hil.open_board`` is imported on first use: ``import snan_hil`` loads no
    sub-package (no numpy, no emulator)."""
    done = subprocess.run([sys.executable, "-c", "import sys, snan_hil; print(sorted(m for m in "
                           "sys.modules if m.startswith('snan_hil.') or m == 'numpy'))"],
                          capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]"


@pytest.mark.parametrize("name", ["open_board"])
def test_open_board_is_reached_from_the_package_root(name):
    import snan_hil
    from snan_hil.lab import notebook
    assert getattr(snan_hil, name) is getattr(notebook, name)


def test_reads_and_maps_from_a_notebook_are_recorded_as_the_commands_record_them(tmp_path):
    # found by a new user: read_cell and map were the notebook's only unrecorded board work
    import snan_hil
    from snan_hil.records.history import History
    with snan_hil.open_board(f"emu://?state={tmp_path / 'c.npz'}", progress=False) as board:
        reading = board.read_cell(3, 5)
        cmap = board.map()
        history = board.session.files.history
    assert reading.conductance_s > 0 and cmap.conductance_s.shape == (32, 8)
    with History.open(history, create=False) as db:
        kinds = sorted(r.kind for r in db.runs())
    assert kinds == ["map", "read"]
