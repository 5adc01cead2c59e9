"""Static checks of the whole package, part of ``make test`` (so CI fails when they fail):

* ruff (pycodestyle, pyflakes, bugbear; settings in pyproject.toml),
* mypy over every sub-package of ``snan_hil`` (settings in pyproject.toml),
* import-linter: the layering contract (tools > host > calibration | firmware_emu >
  protocol | crossbar_model; host never imports the emulator; base modules import no layer),
  explained in docs/architecture.md.

The checks run as subprocesses of this interpreter's environment; each names what it found.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = ROOT / "pyproject.toml"


def _run(argv: list[str], **kwargs: Any) -> subprocess.CompletedProcess[str]:
    return subprocess.run(argv, capture_output=True, text=True, check=False, timeout=600,
                          **kwargs)


def test_ruff_is_clean():
    proc = _run([sys.executable, "-m", "ruff", "check", "--no-cache", "--config",
                 str(PYPROJECT), str(ROOT)])
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_mypy_is_clean(tmp_path):
    # The package is the repository root (package-dir "snan_hil" = "."), which mypy cannot
    # find through the editable install's import hook: give it a folder holding a link named
    # snan_hil to the root, and name the sub-packages and top-level modules explicitly (the
    # root also holds tests/, bench/ and docs/, which are not part of the package).
    (tmp_path / "snan_hil").symlink_to(ROOT, target_is_directory=True)
    targets: list[str] = ["-m", "snan_hil"]
    for entry in sorted(ROOT.iterdir()):
        if entry.is_dir() and (entry / "__init__.py").is_file():
            targets += ["-p", f"snan_hil.{entry.name}"]
        elif entry.suffix == ".py" and entry.name != "__init__.py":
            targets += ["-m", f"snan_hil.{entry.stem}"]
    env = dict(os.environ, MYPYPATH=str(tmp_path))
    proc = _run([sys.executable, "-m", "mypy", "--config-file", str(PYPROJECT), "--cache-dir",
                 str(tmp_path / ".mypy_cache"), *targets], cwd=tmp_path, env=env)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "Success" in proc.stdout


def test_layering_contract_is_kept():
    lint_imports = Path(sys.executable).with_name("lint-imports")
    if not lint_imports.exists():
        pytest.fail(f"{lint_imports} not found: install the test extra (pip install -e .[test])")
    proc = _run([str(lint_imports), "--config", str(PYPROJECT), "--no-cache"], cwd=ROOT)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "0 broken" in proc.stdout
