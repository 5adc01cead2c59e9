"""``snan-hil`` run as a child process of this environment (the docs' fixed-seed runs,
:mod:`snan_hil.tools.doc_tables`, and the equivalence study, :mod:`snan_hil.tools.
equivalence_study`): its stdout, a RuntimeError naming the command on a failure."""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

__all__ = ["run_cli"]


def run_cli(args: Sequence[str], env: Mapping[str, str] | None = None) -> str:
    """Run ``snan-hil ARGS`` (this environment's); stdout. RuntimeError on a failure."""
    full = {**os.environ, "SNAN_HIL_PROGRESS_INTERVAL_S": "600", **(env or {})}
    exe = str(Path(sys.executable).with_name("snan-hil"))
    p = subprocess.run([exe, *args], capture_output=True, text=True, env=full)
    if p.returncode != 0:
        raise RuntimeError(f"snan-hil {shlex.join(args)} failed (exit {p.returncode}): "
                           f"{p.stderr.strip()[-2000:]}")
    return p.stdout
