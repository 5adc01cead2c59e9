"""The emulator inside the host process, opened as an ``emu://`` transport.

:func:`open_inprocess_transport` is what ``--port emu`` amounts to, for tests and benchmarks
that want a transport without the CLI: the ``emu://`` URL of :mod:`.protocol_emu` opened by
:class:`~snan_hil.protocol.transport.SerialTransport` (synchronous: each write is answered
inside the call). Closing the transport saves the chip; so does interpreter exit.
:func:`emulator_of` gives the :class:`Emulator` behind such a transport.
"""

from __future__ import annotations

from pathlib import Path

from snan_hil.firmware_emu.emulator import Emulator
from snan_hil.firmware_emu.protocol_emu import Serial, emu_url, register_url_handler
from snan_hil.protocol.transport import DEFAULT_BAUD, SerialTransport, Transport

__all__ = ["open_inprocess_transport", "emulator_of"]


def open_inprocess_transport(state_file: str | Path | None = None, seed: int | None = None,
                             protocol: str = "framed", baud: int = DEFAULT_BAUD, *,
                             mcu: str = "model", refusals: bool = False,
                             device: str | Path | None = None) -> SerialTransport:
    """Start an in-process emulator and return the host end of its transport.

    ``state_file``: chip state (default :func:`~.state.default_state_path`); loaded if it
    exists, created from ``seed`` otherwise, saved after writes and at close. ``baud`` sets
    the UART time on the virtual clock (the in-process transport itself has no line).
    ``refusals``: the legacy protocol's opt-in ``-CODE,id`` extension; ``device``: a fitted
    device model file whose twin the chip is.
    """
    register_url_handler()
    return SerialTransport(emu_url(state_file, seed, protocol, mcu, refusals, device=device),
                           baud)


def emulator_of(transport: Transport) -> Emulator:
    """The emulator behind an ``emu://`` transport (TypeError for any other transport)."""
    port = getattr(transport, "serial", None)
    if not isinstance(port, Serial):
        raise TypeError(f"{transport.name} is not an in-process emulator (emu://) transport")
    return port.emulator
