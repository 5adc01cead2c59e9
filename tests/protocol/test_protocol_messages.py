"""Messages: exact round trip of every message type, registry, field limits, CRC."""

import dataclasses
import math
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from snan_hil.protocol import learn_messages as lm
from snan_hil.protocol import messages as m
from snan_hil.protocol.board import BoardConstants
from snan_hil.protocol.crc import crc16
from snan_hil.protocol.errors import (ErrorCode, FieldRangeError, MalformedPayloadError,
                                      UnknownTypeError)
from snan_hil.protocol.frames import Frame, FrameDecoder, encode_frame

SETTINGS = settings(max_examples=60, deadline=None, derandomize=True)

u8 = st.integers(0, 0xFF)
u16 = st.integers(0, 0xFFFF)
u32 = st.integers(0, 0xFFFFFFFF)
f64 = st.floats(allow_nan=False)
text = st.text(max_size=30).filter(lambda s: len(s.encode()) <= m.MAX_TEXT)


@st.composite
def spike_batches(draw):
    n_bins = draw(st.integers(0, 1500))
    groups = []
    for _ in range(draw(st.integers(0, 3))):
        rows = tuple(draw(st.lists(st.tuples(u8, u16), max_size=16)))
        bins = tuple(sorted(draw(st.sets(st.integers(0, n_bins - 1), max_size=40))))\
            if n_bins else ()
        groups.append(m.SpikeGroup(rows, bins))
    columns = tuple(sorted(draw(st.sets(st.integers(0, 31), max_size=8))))
    return m.SpikeBatch(tuple(groups), columns, n_bins, draw(u16), draw(u32), draw(st.booleans()))


@st.composite
def spike_batch_replies(draw):
    ncol = draw(st.integers(0, 8))
    codes = draw(st.lists(st.tuples(*[u16] * ncol), max_size=30))
    return m.SpikeBatchReply(draw(u32), ncol, tuple(codes))


@st.composite
def decision_windows(draw):
    i64 = st.integers(-2**63, 2**63 - 1)
    params = draw(st.none() | st.builds(m.DecisionParams, u16, u16, u16, u16, st.integers(0, 1),
                                        u8, u8, u8, st.integers(0, 2**64 - 1),
                                        st.tuples(*[st.integers(0, 2**64 - 1)] * 16),
                                        *[i64] * 7))
    cands = tuple(m.DecisionCandidate(draw(st.integers(0, 31)), draw(st.integers(0, 3)),
                                      tuple(sorted(draw(st.sets(st.integers(0, 50000),
                                                                max_size=12)))))
                  for _ in range(draw(st.integers(0, 7))))
    rows = tuple(draw(st.lists(u8, max_size=7)))
    return m.DecisionWindow(draw(st.integers(0, 2**64 - 1)), rows, cands, params,
                            draw(st.booleans()), draw(u16), draw(st.booleans()))


@st.composite
def decision_replies(draw):
    n = draw(st.integers(0, 4))
    counts = tuple(draw(st.lists(st.integers(0, 20), min_size=n, max_size=n)))
    spikes = draw(st.none() | st.just(tuple((draw(st.integers(0, 16383)), k)
                                            for k in range(n) for _ in range(counts[k]))))
    trace = draw(st.none() | st.lists(st.tuples(*[st.integers(-2**31, 2**31 - 1)] * n),
                                      max_size=20).map(tuple))
    return m.DecisionWindowReply(draw(u16), counts, spikes, trace)


i32 = st.integers(-2**31, 2**31 - 1)
u64 = st.integers(0, 2**64 - 1)


@st.composite
def learn_setups(draw):
    bits = draw(st.integers(0, 7))
    n = (1 << bits) + 1
    syn = tuple(lm.LearnSynapse(draw(u8), draw(i32), draw(i32))
                for _ in range(draw(st.integers(0, 10))))
    return lm.LearnSetup(draw(st.integers(0, 1)), bits, draw(u8), draw(u16), draw(u16),
                         draw(u16), draw(u16), draw(u64), draw(u64), draw(i32), draw(i32),
                         tuple(draw(u64) for _ in range(16)), tuple(draw(u64) for _ in range(16)),
                         tuple(draw(i32) for _ in range(n)), tuple(draw(i32) for _ in range(n)),
                         syn)


@st.composite
def learn_apply_replies(draw):
    orders = tuple(lm.LearnOrder(draw(u8), draw(st.integers(0, 1)), draw(st.integers(1, 127)))
                   for _ in range(draw(st.integers(0, 10))))
    touched = tuple(lm.LearnTouched(draw(u8), draw(i32), draw(i32))
                    for _ in range(draw(st.integers(0, 10))))
    return lm.LearnApplyReply(draw(st.booleans()), draw(u16), draw(u32), orders, touched)


positive = st.floats(1e-3, 1e3)
non_negative = st.floats(0.0, 1e3)
boards = st.builds(BoardConstants, rows=st.integers(1, 32), cols=st.integers(1, 32),
                   dac_bits=st.integers(1, 16), dac_vref_v=positive,
                   write_dac_bits=st.integers(1, 16), write_dac_vref_v=positive,
                   adc_bits=st.integers(1, 16), adc_vref_v=positive,
                   adc_averages=st.integers(1, 255), r_load_ohm=non_negative,
                   r_switch_ohm=non_negative, gain=positive, sum_gain_ohm=positive,
                   max_read_v=non_negative, max_write_v=non_negative, compliance_a=positive)


STRATEGIES = {
    m.Hello: st.builds(m.Hello, u8),
    m.Info: st.builds(lambda board, version, fw, board_id, payload, caps, nonce: m.Info.from_board(
        board, protocol_version=version, firmware_version=fw, board_id=board_id,
        max_payload=payload, capabilities=caps, boot_nonce=nonce),
        boards, u8, text, text, st.integers(240, 0xFFFF), u32, u32),   # >= the INFO itself
    m.ReadCell: st.builds(m.ReadCell, u8, u8, u16),
    m.ReadCellReply: st.builds(m.ReadCellReply, u16),
    m.ReadColumn: st.builds(m.ReadColumn, u8, st.lists(u16, max_size=64).map(tuple)),
    m.ReadColumnReply: st.builds(m.ReadColumnReply, u16),
    m.WritePulse: st.builds(m.WritePulse, u8, u8, st.sampled_from(m.Polarity), u16, u32, u16),
    m.WritePulseReply: st.builds(m.WritePulseReply, u16),
    m.SpikeBatch: spike_batches(),
    m.SpikeBatchReply: spike_batch_replies(),
    m.ProgramCell: st.builds(m.ProgramCell, u8, u8, u16, u16, u16, u16, u16, u16, u32, u16,
                             st.booleans()),
    m.ProgramCellReply: st.builds(m.ProgramCellReply, u16, u16, u16, st.booleans()),
    m.Status: st.just(m.Status()),
    m.StatusReply: st.builds(m.StatusReply, *[u32] * 15),
    m.Clock: st.just(m.Clock()),
    m.ClockReply: st.builds(m.ClockReply, st.integers(0, 2**64 - 1),
                            f64.filter(lambda x: math.isfinite(x) and x >= 0)),
    m.Reset: st.just(m.Reset()),
    m.ResetReply: st.builds(m.ResetReply, u32, u32),
    m.ErrorReply: st.builds(m.ErrorReply, st.sampled_from(ErrorCode), u8, u32, text),
    m.DecisionWindow: decision_windows(),
    m.DecisionWindowReply: decision_replies(),
    lm.LearnSetup: learn_setups(),
    lm.LearnSetupReply: st.builds(lm.LearnSetupReply, u8, u32),
    lm.LearnWindow: st.builds(lm.LearnWindow, u16, u16, st.integers(0, 7), decision_windows()),
    lm.LearnWindowReply: decision_replies().map(
        lambda r: lm.LearnWindowReply(r.n_input_spikes, r.counts, r.motor_spikes, r.trace)),
    lm.LearnApply: st.builds(lm.LearnApply, u16, u16, u8),
    lm.LearnApplyReply: learn_apply_replies(),
    lm.LearnState: st.builds(lm.LearnState, u8, u8),
    lm.LearnStateReply: st.builds(
        lm.LearnStateReply, u16, u32, u8, u8,
        st.lists(st.builds(lm.LearnSynapseState, u8, i32, i32, u16, u16),
                 max_size=10).map(tuple)),
}


def test_every_registered_message_has_a_strategy():
    assert set(STRATEGIES) == set(m.MESSAGE_TYPES.values())


@pytest.mark.parametrize("cls", list(STRATEGIES), ids=lambda c: c.__name__)
def test_round_trip(cls):
    @SETTINGS
    @given(STRATEGIES[cls])
    def check(msg):
        payload = msg.encode()
        assert len(payload) <= m.MAX_PAYLOAD or cls in (m.ReadColumn, m.SpikeBatchReply)
        back = m.decode_message(cls.TYPE, payload)
        assert back == msg and type(back) is cls
        # and through a whole frame and the streaming decoder
        frames = FrameDecoder(max_payload=0xFFFF).feed(encode_frame(Frame.of(msg, 7, 99)))
        assert [f.message() for f in frames] == [msg]

    check()


@pytest.mark.parametrize("cls", list(STRATEGIES), ids=lambda c: c.__name__)
def test_truncated_or_extended_payload_is_malformed(cls):
    @SETTINGS
    @given(STRATEGIES[cls], st.data())
    def check(msg, data):
        payload = msg.encode()
        if payload:
            cut = data.draw(st.integers(0, len(payload) - 1))
            try:
                back = cls.decode(payload[:cut])
            except MalformedPayloadError:
                pass
            else:  # a shorter payload may still be a *different* valid message
                assert back != msg
        with pytest.raises(MalformedPayloadError):
            cls.decode(payload + b"\x01")

    check()


def test_requests_pair_with_replies():
    for code, cls in m.REQUEST_TYPES.items():
        assert code < 0x80
        assert cls.REPLY.TYPE == code | 0x80
        assert issubclass(cls.REPLY, m.Reply)
    assert len(m.REQUEST_TYPES) == 14          # 10 + on-board learning's 4 (issue 34)
    assert m.ErrorReply.TYPE == 0xFF


def test_unknown_type_is_typed_error():
    with pytest.raises(UnknownTypeError):
        m.decode_message(0x42, b"")


def test_field_out_of_range_raises_field_range_error():
    with pytest.raises(FieldRangeError):
        m.ReadCell(row=256).encode()
    with pytest.raises(FieldRangeError):
        m.WritePulse(width_us=-1).encode()
    with pytest.raises(FieldRangeError):  # bins not increasing
        m.SpikeBatch((m.SpikeGroup(((0, 1),), (5, 3)),), (0,), 10).encode()
    with pytest.raises(FieldRangeError):  # bin beyond the window
        m.SpikeBatch((m.SpikeGroup(((0, 1),), (10,)),), (0,), 10).encode()
    with pytest.raises(FieldRangeError):
        m.Info(board_id="x" * 65).encode()
    with pytest.raises(ValueError):  # FieldRangeError is also a ValueError
        m.ReadCellReply(adc=70000).encode()


def test_invalid_enum_on_the_wire_is_malformed():
    payload = bytearray(m.WritePulse().encode())
    payload[2] = 7  # polarity byte
    with pytest.raises(MalformedPayloadError):
        m.WritePulse.decode(bytes(payload))
    with pytest.raises(MalformedPayloadError):
        m.ErrorReply.decode(bytes([200, 0, 0, 0, 0, 0, 0]))


def test_info_with_inconsistent_or_impossible_constants_is_malformed():
    payload = bytearray(m.Info().encode())
    payload[-2:] = struct.pack("<H", m.Info().read_code + 1)       # read_code is the last field
    with pytest.raises(MalformedPayloadError, match="read code"):
        m.Info.decode(bytes(payload))
    impossible = bytearray(m.Info().encode())
    offset = 1 + 1 + 1 + 3                    # version, two empty texts, rows, cols, dac_bits
    impossible[offset:offset + 8] = struct.pack("<d", 0.0)          # dac_vref_v
    with pytest.raises(MalformedPayloadError, match="dac_vref_v"):
        m.Info.decode(bytes(impossible))


def test_spike_batch_bitmap_layout_is_lsb_first():
    sb = m.SpikeBatch((m.SpikeGroup(((3, 246),), (0, 9)),), (1, 7), n_bins=16, bin_us=500)
    payload = sb.encode()
    first_bin, n_bins, bin_us, mask, flags, ngroups = struct.unpack_from("<IHHIBB", payload)
    assert (first_bin, n_bins, bin_us, mask, flags, ngroups) == (0, 16, 500, 0b10000010, 0, 1)
    assert payload[14] == 1                    # one row in the group
    assert payload[15:18] == struct.pack("<BH", 3, 246)
    assert payload[18:20] == bytes([0b00000001, 0b00000010])
    assert len(payload) == 20


def test_spike_batch_order_and_reply_size():
    sb = m.SpikeBatch((m.SpikeGroup(((0, 1),), (2, 5)), m.SpikeGroup(((1, 1),), (2, 3))),
                      (0, 1, 2), n_bins=8)
    assert sb.spike_order() == [(2, 0), (2, 1), (3, 1), (5, 0)]
    assert sb.n_spikes() == 4
    reply = m.SpikeBatchReply(0, 3, ((1, 2, 3),) * 4)
    assert len(reply.encode()) == m.spike_batch_reply_size(4, 3)
    # a full decision window at p = 0.15 with 8 columns fits one frame
    assert m.spike_batch_reply_size(150, 8) < m.MAX_PAYLOAD


def test_info_conversions_follow_reference_formulas():
    info = m.Info()
    assert info.dac_code(0.3) == 246          # the reference: 0.3 V is code 246
    assert info.write_dac_code(3.0) == 2457   # and 3.0 V is 2457 at 5 V
    assert info.dac_volts(4095) == pytest.approx(5.0)
    assert info.adc_volts(2 ** 14) == pytest.approx(5.0)
    assert info.has(m.Capability.SPIKE_BATCH)
    assert not dataclasses.replace(info, capabilities=0).has(m.Capability.SPIKE_BATCH)


def test_crc_check_value_and_independent_reference():
    assert crc16(b"123456789") == 0x29B1

    def bitwise(data: bytes) -> int:
        crc = 0xFFFF
        for byte in data:
            crc ^= byte << 8
            for _ in range(8):
                crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
                crc &= 0xFFFF
        return crc

    for data in (b"", b"\x00", b"\xff" * 33, bytes(range(256))):
        assert crc16(data) == bitwise(data)


def test_bools_on_the_wire_are_0_or_1():
    from snan_hil.protocol.errors import MalformedPayloadError
    reply = m.ProgramCellReply(100, 2, 1, True).encode()
    assert reply[-1] == 1 and m.ProgramCellReply.decode(reply).ok is True
    assert m.ProgramCellReply.decode(reply[:-1] + b"\x00").ok is False
    for bad in (2, 0x80, 0xFF):
        with pytest.raises(MalformedPayloadError, match="0 or 1"):
            m.ProgramCellReply.decode(reply[:-1] + bytes([bad]))
        req = m.ProgramCell(1, 2, 3000, 30).encode()
        with pytest.raises(MalformedPayloadError, match="fine_tune"):
            m.ProgramCell.decode(req[:-1] + bytes([bad]))
    assert m.ProgramCell.decode(m.ProgramCell(fine_tune=False).encode()).fine_tune is False
