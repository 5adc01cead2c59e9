"""``emu://``: the in-process emulator as a pyserial URL, a transport like ``socket://``.

pyserial opens ``scheme://...`` URLs with a module ``protocol_<scheme>`` found in one of the
packages listed in ``serial.protocol_handler_packages``; :func:`register_url_handler` adds this
package, so ``serial.serial_for_url("emu://...")`` (and so
:class:`~snan_hil.protocol.transport.SerialTransport`) opens an emulated board inside the host
process. The protocol layer never imports the emulator: whoever opens ports (the opener,
:mod:`snan_hil.lab.ports`) registers the handler.

URL: ``emu://[?state=PATH][&seed=N][&protocol=framed|legacy][&mcu=model|firmware][&refusals=1]
[&fault=SPEC[,SPEC...]][&device=MODEL.json]``

* ``state``: the chip's state file (default ``$SNAN_HIL_EMU_STATE`` or ``emu-chip.npz`` in the
  user's data folder); loaded if it exists, created from ``seed`` otherwise, saved after writes
  and at close; one process at a time (a lock file);
* ``seed``: seed of a new chip and of the board's ADC noise (default 0);
* ``protocol``: what the emulated firmware speaks (default ``framed``);
* ``mcu``: ``model`` (the Python firmware model, default) or ``firmware`` (the C firmware ELF
  run instruction by instruction, :mod:`~snan_hil.firmware_emu.mcu_isa`);
* ``refusals``: ``1`` turns on the legacy protocol's opt-in ``-CODE,id`` extension (default
  ``0``: silence, as the existing firmware);
* ``fault``: hardware faults of the emulated board, for tests and demos
  (:mod:`~snan_hil.firmware_emu.faults`, e.g. ``fault=adc-stuck-bit:6:1,uart-drop:0.02``);
* ``device``: a fitted device model (``snan-hil characterize --model``): the chip is its twin,
  the measured device made physical (:mod:`snan_hil.crossbar_model.device_twin`); without
  ``state`` the twin's chip is kept in its own file (``twins/`` in the user's data folder,
  named by the model file's content), and a state file holding another chip is refused.

The port is synchronous: every ``write`` is answered inside the call (no thread, no
wall-clock wait); ``read`` returns what is buffered at once, and ``synchronous`` tells the
transport that an empty read means nothing more will come. The line rate (``baudrate``) sets
the UART time on the virtual clock.
"""

from __future__ import annotations

import atexit
import numbers
import weakref
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import parse_qs, urlencode, urlsplit

import serial
from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from snan_hil.common.errors import UserError
from snan_hil.firmware_emu.faults import BoardFaults, parse_faults
from snan_hil.firmware_emu.mcu import MCU_KINDS
from snan_hil.firmware_emu.state import TwinDevice, default_state_path, twin_state_path

if TYPE_CHECKING:                  # the emulator (numba, the MCU) is imported when one opens
    from snan_hil.firmware_emu.emulator import Emulator

__all__ = ["SCHEME", "EmuUrl", "Serial", "emu_url", "register_url_handler"]

SCHEME = "emu"
_PACKAGE = __name__.rpartition(".")[0]
_OPTIONS = ("state", "seed", "protocol", "mcu", "refusals", "fault", "device")


def register_url_handler() -> None:
    """Let pyserial open ``emu://`` URLs (idempotent)."""
    if _PACKAGE not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(_PACKAGE)


def emu_url(state_file: str | Path | None = None, seed: int | None = None,
            protocol: str = "framed", mcu: str = "model", refusals: bool = False,
            faults: BoardFaults | None = None, device: str | Path | None = None) -> str:
    """The ``emu://`` URL of an in-process emulator with these settings."""
    query: dict[str, str] = {}
    if state_file is not None:
        query["state"] = str(state_file)
    if seed is not None:
        query["seed"] = str(int(seed))
    if protocol != "framed":
        query["protocol"] = protocol
    if mcu != "model":
        query["mcu"] = mcu
    if refusals:
        query["refusals"] = "1"
    if faults is not None and faults.specs:
        query["fault"] = ",".join(faults.specs)
    if device is not None:
        query["device"] = str(device)
    return f"{SCHEME}://" + (f"?{urlencode(query, safe='/~:')}" if query else "")


@dataclass(frozen=True)
class EmuUrl:
    """The settings of an ``emu://`` URL (see the module docstring); ``given``: the keys the
    URL names (the others are defaults). :meth:`parse` is the one place the URL is read."""

    state: Path
    seed: int | None = None
    protocol: str = "framed"
    mcu: str = "model"
    refusals: bool = False
    given: frozenset[str] = frozenset()
    faults: BoardFaults = BoardFaults()
    device: Path | None = None

    @classmethod
    def parse(cls, url: str) -> EmuUrl:
        """The settings of ``url``; SerialException naming the fault."""
        parts = urlsplit(url)
        form = ("emu://[?state=PATH][&seed=N][&protocol=framed|legacy][&mcu=model|firmware]"
                "[&refusals=0|1][&fault=SPEC,...][&device=MODEL.json]")
        if parts.scheme != SCHEME or parts.netloc or parts.path:
            raise SerialException(f"expected a URL of the form {form}, got {url!r}")
        options = parse_qs(parts.query, keep_blank_values=True)
        unknown = sorted(set(options) - set(_OPTIONS))
        if unknown:
            raise SerialException(f"unknown option {unknown[0]!r} in {url!r}; {form}")
        repeated = sorted(k for k, v in options.items() if len(v) > 1)
        if repeated:
            raise SerialException(f"option {repeated[0]!r} is given twice in {url!r}; give it "
                                  "once")
        values = {k: v[-1] for k, v in options.items()}
        device = Path(values["device"]).expanduser() if values.get("device") else None
        if "device" in values and device is None:
            raise SerialException(f"device needs a model file in {url!r}")
        if values.get("state"):
            state = Path(values["state"]).expanduser()
        elif device is not None:
            try:
                state = twin_state_path(device)
            except UserError as exc:
                raise SerialException(str(exc)) from None
        else:
            state = default_state_path()
        seed = None
        if "seed" in values:
            try:
                seed = int(values["seed"])
            except ValueError:
                raise SerialException(f"seed must be an integer in {url!r}") from None
        protocol = values.get("protocol", "framed")
        from snan_hil.firmware_emu.emulator import PROTOCOLS
        if protocol not in PROTOCOLS:
            raise SerialException(f"protocol must be one of {', '.join(PROTOCOLS)} in {url!r}")
        mcu = values.get("mcu", "model")
        if mcu not in MCU_KINDS:
            raise SerialException(f"mcu must be one of {', '.join(MCU_KINDS)} in {url!r}")
        refusals = values.get("refusals", "0")
        if refusals not in ("0", "1"):
            raise SerialException(f"refusals must be 0 or 1 in {url!r}")
        try:
            faults = parse_faults(values.get("fault"))
        except UserError as exc:
            raise SerialException(f"{exc} in {url!r}") from None
        return cls(state, seed, protocol, mcu, refusals == "1", frozenset(values), faults,
                   device)


class Serial(SerialBase):
    """A pyserial port whose other end is an :class:`Emulator` in this process."""

    #: Each write is answered inside the call: an empty read means nothing more will come.
    synchronous = True

    def __init__(self, *args: object, **kwargs: object) -> None:
        self._emulator: Emulator | None = None
        self._rx = bytearray()
        self._pipelined = False
        super().__init__(*args, **kwargs)  # type: ignore[arg-type]  # pyserial's untyped kwargs

    def pipeline(self, on: bool) -> None:
        """``on``: the host keeps requests outstanding (framed protocol): its writes go on the
        emulated line (:meth:`Emulator.post`) and the board runs when the host reads, one
        reply at a time (:meth:`Emulator.pump`), so a request written while another runs
        arrives during it, as on a real line. Off: each write is answered inside the call."""
        if self._emulator is not None and self._emulator.protocol == "framed":
            self._pipelined = bool(on)

    def _pump(self) -> None:
        if self._pipelined and not self._rx and self._emulator is not None:
            self._rx += self._emulator.pump()

    @property
    def emulator(self) -> Emulator:
        """The emulated board (for tests and tools that look inside)."""
        if self._emulator is None:
            raise PortNotOpenError()
        return self._emulator

    def open(self) -> None:
        if self.is_open:
            raise SerialException("Port is already open.")
        if self.port is None:
            raise SerialException("Port must be configured before it can be used.")
        url = EmuUrl.parse(self.port)
        self._reconfigure_port()
        from snan_hil.firmware_emu.emulator import Emulator
        # a bad model file is the user's mistake: its one line (UserError) goes up as it is
        device = TwinDevice.load(url.device) if url.device is not None else None
        emu = Emulator(url.state, url.seed, protocol=url.protocol, baud=int(self.baudrate),
                       mcu=url.mcu, legacy_refusals=url.refusals, faults=url.faults,
                       device=device)
        atexit.register(_close_if_alive, weakref.ref(emu))   # save the chip at exit too
        self._emulator = emu
        self._rx.clear()
        self.is_open = True

    def close(self) -> None:
        if self.is_open:
            self.is_open = False
            if self._emulator is not None:
                self._emulator.close()          # saves the chip, releases its lock

    def _reconfigure_port(self) -> None:
        baud = self.baudrate
        if not isinstance(baud, numbers.Integral) or not 0 < int(baud) < 2 ** 32:
            raise ValueError(f"invalid baudrate: {baud!r}")

    @property
    def in_waiting(self) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        self._pump()
        return len(self._rx)

    def read(self, size: int = 1) -> bytes:
        if not self.is_open:
            raise PortNotOpenError()
        self._pump()
        data = bytes(self._rx[:size])
        del self._rx[:size]
        return data

    def write(self, data: Any) -> int:  # a bytes-like object (pyserial's Buffer)
        if not self.is_open or self._emulator is None:
            raise PortNotOpenError()
        raw = bytes(data)
        if self._pipelined:
            self._emulator.post(raw)
            return len(raw)
        out = self._emulator.feed(raw)
        if out:
            self._rx += out
        return len(raw)

    def reset_input_buffer(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()
        self._rx.clear()

    def reset_output_buffer(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()

    @property
    def out_waiting(self) -> int:
        return 0

    def _update_break_state(self) -> None:
        pass

    def _update_rts_state(self) -> None:
        pass

    def _update_dtr_state(self) -> None:
        pass


def _close_if_alive(ref: weakref.ref[Emulator]) -> None:
    emu = ref()
    if emu is not None:
        emu.close()
