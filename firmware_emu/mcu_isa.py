"""The instruction-set-level MCU: the built firmware ELF executed by a RISC-V CPU emulator.

:class:`IsaMcu` runs ``build/firmware/snan-fw.elf`` in ``unicorn`` (32-bit RISC-V) with the
MIK32 memory map (SPIFI flash at 0x8000_0000, 16 KB RAM at 0x0200_0000) and models of the
peripherals the firmware uses (power manager, pad configuration, watchdog, UART_0, TIMER32_1,
SPI_0, GPIO), wired to the board's existing SPI device models, crossbar and virtual clock.

Two peripheral cores implement the same models on one state (:mod:`.mik32_state`):

* ``native`` (default when built: ``make firmware``) - C called by unicorn directly
  (``native/mik32_periph.c``, loaded by :mod:`.mik32_native`): no Python call per register
  access or per translated block;
* ``reference`` - readable Python (:mod:`.mik32_periph`), one Python call per access and block.

``$SNAN_HIL_MCU_CORE`` (``native`` / ``reference``) or ``core=`` chooses; both give the same
replies, SPI traffic, cycle counts and chip state (``tests/firmware/test_firmware_native.py``).

* **time** - virtual time is executed instructions at the MCU clock (32 MHz, one instruction
  per cycle: an assumption, the SCR1 core's CPI and SPIFI wait states are not modelled) plus
  the waits the peripherals impose (see :mod:`.mik32_periph` for the collapsed poll loops). It
  is handed to the board's :class:`~snan_hil.firmware_emu.clock.VirtualClock` before anything on
  the board changes (:meth:`IsaMcu.flush_clock`), so array energy and pulse widths follow the
  firmware's own timing.
* **events** - an SPI frame handed to its chip, the LDAC pin, and (native core) ADC samples
  drawn ahead are handled here (:meth:`IsaMcu.event`).
* **ADC frames without Python** (native core; an emulation shortcut that changes neither timing
  nor results): in a column circuit the C core computes each conversion itself
  (:meth:`IsaMcu._adc_prepare` hands it the circuit, :meth:`AnalogFrontEnd.column_kernel`;
  numpy's own normal generator draws from the array's and the front end's random streams);
  in other circuits the conversions of a whole reading (1 dummy + averages) are drawn ahead in
  one vectorised call when the circuit is switched. Before anything else on the board moves,
  the frames are accounted (device counters, bus trace, busy time) and draws not used are
  returned to the random streams (:meth:`IsaMcu._adc_settle`): the codes and the noise
  streams are those of per-frame sampling.
* **resets** - a CPU fault (unmapped access, illegal instruction: a trap, whose vector restarts
  the firmware) or the MIK32 watchdog (armed by the firmware) reboots the firmware from its
  reset vector (a new boot nonce: the host sees a board reset); :attr:`resets` and
  :attr:`reset_causes` count them. An emulator guard (not MCU behaviour) also reboots after
  :data:`RUN_BUDGET` instructions without going idle, in case a firmware never arms its
  watchdog.
* **boot** - a firmware that does not reach its UART loop (polling the UART with nothing
  received) within :data:`BOOT_BUDGET` instructions of power-on, or that is reset
  :data:`BOOT_RESETS` times in a row without getting there, is refused with one
  :class:`UserError` line naming the ELF (an emulator guard: it would never answer).
* **identity** - the EEPROM (8 KB at 0x0100_0000, read-only here) holds the board's identity
  record with the chip serial (:mod:`.chip_identity`), which the firmware reads at boot and
  reports in INFO; erased (0xFF) without a serial.

Register facts come from the vendor's SDK headers (see ``docs/firmware.md``).
"""

from __future__ import annotations

import ctypes
import logging
import os
import random
from collections.abc import Callable
from typing import Any

from snan_hil.common.errors import UserError
from snan_hil.firmware_emu import chip_identity, mik32_native
from snan_hil.firmware_emu import mik32_state as ms
from snan_hil.firmware_emu import registers as reg
from snan_hil.firmware_emu.fw_image import FirmwareImage
from snan_hil.firmware_emu.isa_coverage import return_addresses
from snan_hil.firmware_emu.mik32_periph import MCU_HZ, ReferenceCore
from snan_hil.firmware_emu.spi_devices import SpiTransaction

log = logging.getLogger(__name__)

TICKS_PER_US = MCU_HZ // 1_000_000
FLASH_BASE, RAM_BASE, RAM_SIZE = 0x8000_0000, 0x0200_0000, 16 * 1024

CS_PINS = tuple(reg.CS_ROW_DAC) + (reg.CS_WRITE_DAC, reg.CS_ADC, reg.CS_SR_ROW, reg.CS_SR_COL)
"""GPIO_1 pin k selects CS_PINS[k] (the board wiring this project assumes)."""
RUN_BUDGET = 400_000_000
"""Emulator guard: instructions one :meth:`feed` may execute without going idle."""
BOOT_BUDGET = 4_000_000
"""Emulator guard: instructions from power-on to the UART loop (125 ms at 32 MHz; the firmware
needs ~15,000)."""
BOOT_RESETS = 3
"""Emulator guard: resets in a row, none reaching the UART loop, before the firmware is refused."""
CORE_ENV = "SNAN_HIL_MCU_CORE"
TIMING_ENV = "SNAN_HIL_MCU_TIMING"
TIMINGS = ("collapsed", "spin")
_NO_CYCLES = [0, 0, 0, 0]
_READ_CIRCUITS = frozenset(("cell", "cell_sum", "column"))
_K_FIRST = ms.McuState.k_rows.offset                  # the column kernel's parameter fields
_K_END = ms.McuState.k_full.offset + ms.McuState.k_full.size
CORES = ("native", "reference")


def choose_timing(timing: str | None) -> str:
    """``poll_timing`` or ``$SNAN_HIL_MCU_TIMING``; default ``collapsed`` (a poll loop ends at its
    first poll, time moved to the cycle its flag becomes true); ``spin``: the loops poll until
    then, as on the MCU (:data:`.mik32_state.SPIN_SLACK`; same replies and chip, slower)."""
    want = timing or os.environ.get(TIMING_ENV) or "collapsed"
    if want not in TIMINGS:
        raise UserError(f"unknown MCU peripheral timing {want!r} (${TIMING_ENV}); use "
                        f"{' or '.join(TIMINGS)}")
    return want


def choose_core(core: str | None) -> str:
    """``core`` or ``$SNAN_HIL_MCU_CORE``; ``None``/``auto``: native when it is built."""
    want = core or os.environ.get(CORE_ENV) or "auto"
    if want not in CORES + ("auto",):
        raise UserError(f"unknown MCU core {want!r} (${CORE_ENV}); use native or reference")
    if want == "auto":
        return "native" if mik32_native.load() is not None else "reference"
    return want


_TEXT_TABLES: dict[tuple, tuple[list[int], list[int]]] = {}


def _text_tables(img: FirmwareImage) -> tuple[list[int], list[int]]:
    """What a boot needs from ``.text``, computed once per code in a process (a power cycle of
    the differential tester boots the same ELF again): the instruction index per half-word
    (RV32C mixes 2- and 4-byte instructions) and the return addresses of ``run_lean``'s
    calls. The lists are shared: not to be changed."""
    key = (img.text, img.symbols.get("run_lean"))
    tables = _TEXT_TABLES.get(key)
    if tables is None:
        base, text = img.text
        starts = [0] * (len(text) // 2 + 2)
        o = count = 0
        while o < len(text):
            starts[o // 2] = count
            length = 4 if (text[o] & 3) == 3 else 2
            if length == 4 and o + 2 < len(text):
                starts[o // 2 + 1] = count + 1
            count += 1
            o += length
        starts[len(text) // 2] = count
        starts[-1] = count
        returns = return_addresses(img, "run_lean") if "run_lean" in img.symbols else []
        if len(_TEXT_TABLES) >= 16:                  # mutation runs: many ELFs in a process
            _TEXT_TABLES.clear()
        tables = _TEXT_TABLES[key] = (starts, returns)
    return tables


class IsaMcu:
    """The firmware ELF on an emulated MIK32, attached to a :class:`Board`."""

    def __init__(self, board, elf=None, *, baud: int = 115200, seed: int = 0,
                 nonce_rng: random.Random | None = None,
                 entropy: Callable[[], int] | None = None, core: str | None = None,
                 chip_serial: str | None = None, poll_timing: str | None = None):
        try:
            import unicorn as uc
            from unicorn import riscv_const as rc
        except ImportError:
            raise UserError("--mcu firmware needs the 'unicorn' package: pip install -e "
                            "'.[firmware]'") from None
        self._uc_mod, self._rc = uc, rc
        self.image = elf if isinstance(elf, FirmwareImage) else FirmwareImage.load(elf)
        self.board = board
        self.clock = board.clock
        self.baud = int(baud)
        self._nonce_rng = nonce_rng or random.Random(seed ^ 0x5EED_F00D)
        self._entropy = entropy
        self._eeprom = chip_identity.eeprom_image(chip_serial)
        self._last_reset = ""
        self._booting = 0               # resets in a row since the UART loop was last reached
        self._devices = [board.bus.devices[name] for name in CS_PINS]
        self._adc = board.bus.devices[reg.CS_ADC]
        timing = board.config.timing
        self._adc_batch = int(timing.adc_dummy + board.config.adc_averages)
        adc_cycle = MCU_HZ / timing.adc_rate_sps
        if adc_cycle != int(adc_cycle):
            raise ValueError(f"ADC cycle of {adc_cycle} MCU cycles is not an integer")
        self.s = s = ms.McuState()
        s.byte_cycles = MCU_HZ * timing.uart_bits_per_byte / self.baud
        s.adc_pin = CS_PINS.index(reg.CS_ADC)
        s.adc_cycle = int(adc_cycle)
        self.poll_timing = choose_timing(poll_timing)
        s.poll_spin = 1 if self.poll_timing == "spin" else 0
        self._window_ctx: Any = None    # the keyed noise of the window running
        self._window_key = 0            # the key of the last window started
        self._rx_last = 0.0             # cycle at which the last host byte arrives
        self.host_cycle = 0.0
        """Cycle at which the host has the last reply it read (:meth:`pump`)."""
        self._tx = bytearray()
        self._event_exc: BaseException | None = None
        self._adc_drawn: list[int] = []
        self._adc_cp = None
        self._kernel_refs: tuple = ()
        self._kernels: dict[tuple, tuple[bytes, tuple]] = {}
        self._kernel_array = None
        self.resets = 0
        self.reset_causes: dict[str, int] = {}
        self.kernel_samples = 0         # ADC samples computed by the native column kernel
        self.core_name = choose_core(core)
        self.core: ReferenceCore | mik32_native.NativeCore
        if self.core_name == "native":
            lib = mik32_native.load()
            if lib is None:
                raise UserError(f"the native MCU core is not built (or stale): run 'make "
                                f"firmware', or set {CORE_ENV}=reference")
            self.core = mik32_native.NativeCore(self.native_event, s, lib)
            s.adc_fast = 1 if board.front_end.noise_checkpoint() is not None else 0
        else:
            self.core = ReferenceCore(self.event, s)
        self._build_cpu()
        self._boot()

    # ------------------------------------------------------------------ CPU
    def _build_cpu(self) -> None:
        uc = self._uc_mod
        cpu = uc.Uc(uc.UC_ARCH_RISCV, uc.UC_MODE_RISCV32)
        img = self.image
        flash_end = max(seg.addr + len(seg.data) for seg in img.segments
                        if seg.addr >= FLASH_BASE)
        size = (flash_end - FLASH_BASE + 0xFFFF) & ~0xFFFF
        cpu.mem_map(FLASH_BASE, size, uc.UC_PROT_READ | uc.UC_PROT_EXEC)
        cpu.mem_map(RAM_BASE, RAM_SIZE, uc.UC_PROT_READ | uc.UC_PROT_WRITE)
        cpu.mem_map(chip_identity.EEPROM_BASE, chip_identity.EEPROM_SIZE, uc.UC_PROT_READ)
        cpu.mem_write(chip_identity.EEPROM_BASE, self._eeprom)
        for seg in img.segments:
            if seg.data and FLASH_BASE <= seg.addr:
                cpu.mem_write(seg.addr, seg.data)
        base, text = img.text
        starts, lean_returns = _text_tables(img)
        self.s.text_base, self.s.text_end = base, base + len(text)
        # the idle loop's poll: the firmware's hal_uart_getc (its receive ring drained by the
        # out-of-line hal_uart_service); two empty polls there with no other access between
        # are the main loop waiting for the host (the emulator then skips to the next byte)
        lo, size = img.symbols.get("hal_uart_getc", (0, 0))
        self.s.idle_lo, self.s.idle_hi = (lo, lo + size) if size else (0, 0)
        self.cpu = cpu
        self.core.attach(cpu, starts)
        if self._entropy is not None:
            # test bench (conformance vectors): the board's entropy source returns given
            # values, like a debugger forcing a TRNG; the firmware itself is unchanged
            addr = img.symbols["hal_entropy"][0]
            cpu.hook_add(uc.UC_HOOK_CODE, self._forced_entropy, begin=addr, end=addr)
        if "window_run" in img.symbols and "run_lean" in img.symbols:
            # a lean decision window's noise keyed by the window (window_noise), as the Python
            # MCU: the key taken where window_run starts, the noise keyed inside run_lean, left
            # where run_lean's callers go on. Every hook is added here, before any code runs:
            # unicorn compiles code hooks into its translated blocks, so a hook added later to
            # code already translated (the caller's code after the call also runs after
            # run_standard) never fires (unicorn-engine/unicorn issue 2200)
            addr = img.symbols["window_run"][0]
            cpu.hook_add(uc.UC_HOOK_CODE, self._window_start, begin=addr, end=addr)
            addr = img.symbols["run_lean"][0]
            cpu.hook_add(uc.UC_HOOK_CODE, self._window_enter, begin=addr, end=addr)
            returns = lean_returns
            if not returns:
                raise UserError(f"firmware ELF {img.path}: run_lean is never called directly "
                                "(inlined?): its keyed window noise cannot be scoped; rebuild "
                                "it with 'make firmware'")
            for ret in returns:
                cpu.hook_add(uc.UC_HOOK_CODE, self._window_leave, begin=ret, end=ret)

    def _window_start(self, cpu, address, size, user_data) -> None:
        """``window_run(p, ...)`` starts: the window's key from its payload."""
        from snan_hil.protocol.messages import DecisionFlag, DecisionParams
        p = cpu.reg_read(self._rc.UC_RISCV_REG_X10)
        flags = bytes(cpu.mem_read(p, 1))[0]
        pos = 1
        if flags & DecisionFlag.PARAMS:
            pos += DecisionParams.SIZE + (1 if flags & DecisionFlag.READ_PLAN else 0)
        self._window_key = int.from_bytes(bytes(cpu.mem_read(p + pos, 8)), "little")

    def _window_enter(self, cpu, address, size, user_data) -> None:
        """``run_lean`` starts (the window's reads): its noise keyed by the window's key; the
        hooks at its callers' return addresses (:meth:`_window_leave`) leave it."""
        from snan_hil.firmware_emu import window_noise
        self._window_close()            # none open: a window left run_lean before this one
        self._settle_board()
        ctx = window_noise.keyed(self.board, self._window_key)
        ctx.__enter__()
        self._window_ctx = ctx

    def _window_leave(self, cpu, address, size, user_data) -> None:
        """A caller of ``run_lean`` goes on (also after ``run_standard`` at a shared return
        address: then no window is keyed and nothing happens)."""
        self._window_close()

    def _window_close(self) -> None:
        """The keyed noise of the window running, if any, left: the chip's running streams
        back where they were (also when the MCU resets inside ``run_lean``)."""
        ctx, self._window_ctx = self._window_ctx, None
        if ctx is not None:
            self._settle_board()
            ctx.__exit__(None, None, None)

    def _forced_entropy(self, cpu, address, size, user_data) -> None:
        """``hal_entropy()`` returns the next forced value: a0 = value, jump to ra."""
        assert self._entropy is not None
        rc = self._rc
        cpu.reg_write(rc.UC_RISCV_REG_X10, int(self._entropy()) & 0xFFFFFFFF)
        cpu.reg_write(rc.UC_RISCV_REG_PC, cpu.reg_read(rc.UC_RISCV_REG_X1))

    def _boot(self) -> None:
        """Power-on: random RAM contents in .noinit (the nonce's entropy), run to idle."""
        noinit = [v for k, v in self.image.symbols.items() if k.startswith("noinit_entropy")]
        if noinit:
            addr, size = noinit[0]
            self.cpu.mem_write(addr, bytes(self._nonce_rng.getrandbits(8) for _ in range(size)))
        self._restart()

    def _restart(self) -> None:
        self._booting += 1
        if self._booting > BOOT_RESETS:
            raise UserError(f"firmware ELF {self.image.path} never reached its UART loop "
                            f"({BOOT_RESETS} resets in a row, the last: {self._last_reset}); "
                            "check the firmware, or rebuild it with 'make firmware'")
        rc = self._rc
        for r in range(rc.UC_RISCV_REG_X1, rc.UC_RISCV_REG_X31 + 1):
            self.cpu.reg_write(r, 0)
        self.cpu.reg_write(rc.UC_RISCV_REG_PC, self.image.entry)
        self._reset_peripherals()
        self._run()

    def _reset_peripherals(self) -> None:
        """MCU reset: every peripheral register to its reset value (time, the UART line, the
        watchdog's reset flag and the fault counters carry on)."""
        s = self.s
        now = float(s.cycles)
        s.pm_m = s.pm_p = s.wdt_clk_mux = 0
        for k in range(3):
            s.pad_cfg[k] = s.pad_ds[k] = s.pad_pupd[k] = 0
            s.gpio_out[k] = s.gpio_dir[k] = 0
        s.tx_end = s.tx_hold_free = now
        s.uart_on = s.prev_flags_read = s.rx_told = s.rx_told_timer = 0
        s.tim_start, s.tim_on, s.ocr, s.oc_armed, s.oc_flag, s.oc_target = s.cycles, 0, 0, 0, 0, 0
        s.ch0_cntrl = s.tim_hold = s.spi_on = 0
        s.spi_config, s.spi_div, s.byte_end = 0, 2, s.cycles
        s.frame_pin, s.frame_done, s.mosi_len, s.frame_start = -1, 0, 0, 0
        s.fifo_head = s.fifo_count = 0
        s.wdt_con = s.wdt_unlocked = s.wdt_enabled = 0
        s.wdt_deadline = 0.0
        s.adc_n = s.adc_used = s.adc_mode = s.k_on = 0

    # ------------------------------------------------------------------ host side
    def feed(self, data: bytes) -> bytes:
        """Bytes from the host on the UART -> the bytes the firmware sent meanwhile."""
        s = self.s
        self._tx = bytearray()
        s.k_on = 0                      # the board may have been changed since (a new array)
        view = memoryview(bytes(data))
        while True:
            t = max(float(s.cycles), self._rx_last)
            room = min(len(view), ms.RX_CAP - s.rx_count)
            mask = ms.RX_CAP - 1
            tail = (s.rx_head + s.rx_count) & mask
            for b in view[:room]:
                t += s.byte_cycles
                s.rx_t[tail] = t
                s.rx_b[tail] = b
                tail = (tail + 1) & mask
            s.rx_count += room
            if room:
                self._rx_last = t
            view = view[room:]
            self._run()
            if not view:
                break
        self._tx_drain()
        self.host_cycle = max(self.host_cycle, float(s.cycles), s.tx_end)
        return bytes(self._tx)

    def post(self, data: bytes) -> None:
        """Bytes the host writes with a request outstanding (a pipelining host): they go on the
        line after the host's last write and no earlier than the end of the last reply it read
        (:attr:`host_cycle`), and wait in the UART's queue for :meth:`pump`."""
        s = self.s
        # the host wrote them once it had the reply; the firmware may have run a little past
        # that reply's end before the emulator paused it (at its next UART poll): they arrive
        # no earlier than that point (a shortcut of at most ~0.1 ms, never in the MCU's past)
        t = max(self.host_cycle, self._rx_last, float(s.cycles))
        mask = ms.RX_CAP - 1
        for b in bytes(data):
            if s.rx_count >= ms.RX_CAP:
                raise RuntimeError("more host bytes in flight than the emulated line holds")
            t += s.byte_cycles
            tail = (s.rx_head + s.rx_count) & mask
            s.rx_t[tail] = t
            s.rx_b[tail] = b
            s.rx_count += 1
        self._rx_last = t

    def pump(self) -> bytes:
        """Run the firmware until it has sent one frame (its delimiter) or is idle; the bytes it
        sent. The host has them when the last one has left the UART: :attr:`host_cycle`."""
        s = self.s
        self._tx = bytearray()
        s.k_on = 0
        s.stop_on_frame = 1
        try:
            self._run()
        finally:
            s.stop_on_frame = s.frame_sent = 0
        self._tx_drain()
        if self._tx:
            self.host_cycle = max(self.host_cycle, s.tx_end)
        return bytes(self._tx)

    def _tx_drain(self) -> None:
        s = self.s
        if s.tx_len:
            self._tx += bytes(s.tx_out[:s.tx_len])
            s.tx_len = 0

    def _run(self) -> None:
        uc = self._uc_mod
        s = self.s
        start = s.instructions
        booting = self._booting > 0
        while True:
            pc = self.cpu.reg_read(self._rc.UC_RISCV_REG_PC)
            s.stop_reason = ms.STOP_NONE
            s.budget_end = start + (BOOT_BUDGET if booting else RUN_BUDGET)
            try:
                self.cpu.emu_start(pc, 0)
            except uc.UcError as exc:
                self._settle_board()
                self._reset(f"CPU fault at pc 0x{pc:08x}: {exc}", "trap")
                return
            finally:
                if self._event_exc is not None:
                    exc2, self._event_exc = self._event_exc, None
                    raise exc2
            reason = s.stop_reason
            if reason == ms.STOP_FRAME:
                self._settle_board()
                return
            if reason == ms.STOP_IDLE:
                self._booting = 0
                self._settle_board()
                return
            if reason == ms.STOP_WATCHDOG:
                self._settle_board()
                s.wdt_rst_flag = 1
                self._reset("watchdog expired", "watchdog")
                return
            if reason == ms.STOP_BUDGET:
                self._settle_board()
                if booting:
                    raise UserError(f"firmware ELF {self.image.path} did not reach its UART "
                                    f"loop within {BOOT_BUDGET:,} instructions of boot "
                                    f"({BOOT_BUDGET / MCU_HZ:g} s at {MCU_HZ / 1e6:g} MHz); "
                                    "check the firmware, or rebuild it with 'make firmware'")
                self._reset("emulator guard: no progress within the run budget", "run budget")
                return

    def _settle_board(self) -> None:
        """Bring the board up to date: pending ADC frames accounted, the clock advanced."""
        if self.s.adc_mode:
            self._adc_settle()
        self.flush_clock()

    def _reset(self, why: str, cause: str) -> None:
        self._window_close()            # a reset inside run_lean: it never returns
        self._last_reset = why
        self.resets += 1
        self.reset_causes[cause] = self.reset_causes.get(cause, 0) + 1
        log.warning("firmware MCU reset (%s)", why)
        self.s.rx_count = 0
        self._restart()

    def write_identity_record(self, record: bytes) -> None:
        """Test bench: write ``record`` (:data:`.chip_identity.RECORD_SIZE` bytes) where the
        board keeps its identity record in the EEPROM, as a lab's EEPROM programmer would; the
        firmware reads it at its next boot (:meth:`press_reset`)."""
        if len(record) != chip_identity.RECORD_SIZE:
            raise ValueError(f"an identity record is {chip_identity.RECORD_SIZE} bytes, not "
                             f"{len(record)}")
        image = bytearray(self._eeprom)
        image[-chip_identity.RECORD_SIZE:] = record
        self._eeprom = bytes(image)
        self.cpu.mem_write(chip_identity.RECORD_ADDR, bytes(record))

    def press_reset(self) -> None:
        """Test bench: the MCU's reset pin - the firmware reboots (new boot nonce, counters 0;
        the chips on the board keep their state)."""
        self._settle_board()
        self._reset("reset pin", "reset pin")

    # ------------------------------------------------------------------ counters
    @property
    def cycles(self) -> int:
        return int(self.s.cycles)

    @property
    def instructions(self) -> int:
        return int(self.s.instructions)

    @property
    def faults(self) -> dict[str, int]:
        """What the peripheral models saw the firmware do wrong (empty for a correct one)."""
        return {name: int(self.s.faults[i]) for i, name in enumerate(ms.FAULT_NAMES)
                if self.s.faults[i]}

    @property
    def adc_early_frames(self) -> int:
        """ADC frames that started within the previous conversion cycle."""
        return int(self.s.adc_early)

    @property
    def spin_polls(self) -> int:
        """Polls of a flag answered "not yet" (spin timing; 0 in the collapsed timing)."""
        return int(self.s.spin_polls)

    # ------------------------------------------------------------------ time
    def flush_clock(self) -> None:
        """Hand the cycles counted since the last flush to the board clock, per category."""
        acc = self.s.acc
        pending = acc[:]
        if pending != _NO_CYCLES:
            ctypes.memset(ctypes.addressof(acc), 0, 32)
            self.clock.advance_parts([(n / TICKS_PER_US, name)
                                      for n, name in zip(pending, ms.CATEGORY_NAMES) if n])

    def _t_us(self, cycle: int) -> float:
        """Board time (us) of an MCU cycle in the past. The same float whenever it is computed
        between two clock flushes (the integer ``pending - (cycles - cycle)`` does not change
        as time goes on), so ADC frames may be timed late without a flush of their own."""
        s = self.s
        pending = s.acc[0] + s.acc[1] + s.acc[2] + s.acc[3]
        return self.clock.now_us + (pending - (s.cycles - cycle)) / TICKS_PER_US

    # ------------------------------------------------------------------ events
    def event(self, kind: int) -> int:
        """An event from a peripheral core (see :mod:`.mik32_state`)."""
        if kind == ms.EV_DELIVER:
            self.deliver()
        elif kind == ms.EV_ADC_PREFETCH:
            self._adc_prefetch()
        elif kind == ms.EV_LDAC:
            self._settle_board()
            for dac in self.board.row_dacs:
                dac._load_all()
        elif kind == ms.EV_TX_FULL:
            self._tx_drain()
        elif kind == ms.EV_ADC_SETTLE:
            self._adc_settle()
        return 0

    def native_event(self, kind: int) -> int:
        """:meth:`event` called from C: an exception stops the CPU and is raised after it."""
        try:
            return self.event(kind)
        except BaseException as exc:             # re-raised by _run once unicorn returns
            self._event_exc = exc
            self.s.stop_reason = ms.STOP_EVENT_ERROR
            self.core.stop_cpu()
            return 0

    def deliver(self) -> None:
        """Hand the open frame to its chip now. The board is brought up to date first; an ADC
        frame changes nothing outside the ADC (no power, no listener), so it does not advance
        the clock: the flush points, hence the energy sums, are the same in both cores."""
        s = self.s
        pin = s.frame_pin
        is_adc = pin == s.adc_pin
        if s.adc_mode:
            self._adc_settle()
        if not is_adc:
            self.flush_clock()
        mosi = ctypes.string_at(ctypes.addressof(s.mosi), s.mosi_len)
        start = s.frame_start
        t_start = self._t_us(start)
        if is_adc:
            if s.adc_have_last and start < s.adc_last_start + s.adc_cycle:
                s.adc_early += 1
            s.adc_last_start = start
            s.adc_have_last = 1
        miso = self._devices[pin].frame(mosi, t_start)
        if is_adc:
            s.adc_result = self._adc.result       # keep the C core's copy of the ADC's result
        bus = self.board.bus
        bus.transactions += 1
        bus.bytes += len(mosi)
        if bus.trace is not None:
            bus.trace.append(SpiTransaction(t_start, CS_PINS[pin], mosi, miso))
        if miso:                                     # RX FIFO overflow: the oldest is lost
            head, count, fifo, cap = s.fifo_head, s.fifo_count, s.fifo, ms.FIFO_CAP
            for b in miso:
                if count == cap:
                    head = (head + 1) % cap
                    count -= 1
                fifo[(head + count) % cap] = b
                count += 1
            s.fifo_head, s.fifo_count = head, count
        s.frame_done = 1
        if s.adc_fast and not is_adc:
            self._adc_prepare()

    # ADC frames without Python (native core) --------------------------------------------
    def _adc_prepare(self) -> None:
        """After a change on the board: a column circuit is handed to the C kernel (its
        samples are then computed natively, from the same random streams); another circuit
        that is read gets one reading's samples drawn ahead."""
        s = self.s
        fe = self.board.front_end
        c = fe.circuit
        if c.kind == "column":
            array = fe.array
            if array is not self._kernel_array:               # another chip: start afresh
                self._kernels.clear()
                self._kernel_array = array
            revision = getattr(array, "revision", None)      # None: no caching possible
            key = (revision, fe.adc_noise_lsb, c.col, c.sum_path, fe.row_volts().tobytes())
            entry = self._kernels.get(key) if revision is not None else None
            if entry is None:
                entry = self._kernel_entry(fe.column_kernel())
                if revision is not None:
                    if len(self._kernels) >= 4096:
                        self._kernels.clear()
                    self._kernels[key] = entry
            blob, refs = entry
            if blob:
                ctypes.memmove(ctypes.addressof(s) + _K_FIRST, blob, len(blob))
                self._kernel_refs = refs                  # the generators stay alive
                s.adc_result = self._adc.result           # what the next frame shifts out
                s.k_on = 1
                return
        s.k_on = 0
        if c.kind in _READ_CIRCUITS:
            self._adc_draw()             # a reading will most likely follow: draw it now

    @staticmethod
    def _kernel_entry(k: dict | None) -> tuple[bytes, tuple]:
        """The kernel's parameter fields (k_rows .. k_full) as raw bytes of the state."""
        if k is None or len(k["g"]) > ms.KERNEL_ROWS:
            return b"", ()
        t = ms.McuState()
        n = len(k["g"])
        t.k_rows = n
        t.k_g[:n] = k["g"]
        t.k_v[:n] = k["v"]
        t.k_r_mac, t.k_rel, t.k_abs = k["r_mac"], k["rel"], k["abs"]
        t.k_read_noisy = 1 if k["read_noisy"] else 0
        t.k_scale, t.k_lsb, t.k_vref, t.k_sigma = k["scale"], k["lsb"], k["vref"], k["sigma"]
        t.k_adc_noisy = 1 if k["adc_noisy"] else 0
        t.k_full = k["full"]
        t.k_gen_read = _bitgen(k["read_generator"])
        t.k_gen_adc = _bitgen(k["adc_generator"])
        raw = ctypes.string_at(ctypes.addressof(t) + _K_FIRST, _K_END - _K_FIRST)
        return raw, (k["read_generator"], k["adc_generator"])

    def _adc_prefetch(self) -> None:
        """The C core needs samples (none drawn, or all used): account, draw a reading."""
        self._adc_settle()
        self._adc_draw()

    def _adc_draw(self) -> None:
        """Draw the conversions of one reading for the C core (0 samples: per-frame path).
        Drawn when the front end switches to a circuit that is read; returned unused by
        :meth:`_adc_settle` if something else changes first."""
        s = self.s
        fe = self.board.front_end
        cp = fe.noise_checkpoint()
        if cp is None:
            s.adc_fast = 0
            return
        codes = fe.sample_codes(self._adc_batch)
        self._adc_cp, self._adc_drawn = cp, codes
        s.adc_result = self._adc.result
        n = len(codes)
        s.adc_codes[:n] = codes                  # sample_codes clips to 0..2^14 - 1
        s.adc_used = 0
        s.adc_n = n
        s.adc_mode = ms.ADC_AHEAD

    def _adc_settle(self) -> None:
        """Account the ADC frames the C core ran (samples drawn ahead: return unused draws;
        kernel: add its samples to the front end's counters)."""
        s = self.s
        mode, n, k = s.adc_mode, s.adc_n, s.adc_used
        if mode == ms.ADC_NONE:
            return
        s.adc_mode = ms.ADC_NONE
        s.adc_n = s.adc_used = 0
        if mode == ms.ADC_KERNEL:
            self.kernel_samples += k
            codes = s.adc_codes[:k]
            fe = self.board.front_end
            fe.samples += k
            fe.saturated_samples += s.k_saturated
            s.k_saturated = 0
        else:
            codes = self._adc_drawn
        if mode == ms.ADC_AHEAD and k < n:
            fe = self.board.front_end
            fe.noise_restore(self._adc_cp)
            if k and fe.sample_codes(k) != codes[:k]:
                raise RuntimeError("ADC samples drawn again differ from those drawn ahead")
        if not k:
            return
        # frame times as _t_us gives them: now + (pending - (cycles - start)) / ticks
        acc = s.acc
        off = acc[0] + acc[1] + acc[2] + acc[3] - s.cycles
        now = self.clock.now_us
        bus = self.board.bus
        bus.transactions += k
        bus.bytes += 2 * k
        if bus.trace is None:
            self._adc.account_frames([now + (off + s.adc_starts[k - 1]) / TICKS_PER_US],
                                     codes[:k])
            return
        starts = [now + (off + c) / TICKS_PER_US for c in s.adc_starts[:k]]
        misos = self._adc.account_frames(starts, codes[:k])
        zero = bytes(2)
        bus.trace.extend(SpiTransaction(t, reg.CS_ADC, zero, miso)
                         for t, miso in zip(starts, misos))


def _bitgen(generator) -> int:
    """Address of a numpy Generator's ``bitgen_t`` (BitGenerator.ctypes, numpy's C API)."""
    address = generator.bit_generator.ctypes.bit_generator.value
    if not address:
        raise RuntimeError("numpy generator without a bitgen_t")
    return int(address)
