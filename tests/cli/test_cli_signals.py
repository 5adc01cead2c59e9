"""Signals at awkward moments (issue 38 item 8): Ctrl-C while the command is still starting
(importing) is one line, no traceback; SIGTERM that lands while Python runs an object's
finalizer (numba and llvmlite free compiler objects in ``__del__`` while kernels compile) still
stops the command instead of being printed and dropped."""

from __future__ import annotations

import subprocess
import sys

_FINALIZER = """
import os, signal, sys, time
from snan_hil.tools import cli
restore = cli._terminate_like_ctrl_c()
sent = []

class Compiled:                       # stands for a compiler object freed while compiling
    def __del__(self):
        if not sent:
            sent.append(1)
            os.kill(os.getpid(), signal.SIGTERM)   # its handler runs here, inside __del__
        sum(range(50))

try:
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        Compiled()
        sum(range(500))               # the compiler's own work between two frees
    print("went on")
except KeyboardInterrupt as exc:
    print("stopped", type(exc).__name__, getattr(exc, "signum", None))
"""


def test_sigterm_inside_a_finalizer_still_stops_the_command():
    proc = subprocess.run([sys.executable, "-c", _FINALIZER], capture_output=True, text=True,
                          timeout=60)
    assert proc.stdout.strip() == "stopped Terminated 15", (proc.stdout, proc.stderr)
    assert "Exception ignored" not in proc.stderr and "Traceback" not in proc.stderr


_STARTING = """
import importlib.abc, os, signal, sys
from snan_hil.tools import cli

class CtrlC(importlib.abc.MetaPathFinder):   # Ctrl-C while a command module is imported
    def find_spec(self, name, path, target=None):
        if name == "snan_hil.tools.commands.read_cell":
            sys.meta_path.remove(self)
            os.kill(os.getpid(), signal.SIGINT)
        return None

sys.meta_path.insert(0, CtrlC())
sys.exit(cli.main(["read-cell", "--help"]))
"""


def test_ctrl_c_while_the_command_starts_is_one_line():
    proc = subprocess.run([sys.executable, "-c", _STARTING], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 130, proc.stderr
    assert proc.stderr == "snan-hil: interrupted while starting; nothing was done\n"
