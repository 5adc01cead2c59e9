"""The emulated chip's state file: where it lives, loading it, saving it.

The in-process emulator (``--port emu``) keeps its crossbar in a default state file so that
separate commands (``program-weights`` then ``run``) act on the same chip, as they would on a
real board. The file is the crossbar model's own npz format (no pickle).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

from snan_hil.errors import UserError

log = logging.getLogger(__name__)

STATE_ENV = "SNAN_HIL_EMU_STATE"
"""Environment variable that overrides the default state file of the in-process emulator."""


def default_state_path() -> Path:
    """``$SNAN_HIL_EMU_STATE`` if set, else :func:`user_state_path`."""
    env = os.environ.get(STATE_ENV)
    if env:
        return Path(env).expanduser()
    return user_state_path()


def user_state_path() -> Path:
    """``$XDG_DATA_HOME/snan-hil/emu-chip.npz`` (default ``~/.local/share/snan-hil/...``)."""
    data_home = os.environ.get("XDG_DATA_HOME") or os.path.join("~", ".local", "share")
    return Path(data_home).expanduser() / "snan-hil" / "emu-chip.npz"


def _array_class():
    from snan_hil.crossbar_model.array import CrossbarArray
    return CrossbarArray


def new_array(seed: int = 0, config: str | None = None):
    """A fresh chip (default YSZ device configuration unless ``config`` names a YAML file)."""
    return _array_class().from_yaml(config, seed=seed)


def load_array(path: str | os.PathLike):
    """Load a saved chip; a missing or unreadable file is a :class:`UserError`."""
    path = Path(path)
    if not path.is_file():
        raise UserError(f"chip state file {path} does not exist")
    try:
        return _array_class().load(str(path))
    except UserError as exc:   # the crossbar's ChipStateError
        raise UserError(f"{exc} ('snan-hil emu --reset-chip --state {path}' makes a fresh "
                        "chip)") from None


def load_or_create(path: str | os.PathLike | None, seed: int = 0,
                   config: str | None = None):
    """The chip saved at ``path`` if that file exists, else a fresh one (not yet saved)."""
    if path is not None and Path(path).exists():
        log.info("loading chip state from %s", path)
        return load_array(path)
    return new_array(seed, config)


def save_array(array, path: str | os.PathLike) -> Path:
    """Save the chip to ``path`` (the array writes a temporary file and renames it)."""
    path = Path(path)
    try:
        array.save(str(path))
    except OSError as exc:
        raise UserError(f"cannot save chip state to {path}: {exc.strerror or exc}") from None
    log.debug("chip state saved to %s", path)
    return path


def delete_state(path: str | os.PathLike) -> bool:
    """Remove a state file; True if one existed."""
    path = Path(path)
    try:
        path.unlink()
        return True
    except FileNotFoundError:
        return False
