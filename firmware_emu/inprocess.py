"""The emulator inside the host process: what ``--port emu`` opens.

:func:`open_inprocess_transport` builds an :class:`Emulator` on the default chip state file
(``$SNAN_HIL_EMU_STATE`` or ``~/.local/share/snan-hil/emu-chip.npz``) and returns the host end of
a transport to it. By default the transport is synchronous (:class:`CallbackTransport`: each
write is answered inside the call, no thread, no wall-clock waits); ``threaded=True`` instead
serves the board end of an in-process byte pipe from a daemon thread, as a separate board would.
Closing the transport (``client.close()``) saves the chip; so does interpreter exit.
"""

from __future__ import annotations

import atexit
import logging
import threading
import weakref
from pathlib import Path

from snan_hil.firmware_emu.emulator import Emulator
from snan_hil.firmware_emu.state import default_state_path
from snan_hil.protocol.errors import TransportError
from snan_hil.protocol.transport import CallbackTransport, Transport, pipe_pair

log = logging.getLogger(__name__)


def open_inprocess_transport(state_file: str | None = None, seed: int | None = None,
                             protocol: str = "framed", baud: int = 115200, *,
                             threaded: bool = False, mcu: str = "model") -> Transport:
    """Start an in-process emulator and return the host end of its transport.

    ``state_file``: chip state (default :func:`default_state_path`); loaded if it exists,
    created from ``seed`` otherwise, saved after writes and at close. ``baud`` sets the UART
    time on the virtual clock (the in-process transport itself has no line).
    """
    path = Path(state_file) if state_file else default_state_path()
    emu = Emulator(path, seed, protocol=protocol, baud=baud, mcu=mcu)
    ref = weakref.ref(emu)
    atexit.register(_close_if_alive, ref)
    name = f"emu (in-process emulator, {mcu} MCU, chip {path})"
    if not threaded:
        transport = CallbackTransport(emu.feed, name=name, on_close=emu.close)
        transport.emulator = emu   # for tests and tools that want to look inside
        return transport
    host, board = pipe_pair(name)
    thread = threading.Thread(target=_serve_pipe, args=(emu, board), name="emu board",
                              daemon=True)
    thread.start()
    host.emulator = emu
    return host


def _serve_pipe(emu: Emulator, board: Transport) -> None:
    try:
        while True:
            data = board.read(65536, 0.5)
            if data:
                out = emu.feed(data)
                if out:
                    board.write(out)
            elif getattr(getattr(board, "_rx", None), "closed", False):  # host end closed
                break
    except TransportError as exc:
        log.debug("in-process emulator: %s", exc)
    finally:
        emu.close()


def _close_if_alive(ref: weakref.ref) -> None:
    emu = ref()
    if emu is not None:
        emu.close()
