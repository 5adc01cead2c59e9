"""One emulated MemriCore board: chip + hardware + firmware + protocol endpoint, as bytes in/out.

:class:`Emulator` is what the servers (pty, TCP, in-process) run: ``feed(received bytes) ->
bytes to send``. It accounts the UART bytes on the virtual clock (10 bits per byte at the
configured baud), speaks the framed protocol (``protocol.device.DeviceEndpoint``) or the old
line protocol (``protocol.legacy_device.LegacyDevice``) around the same firmware dispatcher,
and keeps the chip of its state file durable (:class:`~snan_hil.firmware_emu.durable.ChipStore`):
what a request changed is journaled before its reply is returned, so a kill of the emulator
loses nothing the host has been answered; :meth:`Emulator.close` writes a snapshot that takes in the
journal.

Deterministic boots: the boot nonce and the ADC noise of a start are drawn from streams seeded
by the emulator's seed and the chip's boot number (how often an emulator has started on this
chip, kept with it), so two runs on equal chips see the same nonces and noise — and the same
board times, which depend on the frames' encoded lengths — while a restarted emulator draws a
new nonce (the host sees the restart). Emulators without a state file count boot 1.
"""

from __future__ import annotations

import logging
import random
import threading
import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from snan_hil.common.errors import UserError
from snan_hil.firmware_emu import state
from snan_hil.firmware_emu.board import DEFAULT_ADC_NOISE_LSB, Board
from snan_hil.firmware_emu.config import BoardConfig
from snan_hil.firmware_emu.dispatch import Dispatcher
from snan_hil.firmware_emu.durable import ChipStore, open_store, release_store
from snan_hil.firmware_emu.faults import BoardFaults, UartDropper, apply_faults
from snan_hil.firmware_emu.firmware import Firmware
from snan_hil.firmware_emu.legacy_firmware import LegacyFirmware
from snan_hil.firmware_emu.mcu import FirmwareBackend, check_mcu
from snan_hil.protocol.device import DeviceEndpoint
from snan_hil.protocol.legacy_device import LegacyDevice

log = logging.getLogger(__name__)

PROTOCOLS = ("framed", "legacy")


def boot_seed(seed: int, boot: int, stream: str) -> int:
    """Seed (63 bits) of the random ``stream`` ("adc", "nonce") of boot number ``boot`` of an
    emulator seeded ``seed``: ``SeedSequence([seed, boot, crc32(stream)])``."""
    ss = np.random.SeedSequence([int(seed) & ((1 << 64) - 1), int(boot),
                                 zlib.crc32(stream.encode())])
    return int(ss.generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))
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

    ``state_file``: chip loaded from it (snapshot + journal) if it exists, else created; kept
    durable there (None: never saved). ``seed``: seed of a freshly created chip and, with the
    boot number, of the board's ADC noise and boot nonces (default 0). ``sync``: journal fsync
    policy, "interval" (at most every ``save_interval_s`` seconds, when idle and at close) or
    "request" (before every reply that changed the chip); see :mod:`.journal`.
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
    ``faults``: hardware faults of this board (:mod:`.faults`; tests and demos), in the SPI
    chips, the front end and the UART, met alike by both MCUs.
    ``boot_nonces``: test bench only (the conformance vectors): the boot nonces the board draws,
    in order (at power-on, then at each RESET), instead of random ones; both MCUs.
    ``device``: a fitted device model (:class:`~snan_hil.firmware_emu.state.TwinDevice`) whose
    twin is the chip (:mod:`snan_hil.crossbar_model.device_twin`): a new chip is made of it,
    a state file that holds another chip is refused (UserError).
    """

    def __init__(self, state_file: str | Path | None = None, seed: int | None = None, *,
                 protocol: str = "framed", baud: int = 115200,
                 config: BoardConfig | None = None, array=None,
                 adc_noise_lsb: float = DEFAULT_ADC_NOISE_LSB, save_interval_s: float = 1.0,
                 fast: bool = True, mcu: str = "model", elf=None, sync: str = "interval",
                 boot_nonces: Sequence[int] | None = None,
                 legacy_refusals: bool = False, wall_scale: float | None = None,
                 faults: BoardFaults | None = None, device: state.TwinDevice | None = None):
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
        self.store: ChipStore | None = None
        if array is not None and state_file is not None:
            raise ValueError("give a state file (the chip is loaded from it) or an array, "
                             "not both")
        try:
            if array is None:
                if self.state_file is not None:
                    self.store = open_store(self.state_file, self.seed, sync=sync,
                                            sync_interval_s=save_interval_s, device=device)
                    array = self.store.array
                else:
                    array = state.new_array(self.seed, device=device)
        except BaseException:
            self._release()
            raise
        self.array = array
        self.boot_number = self.store.boot_number if self.store is not None else 1
        self._store_released = False
        """Starts of an emulator on this chip, this one included (1 without a state file)."""
        self.board = Board(array, config, seed=boot_seed(self.seed, self.boot_number, "adc"),
                           baud=baud, adc_noise_lsb=adc_noise_lsb)
        self.faults = faults or BoardFaults()
        apply_faults(self.board, self.faults)
        if self.faults.analog:
            fast = False                  # the fast paths assume healthy hardware
        self._uart: UartDropper | None = None
        if self.faults.uart_drop:
            self._uart = UartDropper(self.faults.uart_drop,
                                     boot_seed(self.seed, self.boot_number, "uart"))
        nonce_rng = random.Random(boot_seed(self.seed, self.boot_number, "nonce"))
        self.backend = None
        nonces = NonceSequence(boot_nonces) if boot_nonces is not None else None
        if mcu == "firmware":
            try:
                self.backend = FirmwareBackend(self.board, baud=baud, seed=self.seed, elf=elf,
                                               on_state_change=self._mark_dirty,
                                               nonce_rng=nonce_rng,
                                               entropy=None if nonces is None else nonces.next,
                                               chip_serial=self.chip_serial)
                if self.faults.analog:
                    self.backend.mcu.s.adc_fast = 0     # every ADC frame through the devices
            except BaseException:
                self._close_store()
                self._release()
                raise
            self.firmware: Firmware | None = None
            self.dispatcher: Dispatcher | None = None
            self.endpoint: DeviceEndpoint | None = None
            self.legacy: LegacyDevice | None = None
        else:
            fw_class = LegacyFirmware if protocol == "legacy" else Firmware
            firmware = fw_class(self.board, nonces if nonces is not None else nonce_rng,
                                fast=fast)
            firmware.chip_id = self.chip_serial
            self.firmware = firmware
            self.dispatcher = Dispatcher(firmware, on_state_change=self._mark_dirty)
            self.endpoint = DeviceEndpoint(self.dispatcher,
                                           boot_nonce=lambda: firmware.boot_nonce,
                                           name="emulator")
            self.legacy = LegacyDevice(self.dispatcher, name="emulator (legacy)",
                                       refusals=legacy_refusals)
        self._lock = threading.RLock()
        self._pending: list[tuple[float, int]] = []
        """Posted host bytes not yet taken by the board: (arrival us, byte)."""
        self._host_us = 0.0
        """Board time at which the host has the last reply it read (:meth:`pump`)."""
        self._line_us = 0.0
        """Board time at which the last posted byte arrives."""
        self._feeding = False
        self._dirty = False
        self.closed = False

    @property
    def clock(self):
        return self.board.clock

    # -- bytes in, bytes out ----------------------------------------------------------------
    def feed(self, data: bytes) -> bytes:
        """Bytes received on the UART -> bytes to send back (the clock counts both). A closed
        emulator answers nothing and runs nothing (its journal is released: a change would be
        lost, and the firmware MCU's CPU must not run while the process exits)."""
        with self._lock:
            if getattr(self, "closed", False):
                log.warning("bytes for a closed emulator dropped (%d)", len(data))
                return b""
            self._feeding = True
            if self._uart is not None:
                data = self._uart(data)
            try:
                if self.backend is not None:       # the firmware MCU times its own UART
                    out = self.backend.feed(data)
                else:
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
                    self._host_us = self._line_us = clock.now_us
            finally:
                self._feeding = False
            self._record()                     # journaled before the reply leaves
            return self._uart(out) if self._uart is not None else out

    # -- a pipelining host: bytes on the line while the board works --------------------------
    def post(self, data: bytes) -> None:
        """Bytes a host writes while a request of its may still run (it keeps two outstanding,
        docs/protocol.md section 4): they go on the line after its earlier bytes and no earlier
        than the end of the last reply it read, at 10 bits a byte, and the board takes them
        while it works (the C firmware from its UART into its receive ring). :meth:`pump`
        runs the board on them. Framed protocol only."""
        with self._lock:
            if self._uart is not None:           # a faulty line loses bytes here too
                data = self._uart(bytes(data))
            if self.backend is not None:
                self.backend.post(bytes(data))
                return
            clock = self.board.clock
            t = max(self._host_us, self._line_us)
            byte_us = clock.uart_us(1)
            for b in bytes(data):
                t += byte_us
                self._pending.append((t, b))
            self._line_us = t

    def pump(self) -> bytes:
        """Run the board until it has sent one frame (or has nothing more to do) on the bytes
        :meth:`post` put on the line; the bytes it sent. The board starts a request once its
        last byte has arrived and it has finished the one before (and sent that one's reply:
        the MCU sends while it waits for nothing else); the host has a reply when its last byte
        has left the board. Both MCUs time it the same way."""
        with self._lock:
            if getattr(self, "closed", False):
                return b""
            self._feeding = True
            try:
                if self.backend is not None:
                    out = self.backend.pump()
                else:
                    out = self._pump_model()
            finally:
                self._feeding = False
            self._record()
            return self._uart(out) if self._uart is not None else out

    def _pump_model(self) -> bytes:
        assert self.endpoint is not None
        clock = self.board.clock
        out = b""
        while self._pending and not out:
            end = next((i for i, (_, b) in enumerate(self._pending) if b == 0),
                       len(self._pending) - 1)
            chunk = self._pending[:end + 1]
            del self._pending[:end + 1]
            clock.wait_until(chunk[-1][0], "uart")          # its last byte has arrived
            t0 = clock.now_us
            out = self.endpoint.feed(bytes(b for _, b in chunk))
            self.last_busy_us = clock.now_us - t0
            clock.uart(len(out))                              # the MCU sends the reply
        if out:
            if clock.now_us < self._host_us:                  # the board was reset meanwhile
                self._line_us = clock.now_us
            self._host_us = clock.now_us
        return out

    # -- state file -------------------------------------------------------------------------
    def _record(self) -> None:
        if self.store is not None:
            self.store.record()

    def _mark_dirty(self) -> None:
        """A request changed conductances: journaled at the end of :meth:`feed`, or now when
        the firmware is driven directly (tests)."""
        self._dirty = True
        if not self._feeding:
            self._record()

    @property
    def dirty(self) -> bool:
        """Conductances changed since the last snapshot (they are journaled already)."""
        return self._dirty

    @property
    def chip_serial(self) -> str | None:
        """The serial of the chip of the state file (None without one)."""
        return self.store.serial if self.store is not None else None

    def maybe_save(self, force: bool = False) -> bool:
        """Idle: sync pending journal records; ``force``: write a snapshot. True if a
        snapshot was written."""
        with self._lock:
            if self.store is None:
                return False
            if force:
                self.store.compact()
                self._dirty = False
                return True
            self.store.idle()
            return False

    def save(self) -> bool:
        """Write a snapshot now (the journal already holds every change)."""
        return self.maybe_save(force=True)

    def _close_store(self) -> None:
        if self.store is not None and not self._store_released:
            self._store_released = True
            release_store(self.store)

    def kill(self) -> None:
        """Stop as ``kill -9`` would (test benches): no snapshot, the journal left as it is (it
        holds every answered request), the state file's lock released; an emulator started on
        the file next replays the journal. Idempotent; :meth:`close` after it does nothing."""
        with self._lock:
            if not self.closed:
                try:
                    if self.store is not None and not self._store_released:
                        self._store_released = True
                        release_store(self.store, clean=False)
                finally:
                    self.closed = True
                    self._release()

    def close(self) -> None:
        """Snapshot and release the state file (idempotent)."""
        with self._lock:
            if not self.closed:
                try:
                    self._close_store()
                except (UserError, OSError) as exc:
                    log.error("%s", exc)
                finally:
                    self.closed = True
                    self._release()
