"""What the machine can give a command: memory checked before a large run starts."""

from __future__ import annotations

import psutil

from snan_hil.common.errors import UserError

__all__ = ["available_memory", "check_memory", "format_bytes"]


def available_memory() -> int:
    """Bytes of memory available to new allocations without swapping (psutil's
    ``virtual_memory().available``: free plus reclaimable caches)."""
    return int(psutil.virtual_memory().available)


def format_bytes(n: float) -> str:
    """``1.5 GB``, ``340 MB`` (powers of 1000, as ``free -h`` shows them in SI)."""
    for unit, size in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if abs(n) >= size:
            return f"{n / size:.1f} {unit}"
    return f"{n:.0f} B"


def check_memory(need_bytes: int, what: str, advice: str) -> None:
    """UserError (one line, exit 2) when ``what`` needs more than the available memory; the
    message gives the estimate, what is available and ``advice``."""
    have = available_memory()
    if need_bytes > have:
        raise UserError(f"{what} needs about {format_bytes(need_bytes)} of memory, "
                        f"{format_bytes(have)} is available; {advice}")
