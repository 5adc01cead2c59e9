"""Where snan-hil keeps its files for a user: one helper, on top of ``platformdirs``.

A base module like :mod:`snan_hil.common.errors`: every layer may import it. On Linux the folder is
``$XDG_DATA_HOME/snan-hil`` (default ``~/.local/share/snan-hil``); other systems get their
platform's user-data folder. The emulated chip (``emu-chip.npz``) and the layouts of real
boards (``layouts/``) live there unless an option or ``$SNAN_HIL_EMU_STATE`` says otherwise.
"""

from __future__ import annotations

from pathlib import Path

import platformdirs

__all__ = ["APP_NAME", "user_data_dir"]

APP_NAME = "snan-hil"


def user_data_dir() -> Path:
    """The user's snan-hil data folder (not created here)."""
    return platformdirs.user_data_path(APP_NAME, appauthor=False)
