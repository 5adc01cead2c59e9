"""Every framed message type through the emulator's endpoint, interlocks as ERROR replies,
legacy lines, UART time on the virtual clock."""

import dataclasses

import numpy as np
import pytest

from snan_hil.firmware_emu import registers as reg
from snan_hil.firmware_emu.config import BoardConfig
from snan_hil.firmware_emu.emulator import Emulator
from snan_hil.firmware_emu.testing import ideal_array
from snan_hil.protocol import messages as m
from snan_hil.protocol.errors import ErrorCode, OutOfRangeError, SafetyLimitError
from snan_hil.protocol.frames import FrameDecoder, Frame, encode_frame
from snan_hil.protocol.link import LinkClient
from snan_hil.protocol.safety import HostSafetyError
from snan_hil.protocol.transport import CallbackTransport


def make(config=None, protocol="framed"):
    emu = Emulator(None, 0, array=ideal_array(), config=config, protocol=protocol,
                   adc_noise_lsb=0.0)
    client = LinkClient(CallbackTransport(emu.feed, name="test emu"), timeout=0.2, retries=0)
    if protocol == "framed":
        client.hello()
    return emu, client


def test_hello_reports_board_constants_and_nonce():
    emu, client = make()
    info = client.info
    assert (info.rows, info.cols, info.dac_bits, info.adc_bits) == (32, 8, 12, 14)
    assert (info.r_load_ohm, info.r_switch_ohm, info.gain, info.sum_gain_ohm) == \
        (3000.0, 10.0, 11.0, 330.0)
    assert info.max_read_v == 0.3 and info.max_write_v == 1.4 and info.compliance_a == 2e-3
    assert info.read_code == info.dac_code(info.v_read_v) == 245   # largest code <= 0.3 V
    assert info.dac_volts(info.read_code) <= info.max_read_v < info.dac_volts(246)
    assert info.boot_nonce == emu.firmware.boot_nonce != 0
    assert info.has(m.Capability.SPIKE_BATCH) and info.has(m.Capability.PROGRAM_CELL)


def test_reads_writes_and_counters():
    emu, client = make()
    array = emu.array
    array.set_conductance(3, 2, 2e-4)
    before = client.read_cell(3, 2)
    after_set = client.write_pulse(3, 2, m.Polarity.SET, 900, 200)
    assert after_set > before                            # SET: conductance and code up
    after_reset = client.write_pulse(3, 2, m.Polarity.RESET, 1100, 500)
    assert after_reset < after_set
    codes = [0] * 32
    codes[3] = 245
    col = client.read_column(2, codes)
    assert col > 0
    status = client.status()
    assert status.cell_reads == 3 and status.column_reads == 1
    assert status.pulses_applied == 2
    assert status.frames_in == status.executed == 6     # hello + 5
    assert emu.dirty                                     # writes mark the chip for saving


def test_spike_batch_returns_codes_per_spike_and_column():
    emu, client = make()
    rng = np.random.default_rng(2)
    for r in range(15):
        for c in range(8):
            emu.array.set_conductance(r, c, rng.uniform(5e-5, 5e-4))
    bins = tuple(int(b) for b in np.flatnonzero(rng.random(200) < 0.15))
    group = m.SpikeGroup(tuple((r, 82) for r in range(15)), bins)
    res = client.spike_batch([group], list(range(8)), n_bins=200)
    assert res.spikes == tuple((b, 0) for b in bins)
    codes = np.array(res.codes)
    assert codes.shape == (len(bins), 8)
    # Noise-free chip and ADC: every spike reads the same column sums; columns differ.
    assert np.all(codes == codes[0])
    g_eff = emu.array.effective_conductance()[:15]
    expected = 2 ** 14 * (82 * 5 / 4095) * g_eff.sum(axis=0) * 330 * 11 / 5
    assert np.allclose(codes[0], expected, atol=1.0)
    assert client.status().spikes_applied == len(bins)


def test_program_cell_reaches_target():
    emu, client = make()
    emu.array.set_conductance(0, 0, 1e-4)
    target = client.read_cell(0, 0) + 1500
    reply = client.program_cell(0, 0, target, 60, max_pulses=400, amp_start_code=300,
                                amp_stop_code=1100, amp_step_code=8)
    assert reply.ok
    assert abs(reply.final_adc - target) <= 60
    assert reply.pulses_stage1 > 0
    assert abs(client.read_cell(0, 0) - target) <= 60


def test_clock_and_reset():
    emu, client = make()
    c0 = client.clock()
    client.read_cell(1, 1)
    c1 = client.clock()
    assert c1.time_us > c0.time_us and c1.energy_j > c0.energy_j
    old_nonce = client.info.boot_nonce
    reply = client.reset()
    assert reply.old_nonce == old_nonce and reply.new_nonce != old_nonce
    assert client.clock().time_us < c1.time_us
    assert client.status().cell_reads == 0
    client.read_cell(1, 1)                # the client learned the new nonce from the reply


def test_uart_bytes_advance_the_clock_at_the_baud():
    emu = Emulator(None, 0, array=ideal_array(), baud=9600, adc_noise_lsb=0.0)
    t0 = emu.clock.now_us
    out = emu.feed(b"\x00" * 48)          # 48 empty frames: no reply
    assert out == b""
    assert emu.clock.now_us - t0 == pytest.approx(48 * 10 / 9600 * 1e6)


# Over-limit requests are sent raw (client.request): the client's convenience methods refuse
# them on the host side already (tests/protocol/test_protocol_safety.py); here the firmware must
# too.
@pytest.mark.parametrize("call, error, code", [
    (lambda c: c.request(m.ReadCell(0, 0, 246)), SafetyLimitError, 246),      # 0.3004 V > 0.3 V
    (lambda c: c.request(m.ReadColumn(0, (0,) * 31 + (300,))), SafetyLimitError, 300),
    (lambda c: c.request(m.WritePulse(0, 0, m.Polarity.SET, 1147, 100)), SafetyLimitError,
     1147),                                                                    # 1.4005 V
    (lambda c: c.request(m.WritePulse(0, 0, m.Polarity.RESET, 1500, 100)), SafetyLimitError,
     1500),
    (lambda c: c.read_cell(32, 0), OutOfRangeError, 32),
    (lambda c: c.read_cell(0, 8), OutOfRangeError, 8),
    (lambda c: c.write_pulse(0, 0, m.Polarity.SET, 500, 0), OutOfRangeError, 0),
    (lambda c: c.request(m.ProgramCell(0, 0, 5000, 10, 100, 300, 1300, 1, 100, 0, True)),
     SafetyLimitError, 1300),
])
def test_interlocks_refuse_without_touching_the_board(call, error, code):
    emu, client = make()
    g0 = emu.array.conductance()
    spi0 = emu.board.bus.transactions
    with pytest.raises(error) as exc:
        call(client)
    assert exc.value.detail == code
    assert emu.board.bus.transactions == spi0            # nothing was sent to the chips
    assert np.array_equal(emu.array.conductance(), g0)
    assert client.status().refusals == 1
    assert emu.firmware.counters.refusals == 1


def test_largest_allowed_codes_pass():
    emu, client = make()
    client.read_cell(0, 0, 245)                          # 0.2991 V
    client.read_column(0, [245] * 32)
    client.write_pulse(0, 0, m.Polarity.RESET, 1146, 10)   # 1.3993 V


def test_compliance_interlock_uses_predicted_current():
    emu, client = make(config=BoardConfig(compliance_a=1e-3))
    emu.array.set_conductance(5, 5, 1e-3)
    g0 = emu.array.conductance()[5, 5]
    allowed = 819                                        # 1.0 V: ~0.86 mA predicted
    refused = 1146                                       # 1.3993 V: ~1.2 mA predicted
    assert emu.array.pulse_current(5, 5, 1.0) < 1e-3 < emu.array.pulse_current(5, 5, 1.4)
    with pytest.raises(SafetyLimitError) as exc:
        client.write_pulse(5, 5, m.Polarity.RESET, refused, 100)
    assert exc.value.code == ErrorCode.SAFETY_LIMIT
    assert exc.value.detail == round(emu.array.pulse_current(5, 5, refused * 5 / 4095) * 1e6)
    assert emu.array.conductance()[5, 5] == g0
    client.write_pulse(5, 5, m.Polarity.RESET, allowed, 100)
    assert emu.array.conductance()[5, 5] < g0


def test_program_cell_never_exceeds_compliance():
    emu, client = make(config=BoardConfig(compliance_a=1e-3))
    array = emu.array
    array.set_conductance(1, 1, 6e-4)
    seen = []
    original = array.apply_pulse

    def spy(row, col, amplitude_v, polarity, width_s):
        seen.append(array.pulse_current(row, col, amplitude_v))
        return original(row, col, amplitude_v, polarity, width_s)

    array.apply_pulse = spy
    reply = client.program_cell(1, 1, 16000, 10, max_pulses=60, amp_start_code=400,
                                amp_stop_code=1146, amp_step_code=40, fine_tune=False)
    assert seen and max(seen) <= 1e-3
    assert not reply.ok                       # an unreachable target stops at the pulse bound
    assert reply.pulses_stage1 <= 60


def test_unknown_type_and_duplicate_retransmission():
    emu, client = make()
    decoder = FrameDecoder()
    nonce = emu.firmware.boot_nonce
    unknown = Frame(0x33, 7, b"", nonce)
    (reply,) = decoder.feed(emu.feed(encode_frame(unknown)))
    err = reply.message()
    assert isinstance(err, m.ErrorReply) and err.code == ErrorCode.UNKNOWN_TYPE
    pulse = Frame.of(m.WritePulse(2, 2, m.Polarity.SET, 900, 100), 8, nonce)
    first = decoder.feed(emu.feed(encode_frame(pulse)))[0].message()
    again = decoder.feed(emu.feed(encode_frame(dataclasses.replace(pulse, flags=1))))
    assert again[0].message() == first
    assert emu.board.front_end.pulses_applied == 1   # the retransmission was not executed


def test_legacy_lines_on_the_same_firmware():
    emu = Emulator(None, 0, array=ideal_array(), protocol="legacy", adc_noise_lsb=0.0)
    emu.array.set_conductance(3, 2, 3e-4)
    read = emu.feed(b"9,246,5,2,3\n")
    adc, id_ = map(int, read.decode().split(","))
    assert id_ == 5 and adc > 0
    # Mode 9 above 0.3 V is clamped by the board (as the old firmware), not refused.
    assert emu.feed(b"9,2000,6,2,3\n") == f"{adc},6\n".encode()
    probe = emu.feed(b"7,0,0,0,0,0,0,0\n")
    assert probe.decode().endswith(",0\n")
    pulse = emu.feed(b"7,900,0,200,1,7,2,3\n")           # SET pulse of 200 us
    set_adc = int(pulse.split(b",")[0])
    assert set_adc > adc and pulse.endswith(b",7\n")
    # the existing firmware has no write interlock: 1.83 V RESET is applied, G falls
    reset = emu.feed(b"7,1500,0,100,0,8,2,3\n")
    assert reset.endswith(b",8\n") and int(reset.split(b",")[0]) < set_adc
    info = emu.feed(b"100\n").decode().strip().split(",")
    assert info[0].startswith("EMU-") and info[2:] == ["32", "8", "12", "14"]
    assert emu.feed(b"10,1,2,3\n") == b""                 # mode 10: not on the serial path


def test_status_reports_saturated_reads():
    emu, client = make()
    assert client.status().saturated_reads == 0
    for row in range(32):
        emu.array.set_conductance(row, 0, 1e-3)          # the column sum clips the ADC
    assert client.read_column(0, [245] * 32) == 2 ** 14 - 1
    client.read_column(0, [10] + [0] * 31)               # in range: not counted
    status = client.status()
    assert status.saturated_reads == 1 == emu.firmware.counters.saturated_reads
    assert status.column_reads == 2


def test_program_cell_zero_amplitude_codes_mean_the_old_hosts_ramp():
    emu, client = make()
    emu.array.set_conductance(0, 0, 5e-5)
    bus = emu.board.bus
    bus.start_trace()
    reply = client.program_cell(0, 0, 16000, 10, max_pulses=3, fine_tune=False)
    trace = bus.stop_trace()
    assert reply.pulses_stage1 == 3 and not reply.ok
    amps, wdac = [], 0
    for t in trace:                  # the write-DAC code latched when each pulse gate opens
        if t.cs == reg.CS_WRITE_DAC:
            wdac = int.from_bytes(t.mosi, "big") & 0xFFF
        elif t.cs == reg.CS_SR_COL and t.mosi[0] & reg.PULSE_GATE:
            amps.append(wdac)
    start, step = round(0.3 * 4095 / 5), round(0.01 * 4095 / 5)
    assert (start, step) == (246, 8)
    assert amps == [start, start + step, start + 2 * step]
    # A zero stop code is 1.2 V = code 983: a ramp may start there, not above.
    stop = round(1.2 * 4095 / 5)
    assert client.program_cell(0, 0, 16000, 10, max_pulses=1, amp_start_code=stop,
                               fine_tune=False).pulses_stage1 == 1
    with pytest.raises(OutOfRangeError):
        client.program_cell(0, 0, 16000, 10, max_pulses=1, amp_start_code=stop + 1)


@pytest.mark.parametrize("v_read_max", [0.3, 0.25, 0.2])
def test_read_limit_is_the_largest_code_not_above_the_limit_and_info_reports_it(v_read_max):
    emu, client = make(config=BoardConfig(max_read_v=v_read_max))
    info = client.info
    code = info.read_code
    assert info.dac_volts(code) <= v_read_max < info.dac_volts(code + 1)   # floor, not round
    assert info.v_read_v == pytest.approx(info.dac_volts(code))
    bus = emu.board.bus
    bus.start_trace()
    client.read_cell(2, 2)                    # the client's default read uses INFO's code
    wdac = [t.mosi for t in bus.stop_trace() if t.cs == reg.CS_WRITE_DAC]
    assert wdac[0] == code.to_bytes(2, "big")
    with pytest.raises(HostSafetyError):                # the host does not send it...
        client.read_cell(2, 2, code + 1)
    with pytest.raises(SafetyLimitError):               # ...and the firmware refuses it raw
        client.request(m.ReadCell(2, 2, code + 1))
    with pytest.raises(SafetyLimitError):
        client.request(m.WritePulse(2, 2, m.Polarity.SET, 500, 100, code + 1))


def test_write_limit_is_the_largest_code_not_above_the_limit():
    cfg = BoardConfig()
    code = cfg.max_write_code
    assert cfg.write_dac_volts(code) <= cfg.max_write_v < cfg.write_dac_volts(code + 1)
    assert code == 1146


# --------------------------------------------------------------------------- issue 17 decisions
SPIKE_EDGE_CASES = [
    # (request, code, detail): docs/protocol.md SPIKE_BATCH, refused before anything is driven
    (m.SpikeBatch((m.SpikeGroup(((1, 100),), ()),), (0,), n_bins=0), ErrorCode.OUT_OF_RANGE, 0),
    (m.SpikeBatch((m.SpikeGroup(((1, 100),), (2,)),), (0,), n_bins=8, bin_us=0, paced=True),
     ErrorCode.OUT_OF_RANGE, 0),
    (m.SpikeBatch((m.SpikeGroup(((1, 100),), (2,)), m.SpikeGroup((), (3,))), (0,), n_bins=8),
     ErrorCode.OUT_OF_RANGE, 1),                       # group 1 drives no row
    (m.SpikeBatch((m.SpikeGroup(((4, 100), (5, 90), (4, 80)), (2,)),), (0,), n_bins=8),
     ErrorCode.OUT_OF_RANGE, 4),                       # row 4 twice in one group
]


@pytest.mark.parametrize("request_, code, detail", SPIKE_EDGE_CASES)
def test_spike_batch_edge_cases_are_refused_untouched(request_, code, detail):
    emu, client = make()
    spi0 = emu.board.bus.transactions
    reply = _raw(emu, client, request_)
    assert (reply.code, reply.detail, reply.request_type) == (code, detail, m.SpikeBatch.TYPE)
    assert emu.board.bus.transactions == spi0
    assert emu.firmware.counters.spikes_applied == 0


def test_spike_batch_bin_us_0_without_pacing_and_empty_mask_are_accepted():
    emu, client = make()
    req = m.SpikeBatch((m.SpikeGroup(((1, 100),), (2, 5)),), (), n_bins=8, bin_us=0)
    reply = client.request(req)
    assert reply == m.SpikeBatchReply(0, 0, ((), ()))
    assert emu.firmware.counters.spikes_applied == 2


def test_host_refuses_the_edge_cases_before_sending():
    from snan_hil.protocol.errors import FieldRangeError
    emu, client = make()
    sent = client.counters.frames_sent
    for kwargs in ({"groups": [m.SpikeGroup(((1, 100),), ())], "n_bins": 0},
                   {"groups": [m.SpikeGroup(((1, 100),), (1,))], "n_bins": 8, "bin_us": 0,
                    "paced": True},
                   {"groups": [m.SpikeGroup((), (1,))], "n_bins": 8},
                   {"groups": [m.SpikeGroup(((1, 100), (1, 90)), (1,))], "n_bins": 8}):
        with pytest.raises(FieldRangeError):
            client.spike_batch(columns=[0], **kwargs)
    assert client.counters.frames_sent == sent


def _raw(emu, client, request_, nonce=None):
    """Send a request without the host's checks; the decoded reply message."""
    frame = Frame(request_.TYPE, 7, request_.encode(),
                  client.boot_nonce if nonce is None else nonce)
    (reply,) = FrameDecoder().feed(emu.feed(encode_frame(frame)))
    return reply.message()


def test_hello_with_another_version_names_the_boards_version():
    emu, client = make()
    reply = _raw(emu, client, m.Hello(2), nonce=0)
    assert (reply.code, reply.detail) == (ErrorCode.BAD_VERSION, m.PROTOCOL_VERSION)


def test_program_cell_bool_must_be_0_or_1():
    emu, client = make()
    payload = bytearray(m.ProgramCell(0, 0, 5000, 50, 3).encode())
    payload[-1] = 2
    frame = Frame(m.ProgramCell.TYPE, 9, bytes(payload), client.boot_nonce)
    (reply,) = FrameDecoder().feed(emu.feed(encode_frame(frame)))
    err = reply.message()
    assert err.code == ErrorCode.MALFORMED and emu.board.front_end.pulses_applied == 0


def test_read_cell_code_0_is_a_0_volt_read_write_pulse_read_code_0_the_nominal():
    emu, client = make()
    emu.array.set_conductance(2, 2, 2e-4)
    assert client.read_cell(2, 2, 0) <= 2                       # 0 V: only the ADC offset
    nominal = client.read_cell(2, 2, 245)
    after = client.write_pulse(2, 2, m.Polarity.SET, 0, 100, 0)  # no pulse, read at code 0
    assert abs(after - nominal) <= 3 and nominal > 1000


def test_cell_reads_use_the_write_dac_rows_the_row_dacs():
    # a board whose write DAC has half the reference: 0.3 V is write-DAC code 491
    cfg = BoardConfig(write_dac_vref_v=2.5)
    assert (cfg.max_cell_read_code, cfg.max_row_read_code, cfg.read_code) == (491, 245, 245)
    assert cfg.v_read_v == pytest.approx(cfg.write_dac_volts(245))
    emu, client = make(config=cfg)
    assert client.info.max_cell_read_code == 491
    client.read_cell(3, 3, 491)                                  # 0.2998 V on the write DAC
    with pytest.raises(SafetyLimitError) as exc:
        client.request(m.ReadCell(3, 3, 492))
    assert exc.value.detail == 492
    with pytest.raises(SafetyLimitError) as exc:
        client.request(m.ReadColumn(0, (0,) * 31 + (246,)))     # 0.3004 V on a row DAC
    assert exc.value.detail == 246
    with pytest.raises(HostSafetyError):
        client.read_column(0, [0] * 31 + [491])                  # host: row limit 245
