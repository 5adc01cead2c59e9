"""The emulated chip's state file: where it lives, loading it, saving it, one owner at a time.

The in-process emulator (``--port emu``) keeps its crossbar in a default state file so that
separate commands (``program-weights`` then ``run``) act on the same chip, as they would on a
real board. The file is the crossbar model's own npz format (no pickle); it is the snapshot
half of the chip's durable state, :mod:`.durable` adds the journal (open a chip through
:class:`~snan_hil.firmware_emu.durable.ChipStore`, which replays it).
"""

from __future__ import annotations

import logging
import os
import threading
from collections.abc import Callable
from pathlib import Path

from snan_hil.common.errors import UserError
from snan_hil.files.userdata import user_data_dir

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
    """``emu-chip.npz`` in the user's data folder (:func:`snan_hil.files.userdata.user_data_dir`:
    ``$XDG_DATA_HOME/snan-hil``, default ``~/.local/share/snan-hil`` on Linux)."""
    return user_data_dir() / "emu-chip.npz"


def _array_class():
    # the chip model (numpy, ~0.25 s) only when a chip is made: lab/ports reads this module's
    # paths at every CLI start
    from snan_hil.crossbar_model.array import CrossbarArray
    return CrossbarArray


def new_array(seed: int = 0, config: str | None = None):
    """A fresh chip (default YSZ device configuration unless ``config`` names a YAML file)."""
    return _array_class().from_yaml(config, seed=seed)


def load_array(path: str | os.PathLike):
    """Load a saved chip; a missing or unreadable file is a :class:`UserError`."""
    path = Path(path)
    if path.is_dir():
        raise UserError(f"chip state {path} is a directory; give a file such as chip.npz")
    if not path.is_file():
        raise UserError(f"chip state file {path} does not exist")
    try:
        return _array_class().load(str(path))
    except UserError as exc:   # the crossbar's ChipStateError (the file is left untouched)
        reason = getattr(exc, "reason", str(exc))
        if getattr(exc, "ours", False):         # a damaged chip of this emulator
            raise UserError(f"{reason}; it was left untouched: move it away, or replace it by "
                            f"a fresh chip with 'snan-hil emu --reset-chip --state {path}'"
                            ) from None
        # anyone's file (weights, data, another format): never suggest overwriting it
        other = free_sibling(path)
        raise UserError(f"{reason}; it was left untouched: keep the chip in another file, e.g. "
                        f"--state {other} (for --port emu: SNAN_HIL_EMU_STATE={other}); a new "
                        "chip is made there") from None


def free_sibling(path: Path) -> Path:
    """A chip file name beside ``path`` that does not exist yet (``chip.npz``,
    ``chip-2.npz``, ...), for hints that must not point at an existing file."""
    for n in range(1, 1000):
        candidate = path.with_name("chip.npz" if n == 1 else f"chip-{n}.npz")
        if not candidate.exists():
            return candidate
    return path.with_name(f"chip-{os.getpid()}.npz")


def save_array(array, path: str | os.PathLike, meta: dict | None = None) -> Path:
    """Save the chip to ``path`` (the array writes a temporary file, fsyncs and renames it);
    ``meta``: the emulator's data about the chip (:mod:`.durable`)."""
    path = Path(path)
    try:
        array.save(str(path), meta=meta)
    except OSError as exc:
        raise UserError(f"cannot save chip state to {path}: {exc.strerror or exc}") from None
    log.debug("chip state saved to %s", path)
    return path


# --------------------------------------------------------------------------- one emulator a file
_held: dict[Path, list[int]] = {}      # resolved state path -> [lock fd, users in this process]
_held_guard = threading.Lock()


def lock_path(path: str | os.PathLike) -> Path:
    """The lock file beside a state file (``.NAME.lock``)."""
    path = Path(path).expanduser()
    return path.with_name(f".{path.name}.lock")


def acquire(path: str | os.PathLike) -> Callable[[], None]:
    """Claim a chip state file for this process; returns the function that releases it.

    Two processes saving one chip would overwrite each other's programming, so a second process
    (a ``snan-hil emu`` server and a ``--port emu`` command, say) gets a :class:`UserError`
    instead. Emulators inside one process share the claim. Advisory ``flock`` on
    :func:`lock_path`; a no-op where ``fcntl`` does not exist.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows
        return lambda: None
    key = Path(path).expanduser().resolve()
    if key.is_dir():
        raise UserError(f"chip state {key} is a directory; give a file such as chip.npz")
    with _held_guard:
        if key in _held:
            _held[key][1] += 1
        else:
            lock = lock_path(key)
            try:
                lock.parent.mkdir(parents=True, exist_ok=True)
                fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
            except OSError as exc:
                raise UserError(f"cannot use chip state {key}: {exc.strerror or exc}") from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                other = os.read(fd, 32).decode(errors="replace").strip() or "?"
                os.close(fd)
                raise UserError(
                    f"chip state {key} is in use by another emulator (process {other}: a "
                    "'snan-hil emu' server or a '--port emu' command); stop it, connect to "
                    "that server's port instead, or give another --state file") from None
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
            _held[key] = [fd, 1]
    released: list[bool] = []

    def release() -> None:
        with _held_guard:
            if released or key not in _held:
                return
            released.append(True)
            _held[key][1] -= 1
            if _held[key][1] == 0:
                os.close(_held.pop(key)[0])     # closing the descriptor drops the flock
    return release
