"""Atomic file writing: a reader sees the old file or the complete new one, never a partial one.

Everything is written to a temporary file in the target's folder (same file system), flushed
and fsync'ed, then renamed onto the target with :func:`os.replace`; on any exception
(KeyboardInterrupt included) the temporary file is removed and the old target is left
untouched. Ctrl-C (and SIGTERM / SIGHUP where the CLI turns them into an exception) arriving
while the temporary file is being created or removed is held back until that step is over,
so no hidden ``.NAME.*.tmp`` file is left behind. A new file gets the permissions the user's
umask gives (``0666 & ~umask``, as ``open`` would); a replaced file keeps its permission bits.

A base module like :mod:`snan_hil.common.errors`: every layer (protocol and crossbar_model included)
may import it.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import stat
import tempfile
import threading
from pathlib import Path
from typing import Any, Iterator

__all__ = ["atomic_path", "atomic_write_text", "atomic_write_bytes", "atomic_write_json",
           "json_default", "current_umask", "new_file_mode", "signals_deferred"]

_DEFERRED = ("SIGINT", "SIGTERM", "SIGHUP")
_umask_lock = threading.Lock()


def current_umask() -> int:
    """The process's umask (read from ``/proc/self/status`` where it is there, else by
    setting and restoring it under a lock)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    with _umask_lock:
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def new_file_mode(*, folder: bool = False) -> int:
    """Permission bits of a new file (``0666 & ~umask``) or folder (``0777 & ~umask``)."""
    return (0o777 if folder else 0o666) & ~current_umask()


@contextlib.contextmanager
def signals_deferred() -> Iterator[None]:
    """Hold SIGINT / SIGTERM / SIGHUP back for the duration of the block, then deliver them
    (to the handlers that were installed before). A no-op outside the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[tuple[int, Any]] = []
    previous: dict[int, Any] = {}

    def hold(signum: int, frame: Any) -> None:
        received.append((signum, frame))

    try:
        for name in _DEFERRED:
            sig = getattr(signal, name, None)
            if sig is not None:
                previous[sig] = signal.signal(sig, hold)
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        for signum, frame in received:
            handler = previous.get(signum)
            if callable(handler):
                handler(signum, frame)
            elif handler == signal.SIG_DFL:
                signal.raise_signal(signum)


def _fsync_file(path: Path) -> None:
    with open(path, "rb") as fh:
        os.fsync(fh.fileno())


def _mode_for(target: Path) -> int:
    """The replaced file's permission bits, or a new file's (umask)."""
    try:
        st = os.stat(target)
    except OSError:
        return new_file_mode()
    return stat.S_IMODE(st.st_mode) if stat.S_ISREG(st.st_mode) else new_file_mode()


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = ".tmp", *,
                prefix: str | None = None) -> Iterator[Path]:
    """Yield a fresh temporary path in ``path``'s folder; on success it is fsync'ed, given
    the permission bits (see the module doc) and replaces ``path``; on any exception it is
    removed and ``path`` is left as it was.

    The body writes the temporary file by name (e.g. ``np.savez`` or ``fig.savefig`` with an
    explicit ``format``); keep ``suffix`` ending in ``.npz`` for ``np.savez``, which appends
    ``.npz`` to other names. ``prefix`` defaults to ``".<name>."`` (a hidden file). Creates
    the folder if needed. A symbolic link at ``path`` stays: the file it points to is replaced.
    """
    target = Path(path)
    if target.is_symlink():               # replace the file the link points to, keep the link
        target = target.resolve()
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp: Path | None = None
    try:
        with signals_deferred():          # no Ctrl-C between creating and owning the file
            fd, name = tempfile.mkstemp(prefix=f".{target.name}." if prefix is None
                                        else prefix, suffix=suffix, dir=target.parent)
            tmp = Path(name)
            os.close(fd)
        yield tmp
        os.chmod(tmp, _mode_for(target))
        _fsync_file(tmp)
        os.replace(tmp, target)
    except BaseException:
        if tmp is not None:
            with signals_deferred():
                tmp.unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns ``path`` as a Path."""
    target = Path(path)
    with atomic_path(target) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(data)
    return target


def atomic_write_text(path: str | os.PathLike, text: str, *, encoding: str = "utf-8",
                      newline: str | None = "") -> Path:
    """Write ``text`` to ``path`` atomically (UTF-8; by default ``\\n`` is not translated);
    returns ``path`` as a Path."""
    target = Path(path)
    with atomic_path(target) as tmp:
        with open(tmp, "w", encoding=encoding, newline=newline) as fh:
            fh.write(text)
    return target


def json_default(obj: Any) -> Any:
    """``json`` fallback for numpy values: scalars via ``.item()``, arrays via ``.tolist()``;
    TypeError for anything else."""
    if hasattr(obj, "item"):
        return obj.item()
    if hasattr(obj, "tolist"):
        return obj.tolist()
    raise TypeError(f"not JSON serializable: {type(obj).__name__}")


def atomic_write_json(path: str | os.PathLike, obj: Any, **json_kwargs: Any) -> Path:
    """Write ``json.dumps(obj, **json_kwargs)`` plus a final newline to ``path`` atomically.

    numpy scalars and arrays are written as numbers and lists (:func:`json_default`, unless
    ``default`` is given). The project's result files pass ``indent=1, allow_nan=False``
    (strict JSON: a NaN raises instead of writing ``NaN``). The text is built before the file
    is touched, so an unserialisable object raises with the old file and the folder unchanged.
    Returns ``path`` as a Path.
    """
    json_kwargs.setdefault("default", json_default)
    return atomic_write_text(path, json.dumps(obj, **json_kwargs) + "\n", newline=None)
