"""The instruction-set-level MCU: the built firmware ELF executed by a RISC-V CPU emulator.

:class:`IsaMcu` runs ``build/firmware/snan-fw.elf`` in ``unicorn`` (32-bit RISC-V) with the
MIK32 memory map (SPIFI flash at 0x8000_0000, 16 KB RAM at 0x0200_0000) and Python models of
the peripherals the firmware uses, wired to the board's existing SPI device models, crossbar
and virtual clock:

* **time** - virtual time is executed instructions at the MCU clock (32 MHz, one instruction
  per cycle: an assumption, the SCR1 core's CPI and SPIFI wait states are not modelled) plus
  the waits the peripherals impose. Instructions are counted per translated block (a block
  hook); every peripheral access of a block sees the time at the block's end. The board's
  :class:`~snan_hil.firmware_emu.clock.VirtualClock` is advanced to that time before the
  access takes effect, so array energy and pulse widths follow the firmware's own timing.
* **poll loops collapsed** (an emulation shortcut that does not change timing): when the
  firmware polls a flag that becomes true at a known future time (SPI busy, UART TX holding
  register, the next UART RX byte, a timer compare), the clock jumps to that time and the flag
  reads true; a real MCU spins until then and sees it one loop iteration later.
* **UART_0** - RX bytes from :meth:`feed` arrive one per 10 bits at the baud rate; TX bytes
  leave through a holding + shift register at the same rate and are returned by :meth:`feed`.
  When the firmware polls an empty receiver twice in a row with nothing to send, it is idle:
  the CPU stops until the next :meth:`feed`.
* **SPI_0** (master, manual chip select) - bytes shift at MCU clock / divider; a chip-select
  frame is handed to the device model (``SpiDevice.frame``) when its GPIO chip select rises,
  or when the firmware first reads a received byte of it (the ADC: nothing on the board
  changes between that read and the chip-select rising). MISO bytes fill the RX FIFO.
* **GPIO_0** pins 0-7 are the chip selects of DAC0..3, WDAC, ADC, SR_ROW, SR_COL, pin 8 the
  AD5328 LDAC (a falling edge loads every DAC register): this project's wiring assumption.
* **TIMER32_1** free-running counter and channel-0 compare flag; **PM** clock gating (an
  access to a peripheral whose clock is off is counted in :attr:`faults`).
* A CPU fault (unmapped access, illegal instruction) or a run without progress (watchdog)
  reboots the firmware from its reset vector (a new boot nonce: the host sees a board reset);
  :attr:`resets` counts them.

Register facts come from the vendor's SDK headers (see ``docs/firmware.md``).
"""

from __future__ import annotations

import logging
import random
from collections import deque
from collections.abc import Callable

from snan_hil.errors import UserError
from snan_hil.firmware_emu import registers as reg
from snan_hil.firmware_emu.fw_image import FirmwareImage

log = logging.getLogger(__name__)

MCU_HZ = 32_000_000
TICKS_PER_US = MCU_HZ // 1_000_000
FLASH_BASE, RAM_BASE, RAM_SIZE = 0x8000_0000, 0x0200_0000, 16 * 1024

PM_BASE, EPIC_BASE, WDT_BASE = 0x5_0000, 0x5_0400, 0x8_1000
UART0_BASE, TIMER32_1_BASE, SPI0_BASE, GPIO0_BASE = 0x8_1400, 0x8_2800, 0x8_3000, 0x8_4000

PM_APB_P_UART0, PM_APB_P_TIMER32_1, PM_APB_P_SPI0, PM_APB_P_GPIO0 = 1 << 1, 1 << 6, 1 << 8, 1 << 12

CS_PINS = tuple(reg.CS_ROW_DAC) + (reg.CS_WRITE_DAC, reg.CS_ADC, reg.CS_SR_ROW, reg.CS_SR_COL)
LDAC_PIN = 8
RUN_BUDGET = 400_000_000
"""Instructions one :meth:`feed` may execute before the watchdog reboots the MCU."""


class IsaMcu:
    """The firmware ELF on an emulated MIK32, attached to a :class:`Board`."""

    def __init__(self, board, elf=None, *, baud: int = 115200, seed: int = 0,
                 nonce_rng: random.Random | None = None,
                 entropy: Callable[[], int] | None = None):
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
        self._rx_last: float = 0.0      # cycle at which the last host byte has arrived
        self.baud = int(baud)
        self.byte_cycles = MCU_HZ * 10 / self.baud         # UART 8N1: 10 bits a byte
        self._nonce_rng = nonce_rng or random.Random(seed ^ 0x5EED_F00D)
        self.cycles = 0                  # virtual time in MCU cycles
        self._synced = 0                 # cycles already given to the board clock
        self.instructions = 0
        self.resets = 0
        self.faults: dict[str, int] = {}
        self.adc_early_frames = 0
        self._devices = [board.bus.devices[name] for name in CS_PINS]
        self._entropy = entropy
        self._build_cpu()
        self._reset_peripherals()
        self._boot()

    # ------------------------------------------------------------------ CPU
    def _build_cpu(self) -> None:
        uc = self._uc_mod
        cpu = uc.Uc(uc.UC_ARCH_RISCV, uc.UC_MODE_RISCV32)
        img = self.image
        flash_end = max(s.addr + len(s.data) for s in img.segments if s.addr >= FLASH_BASE)
        size = (flash_end - FLASH_BASE + 0xFFFF) & ~0xFFFF
        cpu.mem_map(FLASH_BASE, size, uc.UC_PROT_READ | uc.UC_PROT_EXEC)
        cpu.mem_map(RAM_BASE, RAM_SIZE, uc.UC_PROT_READ | uc.UC_PROT_WRITE)
        for s in img.segments:
            if s.data and FLASH_BASE <= s.addr:
                cpu.mem_write(s.addr, s.data)
        self._flash_size = size
        # instruction index per half-word of .text: RV32C mixes 2- and 4-byte instructions
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
        self._text_base, self._text_end, self._istart = base, base + len(text), starts
        cpu.hook_add(uc.UC_HOOK_BLOCK, self._on_block)
        if self._entropy is not None:
            # test bench (conformance vectors): the board's entropy source returns given
            # values, like a debugger forcing a TRNG; the firmware itself is unchanged
            addr = img.symbols["hal_entropy"][0]
            cpu.hook_add(uc.UC_HOOK_CODE, self._forced_entropy, begin=addr, end=addr)
        # 4 KB pages of the APB buses; each handler serves one peripheral's 1 KB window
        pages = {
            0x5_0000: {0x000: (self._pm_rd, self._pm_wr)},
            0x8_1000: {0x000: (self._nop_rd, self._nop_wr), 0x400: (self._uart_rd, self._uart_wr)},
            0x8_2000: {0x800: (self._tim_rd, self._tim_wr)},
            0x8_3000: {0x000: (self._spi_rd, self._spi_wr)},
            0x8_4000: {0x000: (self._gpio_rd, self._gpio_wr)},
        }
        for page, handlers in pages.items():
            table_rd = [self._unmapped_rd] * 4
            table_wr = [self._unmapped_wr] * 4
            for off, (rd, wr) in handlers.items():
                table_rd[off >> 10], table_wr[off >> 10] = rd, wr
            if page == 0x5_0000:
                table_rd[1], table_wr[1] = self._nop_rd, self._nop_wr      # EPIC

            def rd(cpu, off, size, ud, t=table_rd):
                return t[off >> 10](cpu, off & 0x3FF, size, ud)

            def wr(cpu, off, size, value, ud, t=table_wr):
                t[off >> 10](cpu, off & 0x3FF, size, value, ud)
            cpu.mmio_map(page, 0x1000, rd, None, wr, None)
        self.cpu = cpu

    def _forced_entropy(self, cpu, address, size, user_data) -> None:
        """``hal_entropy()`` returns the next forced value: a0 = value, jump to ra."""
        assert self._entropy is not None
        rc = self._rc
        cpu.reg_write(rc.UC_RISCV_REG_X10, int(self._entropy()) & 0xFFFFFFFF)
        cpu.reg_write(rc.UC_RISCV_REG_PC, cpu.reg_read(rc.UC_RISCV_REG_X1))

    def _on_block(self, cpu, address, size, user_data) -> None:
        off = address - self._text_base
        if 0 <= off and address + size <= self._text_end:
            n = self._istart[(off + size) // 2] - self._istart[off // 2]
        else:
            n = max(1, size // 4)
        self.cycles += n
        self.instructions += n

    def _boot(self) -> None:
        """Power-on: random RAM contents in .noinit (the nonce's entropy), run to idle."""
        sym = self.image.symbols
        start, end = RAM_BASE, RAM_BASE + RAM_SIZE
        noinit = [v for k, v in sym.items() if k.startswith("noinit_entropy")]
        if noinit:
            addr, size = noinit[0]
            self.cpu.mem_write(addr, bytes(self._nonce_rng.getrandbits(8) for _ in range(size)))
        del start, end
        self._restart()

    def _restart(self) -> None:
        rc = self._rc
        for r in range(rc.UC_RISCV_REG_X1, rc.UC_RISCV_REG_X31 + 1):
            self.cpu.reg_write(r, 0)
        self.cpu.reg_write(rc.UC_RISCV_REG_PC, self.image.entry)
        self._reset_peripherals()
        self._run()

    # ------------------------------------------------------------------ host side
    def feed(self, data: bytes) -> bytes:
        """Bytes from the host on the UART -> the bytes the firmware sent meanwhile."""
        t = max(self.cycles, self._rx_last)
        for b in data:
            t += self.byte_cycles
            self._rx.append((t, b))
        self._rx_last = t
        self._tx_out = bytearray()
        self._run()
        return bytes(self._tx_out)

    def _run(self) -> None:
        uc = self._uc_mod
        self._idle = False
        self._prev_flags_read = False
        start = self.instructions
        while not self._idle:
            pc = self.cpu.reg_read(self._rc.UC_RISCV_REG_PC)
            budget = RUN_BUDGET - (self.instructions - start)
            if budget <= 0:
                self._fault("watchdog: no progress within the run budget")
                return
            try:
                self.cpu.emu_start(pc, 0, 0, budget)
            except uc.UcError as exc:
                self._fault(f"CPU fault at pc 0x{pc:08x}: {exc}")
                return
            if not self._idle and self.instructions - start >= RUN_BUDGET:
                self._fault("watchdog: no progress within the run budget")
                return

    def _fault(self, why: str) -> None:
        self.resets += 1
        log.warning("firmware MCU reset (%s)", why)
        self._rx.clear()
        self._restart()

    @property
    def boot_nonce_hint(self) -> None:
        return None

    # ------------------------------------------------------------------ time
    def _sync(self) -> None:
        delta = self.cycles - self._synced
        if delta > 0:
            self.clock.advance(delta / TICKS_PER_US, "mcu")
            self._synced = self.cycles

    def _wait_until(self, cycles: float, category: str = "idle") -> None:
        """A poll loop collapsed: jump to ``cycles`` (never backwards)."""
        self._sync()
        if cycles > self.cycles:
            target = int(-(-cycles // 1))
            self.clock.advance((target - self.cycles) / TICKS_PER_US, category)
            self.cycles = self._synced = target

    # ------------------------------------------------------------------ peripherals
    def _reset_peripherals(self) -> None:
        self._pm_p = 0
        self._pm_m = 0
        self._rx: deque = deque() if not hasattr(self, "_rx") else self._rx
        self._rx_last = getattr(self, "_rx_last", 0)
        self._tx_out = getattr(self, "_tx_out", bytearray())
        self._tx_end = self._tx_hold_free = self.cycles
        self._uart_on = False
        self._tim_start = self.cycles
        self._tim_on = False
        self._ocr = 0
        self._oc_target: int | None = None
        self._oc_flag = False
        self._gpio_out = 0
        self._spi_config = 0
        self._spi_div = 2
        self._byte_end = self.cycles
        self._frame_pin = -1
        self._frame_mosi = bytearray()
        self._frame_start = 0
        self._frame_done = False
        self._spi_rx: deque = deque()
        self._idle = False
        self._prev_flags_read = False

    def _gate(self, bit: int, what: str) -> None:
        if not self._pm_p & bit:
            self.faults[what] = self.faults.get(what, 0) + 1

    def _unmapped_rd(self, cpu, off, size, ud):
        self.faults["access to an unmodelled peripheral"] = \
            self.faults.get("access to an unmodelled peripheral", 0) + 1
        return 0

    def _unmapped_wr(self, cpu, off, size, value, ud):
        self._unmapped_rd(cpu, off, size, ud)

    def _nop_rd(self, cpu, off, size, ud):
        return 0

    def _nop_wr(self, cpu, off, size, value, ud):
        return None

    def _pm_rd(self, cpu, off, size, ud):
        return {0x14: self._pm_m, 0x1C: self._pm_p}.get(off, 0)

    def _pm_wr(self, cpu, off, size, value, ud):
        if off == 0x14:
            self._pm_m |= value
        elif off == 0x18:
            self._pm_m &= ~value
        elif off == 0x1C:
            self._pm_p |= value
        elif off == 0x20:
            self._pm_p &= ~value

    # UART_0 -----------------------------------------------------------
    def _uart_rd(self, cpu, off, size, ud):
        self._gate(PM_APB_P_UART0, "uart clock off")
        if off == 0x1C:                                    # FLAGS
            if self.cycles < self._tx_hold_free:           # waiting to transmit
                self._wait_until(self._tx_hold_free)
            flags = 1 << 7                                 # TXE
            if self.cycles >= self._tx_end:
                flags |= 1 << 6                            # TC
            rx = self._rx
            if rx:
                if rx[0][0] > self.cycles:
                    self._wait_until(rx[0][0], "uart")
                flags |= 1 << 5                            # RXNE
                self._prev_flags_read = False
            else:
                if self._prev_flags_read:                  # idle: nothing to do until feed()
                    self._idle = True
                    cpu.emu_stop()
                self._prev_flags_read = True
            return flags
        self._prev_flags_read = False
        if off == 0x24:                                    # RXDATA
            if self._rx and self._rx[0][0] <= self.cycles:
                return self._rx.popleft()[1]
            return 0
        return 0

    def _uart_wr(self, cpu, off, size, value, ud):
        self._gate(PM_APB_P_UART0, "uart clock off")
        self._prev_flags_read = False
        if off == 0x28:                                    # TXDATA
            start = max(self.cycles, self._tx_end)
            self._tx_hold_free = start
            self._tx_end = start + self.byte_cycles
            self._tx_out.append(value & 0xFF)
        elif off == 0x00:
            self._uart_on = bool(value & 1)

    # TIMER32_1 --------------------------------------------------------
    def _tim_value(self, at: int) -> int:
        return (at - self._tim_start) & 0xFFFF_FFFF

    def _arm(self) -> None:
        delta = (self._ocr - self._tim_value(self.cycles)) & 0xFFFF_FFFF
        self._oc_target = self.cycles + delta

    def _tim_rd(self, cpu, off, size, ud):
        self._gate(PM_APB_P_TIMER32_1, "timer clock off")
        self._prev_flags_read = False
        if off == 0x00:
            return self._tim_value(self.cycles)
        if off == 0x1C:                                    # INT_FLAGS
            if self._oc_target is not None and not self._oc_flag:
                self._wait_until(self._oc_target)
                self._oc_flag = True
            return (1 << 6) if self._oc_flag else 0
        if off == 0x84:
            return self._ocr
        return 0

    def _tim_wr(self, cpu, off, size, value, ud):
        self._gate(PM_APB_P_TIMER32_1, "timer clock off")
        self._prev_flags_read = False
        if off == 0x10:                                    # ENABLE
            if value & 2:
                self._tim_start = self.cycles
            self._tim_on = bool(value & 1)
        elif off == 0x84:                                  # CH0 OCR
            self._ocr = value & 0xFFFF_FFFF
            self._oc_flag = False
            self._arm()
        elif off == 0x18:                                  # INT_CLEAR
            if value & (1 << 6):
                self._oc_flag = False
                self._arm()

    # SPI_0 ------------------------------------------------------------
    def _spi_rd(self, cpu, off, size, ud):
        self._gate(PM_APB_P_SPI0, "spi clock off")
        self._prev_flags_read = False
        if off == 0x04:                                    # INT_STATUS
            if self._byte_end > self.cycles:
                self._wait_until(self._byte_end, "spi")
            st = 1 << 2                                    # TX FIFO not full
            if self._spi_rx or (self._frame_pin >= 0 and not self._frame_done
                                and self._frame_mosi):
                st |= 1 << 4
            return st
        if off == 0x20:                                    # RXDATA
            if self._frame_pin >= 0 and not self._frame_done and self._frame_mosi:
                if self._byte_end > self.cycles:
                    self._wait_until(self._byte_end, "spi")
                self._deliver()
            return self._spi_rx.popleft() if self._spi_rx else 0
        if off == 0x00:
            return self._spi_config
        return 0

    def _spi_wr(self, cpu, off, size, value, ud):
        self._gate(PM_APB_P_SPI0, "spi clock off")
        self._prev_flags_read = False
        if off == 0x1C:                                    # TXDATA
            if self._frame_pin < 0:
                self.faults["spi byte without chip select"] = \
                    self.faults.get("spi byte without chip select", 0) + 1
                return
            if self._frame_done:
                self.faults["spi byte after the frame was read"] = \
                    self.faults.get("spi byte after the frame was read", 0) + 1
                return
            start = max(self.cycles, self._byte_end)
            if not self._frame_mosi:
                self._frame_start = start
            self._byte_end = start + 8 * self._spi_div
            self._frame_mosi.append(value & 0xFF)
        elif off == 0x00:
            self._spi_config = value
            self._spi_div = 2 << ((value >> 3) & 7)
        elif off == 0x14:                                  # ENABLE
            if value & (1 << 3):
                self._spi_rx.clear()

    def _deliver(self) -> None:
        """Hand the open frame to its device now (clock synced first)."""
        self._sync()
        dev = self._devices[self._frame_pin]
        mosi = bytes(self._frame_mosi)
        t_start = self.clock.now_us - (self.cycles - self._frame_start) / TICKS_PER_US
        if dev.ready_at_us() > t_start + 1e-9:
            self.adc_early_frames += 1
        miso = dev.frame(mosi, t_start)
        bus = self.board.bus
        bus.transactions += 1
        bus.bytes += len(mosi)
        if bus.trace is not None:
            from snan_hil.firmware_emu.spi_devices import SpiTransaction
            bus.trace.append(SpiTransaction(t_start, CS_PINS[self._frame_pin], mosi, miso))
        self._spi_rx.extend(miso)
        while len(self._spi_rx) > 8:                       # RX FIFO overflow: oldest dropped
            self._spi_rx.popleft()
        self._frame_done = True

    # GPIO_0 -----------------------------------------------------------
    def _gpio_rd(self, cpu, off, size, ud):
        self._gate(PM_APB_P_GPIO0, "gpio clock off")
        self._prev_flags_read = False
        return self._gpio_out if off in (0x00, 0x10) else 0

    def _gpio_wr(self, cpu, off, size, value, ud):
        self._gate(PM_APB_P_GPIO0, "gpio clock off")
        self._prev_flags_read = False
        if off == 0x00:                                    # SET
            rising = value & ~self._gpio_out
            self._gpio_out |= value
            if self._frame_pin >= 0 and rising & (1 << self._frame_pin):
                if self._byte_end > self.cycles:
                    self.faults["chip select raised while shifting"] = \
                        self.faults.get("chip select raised while shifting", 0) + 1
                if not self._frame_done and self._frame_mosi:
                    self._deliver()
                self._frame_pin = -1
        elif off == 0x04:                                  # CLEAR
            falling = value & self._gpio_out
            self._gpio_out &= ~value
            for pin in range(len(CS_PINS)):
                if falling & (1 << pin):
                    if self._frame_pin >= 0:
                        self.faults["two chip selects low"] = \
                            self.faults.get("two chip selects low", 0) + 1
                    self._frame_pin = pin
                    self._frame_mosi = bytearray()
                    self._frame_done = False
            if falling & (1 << LDAC_PIN):
                self._sync()
                for dac in self.board.row_dacs:
                    dac._load_all()
        elif off == 0x08:
            pass
