"""``snan-hil version``: package and dependency versions (for bug reports)."""

from __future__ import annotations

import argparse
import platform
from importlib import metadata

from snan_hil.common.version import __version__

NAME = "version"
HELP = "print the versions of snan-hil, Python and the main dependencies"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    del parser


def run(args: argparse.Namespace) -> int:
    del args
    print(f"snan-hil {__version__}")
    print(f"python {platform.python_version()}")
    for dist in ("numpy", "numba", "pyserial", "crcmod", "rich", "ruamel.yaml", "pydantic"):
        try:
            print(f"{dist} {metadata.version(dist)}")
        except metadata.PackageNotFoundError:
            print(f"{dist} (not installed)")
    return 0
