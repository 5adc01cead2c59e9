"""The emulated chip's state file: where it lives, loading it, saving it, one owner at a time.

The in-process emulator (``--port emu``) keeps its crossbar in a default state file so that
separate commands (``program-weights`` then ``run``) act on the same chip, as they would on a
real board. The file is the crossbar model's own npz format (no pickle); it is the snapshot
half of the chip's durable state, :mod:`.durable` adds the journal (open a chip through
:class:`~snan_hil.firmware_emu.durable.ChipStore`, which replays it).
"""

from __future__ import annotations

import hashlib
import logging
import os
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

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


def twins_dir() -> Path:
    """Where the in-process emulator keeps the chips of fitted device models when no state
    file is named: ``twins/`` in the user's data folder."""
    return user_data_dir() / "twins"


def made_by_us(path: Path) -> bool:
    """Whether ``path`` is a chip file whose folder the emulator may create: the default chip
    or a twin's default file (:func:`twin_state_path`)."""
    path = Path(path).expanduser()
    return path == user_state_path() or path.parent == twins_dir()


@dataclass(frozen=True)
class TwinDevice:
    """A fitted device model the emulator makes its chip of (``--device FILE``,
    ``emu://?device=FILE``): the model, its file and the digest that names its twin."""

    model: Any                      # crossbar_model.fitted.DeviceModel
    path: Path
    digest: str

    @classmethod
    def load(cls, path: str | os.PathLike) -> "TwinDevice":
        """Read the model file (UserError, one line, when it is not a device model)."""
        from snan_hil.crossbar_model.device_twin import load_device_model, model_digest
        model = load_device_model(Path(path))
        return cls(model, Path(path).expanduser(), model_digest(model))

    def meta(self) -> dict[str, Any]:
        """What the chip's meta records of the model it was made of."""
        return {"digest": self.digest, "model": str(self.path)}


def twin_state_path(device: str | os.PathLike) -> Path:
    """The default chip file of the twin of the device model file ``device`` (no state file
    named): ``twins/<stem>-<12 hex digits of the file's SHA-256>.npz`` in the user's data
    folder, so a changed model file is another chip. UserError when the file cannot be read."""
    path = Path(device).expanduser()
    try:
        digest = hashlib.sha256(path.read_bytes()).hexdigest()[:12]
    except FileNotFoundError:
        raise UserError(f"device model {path} does not exist; write one with 'snan-hil "
                        "characterize --model FILE' (or --from a pulse CSV)") from None
    except OSError as exc:
        raise UserError(f"device model {path}: {exc.strerror or exc}; give a file written by "
                        "'snan-hil characterize --model'") from None
    return twins_dir() / f"{path.stem}-{digest}.npz"


def _array_class():
    # the chip model (numpy, ~0.25 s) only when a chip is made: lab/ports reads this module's
    # paths at every CLI start
    from snan_hil.crossbar_model.array import CrossbarArray
    return CrossbarArray


SPREAD_KEYS = ("variability.g_min_sigma_log", "variability.g_max_sigma_log",
               "variability.rate_sigma_log", "variability.threshold_sigma_v")
"""The device-to-device spread of a chip (configs/device-ysz.yaml ``variability``): what
``spread`` scales."""


def new_array(seed: int = 0, config: str | None = None, device: TwinDevice | None = None,
              spread: float = 1.0):
    """A fresh chip: the twin of ``device`` (a fitted model made physical,
    :mod:`snan_hil.crossbar_model.device_twin`, read noise per draw for this board's ADC
    averages), else the default YSZ device configuration unless ``config`` names a YAML file.
    ``spread`` (>= 0; not with ``device``, whose spread is the measured one) multiplies the
    configuration's device-to-device sigmas (:data:`SPREAD_KEYS`): 0.5 a more uniform chip,
    2 a chip whose cells differ twice as much (an assumption to test a result across chips,
    not a measured chip). ValueError for a negative ``spread`` or one given with ``device``."""
    if not spread >= 0:
        raise ValueError(f"spread must be >= 0, got {spread}")
    if device is not None:
        if spread != 1.0:
            raise ValueError("a twin's spread is its model's: give spread 1 with a device")
        from snan_hil.crossbar_model.device_twin import twin_spec
        from snan_hil.firmware_emu.config import BoardConfig
        spec = twin_spec(device.model, read_draws=BoardConfig().adc_averages,
                         digest=device.digest)
        return spec.build(seed)
    if spread == 1.0:
        return _array_class().from_yaml(config, seed=seed)
    from snan_hil.crossbar_model.config import ArrayConfig
    base = ArrayConfig.from_yaml(config)
    values = base.to_dict()
    scaled = {k: float(values[k.split(".")[0]][k.split(".")[1]]) * float(spread)
              for k in SPREAD_KEYS}
    return _array_class()(base.with_overrides(scaled), seed=seed)


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
