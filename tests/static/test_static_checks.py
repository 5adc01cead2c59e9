"""Static checks of the whole package, part of ``make test`` (so CI fails when they fail):

* ruff (pycodestyle, pyflakes, bugbear, mccabe complexity <= 15; settings in pyproject.toml),
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

ROOT = Path(__file__).resolve().parents[2]
PYPROJECT = ROOT / "pyproject.toml"


def _run(argv: list[str], **kwargs: Any) -> subprocess.CompletedProcess[str]:
    return subprocess.run(argv, capture_output=True, text=True, check=False, timeout=600,
                          **kwargs)


def test_ruff_is_clean():
    proc = _run([sys.executable, "-m", "ruff", "check", "--no-cache", "--config",
                 str(PYPROJECT), str(ROOT)])
    assert proc.returncode == 0, proc.stdout + proc.stderr


@pytest.mark.timeout(300)     # a cold whole-project check beside another test worker
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


STRICT_PACKAGES = ("calibration", "board", "lab")
"""Packages whose public signatures name array element types: mypy's ``disallow_any_generics``
(pyproject.toml) catches a bare ``dict``, but numpy's ``ndarray`` has default type parameters,
so a bare ``np.ndarray`` is looked for here."""


def test_public_signatures_name_their_array_types():
    import ast
    found = []
    for package in STRICT_PACKAGES:
        for path in sorted((ROOT / package).glob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            for node in ast.walk(tree):
                if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    continue
                notes = [a.annotation for a in (*node.args.args, *node.args.kwonlyargs,
                                                 *node.args.posonlyargs) if a.annotation]
                notes += [node.returns] if node.returns is not None else []
                for note in notes:
                    text = ast.unparse(note)
                    if "ndarray" in text:
                        found.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name}: {text}")
    assert not found, "use numpy.typing.NDArray[<dtype>]:\n" + "\n".join(found)


LONG_JOBS = ("calibration/programmer.py", "calibration/program_report.py", "host/hil/compare.py",
             "host/hil/compare_results.py", "board", "lab")
"""The two long jobs (programming, the comparison) and the session layers: cut along their
plan / execute / record seams, no function above complexity 15 (issue 21, point 3; the
whole tree has the same limit in pyproject.toml, point 7, with the numba kernels and their
reference exempted)."""


def test_the_long_jobs_keep_a_complexity_limit():
    proc = _run([sys.executable, "-m", "ruff", "check", "--no-cache", "--select", "C901",
                 "--config", "lint.mccabe.max-complexity = 15", *LONG_JOBS], cwd=ROOT)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_the_version_is_defined_once_in_a_base_module():
    """``__version__`` is assigned in common/version.py only; pyproject.toml reads it there, the
    package root re-exports it, and no module of the package imports it from the root."""
    import ast
    import importlib.metadata
    import tomllib

    import snan_hil
    from snan_hil.common import version
    assigned, from_root = [], []
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT)
        if rel.parts[0] in ("tests", "bench", "build", "docs") or rel.parts[0].startswith("."):
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Assign) and any(
                    isinstance(t, ast.Name) and t.id == "__version__" for t in node.targets):
                assigned.append(str(rel))
            if isinstance(node, ast.ImportFrom) and node.module == "snan_hil" and any(
                    a.name == "__version__" for a in node.names):
                from_root.append(str(rel))
    assert assigned == ["common/version.py"]
    assert from_root == [], "import it from snan_hil.common.version"
    project = tomllib.loads(PYPROJECT.read_text())
    assert "version" in project["project"]["dynamic"]
    assert project["tool"]["setuptools"]["dynamic"]["version"] == {
        "attr": "snan_hil.common.version.__version__"}
    assert snan_hil.__version__ == version.__version__ == importlib.metadata.version("snan-hil")
