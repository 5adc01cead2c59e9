"""The MIK32 peripheral models of the instruction-level MCU - the readable reference core.

Each register access of the firmware is one call of :meth:`ReferenceCore.apbm_read` /
``apbm_write`` (the APB_M page at 0x5_0000: power manager, EPIC, pad configuration) or
``apbp_read`` / ``apbp_write`` (0x8_1000..0x8_4FFF: watchdog, UART_0, TIMER32_1, SPI_0, GPIO),
and each translated block one call of :meth:`ReferenceCore.block`. The state lives in a
:class:`~snan_hil.firmware_emu.mik32_state.McuState`; ``native/mik32_periph.c`` implements the
very same models in C on the same structure (the fast core;
``tests/firmware/test_firmware_native.py``
runs both and compares them). What touches the board (an SPI frame handed to its chip, the DAC
LDAC pin) is an *event* handled by :class:`~snan_hil.firmware_emu.mcu_isa.IsaMcu`.

Models (register facts: docs/firmware.md; ASSUMPTION marks what the vendor's headers do not say):

* **time** - ``cycles`` = executed instructions (one cycle each, ASSUMPTION) plus waits. A block
  adds all its instructions when it starts, so every access inside a block sees the block's end.
* **poll loops collapsed** (emulation shortcut, no change of timing): reading a flag that
  becomes true at a known cycle (UART TX holding register free, next RX byte, SPI shift done,
  timer compare) moves ``cycles`` to that cycle (never backwards); a real MCU spins until then.
  **Spin timing** (``poll_spin``, ``IsaMcu(timing="spin")``): such a flag reads "not yet" while
  more than ``SPIN_SLACK`` cycles remain, so the firmware's wait loops run their iterations as
  on the MCU (SPI_0 INT_STATUS then shows ACTIVE, and TX_NOT_FULL from the bytes still queued);
  the last ``SPIN_SLACK`` cycles are collapsed as above.
  The time is filed under a category (``acc``: mcu, spi, idle, uart) and handed to the board's
  virtual clock in one step before anything on the board changes (:meth:`IsaMcu.flush_clock`).
* **UART_0** - RX bytes arrive at ``rx_t`` (10 bits a byte); FLAGS.RXNE when the first has
  arrived; TXDATA goes through a holding and a shift register at the baud rate. Two empty FLAGS
  polls in a row with nothing else in between (watchdog kicks aside): the firmware is idle and
  the CPU stops until the host sends more (``STOP_IDLE``).
* **TIMER32_1** - free-running up-counter at the MCU clock; channel 0 compare flag.
* **SPI_0** (master, manual chip select) - bytes shift at MCU clock / divider; a frame goes to
  its chip when the chip select rises, or when the firmware first reads a received byte of it.
  RX FIFO of 8 bytes (ASSUMPTION).
* **GPIO_1** pins 0-7 are the chip selects DAC0..3, WDAC, ADC, SR_ROW, SR_COL and pin 8 the
  AD5328 LDAC (this project's wiring, ASSUMPTION); GPIO_0 and GPIO_2 keep their latches only.
* **PM** clock gating, WDT clock source; **PAD_CONFIG** port modes (UART_0 and SPI_0 pins must
  be in serial mode, chip selects GPIO outputs: a fault counter otherwise).
* **WDT** - key-protected (unlock 0x1E, start 0x71, stop 0xE8); counts from PRELOAD to 4096 at
  its clock / prescaler, then resets the MCU (``STOP_WATCHDOG``; STA.RST_FLAG set).
"""

from __future__ import annotations

import math

from snan_hil.firmware_emu import mik32_state as ms
from snan_hil.protocol.board import MCU_HZ

WDT_SLOW_HZ = 32_768
WDT_PRESCALE = (1, 2, 4, 16, 64, 256, 1024, 4096)

# APB_M page 0x5_0000 (offsets in the page)
PM_OFF, EPIC_OFF, TIMER32_0_OFF, PAD_OFF = 0x000, 0x400, 0x800, 0xC00
# APB_P window 0x8_1000..0x8_4FFF (offsets from 0x8_1000)
WDT_OFF, UART0_OFF, TIMER32_1_OFF, SPI0_OFF = 0x0000, 0x0400, 0x1800, 0x2000
GPIO_OFF = (0x3000, 0x3400, 0x3800)
APBM_BASE, APBP_BASE, APBP_SIZE = 0x5_0000, 0x8_1000, 0x4000

# clock gates (mik32_memory_map.h)
APB_M_PAD_CONFIG = 1 << 3
APB_P_WDT, APB_P_UART0, APB_P_TIMER32_1, APB_P_SPI0 = 1 << 0, 1 << 1, 1 << 6, 1 << 8
APB_P_GPIO = (1 << 12, 1 << 13, 1 << 14)

UART_ON = 0xD              # CONTROL1: UE (bit 0), RE (2), TE (3)
TIM_CH_COMPARE_ON = 0xA0   # CH_CNTRL: ENABLE (bit 7), MODE (bits 4-5) = 2, compare (ASSUMPTION:
#                            the SDK's TIMER32_CH_CNTRL values, docs/firmware.md)
PAD_SERIAL = 0b01          # MIK32V2: 00 GPIO, 01 first peripheral function (UART_0, SPI_0)
UART0_PINS = (5, 6)        # port 0: UART0_RXD, UART0_TXD
SPI0_PINS = (0, 1, 2)      # port 0: SPI0_MISO, SPI0_MOSI, SPI0_CLK
CS_PORT = 1                # chip selects and LDAC on GPIO_1 (ASSUMPTION: board wiring)
N_CS = 8
LDAC_PIN = 8


def wdt_timeout_cycles(con: int, clk_mux: int) -> float:
    """MCU cycles from a watchdog start to its reset: (4096 - PRELOAD) ticks of the watchdog
    clock / prescaler (ASSUMPTION: the counter runs from PRELOAD to its 12-bit overflow; the
    vendor HAL loads 4095 - ticks)."""
    ticks = 4096 - (con & 0xFFF)
    prescale = WDT_PRESCALE[(con >> 12) & 7]
    hz = MCU_HZ if (clk_mux & 3) < 2 else WDT_SLOW_HZ
    return ticks * prescale * MCU_HZ / hz


class ReferenceCore:
    """Python implementation of the peripheral models on an :class:`McuState`."""

    name = "reference"

    def __init__(self, event: ms.EventHandler, state: ms.McuState):
        self.event = event
        self.s = state
        self._istart: list[int] = []

    # ------------------------------------------------------------------ set-up
    def attach(self, cpu, istart: list[int]) -> None:
        """Hook the CPU: the block counter and the two APB windows."""
        import unicorn as uc     # the firmware extra
        self.cpu = cpu
        self._istart = istart
        cpu.hook_add(uc.UC_HOOK_BLOCK, self.block)
        cpu.mmio_map(APBM_BASE, 0x1000, self.apbm_read, None, self.apbm_write, None)
        cpu.mmio_map(APBP_BASE, APBP_SIZE, self.apbp_read, None, self.apbp_write, None)

    def stop(self, reason: int) -> None:
        if not self.s.stop_reason:
            self.s.stop_reason = reason
        self.cpu.emu_stop()

    def stop_cpu(self) -> None:
        self.cpu.emu_stop()

    def fault(self, sym: str) -> None:
        self.s.faults[ms.F[sym]] += 1

    def _apb_clocked(self, clock_bit: int, sym: str) -> ms.McuState:
        """The state, after counting fault ``sym`` if the peripheral's APB_P clock (bit
        ``clock_bit`` of ``pm_p``) is off; the access goes on (the C core's ``apb_clocked``)."""
        s = self.s
        if not s.pm_p & clock_bit:
            self.fault(sym)
        return s

    def _apb_access(self, clock_bit: int, sym: str) -> ms.McuState:
        """:meth:`_apb_clocked`, and the access ends a run of empty UART FLAGS polls."""
        s = self._apb_clocked(clock_bit, sym)
        s.prev_flags_read = 0
        s.uart_poll = 0
        return s

    # ------------------------------------------------------------------ time
    def block(self, cpu, address: int, size: int, user_data) -> None:
        s = self.s
        s.block_pc = address
        off = address - s.text_base
        if 0 <= off and address + size <= s.text_end:
            n = self._istart[(off + size) >> 1] - self._istart[off >> 1]
        else:
            n = max(1, size >> 2)
        s.cycles += n
        s.instructions += n
        s.acc[ms.CAT_MCU] += n
        if s.instructions >= s.budget_end:
            self.stop(ms.STOP_BUDGET)
        elif s.wdt_enabled and s.cycles >= s.wdt_deadline:
            self.stop(ms.STOP_WATCHDOG)

    def spin(self, target: float) -> bool:
        """Spin timing: the flag that becomes true at ``target`` reads "not yet" (counted)."""
        s = self.s
        if s.poll_spin and target - s.cycles > ms.SPIN_SLACK:
            s.spin_polls += 1
            return True
        return False

    def wait_until(self, target: float, cat: int) -> None:
        """A poll loop collapsed: jump to ``target`` (never backwards); the watchdog fires
        first if its deadline comes earlier."""
        s = self.s
        if target <= s.cycles:
            return
        t = math.ceil(target)
        if s.wdt_enabled and t > s.wdt_deadline:
            t = max(s.cycles, math.ceil(s.wdt_deadline))
            self.stop(ms.STOP_WATCHDOG)
        s.acc[cat] += t - s.cycles
        s.cycles = t

    # ------------------------------------------------------------------ APB_M page
    def apbm_read(self, cpu, off: int, size: int, ud) -> int:
        s = self.s
        if off < EPIC_OFF:                                 # PM
            return {0x14: s.pm_m, 0x1C: s.pm_p, 0x28: s.wdt_clk_mux}.get(off, 0)
        if off < TIMER32_0_OFF:                            # EPIC: no interrupts used
            return 0
        if off >= PAD_OFF:
            if not s.pm_m & APB_M_PAD_CONFIG:
                self.fault("PAD_CLOCK")
            r = off - PAD_OFF
            port, reg = divmod(r, 0x0C)
            if port < 3 and reg in (0, 4, 8):
                return (s.pad_cfg, s.pad_ds, s.pad_pupd)[reg // 4][port]
            return 0
        self.fault("UNMODELLED")
        return 0

    def apbm_write(self, cpu, off: int, size: int, value: int, ud) -> None:
        s = self.s
        if off < EPIC_OFF:
            if off == 0x14:
                s.pm_m |= value
            elif off == 0x18:
                s.pm_m &= ~value & 0xFFFFFFFF
            elif off == 0x1C:
                s.pm_p |= value
            elif off == 0x20:
                s.pm_p &= ~value & 0xFFFFFFFF
            elif off == 0x28:
                s.wdt_clk_mux = value & 3
            return
        if off < TIMER32_0_OFF:
            return
        if off >= PAD_OFF:
            if not s.pm_m & APB_M_PAD_CONFIG:
                self.fault("PAD_CLOCK")
            r = off - PAD_OFF
            port, reg = divmod(r, 0x0C)
            if port < 3 and reg in (0, 4, 8):
                (s.pad_cfg, s.pad_ds, s.pad_pupd)[reg // 4][port] = value & 0xFFFFFFFF
            return
        self.fault("UNMODELLED")

    # ------------------------------------------------------------------ APB_P window
    def apbp_read(self, cpu, off: int, size: int, ud) -> int:
        if off < UART0_OFF:
            return self.wdt_read(off)
        if off < UART0_OFF + 0x400:
            return self.uart_read(off - UART0_OFF)
        if TIMER32_1_OFF <= off < TIMER32_1_OFF + 0x400:
            return self.timer_read(off - TIMER32_1_OFF)
        if SPI0_OFF <= off < SPI0_OFF + 0x400:
            return self.spi_read(off - SPI0_OFF)
        for port, base in enumerate(GPIO_OFF):
            if base <= off < base + 0x400:
                return self.gpio_read(port, off - base)
        self.fault("UNMODELLED")
        return 0

    def apbp_write(self, cpu, off: int, size: int, value: int, ud) -> None:
        value &= 0xFFFFFFFF
        if off < UART0_OFF:
            self.wdt_write(off, value)
        elif off < UART0_OFF + 0x400:
            self.uart_write(off - UART0_OFF, value)
        elif TIMER32_1_OFF <= off < TIMER32_1_OFF + 0x400:
            self.timer_write(off - TIMER32_1_OFF, value)
        elif SPI0_OFF <= off < SPI0_OFF + 0x400:
            self.spi_write(off - SPI0_OFF, value)
        else:
            for port, base in enumerate(GPIO_OFF):
                if base <= off < base + 0x400:
                    self.gpio_write(port, off - base, value)
                    return
            self.fault("UNMODELLED")

    # WDT --------------------------------------------------------------
    def wdt_read(self, off: int) -> int:
        s = self._apb_clocked(APB_P_WDT, "WDT_CLOCK")
        if off == 0x84:
            return s.wdt_con
        if off == 0x9C:                                    # STA
            return (1 if s.wdt_enabled else 0) | (0x100 if s.wdt_rst_flag else 0)
        return 0

    def wdt_write(self, off: int, value: int) -> None:
        s = self._apb_clocked(APB_P_WDT, "WDT_CLOCK")
        if off == 0x9C:                                    # KEY (byte)
            key = value & 0xFF
            if key == 0x1E:
                s.wdt_unlocked = 1
                return
            if not s.wdt_unlocked:
                self.fault("WDT_LOCKED")
                return
            s.wdt_unlocked = 0
            if key == 0x71:                                # start / reload
                s.wdt_enabled = 1
                s.wdt_kicks += 1
                s.wdt_deadline = s.cycles + wdt_timeout_cycles(s.wdt_con, s.wdt_clk_mux)
            elif key == 0xE8:
                s.wdt_enabled = 0
        elif off == 0x84:                                  # CON
            if not s.wdt_unlocked:
                self.fault("WDT_LOCKED")
                return
            s.wdt_unlocked = 0
            s.wdt_con = value & 0x7FFF

    # UART_0 -----------------------------------------------------------
    def _uart_pads(self) -> None:
        cfg = self.s.pad_cfg[0]
        if any((cfg >> (2 * p)) & 3 != PAD_SERIAL for p in UART0_PINS):
            self.fault("UART_PADS")

    def uart_read(self, off: int) -> int:
        s = self._apb_clocked(APB_P_UART0, "UART_CLOCK")
        s.uart_poll = 1
        if off == 0x1C:                                    # FLAGS
            if s.frame_sent:                               # pause after a frame (pump); the
                s.frame_sent = 0                           # read runs again on resuming
                self.stop(ms.STOP_FRAME)
                return 0
            self._wait_transmit()
            flags = 0
            if s.cycles >= s.tx_hold_free:
                flags |= 1 << 7                            # TXE
            if s.cycles >= s.tx_end:
                flags |= 1 << 6                            # TC
            return flags | self._poll_receive()
        s.prev_flags_read = 0
        if off == 0x24:                                    # RXDATA
            return self._read_byte()
        if off == 0x00:
            return 0xD if s.uart_on else 0
        return 0

    def _wait_transmit(self) -> None:
        """A FLAGS poll waiting to transmit: until the holding register is free, or a host
        byte arrives (the poll loop sees it at its next poll); a byte that arrived and was not
        yet reported: at once."""
        s = self.s
        if s.cycles >= s.tx_hold_free:
            return
        t = s.tx_hold_free
        if s.rx_count:
            if s.rx_t[s.rx_head] > s.cycles:
                t = min(t, s.rx_t[s.rx_head])
            elif s.rx_told != s.rx_head + 1:
                t = s.cycles
        if not self.spin(t):
            self.wait_until(t, ms.CAT_IDLE)

    def _poll_receive(self) -> int:
        """RXNE of a FLAGS poll (bit 5), and the idle loop: two empty polls in hal_uart_getc
        with no other access between wait for the next host byte (or stop the CPU)."""
        s = self.s
        if s.rx_count and s.rx_t[s.rx_head] <= s.cycles:
            s.rx_told = s.rx_head + 1                      # RXNE: a byte has arrived
            s.prev_flags_read = 0
            return 1 << 5
        if s.idle_hi and not s.idle_lo <= s.block_pc < s.idle_hi:
            s.prev_flags_read = 0                          # a poll while working
        elif s.prev_flags_read:                            # the idle loop polled twice
            if s.rx_count:
                self.wait_until(s.rx_t[s.rx_head], ms.CAT_UART)
                s.prev_flags_read = 0
                return 1 << 5
            self.stop(ms.STOP_IDLE)                        # idle until the host sends more
        else:
            s.prev_flags_read = 1
        return 0

    def _read_byte(self) -> int:
        """RXDATA: the oldest host byte that has arrived (0 if none); a fault if the next one
        had arrived too (the receive register was overwritten on the chip)."""
        s = self.s
        self._uart_pads()
        if not (s.rx_count and s.rx_t[s.rx_head] <= s.cycles):
            return 0
        if s.rx_count > 1 and s.rx_t[(s.rx_head + 1) & (ms.RX_CAP - 1)] <= s.cycles:
            self.fault("UART_OVERRUN")                     # the next byte came meanwhile
        b = s.rx_b[s.rx_head]
        s.rx_head = (s.rx_head + 1) & (ms.RX_CAP - 1)
        s.rx_count -= 1
        s.rx_told = s.rx_told_timer = 0
        return b

    def uart_write(self, off: int, value: int) -> None:
        s = self._apb_access(APB_P_UART0, "UART_CLOCK")
        if off == 0x28:                                    # TXDATA
            self._uart_pads()
            if not s.uart_on:                              # disabled: nothing goes out
                self.fault("UART_OFF")
                return
            start = max(float(s.cycles), s.tx_end)
            s.tx_hold_free = start
            s.tx_end = start + s.byte_cycles
            if s.tx_len >= ms.TX_CAP:
                self.event(ms.EV_TX_FULL)
            s.tx_out[s.tx_len] = value & 0xFF
            s.tx_len += 1
            if s.stop_on_frame and not value & 0xFF:       # a frame sent: the host may answer
                s.frame_sent = 1
        elif off == 0x00:
            s.uart_on = 1 if value & UART_ON == UART_ON else 0

    # TIMER32_1 --------------------------------------------------------
    def _value(self) -> int:
        """VALUE: counting from ``tim_start`` while enabled, else held."""
        s = self.s
        return (s.cycles - s.tim_start) & 0xFFFFFFFF if s.tim_on else s.tim_hold

    def _arm(self) -> None:
        s = self.s
        value = self._value()
        s.oc_target = s.cycles + ((s.ocr - value) & 0xFFFFFFFF)
        s.oc_armed = 1

    def timer_read(self, off: int) -> int:
        polled = self.s.uart_poll
        s = self._apb_access(APB_P_TIMER32_1, "TIMER_CLOCK")
        if off == 0x00:                                    # VALUE
            return self._value()
        if off == 0x1C:                                    # INT_FLAGS
            if s.oc_armed and not s.oc_flag and s.tim_on and \
                    s.ch0_cntrl & 0xB0 == TIM_CH_COMPARE_ON:
                if self.spin(s.oc_target):
                    return 0
                if s.rx_count and self._host_byte_first(polled):
                    return 0
                self.wait_until(s.oc_target, ms.CAT_IDLE)
                s.oc_flag = 1
            return (1 << 6) if s.oc_flag else 0
        if off == 0x84:
            return s.ocr
        return 0

    def _host_byte_first(self, polled: int) -> bool:
        """A compare poll that is not yet due, with a host byte queued: "not yet" once for that
        byte, at its arrival (a loop that serves the UART between its polls reads it in time,
        as on the MCU; one that does not polls again and jumps to its compare). A byte that
        arrived before this poll and was not yet answered for: "not yet" at once - jumping to
        the compare here lost the next byte (seed 14 of the fast differential tester, a long
        pulse's served wait, tests/firmware/test_poll_timing.py)."""
        s = self.s
        t = math.ceil(s.rx_t[s.rx_head])
        slack = 0 if polled else ms.SPIN_SLACK
        if s.cycles < t:
            if t + slack >= s.oc_target:
                return False
            self.wait_until(t, ms.CAT_IDLE)
        elif s.rx_told_timer == s.rx_head + 1 or s.cycles + slack >= s.oc_target:
            return False
        s.rx_told_timer = s.rx_head + 1
        return True

    def timer_write(self, off: int, value: int) -> None:
        s = self._apb_access(APB_P_TIMER32_1, "TIMER_CLOCK")
        if off == 0x10:                                    # ENABLE: CLR (bit 1), EN (bit 0)
            now = 0 if value & 2 else self._value()
            s.tim_on = value & 1
            if s.tim_on:
                s.tim_start = s.cycles - now
            else:
                s.tim_hold = now
            if s.oc_armed:
                self._arm()
        elif off == 0x84:                                  # CH0 OCR (OC0 stays as it is:
            s.ocr = value                                  # INT_CLEAR clears it)
            self._arm()
        elif off == 0x80:                                  # CH0 CNTRL
            s.ch0_cntrl = value
        elif off == 0x18:                                  # INT_CLEAR
            if value & (1 << 6):
                s.oc_flag = 0
                self._arm()

    # SPI_0 ------------------------------------------------------------
    def _frame_pending(self) -> bool:
        s = self.s
        return s.frame_pin >= 0 and not s.frame_done and s.mosi_len > 0

    def spi_read(self, off: int) -> int:
        s = self._apb_access(APB_P_SPI0, "SPI_CLOCK")
        if off == 0x04:                                    # INT_STATUS
            if s.byte_end > s.cycles:
                if self.spin(s.byte_end):                  # shifting: ACTIVE; TX FIFO full
                    per_byte = 8 * s.spi_div               # when FIFO_CAP bytes wait behind
                    queued = (s.byte_end - s.cycles + per_byte - 1) // per_byte - 1
                    st = (1 << 15) | ((1 << 2) if queued < ms.FIFO_CAP else 0)
                    return st | ((1 << 4) if s.fifo_count or self._frame_pending() else 0)
                self.wait_until(s.byte_end, ms.CAT_SPI)
            st = 1 << 2                                    # TX FIFO not full
            if s.fifo_count or self._frame_pending():
                st |= 1 << 4                               # RX FIFO not empty
            return st
        if off == 0x20:                                    # RXDATA
            if self._frame_pending():
                if s.byte_end > s.cycles:
                    self.wait_until(s.byte_end, ms.CAT_SPI)
                self.deliver()
            if s.fifo_count:
                b = s.fifo[s.fifo_head]
                s.fifo_head = (s.fifo_head + 1) % ms.FIFO_CAP
                s.fifo_count -= 1
                return b
            return 0
        if off == 0x00:
            return s.spi_config
        return 0

    def spi_write(self, off: int, value: int) -> None:
        s = self._apb_access(APB_P_SPI0, "SPI_CLOCK")
        if off == 0x1C:                                    # TXDATA
            cfg = s.pad_cfg[0]
            if any((cfg >> (2 * p)) & 3 != PAD_SERIAL for p in SPI0_PINS):
                self.fault("SPI_PADS")
            if not s.spi_on:                               # disabled: nothing shifts
                self.fault("SPI_OFF")
                return
            if s.frame_pin < 0:
                self.fault("SPI_NO_CS")
                return
            if s.frame_done:
                self.fault("SPI_AFTER_READ")
                return
            if s.mosi_len >= ms.MOSI_CAP:
                self.fault("FRAME_TOO_LONG")
                return
            start = max(s.cycles, s.byte_end)
            if not s.mosi_len:
                s.frame_start = start
            s.byte_end = start + 8 * s.spi_div
            s.mosi[s.mosi_len] = value & 0xFF
            s.mosi_len += 1
        elif off == 0x00:
            s.spi_config = value
            s.spi_div = 2 << ((value >> 3) & 7)
        elif off == 0x14:                                  # ENABLE
            s.spi_on = value & 1
            if value & (1 << 3):
                s.fifo_count = 0

    def deliver(self) -> None:
        """The open frame goes to its chip (the board side: :meth:`IsaMcu.deliver`)."""
        self.event(ms.EV_DELIVER)

    # GPIO -------------------------------------------------------------
    def gpio_read(self, port: int, off: int) -> int:
        s = self._apb_access(APB_P_GPIO[port], "GPIO_CLOCK")
        if off in (0x00, 0x10):
            return s.gpio_out[port]
        if off in (0x08, 0x0C):
            return s.gpio_dir[port]
        return 0

    def gpio_write(self, port: int, off: int, value: int) -> None:
        s = self._apb_access(APB_P_GPIO[port], "GPIO_CLOCK")
        old = s.gpio_out[port]
        if off == 0x00:                                    # SET
            new = old | value
        elif off == 0x04:                                  # CLEAR
            new = old & ~value & 0xFFFFFFFF
        elif off == 0x10:                                  # OUTPUT
            new = value
        else:
            if off == 0x08:
                s.gpio_dir[port] |= value
            elif off == 0x0C:
                s.gpio_dir[port] &= ~value & 0xFFFFFFFF
            return
        s.gpio_out[port] = new
        if port == CS_PORT:
            self.pins_changed(old, new)

    def pins_changed(self, old: int, new: int) -> None:
        """Chip-select and LDAC edges on GPIO_1."""
        s = self.s
        rising, falling = new & ~old, old & ~new
        if s.frame_pin >= 0 and rising & (1 << s.frame_pin):
            if s.byte_end > s.cycles:
                self.fault("CS_WHILE_SHIFTING")
            if not s.frame_done and s.mosi_len:
                self.deliver()
            s.frame_pin = -1
        cs_falling = falling & ((1 << N_CS) - 1)
        if cs_falling:
            cfg = s.pad_cfg[CS_PORT]
            for pin in range(N_CS):
                if cs_falling & (1 << pin):
                    if (cfg >> (2 * pin)) & 3 != 0 or not s.gpio_dir[CS_PORT] & (1 << pin):
                        self.fault("CS_PAD")
                    if s.frame_pin >= 0:
                        self.fault("TWO_CS")
                    s.frame_pin = pin
                    s.mosi_len = 0
                    s.frame_done = 0
        if falling & (1 << LDAC_PIN):
            self.event(ms.EV_LDAC)
