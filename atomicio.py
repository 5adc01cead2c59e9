"""Atomic file writing: a reader sees the old file or the complete new one, never a partial one.

Everything is written to a temporary file in the target's folder (same file system), flushed
and fsync'ed, then renamed onto the target with :func:`os.replace`; on any exception the
temporary file is removed and the old target is left untouched. A base module like
:mod:`snan_hil.errors`: every layer (protocol and crossbar_model included) may import it.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any, Iterator

__all__ = ["atomic_path", "atomic_write_text", "atomic_write_bytes", "atomic_write_json",
           "json_default"]


def _fsync_file(path: Path) -> None:
    with open(path, "rb") as fh:
        os.fsync(fh.fileno())


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str = ".tmp", *,
                prefix: str | None = None) -> Iterator[Path]:
    """Yield a fresh temporary path in ``path``'s folder; on success it is fsync'ed and
    replaces ``path``, on any exception it is removed and ``path`` is left as it was.

    The body writes the temporary file by name (e.g. ``np.savez`` or ``fig.savefig`` with an
    explicit ``format``); keep ``suffix`` ending in ``.npz`` for ``np.savez``, which appends
    ``.npz`` to other names. ``prefix`` defaults to ``".<name>."`` (a hidden file). Creates
    the folder if needed.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=f".{target.name}." if prefix is None else prefix,
                                suffix=suffix, dir=target.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        _fsync_file(tmp)
        os.replace(tmp, target)
    except BaseException:
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
