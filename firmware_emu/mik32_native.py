"""The native peripheral core of the instruction-level MCU: ``libmik32periph.so`` in unicorn.

:func:`load` opens ``build/firmware/libmik32periph.so`` (``make firmware`` builds it from
``native/mik32_periph.c`` with the pip-installed Zig toolchain; ``$SNAN_HIL_MCU_NATIVE_LIB``
names another file) and checks that it was built for this state layout
(:func:`snan_hil.firmware_emu.mik32_state.layout_hash`) and this numpy (its column-read kernel
links numpy's normal generator); a missing or stale library gives
``None`` (the MCU then uses the Python reference core). :class:`NativeCore` hands unicorn the
library's block hook and MMIO handlers (``uc_hook_add`` / ``uc_mmio_map`` through the binding's
own ``ctypes`` library object), with the :class:`~.mik32_state.McuState` as their user data.
"""

from __future__ import annotations

import ctypes
import logging
import os
from functools import lru_cache
from pathlib import Path

import numpy

from snan_hil.firmware_emu import mik32_state as ms
from snan_hil.firmware_emu.mik32_periph import APBM_BASE, APBP_BASE, APBP_SIZE

log = logging.getLogger(__name__)

LIB_ENV = "SNAN_HIL_MCU_NATIVE_LIB"
LIB_NAME = "libmik32periph.so"
_ROOT = Path(__file__).resolve().parent.parent
EVENT_FN = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_int)


def default_lib_path() -> Path:
    env = os.environ.get(LIB_ENV)
    return Path(env).expanduser() if env else _ROOT / "build" / "firmware" / LIB_NAME


@lru_cache(maxsize=4)
def _load(path: str) -> ctypes.CDLL | None:
    p = Path(path)
    if not p.is_file():
        log.warning("native MCU core %s not built ('make firmware'); using the slow Python "
                    "reference core", p)
        return None
    try:
        lib = ctypes.CDLL(str(p))
        lib.mik32_state_size.restype = ctypes.c_int
        lib.mik32_state_layout.restype = ctypes.c_char_p
        lib.mik32_numpy_version.restype = ctypes.c_char_p
        size, layout = lib.mik32_state_size(), lib.mik32_state_layout().decode()
        np_version = lib.mik32_numpy_version().decode()
    except (OSError, AttributeError) as exc:
        log.warning("native MCU core %s unusable (%s); using the Python reference core", p, exc)
        return None
    if size != ctypes.sizeof(ms.McuState) or layout != ms.layout_hash() or \
            np_version != numpy.__version__:
        log.warning("native MCU core %s is stale (state layout %s, numpy %s; expected %s, %s); "
                    "run 'make firmware'; using the Python reference core", p, layout,
                    np_version, ms.layout_hash(), numpy.__version__)
        return None
    return lib


def load() -> ctypes.CDLL | None:
    """The native core library, or None (missing, unloadable or built for another layout)."""
    return _load(str(default_lib_path()))


class NativeCore:
    """The C peripheral models attached to a unicorn CPU (see module doc)."""

    name = "native"

    def __init__(self, event: ms.EventHandler, state: ms.McuState, lib: ctypes.CDLL):
        self.s = state
        self.lib = lib
        self._event_cb = EVENT_FN(event)                # kept alive with the core

    def attach(self, cpu, istart: list[int]) -> None:
        from unicorn import UC_HOOK_BLOCK, UcError     # the firmware extra
        from unicorn.unicorn_py3.unicorn import uc_hook_h, uclib
        self.cpu = cpu
        self._uclib = uclib
        self._uch = cpu._uch                            # the engine handle of the binding
        self._istart = (ctypes.c_uint32 * len(istart))(*istart)
        s = self.s
        s.istart = ctypes.addressof(self._istart)
        s.uc = self._uch.value
        s.emu_stop = ctypes.cast(uclib.uc_emu_stop, ctypes.c_void_p).value
        s.event = ctypes.cast(self._event_cb, ctypes.c_void_p).value
        ud = ctypes.c_void_p(ctypes.addressof(s))

        def fn(name: str) -> int:
            value = ctypes.cast(getattr(self.lib, name), ctypes.c_void_p).value
            assert value is not None
            return value

        hook = uc_hook_h()
        status = uclib.uc_hook_add(self._uch, ctypes.byref(hook), UC_HOOK_BLOCK,
                                   fn("mik32_block"), ud, ctypes.c_uint64(1), ctypes.c_uint64(0))
        if status:
            raise UcError(status)
        for base, size, rd, wr in ((APBM_BASE, 0x1000, "mik32_apbm_read", "mik32_apbm_write"),
                                   (APBP_BASE, APBP_SIZE, "mik32_apbp_read",
                                    "mik32_apbp_write")):
            status = uclib.uc_mmio_map(self._uch, base, size, fn(rd), ud, fn(wr), ud)
            if status:
                raise UcError(status)

    def stop_cpu(self) -> None:
        self._uclib.uc_emu_stop(self._uch)
