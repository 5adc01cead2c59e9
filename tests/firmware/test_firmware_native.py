"""The two peripheral cores of the instruction-level MCU agree, and the MCU's resets work.

* register by register: a random sequence of accesses to every modelled (and some unmodelled)
  register, and of translated blocks, gives the same state, read values, events and CPU stops
  in the Python reference core (firmware_emu/mik32_periph.py) and the native C core
  (firmware_emu/native/mik32_periph.c);
* the firmware end to end: the same session gives the same replies, cycle and instruction
  counts, SPI traffic (with times), board clock (time, energy, breakdown) and chip in both;
* the watchdog the firmware arms resets a hung firmware within its 2 s; long requests (a 1 s
  pulse, a paced spike batch of 4 s) do not trip it; a CPU trap reboots the firmware; after
  either the board keeps serving and the host sees a reset (new boot nonce, counters from 0).
"""

import ctypes
import random
import struct
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("unicorn")

from snan_hil.firmware_emu import mik32_native, mik32_state as ms          # noqa: E402
from snan_hil.firmware_emu.emulator import Emulator                       # noqa: E402
from snan_hil.firmware_emu.fw_image import default_elf_path               # noqa: E402
from snan_hil.firmware_emu.mik32_periph import ReferenceCore              # noqa: E402
from snan_hil.firmware_emu.testing import default_array                    # noqa: E402
from snan_hil.protocol import messages as m                                # noqa: E402
from snan_hil.protocol.errors import BoardResetError, LinkTimeoutError     # noqa: E402
from snan_hil.protocol.link import LinkClient                              # noqa: E402
from snan_hil.protocol.transport import CallbackTransport                  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import test_firmware_mcu as script                                         # noqa: E402

if not default_elf_path().is_file():
    pytest.skip("firmware ELF not built ('make firmware')", allow_module_level=True)
LIB = mik32_native.load()
needs_native = pytest.mark.skipif(LIB is None, reason="native MCU core not built")
POINTERS = ("istart", "uc", "emu_stop", "event")


# the native core's own fields: samples drawn ahead, the column kernel's parameters
NATIVE_ONLY = ("adc_fast", "adc_result", "adc_codes", "adc_starts") + tuple(
    name for name, *_ in ms.FIELDS if name.startswith("k_"))


def state_bytes(s: ms.McuState, skip: tuple[str, ...] = ()) -> bytes:
    """The state without the fields that hold host addresses (and ``skip``)."""
    raw = bytearray(ctypes.string_at(ctypes.addressof(s), ctypes.sizeof(s)))
    for name in POINTERS + skip:
        field = getattr(ms.McuState, name)
        raw[field.offset:field.offset + field.size] = bytes(field.size)
    return bytes(raw)


# ---------------------------------------------------------------- register by register
class Bench:
    """One core on a fresh state, with a stand-in board: a frame's MISO is a function of its
    bytes; every event and CPU stop is logged."""

    def __init__(self, native: bool):
        self.s = s = ms.McuState()
        s.byte_cycles = 32e6 * 10 / 115200
        s.adc_pin, s.adc_cycle, s.spi_div, s.frame_pin = 5, 160, 2, -1
        s.text_base, s.text_end, s.budget_end = 0x1000, 0x1000, 1 << 62
        s.wdt_deadline = 0.0
        self.log: list = []
        self.native = native
        if native:
            self._ev = mik32_native.EVENT_FN(self.event)
            self._stop = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p)(self._stopped)
            s.event = ctypes.cast(self._ev, ctypes.c_void_p).value
            s.emu_stop = ctypes.cast(self._stop, ctypes.c_void_p).value
            for name, res in (("mik32_apbp_read", ctypes.c_uint64),
                              ("mik32_apbm_read", ctypes.c_uint64)):
                getattr(LIB, name).restype = res
            u64, ptr = ctypes.c_uint64, ctypes.c_void_p
            LIB.mik32_apbp_read.argtypes = LIB.mik32_apbm_read.argtypes = \
                [ptr, u64, ctypes.c_uint, ptr]
            LIB.mik32_apbp_write.argtypes = LIB.mik32_apbm_write.argtypes = \
                [ptr, u64, ctypes.c_uint, u64, ptr]
            LIB.mik32_block.argtypes = [ptr, u64, ctypes.c_uint32, ptr]
            self.ud = ctypes.c_void_p(ctypes.addressof(s))
        else:
            self.core = ReferenceCore(self.event, s)
            self.core.cpu = self                          # emu_stop() below

    # stand-ins for the CPU and the board
    def _stopped(self, uc) -> int:
        self.log.append(("stop", self.s.stop_reason))
        return 0

    def emu_stop(self) -> None:
        self._stopped(None)

    def event(self, kind: int) -> int:
        s = self.s
        self.log.append(("event", kind, s.frame_pin, bytes(s.mosi[:s.mosi_len])))
        if kind == ms.EV_DELIVER:
            for b in bytes(s.mosi[:s.mosi_len])[::-1]:
                if s.fifo_count == ms.FIFO_CAP:
                    s.fifo_head = (s.fifo_head + 1) % ms.FIFO_CAP
                    s.fifo_count -= 1
                s.fifo[(s.fifo_head + s.fifo_count) % ms.FIFO_CAP] = b ^ 0x5A
                s.fifo_count += 1
            s.frame_done = 1
        elif kind == ms.EV_TX_FULL:
            s.tx_len = 0
        return 0

    # the accesses
    def read(self, apbm: bool, off: int) -> int:
        if self.native:
            fn = LIB.mik32_apbm_read if apbm else LIB.mik32_apbp_read
            return int(fn(None, off, 4, self.ud))
        return (self.core.apbm_read if apbm else self.core.apbp_read)(None, off, 4, None)

    def write(self, apbm: bool, off: int, value: int) -> None:
        if self.native:
            fn = LIB.mik32_apbm_write if apbm else LIB.mik32_apbp_write
            fn(None, off, 4, value, self.ud)
        else:
            (self.core.apbm_write if apbm else self.core.apbp_write)(None, off, 4, value, None)

    def block(self, size: int) -> None:
        if self.native:
            LIB.mik32_block(None, 0x9000, size, self.ud)
        else:
            self.core.block(None, 0x9000, size, None)


APBP_REGS = (
    [0x0084, 0x009C] +                                            # WDT CON, KEY/STA
    [0x0400 + o for o in (0x00, 0x1C, 0x1C, 0x1C, 0x24, 0x28)] +  # UART_0
    [0x1800 + o for o in (0x00, 0x10, 0x18, 0x1C, 0x1C, 0x80, 0x84)] +  # TIMER32_1
    [0x2000 + o for o in (0x00, 0x04, 0x04, 0x14, 0x1C, 0x1C, 0x20, 0x20)] +   # SPI_0
    [0x3400 + o for o in (0x00, 0x04, 0x04, 0x08, 0x0C, 0x10)] +  # GPIO_1 (chip selects)
    [0x3000, 0x3004, 0x3808, 0x0800, 0x1C00, 0x2400, 0x3C00])     # GPIO_0/2, unmodelled
APBM_REGS = [0x14, 0x18, 0x1C, 0x20, 0x28, 0x400, 0x800, 0xC00, 0xC0C, 0xC18, 0xC04]


def _value(rng: random.Random, apbm: bool, off: int) -> int:
    if not apbm and off == 0x009C:
        return rng.choice((0x1E, 0x71, 0xE8, 0x1E, 0x71, 0x33))
    if not apbm and off == 0x0084:
        return rng.randrange(0x8000)
    if not apbm and off in (0x3400, 0x3404):
        return 1 << rng.randrange(10)
    if not apbm and off in (0x1810, 0x2014):      # timer / SPI ENABLE: on, off, cleared
        return rng.choice((1, 1, 3, 1 | 8, 0, 2, rng.getrandbits(4)))
    if not apbm and off == 0x1880:                # CH0_CNTRL: compare on, or not
        return rng.choice((0xA0, 0xA0, 0xA0, 0x20, 0x80, 0xB0, rng.getrandbits(8)))
    if not apbm and off == 0x0400:                # UART CONTROL1: on, or UE/RE/TE missing
        return rng.choice((0xD, 0xD, 0xD, 0xC, 0x9, 0xE, rng.getrandbits(4)))
    if not apbm and off == 0x1884:
        return rng.randrange(1 << 12)
    if apbm and off in (0x14, 0x1C):
        return rng.getrandbits(16) | (0xFFFF if rng.random() < 0.5 else 0)
    if apbm and off in (0x18, 0x20):
        return 1 << rng.randrange(16)
    if apbm and off == 0xC00:
        return rng.choice((0x1415, 0x0000, 0x1400, 0xFFFFFFFF))
    return rng.getrandbits(32)


@needs_native
@pytest.mark.parametrize("spin", (0, 1), ids=("collapsed", "spin"))
@pytest.mark.parametrize("seed", range(4))
def test_cores_agree_register_by_register(seed, spin):
    rng = random.Random(seed)
    a, b = Bench(native=False), Bench(native=True)
    for bench in (a, b):                          # host bytes in flight
        s = bench.s
        s.poll_spin = spin
        for i in range(40):
            s.rx_t[i], s.rx_b[i] = 2000.0 + 2777.78 * i, (7 * i) & 0xFF
        s.rx_count = 40
    for step in range(3000):
        r = rng.random()
        if r < 0.04:                              # unlock, then a key or the configuration
            second = (0x0084, rng.randrange(0x8000)) if rng.random() < 0.3 else \
                (0x009C, rng.choice((0x71, 0x71, 0xE8)))
            for off, value in ((0x009C, 0x1E), second):
                a.write(False, off, value)
                b.write(False, off, value)
        elif r < 0.15:
            size = rng.choice((2, 4, 6, 12, 40))
            a.block(size)
            b.block(size)
        else:
            apbm = rng.random() < 0.15
            off = rng.choice(APBM_REGS if apbm else APBP_REGS)
            if rng.random() < 0.5:
                assert a.read(apbm, off) == b.read(apbm, off), (step, hex(off))
            else:
                value = _value(rng, apbm, off)
                a.write(apbm, off, value)
                b.write(apbm, off, value)
        assert a.log == b.log, step
        assert state_bytes(a.s) == state_bytes(b.s), step
    for off in [0x41C, 0x424] * 41 + [0x41C, 0x41C]:   # drain the UART, then two empty polls
        assert a.read(False, off) == b.read(False, off)
    assert a.log == b.log and state_bytes(a.s) == state_bytes(b.s)
    # the sequence reached the interesting states
    kinds = {e[1] for e in a.log if e[0] == "event"}
    assert ms.EV_DELIVER in kinds and ms.EV_LDAC in kinds
    assert any(e[0] == "stop" for e in a.log) or spin   # (spinning, time moves by blocks only)
    assert a.s.wdt_kicks > 0 and a.s.cycles > 0
    assert sum(a.s.faults) > 0 and a.s.faults[ms.F["WDT_LOCKED"]] > 0
    assert (a.s.spin_polls > 0) == bool(spin)


# ---------------------------------------------------------------- the firmware end to end
@needs_native
@pytest.mark.parametrize("timing", ("collapsed", "spin"))
def test_cores_agree_on_a_firmware_session(monkeypatch, timing):
    monkeypatch.setenv("SNAN_HIL_MCU_TIMING", timing)
    runs = {}
    for core in ("reference", "native"):
        monkeypatch.setenv("SNAN_HIL_MCU_CORE", core)
        board = script.Board("firmware")
        board.emu.board.bus.start_trace()
        replies = script.scripted(board)
        mcu = board.emu.backend.mcu
        assert mcu.core_name == core
        runs[core] = (replies, mcu, board.emu.board.bus.stop_trace(), board.emu.clock,
                      board.emu.array.conductance())
    (ra, ma, ta, ca, ga), (rb, mb, tb, cb, gb) = runs["reference"], runs["native"]
    assert [(f.type, f.seq, f.flags, f.payload) for f in ra] == \
        [(f.type, f.seq, f.flags, f.payload) for f in rb]
    assert (ma.cycles, ma.instructions) == (mb.cycles, mb.instructions) and ma.cycles > 10**7
    assert len(ta) == len(tb) > 1000
    assert [(t.t_us, t.cs, t.mosi, t.miso) for t in ta] == \
        [(t.t_us, t.cs, t.mosi, t.miso) for t in tb]
    assert (ca.now_us, ca.energy_j, dict(ca.breakdown_us)) == \
        (cb.now_us, cb.energy_j, dict(cb.breakdown_us))
    assert np.array_equal(ga, gb)
    assert state_bytes(ma.s, NATIVE_ONLY) == state_bytes(mb.s, NATIVE_ONLY)
    assert ma.resets == mb.resets == 0 and ma.faults == mb.faults == {}
    assert mb.kernel_samples > 300 and ma.kernel_samples == 0
    assert (ma.spin_polls == mb.spin_polls > 1000) == (timing == "spin")


# ---------------------------------------------------------------- resets
def _board():
    emu = Emulator(None, 0, array=default_array(0), mcu="firmware")
    client = LinkClient(CallbackTransport(emu.feed, name="fw"), retries=0, timeout=0.05)
    client.hello()
    return emu, client


def _patch(emu, symbol: str, word: int) -> None:
    """Overwrite the first instruction of a firmware function in flash (a fault injection)."""
    mcu = emu.backend.mcu
    addr = mcu.image.symbols[symbol][0]
    mcu.cpu.mem_write(addr, struct.pack("<I", word))
    mcu.cpu.ctl_remove_cache(addr, addr + 4)          # drop the translated block


def _serves_after_reset(emu, client, nonce_before):
    with pytest.raises(BoardResetError):
        client.status()                               # an old-nonce request is refused
    info = client.hello()
    assert info.boot_nonce != nonce_before
    st = client.status()
    # counters since the new boot: the refused STATUS, HELLO, this STATUS
    assert (st.frames_in, st.nonce_mismatches, st.executed) == (3, 1, 2)
    assert client.read_column(0, [245] + [0] * 31) > 0
    return emu.backend.mcu


@needs_native
def test_watchdog_resets_a_hung_firmware_and_the_board_keeps_serving():
    emu, client = _board()
    nonce = client.boot_nonce
    _patch(emu, "ops_read_cell", 0x0000006F)          # "j ." : the firmware hangs there
    mcu = emu.backend.mcu
    t0 = mcu.cycles
    with pytest.raises(LinkTimeoutError):
        client.read_cell(1, 1)                        # no reply: the board rebooted
    assert mcu.reset_causes == {"watchdog": 1}
    assert 1.9 < (mcu.cycles - t0) / 32e6 < 2.2      # the 2 s watchdog (+ reboot to idle)
    assert mcu.s.wdt_rst_flag == 1                    # STA.RST_FLAG for the new boot
    _serves_after_reset(emu, client, nonce)
    assert mcu.faults == {}


@needs_native
def test_long_requests_keep_the_watchdog_quiet():
    emu, client = _board()
    mcu = emu.backend.mcu
    kicks = mcu.s.wdt_kicks
    client.write_pulse(3, 3, m.Polarity.RESET, 300, 1_000_000)          # the longest pulse
    res = client.spike_batch([m.SpikeGroup(((2, 100),), (0, 60))], [0], n_bins=61,
                             bin_us=65535, paced=True)                  # 3.9 s paced
    assert len(res.codes) == 2
    assert mcu.resets == 0 and mcu.faults == {}
    assert mcu.s.wdt_kicks > kicks + 7                # the paced wait kicks every 0.5 s
    assert emu.clock.now_us > 4.9e6


@needs_native
def test_cpu_trap_reboots_the_firmware_and_the_board_keeps_serving():
    emu, client = _board()
    nonce = client.boot_nonce
    pulses = client.status().pulses_applied
    _patch(emu, "ops_write_pulse", 0x00000000)        # an illegal instruction
    mcu = emu.backend.mcu
    with pytest.raises(LinkTimeoutError):
        client.write_pulse(1, 1, m.Polarity.SET, 600, 20)
    assert mcu.reset_causes == {"trap": 1} and mcu.s.wdt_rst_flag == 0
    assert emu.board.front_end.pulses_applied == pulses        # nothing was applied
    _serves_after_reset(emu, client, nonce)


# ---------------------------------------------------------------- the native column-read kernel
@needs_native
@pytest.mark.parametrize("board", ["default", "no ADC noise", "ideal array"])
def test_column_kernel_gives_the_python_samplers_codes(board):
    """READ_COLUMN with 1..32 driven rows (numpy's summation below and above 8 terms), random
    codes, every column, also saturating: the same codes and counters as the Python model."""
    from snan_hil.firmware_emu.testing import ideal_array
    rng = random.Random(7)
    requests = []
    for k in list(range(1, 33)) + [32, 32, 15]:
        rows = rng.sample(range(32), k)
        codes = [0] * 32
        for r in rows:
            codes[r] = rng.randrange(1, 246)
        if k == 32 and len(requests) >= 32:
            codes = [245] * 32                        # all rows at the limit: saturates
        requests.append(m.ReadColumn(rng.randrange(8), tuple(codes)))
    out = {}
    for mcu in ("model", "firmware"):
        kw = {"adc_noise_lsb": 0.0} if board == "no ADC noise" else {}
        array = ideal_array(3) if board == "ideal array" else default_array(3)
        emu = Emulator(None, 3, array=array, mcu=mcu, **kw)
        client = LinkClient(CallbackTransport(emu.feed, name=mcu))
        client.hello()
        codes = [client.read_column(r.col, list(r.row_codes)) for r in requests]
        st = client.status()
        out[mcu] = (codes, st.saturated_reads, emu.board.front_end.samples,
                    emu.board.front_end.saturated_samples)
        if mcu == "firmware":                         # every sample came from the kernel
            assert emu.backend.mcu.kernel_samples == 11 * len(requests)
    assert out["model"] == out["firmware"]
    assert out["model"][1] >= 1 and len(set(out["model"][0])) > 30
