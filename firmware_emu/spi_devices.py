"""Register-level models of the SPI chips on the board, and the SPI bus that connects them.

Each device decodes the bytes the real chip expects in one chip-select frame (CS low, bytes
clocked MSB first, CS high) and returns the bytes it would drive on MISO.

* :class:`AD5328` — 8-channel 12-bit DAC (four of them drive the 32 rows). 16-bit words:
  bit 15 = 0 is a data write (bits 14-12 channel A-H, bits 11-0 code); bit 15 = 1 is a control
  word selected by bits 14-13: ``00`` gain/buffer/reference (D5 GAIN E-H, D4 GAIN A-D, D3 BUF
  E-H, D2 BUF A-D, D1 VDD-as-reference E-H, D0 VDD-as-reference A-D), ``01`` LDAC mode (D1-D0:
  ``00`` outputs follow every write, ``01`` outputs hold, ``10`` one update of all outputs,
  ``11`` ignored), ``10`` power-down (D7-D0 = channels H..A), ``11`` reset (D12 = 0 data,
  1 data and control). ASSUMPTIONS: after a reset the LDAC mode is "hold" (the board's LDAC
  pin is taken as tied high, so the firmware must select a mode at start-up); the transfer
  function is the host's ``V = code * Vref / 4095`` (times 2 with GAIN set, clipped to VDD);
  a frame that is not exactly 16 bits is counted as a framing error (short frames are ignored,
  long frames use their first word).
* :class:`WriteDac` — single-channel 12-bit DAC of AD5320 class for the write bus: bits 13-12
  power-down mode (``00`` normal), bits 11-0 code; output updates at the end of the frame.
* :class:`TLC3541` — 14-bit ADC, 200 kS/s. CS falling samples the analog input; the 16 clocks
  of a frame shift out the result of the *previous* conversion (14 bits MSB first, 2 zero bits),
  so ``value = (b0 << 6) | (b1 >> 2)`` and the first conversion after a change is stale (hence
  the driver's dummy conversion). A new frame cannot start before the previous conversion cycle
  (5 us) has ended; the bus waits for it.
* :class:`ShiftRegister595` — 74HC595: bytes shift in MSB first, the output latch loads at CS
  rising (RCLK tied to CS); MISO is the serial output QH', i.e. the previous contents.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

from snan_hil.firmware_emu.clock import VirtualClock

log = logging.getLogger(__name__)

Listener = Callable[[], None]


class SpiDevice:
    """Base of the device models: one chip-select frame in, MISO bytes out."""

    name = "device"

    def __init__(self) -> None:
        self.frames = 0
        self.framing_errors = 0
        self._listeners: list[Listener] = []

    def on_change(self, listener: Listener) -> None:
        """Call ``listener()`` whenever an analog-visible output changes."""
        self._listeners.append(listener)

    def _changed(self) -> None:
        for listener in self._listeners:
            listener()

    def ready_at_us(self) -> float:
        """Earliest time a new frame may start (us); 0 = any time."""
        return 0.0

    def frame(self, mosi: bytes, t_start_us: float) -> bytes:  # pragma: no cover - abstract
        raise NotImplementedError

    def batch_cycle_us(self, mosi: bytes) -> float | None:
        """For :meth:`SpiBus.transfer_many`: None if frames of ``mosi`` must run one by one;
        else the device's frames change nothing outside it (no listener fires) and the next
        frame may start that many us after the previous one started (then :meth:`frame_many`)."""
        return None

    def frame_many(self, mosi: bytes, starts_us: list[float]) -> list[bytes]:
        """Several frames of ``mosi`` starting at ``starts_us``; MISO of each (default: one by
        one)."""
        return [self.frame(mosi, t) for t in starts_us]


class AD5328(SpiDevice):
    """8-channel 12-bit DAC with input and DAC registers, LDAC modes, gain/buffer, power-down."""

    CHANNELS = 8
    LDAC_CONTINUOUS, LDAC_HOLD, LDAC_PULSE = 0, 1, 2

    def __init__(self, name: str, vref: float = 5.0, vdd: float = 5.0, bits: int = 12):
        super().__init__()
        self.name = name
        self.vref = vref
        self.vdd = vdd
        self.full_scale = (1 << bits) - 1
        self.power_on_reset()

    def power_on_reset(self) -> None:
        self.input_reg = [0] * self.CHANNELS
        self.dac_reg = [0] * self.CHANNELS
        self._reset_control()

    def _reset_control(self) -> None:
        self.gain2 = [False, False]       # (A-D, E-H)
        self.buffered = [False, False]
        self.vdd_ref = [False, False]
        self.ldac_mode = self.LDAC_HOLD
        self.powered_down = [False] * self.CHANNELS

    def frame(self, mosi: bytes, t_start_us: float) -> bytes:
        self.frames += 1
        if len(mosi) != 2:
            self.framing_errors += 1
            if len(mosi) < 2:
                log.debug("%s: short frame of %d bytes ignored", self.name, len(mosi))
                return bytes(len(mosi))
        self.write_word((mosi[0] << 8) | mosi[1])
        return bytes(len(mosi))

    def write_word(self, word: int) -> None:
        """Decode one 16-bit word."""
        if not word & 0x8000:
            channel = (word >> 12) & 0x7
            self.input_reg[channel] = word & 0x0FFF
            if self.ldac_mode == self.LDAC_CONTINUOUS:
                self._load(channel)
            return
        kind = (word >> 13) & 0x3
        if kind == 0b00:
            self.gain2 = [bool(word & 0x10), bool(word & 0x20)]
            self.buffered = [bool(word & 0x04), bool(word & 0x08)]
            self.vdd_ref = [bool(word & 0x01), bool(word & 0x02)]
            self._changed()
        elif kind == 0b01:
            mode = word & 0x3
            if mode == 0b00:
                self.ldac_mode = self.LDAC_CONTINUOUS
                self._load_all()
            elif mode == 0b01:
                self.ldac_mode = self.LDAC_HOLD
            elif mode == 0b10:
                self._load_all()          # one LDAC pulse; the mode itself stays as it was
        elif kind == 0b10:
            self.powered_down = [bool(word >> ch & 1) for ch in range(self.CHANNELS)]
            self._changed()
        else:
            self.input_reg = [0] * self.CHANNELS
            self.dac_reg = [0] * self.CHANNELS
            if word & 0x1000:
                self._reset_control()
            self._changed()

    def _load(self, channel: int) -> None:
        if self.dac_reg[channel] != self.input_reg[channel]:
            self.dac_reg[channel] = self.input_reg[channel]
            self._changed()

    def _load_all(self) -> None:
        if self.dac_reg != self.input_reg:
            self.dac_reg = list(self.input_reg)
            self._changed()

    def output_volts(self, channel: int) -> float:
        """Output of one channel (V)."""
        return self.code_volts(channel, self.dac_reg[channel])

    def code_volts(self, channel: int, code: int) -> float:
        """Output (V) ``channel`` would drive with ``code`` in its DAC register, under the
        present control settings (reference, gain, power-down)."""
        if self.powered_down[channel]:
            return 0.0
        half = channel // 4
        ref = self.vdd if self.vdd_ref[half] else self.vref
        volts = ref * code / self.full_scale
        if self.gain2[half]:
            volts *= 2.0
        return min(volts, self.vdd)

    def outputs(self) -> list[float]:
        return [self.output_volts(ch) for ch in range(self.CHANNELS)]

    @staticmethod
    def data_word(channel: int, code: int) -> bytes:
        """The two bytes that write ``code`` to ``channel`` (0-7)."""
        word = ((channel & 0x7) << 12) | (code & 0x0FFF)
        return bytes(((word >> 8) & 0xFF, word & 0xFF))

    @staticmethod
    def control_word(kind: int, bits: int) -> bytes:
        """The two bytes of a control word (``kind`` 0-3 as in the class docstring)."""
        word = 0x8000 | ((kind & 0x3) << 13) | (bits & 0x1FFF)
        return bytes(((word >> 8) & 0xFF, word & 0xFF))


class WriteDac(SpiDevice):
    """Single-channel 12-bit DAC (AD5320 class) driving the write bus."""

    def __init__(self, name: str = "WDAC", vref: float = 5.0, bits: int = 12):
        super().__init__()
        self.name = name
        self.vref = vref
        self.full_scale = (1 << bits) - 1
        self.code = 0
        self.power_down = 0

    def frame(self, mosi: bytes, t_start_us: float) -> bytes:
        self.frames += 1
        if len(mosi) != 2:
            self.framing_errors += 1
            if len(mosi) < 2:
                return bytes(len(mosi))
        word = (mosi[0] << 8) | mosi[1]
        code, power_down = word & 0x0FFF, (word >> 12) & 0x3
        if (code, power_down) != (self.code, self.power_down):
            self.code, self.power_down = code, power_down
            self._changed()
        return bytes(len(mosi))

    def output_volts(self) -> float:
        if self.power_down:
            return 0.0
        return self.vref * self.code / self.full_scale

    @staticmethod
    def data_word(code: int) -> bytes:
        return bytes(((code >> 8) & 0x0F, code & 0xFF))


class TLC3541(SpiDevice):
    """14-bit pipelined ADC: each 16-clock frame returns the previous conversion."""

    def __init__(self, sample: Callable[[], int], cycle_us: float, name: str = "ADC",
                 sample_many: Callable[[int], list[int]] | None = None):
        """``sample()`` returns the code of the analog input at the moment of sampling;
        ``sample_many(n)``, if given, the codes of ``n`` consecutive samples while the input
        circuit does not change (what ``n`` calls of ``sample()`` would return)."""
        super().__init__()
        self.name = name
        self.sample = sample
        self.sample_many = sample_many
        self.cycle_us = cycle_us
        self.result = 0
        self.conversions = 0
        self._busy_until = 0.0
        self.stuck_bit: tuple[int, int] | None = None
        """A faulty chip (:mod:`.faults`): (mask, value) of an output bit stuck at a level."""

    def _out(self, code: int) -> int:
        """The conversion as the chip shifts it out (14 bits; a stuck bit forced)."""
        code &= 0x3FFF
        if self.stuck_bit is not None:
            mask, value = self.stuck_bit
            code = (code & ~mask) | value
        return code

    def ready_at_us(self) -> float:
        return self._busy_until

    def frame(self, mosi: bytes, t_start_us: float) -> bytes:
        self.frames += 1
        out = bytes((((self.result >> 6) & 0xFF), ((self.result & 0x3F) << 2)))
        if len(mosi) != 2:
            # A frame of fewer than 16 clocks aborts the conversion; extra clocks read zeros.
            self.framing_errors += 1
            if len(mosi) < 2:
                return out[: len(mosi)]
            out += bytes(len(mosi) - 2)
        self.result = self._out(self.sample())
        self.conversions += 1
        self._busy_until = t_start_us + self.cycle_us
        return out

    def batch_cycle_us(self, mosi: bytes) -> float | None:
        # Conversions change no other device; full 16-clock frames pace at the cycle.
        return self.cycle_us if len(mosi) == 2 and self.sample_many is not None else None

    def frame_many(self, mosi: bytes, starts_us: list[float]) -> list[bytes]:
        """Full frames at ``starts_us`` (>= one cycle apart): the same MISO bytes, result,
        counters and busy time as one :meth:`frame` per start, with one ``sample_many`` call."""
        if self.batch_cycle_us(mosi) is None:
            return super().frame_many(mosi, starts_us)
        n = len(starts_us)
        if n == 0:
            return []
        assert self.sample_many is not None          # batch_cycle_us() checked it
        results = [self.result] + [self._out(code) for code in self.sample_many(n)]
        self.result = results[-1]
        # Frame k shifts out conversion k-1: ((r >> 6) & 0xFF, (r & 0x3F) << 2) == (r << 2) as
        # two big-endian bytes, for r < 2^14.
        out = [(r << 2).to_bytes(2, "big") for r in results[:-1]]
        self.frames += n
        self.conversions += n
        self._busy_until = starts_us[-1] + self.cycle_us
        return out

    def account_frames(self, starts_us: list[float], results: list[int]) -> list[bytes]:
        """Full frames whose conversions were sampled elsewhere (``results``, in order: the
        ISA-level MCU draws a reading's samples ahead): the same result, counters and busy time
        as one :meth:`frame` per frame with ``sample()`` returning ``results`` in turn. Returns
        the MISO bytes of each frame when ``starts_us`` gives every frame's start (us), else
        (only the last frame's start) nothing."""
        n = len(results)
        if not n:
            return []
        out = []
        if len(starts_us) == n:
            r = self.result
            for code in results:
                out.append(bytes(((r >> 6) & 0xFF, (r & 0x3F) << 2)))
                r = self._out(code)
        self.result = self._out(results[-1])
        self.frames += n
        self.conversions += n
        self._busy_until = starts_us[-1] + self.cycle_us
        return out

    @staticmethod
    def decode(b0: int, b1: int) -> int:
        """The driver's decoding: ``(b0 << 6) | (b1 >> 2)``."""
        return (b0 << 6) | (b1 >> 2)


class ShiftRegister595(SpiDevice):
    """74HC595: 8-bit shift register with output latch loaded at chip-select rising."""

    def __init__(self, name: str):
        super().__init__()
        self.name = name
        self.shift = 0
        self.latch = 0
        self.wiring: tuple[int, int] | None = None
        """A faulty board (:mod:`.faults`): two outputs whose lines are exchanged; ``latch``
        is what the lines carry."""

    def frame(self, mosi: bytes, t_start_us: float) -> bytes:
        self.frames += 1
        out = bytearray()
        for byte in mosi:
            out.append(self.shift)
            self.shift = byte
        lines = self.shift
        if self.wiring is not None:
            a, b = self.wiring
            if ((lines >> a) ^ (lines >> b)) & 1:
                lines ^= (1 << a) | (1 << b)
        if mosi and self.latch != lines:
            self.latch = lines
            self._changed()
        return bytes(out)


@dataclass(frozen=True)
class SpiTransaction:
    """One chip-select frame as seen on the bus (time of CS falling in us)."""

    t_us: float
    cs: str
    mosi: bytes
    miso: bytes

    def __str__(self) -> str:
        return (f"{self.t_us:10.3f} us  {self.cs:<6} MOSI {self.mosi.hex(' ')}  "
                f"MISO {self.miso.hex(' ')}")


class SpiBus:
    """The MCU's SPI master: chip selects, byte timing on the virtual clock, optional trace."""

    def __init__(self, clock: VirtualClock):
        self.clock = clock
        self.devices: dict[str, SpiDevice] = {}
        self.transactions = 0
        self.bytes = 0
        self.trace: list[SpiTransaction] | None = None

    def attach(self, cs: str, device: SpiDevice) -> SpiDevice:
        self.devices[cs] = device
        return device

    def start_trace(self) -> None:
        """Record every following transaction in :attr:`trace`."""
        self.trace = []

    def stop_trace(self) -> list[SpiTransaction]:
        trace, self.trace = self.trace or [], None
        return trace

    def transfer_many(self, cs: str, mosi: bytes, count: int) -> list[bytes]:
        """``count`` back-to-back frames of ``mosi`` on ``cs`` (e.g. the ADC frames of one
        reading); MISO of each.

        Identical in effect to ``count`` calls of :meth:`transfer` — same MISO bytes, frame
        start times, trace, clock time per category and energy (bit for bit) — but when the
        device's frames change nothing outside it (``device.batch_cycle_us``; the ADC) the clock
        is advanced once for all frames and the device samples them in one call.
        """
        device = self.devices[cs]
        cycle_us = device.batch_cycle_us(mosi) if count > 1 else None
        if cycle_us is None:
            return [self.transfer(cs, mosi) for _ in range(count)]
        clock = self.clock
        starts = clock.advance_frames(count, clock.timing.mcu_overhead_us,
                                      clock.spi_bits_us(len(mosi)), device.ready_at_us(), cycle_us)
        misos = device.frame_many(mosi, starts)
        self.transactions += count
        self.bytes += count * len(mosi)
        if self.trace is not None:
            mosi = bytes(mosi)
            self.trace.extend(SpiTransaction(t, cs, mosi, miso) for t, miso in zip(starts, misos))
        return misos

    def latch(self, cs: str, mosi: bytes) -> bytes:
        """A frame whose bytes were shifted in earlier, while something else went on, and that
        takes effect now, at its chip-select edge, without clock time of its own (the pulse
        gate's closing byte: ``Firmware._pulse``, as the C firmware's ``hal_pulse``)."""
        t = self.clock.now_us
        miso = self.devices[cs].frame(mosi, t)
        self.transactions += 1
        self.bytes += len(mosi)
        if self.trace is not None:
            self.trace.append(SpiTransaction(t, cs, bytes(mosi), miso))
        return miso

    def transfer(self, cs: str, mosi: bytes, overhead_us: float | None = None) -> bytes:
        """One frame on chip select ``cs``; returns the MISO bytes.

        Costs the MCU overhead (``overhead_us``, default the timing's ``mcu_overhead_us``),
        then any wait for the device to be ready (an ADC conversion cycle in progress), then 8
        bits per byte at the SPI clock.
        """
        device = self.devices[cs]
        clock = self.clock
        # The MCU's per-transaction work (CS GPIO, driver call) runs first; CS falls no earlier
        # than the device is ready (an ADC conversion cycle still in progress).
        clock.advance(clock.timing.mcu_overhead_us if overhead_us is None else overhead_us,
                      "mcu")
        clock.wait_until(device.ready_at_us(), "adc")
        t_start = clock.now_us
        clock.advance(clock.spi_bits_us(len(mosi)), "spi")
        # Latches and DAC updates take effect at CS rising, i.e. after the clocked bits; the
        # ADC's sample instant (CS falling) sees the same analog state, nothing moves in between.
        miso = device.frame(mosi, t_start)
        self.transactions += 1
        self.bytes += len(mosi)
        if self.trace is not None:
            self.trace.append(SpiTransaction(t_start, cs, bytes(mosi), miso))
        return miso
