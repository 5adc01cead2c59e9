"""The legacy emulator behaves like the existing firmware: every amplitude the real board takes,
its clamps, silence or the opt-in refusal, replies only after the pulse (virtual and wall time)."""

import time

import numpy as np
import pytest

from snan_hil.common.errors import UserError
from snan_hil.firmware_emu import registers as reg
from snan_hil.firmware_emu.emulator import Emulator
from snan_hil.firmware_emu.server import PtyServer, TcpServer
from snan_hil.firmware_emu.testing import ideal_array
from snan_hil.common.polarity import Polarity
from snan_hil.protocol.board import MEMRICORE
from snan_hil.protocol.errors import OutOfRangeError
from snan_hil.protocol.legacy_client import LegacyClient
from snan_hil.protocol.transport import SerialTransport
from snan_hil.tools import cli
from snan_hil.tools.ports import open_client


def legacy_emu(**kw):
    kw.setdefault("array", ideal_array())
    return Emulator(None, 0, protocol="legacy", adc_noise_lsb=0.0, **kw)


def reply(emu, line: bytes) -> tuple[int, int]:
    out = emu.feed(line)
    assert out.endswith(b"\n") and out.count(b"\n") == 1, out
    adc, id_ = out.decode().strip().split(",")
    return int(adc), int(id_)


def wdac_codes(emu, line: bytes) -> list[int]:
    """The write-DAC codes the firmware sends for ``line``."""
    bus = emu.board.bus
    bus.start_trace()
    emu.feed(line)
    return [int.from_bytes(t.mosi, "big") & 0xFFF for t in bus.stop_trace()
            if t.cs == reg.CS_WRITE_DAC]


def test_the_amplitudes_the_existing_host_uses_are_applied_not_refused():
    emu = legacy_emu()
    emu.array.set_conductance(7, 2, 3e-4)
    g = emu.array.conductance
    # issue 11: 1147 (the old host's 1.4 V) and ~1394 (its 1.7 V ramp end) were refused (-5)
    for code, sign, direction in ((1147, 0, -1), (1394, 0, -1), (1394, 1, +1), (1147, 1, +1)):
        before = g()[7, 2]
        adc, id_ = reply(emu, f"7,{code},0,100,{sign},{code + sign},2,7\n".encode())
        assert id_ == code + sign and adc > 0
        assert np.sign(g()[7, 2] - before) == direction
    assert emu.legacy.counters.refusals == 0


def test_reset_is_clamped_at_3_volts_set_is_not_and_reads_are_at_246():
    emu = legacy_emu()
    assert wdac_codes(emu, b"7,4000,0,100,0,1,0,0\n") == [MEMRICORE.reset_clamp_code, 0,
                                                            MEMRICORE.legacy_read_code, 0]
    assert wdac_codes(emu, b"7,3000,0,100,1,2,0,1\n")[0] == 3000     # SET: as asked
    assert wdac_codes(emu, b"9,4000,3,0,2\n") == [MEMRICORE.legacy_read_code, 0]
    assert wdac_codes(emu, b"9,200,4,0,2\n") == [200, 0]
    assert wdac_codes(emu, b"7,0,0,0,0,5,0,2\n") == [MEMRICORE.legacy_read_code, 0]


def test_out_of_range_requests_get_silence_by_default_and_codes_only_opted_in():
    quiet, loud = legacy_emu(), legacy_emu(legacy_refusals=True)
    for line, answer in ((b"9,245,1,8,0\n", b"-4,1\n"), (b"9,245,2,0,32\n", b"-4,2\n"),
                         (b"7,4096,0,100,1,3,0,0\n", b"-4,3\n")):
        assert quiet.feed(line) == b""                  # as the existing firmware: no reply
        assert loud.feed(line) == answer                # opt-in: -OUT_OF_RANGE,id
    assert quiet.legacy.counters.refusals == 3
    # wl/bl/sign wider than their 8-bit fields, or a 16-bit field overflowing: not a request
    for line in (b"9,245,4,256,0\n", b"9,65536,4,0,0\n", b"7,100,0,100,256,4,0,0\n"):
        assert quiet.feed(line) == loud.feed(line) == b""
    assert quiet.board.front_end.pulses_applied == 0
    with pytest.raises(OutOfRangeError):
        quiet.firmware.write_pulse(0, 0, Polarity.SET, 4096, 100)


def test_a_pulse_is_answered_after_its_width_in_virtual_time():
    emu = legacy_emu()
    for t_ms, t_us in ((0, 100), (5, 0), (1000, 0), (65, 535)):
        t0 = emu.clock.now_us
        reply(emu, f"7,500,{t_ms},{t_us},1,9,0,0\n".encode())
        assert emu.clock.now_us - t0 >= t_ms * 1000 + t_us
        assert emu.last_busy_us >= t_ms * 1000 + t_us


@pytest.mark.parametrize("server", ["pty", "tcp"])
def test_a_one_second_pulse_is_answered_after_it_in_wall_time(server):
    emu = legacy_emu()
    srv = PtyServer(emu) if server == "pty" else TcpServer(emu, "127.0.0.1", 0)
    with srv:
        url = srv.slave_path if server == "pty" else srv.url
        # issue 11: a 0.1 s timeout used to lose this reply
        client = LegacyClient(SerialTransport(url), timeout=0.1, retries=0)
        try:
            client.hello()
            t0 = time.monotonic()
            adc = client.write_pulse(3, 2, Polarity.SET, 60, 1_000_000)
            took = time.monotonic() - t0
            assert adc > 0 and client.counters.uncertain_writes == 0
            assert 1.0 <= took < 3.0
            # the existing host reads at once with 75 ms: nothing yet, the reply comes later
            client.transport.write(b"7,60,400,0,1,77,2,3\n")
            assert client.transport.read(64, 0.075) == b""
            time.sleep(0.4)
            got = b""
            while not got.endswith(b"\n"):
                data = client.transport.read(64, 1.0)
                assert data, got
                got += data
            assert got.endswith(b",77\n")
        finally:
            client.close()
    assert emu.board.front_end.pulses_applied == 2


def test_wall_pacing_scale_and_options(capsys):
    assert legacy_emu().wall_scale == 1.0
    assert Emulator(None, 0, array=ideal_array()).wall_scale == 0.0      # framed: unchanged
    assert legacy_emu(wall_scale=0.0).wall_scale == 0.0
    with pytest.raises(UserError):
        legacy_emu(wall_scale=-1.0)
    for argv, needle in ((["emu", "--legacy-refusals"], "--protocol legacy"),
                         (["emu", "--protocol", "legacy", "--wall-scale", "-2"], "--wall-scale")):
        assert cli.main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and needle in err


def test_refusals_opt_in_through_the_port_options(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    client = open_client("emu", protocol="legacy", legacy_refusals=True)
    try:
        assert client.refusals
        with pytest.raises(OutOfRangeError):
            client.read_cell(40, 0)
    finally:
        client.close()
    assert cli.main(["info", "--port", "emu", "--legacy-refusals"]) == 2
    assert "--protocol legacy" in capsys.readouterr().err


def test_breakdown_on_the_emulated_board():
    emu = legacy_emu()
    emu.array.set_conductance(5, 5, 1e-4)                 # 10 kOhm: 3 V puts ~2.96 V on it
    before, _ = reply(emu, b"9,245,1,5,5\n")
    after, _ = reply(emu, b"7,4000,0,100,0,2,5,5\n")      # RESET clamped to 3.0 V: breaks down
    assert emu.array.broken[5, 5] and after > 3 * before   # ~500 Ohm now
    again, _ = reply(emu, b"7,1000,0,100,0,3,5,5\n")      # a shorted cell no longer switches
    assert abs(again - after) <= 2
    emu.array.set_conductance(6, 5, 1e-4)
    reply(emu, b"7,1394,0,100,0,4,5,6\n")                 # the old host's 1.7 V: no damage
    assert not emu.array.broken[6, 5]
