"""The instruction-level MCU's spin timing (``IsaMcu(poll_timing="spin")``, issue 37 point 4):
its wait loops poll until the flag becomes true, as on the MCU, and nothing but time changes;
and host bytes that arrive during a wait are read in time in either timing."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("unicorn")

from snan_hil.common.errors import UserError                               # noqa: E402
from snan_hil.firmware_emu import differential_fast as fast                 # noqa: E402
from snan_hil.firmware_emu import mik32_state as ms                        # noqa: E402
from snan_hil.firmware_emu.fw_image import FirmwareImage, default_elf_path  # noqa: E402
from snan_hil.firmware_emu.isa_coverage import BranchCoverage              # noqa: E402
from snan_hil.firmware_emu.mcu_isa import choose_timing                    # noqa: E402
from snan_hil.protocol import messages as m                                # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import test_firmware_mcu as script                                         # noqa: E402

if not default_elf_path().is_file():
    pytest.skip("firmware ELF not built ('make firmware')", allow_module_level=True)

# the HAL's wait loops: their "wait again" outcome is reached only when a poll says "not yet"
WAIT_LOOPS = ("hal_wait_until", "hal_spi_write", "hal_adc_frames")


def _session(monkeypatch, timing: str):
    monkeypatch.setenv("SNAN_HIL_MCU_TIMING", timing)
    board = script.Board("firmware")
    mcu = board.emu.backend.mcu
    cov = BranchCoverage(FirmwareImage.load())
    cov.attach(mcu)
    board.emu.board.bus.start_trace()
    replies = script.scripted(board)
    trace = board.emu.board.bus.stop_trace()
    outcomes = {f.name: f.outcomes for f in cov.functions()}
    return replies, trace, board.emu.array.conductance(), mcu, outcomes


def test_spin_timing_runs_the_wait_loops_and_changes_nothing_but_time(monkeypatch):
    (ra, ta, ga, ma, ca), (rb, tb, gb, mb, cb) = (_session(monkeypatch, t)
                                                 for t in ("collapsed", "spin"))
    assert ma.poll_timing == "collapsed" and mb.poll_timing == "spin"
    # every reply but CLOCK's times and RESET's new nonce (hal_entropy mixes in the timer),
    # every SPI frame's bytes, the chip: the same
    timed = (m.ClockReply.TYPE, m.ResetReply.TYPE)
    key = [(f.type, f.seq, f.flags, f.payload) for f in ra if f.type not in timed]
    assert key == [(f.type, f.seq, f.flags, f.payload) for f in rb if f.type not in timed]
    assert len(key) >= len(ra) - 2
    assert [(t.cs, t.mosi, t.miso) for t in ta] == [(t.cs, t.mosi, t.miso) for t in tb]
    assert np.array_equal(ga, gb)
    assert ma.faults == mb.faults == {} and ma.resets == mb.resets == 0
    # the loops really wait: polls answered "not yet", instructions spent spinning
    assert ma.spin_polls == 0 and mb.spin_polls > 1000
    assert mb.instructions > 3 * ma.instructions
    for name in WAIT_LOOPS:
        assert cb[name] > ca[name], name          # the "wait again" outcomes


def test_a_timing_that_does_not_exist_is_one_line(monkeypatch):
    assert choose_timing(None) == "collapsed"
    monkeypatch.setenv("SNAN_HIL_MCU_TIMING", "cycle")
    with pytest.raises(UserError, match="SNAN_HIL_MCU_TIMING.*collapsed or spin"):
        choose_timing(None)


@pytest.mark.parametrize("timing", ("collapsed", "spin"))
def test_host_bytes_arriving_during_a_wait_are_read_in_time(monkeypatch, timing):
    """Seed 2 sends two frames in one write while the firmware works (write 555: a
    SPIKE_BATCH, then the next request). The collapsed timing jumped the first poll of a
    waiting loop to its compare past the host bytes (UART_OVERRUN counted, the stream
    stopped), and the firmware left 3,103 cycles (> one byte time, 2,778) between its UART
    services after a reading's frames."""
    monkeypatch.setenv("SNAN_HIL_MCU_TIMING", timing)
    stats = fast.run_stream(2, 700)
    assert stats.frames >= 700


def test_corner_requests_are_answered_alike_past_the_timer_wrap_and_at_full_scale(monkeypatch):
    """The corner requests (firmware_emu/corner_cases.py) on both MCUs, compared write by
    write: a paced batch whose spike comes after the firmware's 32-bit timer wrapped, and
    column readings climbing to full scale."""
    from snan_hil.firmware_emu import corner_cases
    monkeypatch.setenv("SNAN_HIL_MCU_TIMING", "collapsed")
    twin = fast.FastTwin(1, (11, 12, 13))
    try:
        replies = corner_cases.run(twin, fast.RequestStream(1),
                                   corner_cases.timer_half() + corner_cases.timer_wrap() +
                                   corner_cases.saturation())
        mcu = twin.emus["firmware"].backend.mcu
        assert mcu.cycles > 1 << 32                       # the timer wrapped during the batch
    finally:
        twin.close()
    half, batch, *reads = [f.message() for f in replies]
    assert isinstance(half, m.SpikeBatchReply) and len(half.codes) == 1
    assert isinstance(batch, m.SpikeBatchReply) and len(batch.codes) == 1
    codes = [r.adc for r in reads]
    assert len(codes) == 3 * 32
    assert codes.count(16383) >= 3 and min(codes) < 2000  # from low to full scale
    assert any(16000 < c < 16383 for c in codes)          # a reading just below it


def test_program_cell_stops_at_once_when_its_first_reading_is_its_target():
    """PROGRAM_CELL to the code the cell just read, 64 cells, both MCUs compared: where the
    command's own first reading equals the target, fine tuning applies no pulse (``a <=
    target`` and ``a >= target`` both hold; a ``<`` would pulse)."""
    from snan_hil.firmware_emu import corner_cases
    twin = fast.FastTwin(1, (11, 12, 13))
    try:
        replies = [f.message() for f in corner_cases.program_at_reading(
            twin, fast.RequestStream(1))]
    finally:
        twin.close()
    assert len(replies) == len(corner_cases.BOUNDARY_CELLS)
    assert all(isinstance(r, m.ProgramCellReply) and r.ok for r in replies)
    assert any(r.pulses_stage1 == r.pulses_stage2 == 0 for r in replies)


def _wait_with_a_host_byte_in(native: bool, serve: bool):
    """A compare wait of 3,000 cycles on one peripheral core (collapsed timing), entered with
    a host byte that arrived 5 cycles before its first poll and the next one due 2,700 cycles
    later: the HAL's ``wait_until`` loop, serving the UART between its polls (``serve``) or
    not. Returns the bench, the bytes read and the compare polls made."""
    from test_firmware_native import LIB, Bench
    if native and LIB is None:
        pytest.skip("native MCU core not built")
    bench = Bench(native)
    s = bench.s
    s.pm_p, s.pad_cfg[0], s.uart_on = 0xFFFFFFFF, 0x55555555, 1
    s.idle_lo, s.idle_hi = 0x100, 0x200                  # the loop is not the idle loop
    s.cycles = 100_000
    s.tim_on, s.tim_start, s.ch0_cntrl = 1, 0, 0xA0
    s.oc_armed, s.oc_target = 1, s.cycles + 3000
    for k, (dt, b) in enumerate(((-5, 0xA5), (2700, 0x5A))):
        s.rx_t[k], s.rx_b[k] = s.cycles + dt, b
    s.rx_head, s.rx_count = 0, 2
    got, polls = [], 0
    for _ in range(100):
        bench.block(12)
        polls += 1
        if bench.read(False, 0x1800 + 0x1C) & (1 << 6):  # TIMER32_1 INT_FLAGS.OC0
            break
        if serve:
            bench.block(40)                                # hal_uart_service
            if bench.read(False, 0x0400 + 0x1C) & (1 << 5):   # UART FLAGS.RXNE
                got.append(bench.read(False, 0x0400 + 0x24))
    return bench, got, polls


@pytest.mark.parametrize("native", (False, True), ids=("reference", "native"))
def test_a_host_byte_that_arrived_before_a_served_wait_is_read_in_time(native):
    """Seed 14 of the fast differential tester (write 24,229: a PROGRAM_CELL and the next
    request in one write): a byte arrived between a long pulse's UART service and the first
    poll of its served wait; the collapsed timing jumped that poll to the compare, past the
    next byte (UART_OVERRUN counted; a real MCU polls "not yet" and serves the byte)."""
    bench, got, _ = _wait_with_a_host_byte_in(native, serve=True)
    s = bench.s
    assert got == [0xA5, 0x5A]
    assert s.faults[ms.F["UART_OVERRUN"]] == 0
    assert s.cycles >= s.oc_target and s.oc_flag == 1


@pytest.mark.parametrize("native", (False, True), ids=("reference", "native"))
def test_a_wait_that_does_not_serve_the_uart_still_ends_at_its_compare(native):
    """The same wait without the UART served (the pulse gate's tight loop, an ADC frame's
    spacing): one "not yet" for the waiting byte, then the compare at its exact cycle - and
    the byte overrun there, as on the MCU."""
    bench, got, polls = _wait_with_a_host_byte_in(native, serve=False)
    s = bench.s
    assert got == [] and polls == 2
    assert s.cycles == s.oc_target and s.oc_flag == 1
