"""State of the emulated MIK32's peripherals: one memory layout for both peripheral cores.

The instruction-level MCU (:mod:`.mcu_isa`) keeps the whole state of its peripheral models -
virtual time, UART, TIMER32_1, SPI_0, GPIO, power manager, pad configuration, watchdog and the
ADC sample buffer - in one :class:`McuState` (a ``ctypes`` structure). Two cores operate on it
and must agree bit for bit (``tests/firmware/test_firmware_native.py``):

* the **reference** core, :mod:`.mik32_periph` - readable Python, one Python call per register
  access and per translated block;
* the **native** core, ``firmware_emu/native/mik32_periph.c`` - the same models in C, called by
  unicorn directly (:mod:`.mik32_native` builds and loads it).

:data:`FIELDS` is the single definition of the layout: :class:`McuState` is made from it here
and ``native/build.py`` writes the C header (``mcu_state.h``) from it, so the two cannot drift
(the native library also reports its ``sizeof`` and a layout hash, checked at load).
"""

from __future__ import annotations

import ctypes
import hashlib
from collections.abc import Callable
from typing import Any

# capacities (power of two where used as a ring)
RX_CAP = 1 << 14          #: UART receive queue (bytes in flight from the host)
TX_CAP = 1 << 14          #: UART bytes sent and not yet collected by the host side
MOSI_CAP = 256            #: bytes of one chip-select frame
FIFO_CAP = 8              #: SPI RX FIFO depth (ASSUMPTION, docs/firmware.md)
ADC_CAP = 64              #: ADC samples drawn ahead or logged (native core only)
KERNEL_ROWS = 32          #: driven rows the native column-read kernel takes
SPIN_SLACK = 4
"""Spin timing (``poll_spin``): a polled flag reads "not yet" until this many MCU cycles before
it becomes true; the last ones are collapsed as in the default timing, so a poll loop of at
most this many instructions (the firmware's tight loops: 3) sees the flag at the very cycle it
becomes true - the pulse gate keeps its exact width (docs/firmware.md)."""
N_FAULTS = 19

# categories of virtual time (clock.CATEGORIES names)
CAT_MCU, CAT_SPI, CAT_IDLE, CAT_UART = range(4)
CATEGORY_NAMES = ("mcu", "spi", "idle", "uart")

# why the CPU stopped
STOP_NONE, STOP_IDLE, STOP_WATCHDOG, STOP_BUDGET, STOP_EVENT_ERROR, STOP_FRAME = range(6)

# events the cores raise to the Python side (the board)
EV_DELIVER, EV_LDAC, EV_ADC_PREFETCH, EV_TX_FULL, EV_ADC_SETTLE = range(1, 6)

EventHandler = Callable[[int], int]
"""What a peripheral core calls with an event (``EV_*``): the MCU's handler
(:meth:`.mcu_isa.IsaMcu.event`, or ``native_event`` for the C core); its return value goes back
to the core."""

# what the ADC sample buffer holds (native core)
ADC_NONE, ADC_AHEAD, ADC_KERNEL = range(3)

#: fault counters: (symbol, what the models saw the firmware do wrong); a correct firmware
#: never counts one (the tests assert they stay 0)
FAULTS: tuple[tuple[str, str], ...] = (
    ("UNMODELLED", "access to an unmodelled peripheral"),
    ("UART_CLOCK", "uart clock off"),
    ("TIMER_CLOCK", "timer clock off"),
    ("SPI_CLOCK", "spi clock off"),
    ("GPIO_CLOCK", "gpio clock off"),
    ("SPI_NO_CS", "spi byte without chip select"),
    ("SPI_AFTER_READ", "spi byte after the frame was read"),
    ("CS_WHILE_SHIFTING", "chip select raised while shifting"),
    ("TWO_CS", "two chip selects low"),
    ("FRAME_TOO_LONG", "spi frame longer than modelled"),
    ("UART_PADS", "uart used with its pads not in serial mode"),
    ("SPI_PADS", "spi used with its pads not in serial mode"),
    ("CS_PAD", "chip select on a pin that is not a GPIO output"),
    ("WDT_CLOCK", "watchdog clock off"),
    ("PAD_CLOCK", "pad configuration clock off"),
    ("WDT_LOCKED", "watchdog written without the unlock key"),
    ("UART_OVERRUN", "a host byte read after the next one had arrived (lost on the chip)"),
    ("UART_OFF", "uart byte sent with CONTROL1's UE, RE or TE clear (not sent)"),
    ("SPI_OFF", "spi byte written with ENABLE.EN clear (not shifted out)"),
)
FAULT_NAMES = tuple(what for _, what in FAULTS)
F = {sym: i for i, (sym, _) in enumerate(FAULTS)}
"""fault symbol -> counter index"""
assert len(FAULTS) == N_FAULTS

_U8, _U16, _U32, _I32, _U64, _F64 = (ctypes.c_uint8, ctypes.c_uint16, ctypes.c_uint32,
                                      ctypes.c_int32, ctypes.c_uint64, ctypes.c_double)
_C = {_U8: "uint8_t", _U16: "uint16_t", _U32: "uint32_t", _I32: "int32_t", _U64: "uint64_t",
      _F64: "double"}

#: (name, ctypes type, array length or 0, meaning). Pointers are stored as u64 addresses.
FIELDS: tuple[tuple[str, Any, int, str], ...] = (
    # -- virtual time and run control
    ("cycles", _U64, 0, "virtual time: MCU cycles since power-on"),
    ("instructions", _U64, 0, "instructions executed since power-on"),
    ("acc", _U64, 4, "cycles per category not yet given to the board clock"),
    ("text_base", _U64, 0, "address of .text"),
    ("text_end", _U64, 0, "end of .text"),
    ("istart", _U64, 0, "address of the u32 table: instruction index per half-word of .text"),
    ("budget_end", _U64, 0, "stop when instructions reach this (emulator guard)"),
    ("stop_reason", _I32, 0, "STOP_*"),
    ("poll_spin", _U32, 0, "spin timing: polled flags read not-ready until SPIN_SLACK cycles "
     "before they become true (0: poll loops collapsed at their first poll)"),
    ("spin_polls", _U64, 0, "polls answered not-ready in spin timing"),
    ("uc", _U64, 0, "uc_engine* (native core)"),
    ("emu_stop", _U64, 0, "uc_emu_stop (native core)"),
    ("event", _U64, 0, "int (*)(int kind): the Python event handler (native core)"),
    # -- power manager (clock gating, WDT clock) and pad configuration
    ("pm_m", _U32, 0, "APB_M clock gates"),
    ("pm_p", _U32, 0, "APB_P clock gates"),
    ("wdt_clk_mux", _U32, 0, "PM WDT_CLK_MUX: 0/1 32 MHz, 2/3 32.768 kHz"),
    ("pad_cfg", _U32, 3, "PAD_CONFIG PORT_n_CFG (2 bits a pin)"),
    ("pad_ds", _U32, 3, "PAD_CONFIG PORT_n_DS"),
    ("pad_pupd", _U32, 3, "PAD_CONFIG PORT_n_PUPD"),
    # -- UART_0
    ("rx_t", _F64, RX_CAP, "arrival cycle of each queued host byte"),
    ("rx_b", _U8, RX_CAP, "queued host bytes"),
    ("rx_head", _U32, 0, "index of the oldest queued byte"),
    ("rx_count", _U32, 0, "queued bytes"),
    ("byte_cycles", _F64, 0, "cycles per UART byte (10 bits at the baud rate)"),
    ("tx_end", _F64, 0, "cycle at which the shift register is empty"),
    ("tx_hold_free", _F64, 0, "cycle at which the holding register is free"),
    ("tx_out", _U8, TX_CAP, "bytes sent, not yet collected"),
    ("tx_len", _U32, 0, "bytes in tx_out"),
    ("uart_on", _U32, 0, "CONTROL1 has UE, RE and TE set (the UART sends and receives)"),
    ("prev_flags_read", _U32, 0, "the last access was an empty FLAGS poll of the idle loop"),
    ("rx_told", _U32, 0, "1 + rx_head of the byte a FLAGS poll last reported (RXNE), 0: none"),
    ("rx_told_timer", _U32, 0, "1 + rx_head of the host byte a compare poll (TIMER32_1 "
     "INT_FLAGS) last answered \"not yet\" for, so that the loop can read it; 0: none"),
    ("block_pc", _U64, 0, "start address of the basic block being run"),
    ("idle_lo", _U64, 0, "the idle loop's UART poll (hal_uart_getc): its code's first address"),
    ("idle_hi", _U64, 0, "... and its end (0: every FLAGS poll counts as the idle loop's)"),
    ("stop_on_frame", _U32, 0, "stop the CPU once it has sent a frame delimiter (0x00)"),
    ("frame_sent", _U32, 0, "a delimiter was sent: stop at the next FLAGS read"),
    ("uart_poll", _U32, 0, "the UART was read since the last access to another peripheral"),
    # -- TIMER32_1
    ("tim_start", _U64, 0, "cycle at which VALUE was 0"),
    ("tim_on", _U32, 0, "ENABLE.EN: the counter runs"),
    ("tim_hold", _U32, 0, "VALUE while the counter is stopped"),
    ("ocr", _U32, 0, "channel 0 compare value"),
    ("oc_armed", _U32, 0, "a compare is pending"),
    ("oc_flag", _U32, 0, "INT_FLAGS.OC0"),
    ("ch0_cntrl", _U32, 0, "CH0_CNTRL: the compare sets OC0 only in compare mode and enabled"),
    ("oc_target", _U64, 0, "cycle at which VALUE reaches OCR"),
    # -- SPI_0
    ("spi_config", _U32, 0, "CONFIG"),
    ("spi_on", _U32, 0, "ENABLE.EN: bytes written to TXDATA are shifted out"),
    ("spi_div", _U32, 0, "SCLK = MCU clock / spi_div"),
    ("byte_end", _U64, 0, "cycle at which the last byte written has shifted out"),
    ("frame_pin", _I32, 0, "chip select (GPIO_1 pin) of the open frame, -1 none"),
    ("frame_done", _U32, 0, "the open frame was handed to its device"),
    ("mosi", _U8, MOSI_CAP, "bytes of the open frame"),
    ("mosi_len", _U32, 0, "bytes in mosi"),
    ("frame_start", _U64, 0, "cycle at which the open frame's first byte started"),
    ("fifo", _U8, FIFO_CAP, "RX FIFO"),
    ("fifo_head", _U32, 0, "oldest byte in the RX FIFO"),
    ("fifo_count", _U32, 0, "bytes in the RX FIFO"),
    # -- GPIO_0..2 (outputs, directions)
    ("gpio_out", _U32, 3, "output latches"),
    ("gpio_dir", _U32, 3, "1 = output"),
    # -- watchdog
    ("wdt_con", _U32, 0, "CON: PRELOAD 0-11, PRESCALE 12-14"),
    ("wdt_unlocked", _U32, 0, "the last KEY write was the unlock key"),
    ("wdt_enabled", _U32, 0, "STA.ENABLED"),
    ("wdt_rst_flag", _U32, 0, "STA.RST_FLAG: the last reset came from the watchdog"),
    ("wdt_deadline", _F64, 0, "cycle at which the watchdog resets the MCU"),
    ("wdt_kicks", _U64, 0, "START keys written"),
    # -- ADC samples drawn ahead or computed natively (native core; docs/firmware.md)
    ("adc_fast", _U32, 0, "draw ADC samples ahead (0: every frame goes to Python)"),
    ("adc_pin", _I32, 0, "chip select of the TLC3541"),
    ("adc_mode", _U32, 0, "ADC_NONE / ADC_AHEAD (samples drawn ahead) / ADC_KERNEL (log)"),
    ("adc_n", _U32, 0, "samples in adc_codes (ADC_AHEAD)"),
    ("adc_used", _U32, 0, "samples used / frames logged"),
    ("adc_result", _U32, 0, "the conversion the next frame shifts out"),
    ("adc_codes", _U16, ADC_CAP, "samples drawn ahead"),
    ("adc_starts", _U64, ADC_CAP, "start cycle of the frame that used each sample"),
    ("adc_last_start", _U64, 0, "start cycle of the last ADC frame"),
    ("adc_have_last", _U32, 0, "adc_last_start is valid"),
    ("adc_cycle", _U32, 0, "cycles between two conversion starts (5 us)"),
    ("adc_early", _U32, 0, "ADC frames started within a conversion cycle"),
    # -- the column-read kernel: one ADC sample of a column circuit computed in C with numpy's
    #    own normal generator on the array's and the front end's random streams
    ("k_on", _U32, 0, "the parameters below describe the present circuit"),
    ("k_rows", _U32, 0, "driven rows k"),
    ("k_g", _F64, KERNEL_ROWS, "conductance of each driven cell of the column (S)"),
    ("k_v", _F64, KERNEL_ROWS, "row voltage of each driven row (V)"),
    ("k_r_mac", _F64, 0, "series resistance of a cell in a column read (Ohm)"),
    ("k_rel", _F64, 0, "read noise: relative sigma"),
    ("k_abs", _F64, 0, "read noise: absolute sigma (S)"),
    ("k_read_noisy", _U32, 0, "draw read noise"),
    ("k_gen_read", _U64, 0, "bitgen_t* of the array's random stream"),
    ("k_scale", _F64, 0, "gain x transimpedance (V/A)"),
    ("k_lsb", _F64, 0, "2^adc_bits"),
    ("k_vref", _F64, 0, "ADC reference (V)"),
    ("k_sigma", _F64, 0, "ADC noise (LSB rms)"),
    ("k_adc_noisy", _U32, 0, "draw ADC noise"),
    ("k_gen_adc", _U64, 0, "bitgen_t* of the front end's random stream"),
    ("k_full", _U32, 0, "ADC full-scale code"),
    ("k_saturated", _U32, 0, "logged samples clipped to the code range"),
    # -- faults
    ("faults", _U32, N_FAULTS, "FAULT_NAMES counters"),
)


def _ctype(t: Any, n: int) -> Any:
    return t * n if n else t


class McuState(ctypes.Structure):
    """The peripheral state (layout: :data:`FIELDS`)."""

    _fields_ = [(name, _ctype(t, n)) for name, t, n, _ in FIELDS]


def layout_hash() -> str:
    """Hash of the layout (names, types, lengths); the native library is built with it."""
    text = ";".join(f"{name}:{_C[t]}:{n}" for name, t, n, _ in FIELDS)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def c_header() -> str:
    """``mcu_state.h`` for the native core: the same struct, capacities and constants."""
    lines = ["/* GENERATED from snan_hil.firmware_emu.mik32_state.FIELDS: do not edit. */",
             "#ifndef MCU_STATE_H", "#define MCU_STATE_H", "#include <stdint.h>", ""]
    consts = {"RX_CAP": RX_CAP, "TX_CAP": TX_CAP, "MOSI_CAP": MOSI_CAP, "FIFO_CAP": FIFO_CAP,
              "ADC_CAP": ADC_CAP, "N_FAULTS": N_FAULTS,
              "CAT_MCU": CAT_MCU, "CAT_SPI": CAT_SPI, "CAT_IDLE": CAT_IDLE, "CAT_UART": CAT_UART,
              "STOP_NONE": STOP_NONE, "STOP_IDLE": STOP_IDLE, "STOP_WATCHDOG": STOP_WATCHDOG,
              "STOP_BUDGET": STOP_BUDGET, "STOP_EVENT_ERROR": STOP_EVENT_ERROR,
              "STOP_FRAME": STOP_FRAME,
              "EV_DELIVER": EV_DELIVER, "EV_LDAC": EV_LDAC, "EV_ADC_PREFETCH": EV_ADC_PREFETCH,
              "EV_TX_FULL": EV_TX_FULL, "EV_ADC_SETTLE": EV_ADC_SETTLE,
              "ADC_NONE": ADC_NONE, "ADC_AHEAD": ADC_AHEAD, "ADC_KERNEL": ADC_KERNEL,
              "KERNEL_ROWS": KERNEL_ROWS, "SPIN_SLACK": SPIN_SLACK}
    for k, v in consts.items():
        lines.append(f"#define {k} {v}")
    for i, (sym, what) in enumerate(FAULTS):
        lines.append(f"#define F_{sym} {i}  /* {what} */")
    lines.append(f'#define MCU_STATE_LAYOUT "{layout_hash()}"')
    lines += ["", "typedef struct {"]
    for name, t, n, what in FIELDS:
        lines.append(f"    {_C[t]} {name}{f'[{n}]' if n else ''};  /* {what} */")
    lines += ["} mcu_state;", "", "#endif", ""]
    return "\n".join(lines)
