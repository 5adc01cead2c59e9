"""One emulated MemriCore board: chip + hardware + firmware + protocol endpoint, as bytes in/out.

:class:`Emulator` is what the servers (pty, TCP, in-process) run: ``feed(received bytes) ->
bytes to send``. It accounts the UART bytes on the virtual clock (10 bits per byte at the
configured baud), speaks the framed protocol (``protocol.device.DeviceEndpoint``) or the old
line protocol (``protocol.legacy.LegacyDevice``) around the same firmware dispatcher, and keeps
the chip's state file up to date (saved after state-changing requests, at most every
``save_interval_s`` seconds, and always at :meth:`close`).
"""

from __future__ import annotations

import logging
import random
import threading
import time
from collections.abc import Sequence
from pathlib import Path

from snan_hil.errors import UserError
from snan_hil.firmware_emu import state
from snan_hil.firmware_emu.board import DEFAULT_ADC_NOISE_LSB, Board
from snan_hil.firmware_emu.config import BoardConfig
from snan_hil.firmware_emu.dispatch import Dispatcher
from snan_hil.firmware_emu.firmware import Firmware
from snan_hil.firmware_emu.legacy_firmware import LegacyFirmware
from snan_hil.firmware_emu.mcu import FirmwareBackend, check_mcu
from snan_hil.protocol.device import DeviceEndpoint
from snan_hil.protocol.legacy import LegacyDevice

log = logging.getLogger(__name__)

PROTOCOLS = ("framed", "legacy")


class NonceSequence(random.Random):
    """A nonce source that returns given values in order (then repeats the last + 1, ...): the
    conformance vectors' stated boot nonces. ``getrandbits`` serves the Python model, ``next``
    the C firmware's entropy hook."""

    def __init__(self, values: Sequence[int]):
        super().__init__(0)
        self._values = [int(v) & 0xFFFFFFFF for v in values] or [1]
        self._i = 0

    def next(self) -> int:
        if self._i < len(self._values):
            value = self._values[self._i]
        else:
            value = (self._values[-1] + self._i - len(self._values) + 1) & 0xFFFFFFFF
        self._i += 1
        return value

    def getrandbits(self, k: int) -> int:
        return self.next() & ((1 << k) - 1)


class Emulator:
    """A complete emulated board behind a byte interface.

    ``state_file``: chip loaded from it if it exists, saved to it (None: never saved).
    ``seed``: seed of a freshly created chip and of the board's ADC noise (default 0).
    ``array``: use this crossbar instead of loading/creating one.
    ``fast``: ADC frames of a reading in one batch (default) or frame by frame (reference);
    see :attr:`Firmware.fast`.
    ``mcu``: "model" (the Python firmware model) or "firmware" (the C firmware ELF ``elf``,
    default ``build/firmware/snan-fw.elf``, on the ISA-level MCU; framed protocol only).
    ``protocol="legacy"`` runs the existing firmware's behaviour
    (:class:`~snan_hil.firmware_emu.legacy_firmware.LegacyFirmware`) behind the line protocol;
    ``legacy_refusals`` turns on the opt-in ``-CODE,id`` extension (default: silence, as the
    old firmware).
    ``wall_scale``: how a server (pty, TCP) paces replies in wall time: a reply leaves no
    earlier than ``wall_scale`` x the board time (virtual, without the UART) its request took
    after the request arrived (1.0: real time, so a 1 s pulse is answered after 1 s; 0: at
    once). Default: 1.0 for the legacy protocol, 0 for the framed one. In-process transports
    never wait (virtual time only).
    ``boot_nonces``: test bench only (the conformance vectors): the boot nonces the board draws,
    in order (at power-on, then at each RESET), instead of random ones; both MCUs.
    """

    def __init__(self, state_file: str | Path | None = None, seed: int | None = None, *,
                 protocol: str = "framed", baud: int = 115200,
                 config: BoardConfig | None = None, array=None,
                 adc_noise_lsb: float = DEFAULT_ADC_NOISE_LSB, save_interval_s: float = 1.0,
                 fast: bool = True, mcu: str = "model", elf=None,
                 boot_nonces: Sequence[int] | None = None,
                 legacy_refusals: bool = False, wall_scale: float | None = None):
        if protocol not in PROTOCOLS:
            raise UserError(f"unknown protocol {protocol!r}; use framed or legacy")
        if baud <= 0:
            raise UserError(f"baud must be positive, got {baud}")
        self.mcu_kind = check_mcu(mcu)
        if mcu == "firmware" and protocol != "framed":
            raise UserError("the C firmware (--mcu firmware) speaks the framed protocol only; "
                            "use --protocol framed or --mcu model")
        if wall_scale is not None and not 0 <= wall_scale < float("inf"):
            raise UserError(f"wall-time scale must be >= 0, got {wall_scale}")
        self.wall_scale = float(wall_scale if wall_scale is not None
                                else (1.0 if protocol == "legacy" else 0.0))
        self.last_busy_us = 0.0
        """Board time (virtual us, without the UART) of the last :meth:`feed`."""
        self.seed = 0 if seed is None else int(seed)
        self.state_file = Path(state_file) if state_file is not None else None
        self.protocol = protocol
        self.save_interval_s = float(save_interval_s)
        # One process at a time may own a state file (raises UserError otherwise).
        self._release = state.acquire(self.state_file) if self.state_file is not None \
            else (lambda: None)
        try:
            if array is None:
                array = state.load_or_create(self.state_file, self.seed)
        except BaseException:
            self._release()
            raise
        self.array = array
        self.board = Board(array, config, seed=self.seed, baud=baud,
                           adc_noise_lsb=adc_noise_lsb)
        self.backend = None
        nonces = NonceSequence(boot_nonces) if boot_nonces is not None else None
        if mcu == "firmware":
            try:
                self.backend = FirmwareBackend(self.board, baud=baud, seed=self.seed, elf=elf,
                                               on_state_change=self._mark_dirty,
                                               entropy=None if nonces is None else nonces.next)
            except BaseException:
                self._release()
                raise
            self.firmware: Firmware | None = None
            self.dispatcher: Dispatcher | None = None
            self.endpoint: DeviceEndpoint | None = None
            self.legacy: LegacyDevice | None = None
        else:
            fw_class = LegacyFirmware if protocol == "legacy" else Firmware
            firmware = fw_class(self.board, nonces, fast=fast)
            self.firmware = firmware
            self.dispatcher = Dispatcher(firmware, on_state_change=self._mark_dirty)
            self.endpoint = DeviceEndpoint(self.dispatcher,
                                           boot_nonce=lambda: firmware.boot_nonce,
                                           name="emulator")
            self.legacy = LegacyDevice(self.dispatcher, name="emulator (legacy)",
                                       refusals=legacy_refusals)
        self._lock = threading.RLock()
        self._dirty = self.state_file is not None and not self.state_file.exists()
        self._last_save = time.monotonic()
        self.closed = False

    @property
    def clock(self):
        return self.board.clock

    # -- bytes in, bytes out ----------------------------------------------------------------
    def feed(self, data: bytes) -> bytes:
        """Bytes received on the UART -> bytes to send back (the clock counts both)."""
        with self._lock:
            if self.backend is not None:       # the firmware MCU times its own UART
                out = self.backend.feed(data)
                self.maybe_save()
                return out
            clock = self.board.clock
            clock.uart(len(data))
            t0 = clock.now_us
            if self.protocol == "legacy":
                assert self.legacy is not None
                out = self.legacy.feed(data)
            else:
                assert self.endpoint is not None
                out = self.endpoint.feed(data)
            self.last_busy_us = clock.now_us - t0
            clock.uart(len(out))
            self.maybe_save()
            return out

    # -- state file -------------------------------------------------------------------------
    def _mark_dirty(self) -> None:
        self._dirty = True

    @property
    def dirty(self) -> bool:
        """Conductances changed since the last save."""
        return self._dirty

    def maybe_save(self, force: bool = False) -> bool:
        """Save the chip if it changed and the save interval has passed (or ``force``)."""
        with self._lock:
            if self.state_file is None or not self._dirty:
                return False
            now = time.monotonic()
            if not force and now - self._last_save < self.save_interval_s:
                return False
            state.save_array(self.array, self.state_file)
            self._dirty = False
            self._last_save = now
            return True

    def save(self) -> bool:
        """Save now if anything changed; True if written."""
        return self.maybe_save(force=True)

    def close(self) -> None:
        """Save pending changes (idempotent)."""
        with self._lock:
            if not self.closed:
                try:
                    self.save()
                except UserError as exc:
                    log.error("%s", exc)
                finally:
                    self.closed = True
                    self._release()
