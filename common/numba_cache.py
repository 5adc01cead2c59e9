"""A damaged numba cache is a cache miss, not a failure of every later run.

The kernel modules (``host/snan_kernel.py``, ``firmware_emu/spike_fastpath.py``) compile with
``cache=True``: numba keeps each compiled function as an index file (``*.nbi``) and data files
(``*.nbc``) in the module's ``__pycache__``. Numba treats a *missing* data file as a miss, but
a truncated or otherwise damaged one (a full disk, a killed process, a copy cut short) raises
from ``pickle`` on every call, so every run fails until the files are deleted by hand (issue 27
item 11). :func:`tolerate_damaged_cache` wraps the cache loader of each numba function of a
module: a cache entry that cannot be read is logged once, its files are removed, and the
function is compiled again (and cached afresh).

This module runs no compiled code and imports nothing of numba at import time; it relies on
numba's (internal, stable since 0.49) ``Dispatcher._cache.load_overload`` and the cache file's
``_cache_path`` / ``_index_name`` attributes, and does nothing where they are absent.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from typing import Any

__all__ = ["tolerate_damaged_cache", "remove_cache_entry", "announce_compile"]

log = logging.getLogger(__name__)


def remove_cache_entry(cache_file: Any) -> list[str]:
    """Remove the index and data files of one numba cache entry (its ``<base>.nbi`` and
    ``<base>.<n>.nbc`` in its cache folder); returns the removed paths."""
    folder = getattr(cache_file, "_cache_path", None)
    index = getattr(cache_file, "_index_name", None)
    if not isinstance(folder, str) or not isinstance(index, str) or not os.path.isdir(folder):
        return []
    base = index[:-len(".nbi")] if index.endswith(".nbi") else index
    removed = []
    for name in os.listdir(folder):
        if name == index or (name.startswith(base + ".") and name.endswith(".nbc")):
            path = os.path.join(folder, name)
            try:
                os.unlink(path)
                removed.append(path)
            except OSError:                       # gone already, or not ours to remove
                pass
    return removed


def _tolerant(dispatcher: Any) -> None:
    cache: Any = getattr(dispatcher, "_cache", None)
    load = getattr(cache, "load_overload", None)
    if load is None or getattr(load, "_tolerant", False):
        return
    name = getattr(dispatcher, "__qualname__", getattr(dispatcher, "__name__", "?"))

    def load_overload(sig: Any, target_context: Any) -> Any:
        try:
            return load(sig, target_context)
        except Exception as exc:  # noqa: BLE001 - any unreadable entry is a miss
            removed = remove_cache_entry(getattr(cache, "_cache_file", None))
            log.warning("numba cache of %s could not be read (%s: %s); removed %d file(s), "
                        "compiling it again", name, type(exc).__name__, exc, len(removed))
            return None

    setattr(load_overload, "_tolerant", True)     # marks the wrapper  # noqa: B010
    cache.load_overload = load_overload


def tolerate_damaged_cache(namespace: Mapping[str, Any]) -> None:
    """Make every cached numba function in ``namespace`` (a kernel module's ``globals()``)
    treat an unreadable cache entry as a miss (see the module docstring). Idempotent."""
    for value in list(namespace.values()):
        if hasattr(value, "_cache") and hasattr(value, "py_func"):
            _tolerant(value)


@contextmanager
def announce_compile(note: Callable[[], object]) -> Iterator[None]:
    """Call ``note()`` once, when numba starts compiling a function inside the block (in this
    process): a function loaded from numba's cache, or compiled already, does not call it. So
    a command says "compiling ..." exactly when something compiles (a prediction from the
    cache's index said so on every start where it misjudged). Uses numba's public event API
    (``numba.core.event``, the ``numba:compile`` event of a cache miss)."""
    from numba.core import event

    said: list[bool] = []

    class _First(event.Listener):
        def on_start(self, ev: Any) -> None:
            if not said:
                said.append(True)
                note()

        def on_end(self, ev: Any) -> None:
            pass

    with event.install_listener("numba:compile", _First()):
        yield
