"""Every decoder fuzzed with CRC-valid frames of extreme field values (issue 27, point 3).

Payloads are built field by field from each message's wire layout, every field drawn from its
extremes (0, 1, the largest integer of its width, the values next to the board's limits; for
f64: NaN, +-inf, +-1e308, +-0, the smallest subnormal, negative values), sometimes with a
byte too many or too few. What must hold:

* host side - every reply decoder (INFO included) returns a message or raises
  ``MalformedPayloadError`` (a ``MessageError``), never anything untyped; an accepted INFO's
  derived values (read codes, the read chain) can be computed; a link client that is sent such
  an INFO counts it as an unexpected reply and ends with a typed ``ProtocolError``;
* board side, Python - every request decoder returns a request or raises
  ``MalformedPayloadError``; the endpoint answers each frame with one reply, never ERROR
  INTERNAL (no untyped exception in a handler either);
* board side, C - the same frames give the same replies, SPI traffic and chip on the C
  firmware as on the Python model (the twin boards of tests/firmware/test_differential.py), without
  a
  trap, a watchdog reset or a bad register access.
"""

import math
import re
import struct

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from snan_hil.protocol import errors as E
from snan_hil.protocol import learn_messages as lm
from snan_hil.protocol import messages as m
from snan_hil.protocol.conformance import frames_of
from snan_hil.protocol.frames import Frame, encode_frame
from snan_hil.protocol.link import LinkClient
from snan_hil.protocol.transport import CallbackTransport

QUICK = settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))

INTS = {
    "B": [0, 1, 2, 7, 8, 31, 32, 127, 128, 254, 255],
    "H": [0, 1, 245, 246, 1146, 1147, 4095, 4096, 16383, 16384, 32767, 32768, 65534, 65535],
    "I": [0, 1, 100, 1_000_000, 1_000_001, 2**31 - 1, 2**31, 2**32 - 2, 2**32 - 1],
    "Q": [0, 1, 2**32, 2**63 - 1, 2**63, 2**64 - 1],
}
FLOATS = [math.nan, -math.nan, math.inf, -math.inf, 1e308, -1e308, 0.0, -0.0, 5e-324, -5e-324,
          -1.0, 1.0, 5.0, 0.3, 1.4, 2e-3, 3000.0, 1e-300, 2.0**1023]


def field(code: str) -> st.SearchStrategy:
    """An extreme value (or any value) of one struct field."""
    if code == "d":
        return st.one_of(st.sampled_from(FLOATS), st.floats(allow_nan=True, allow_infinity=True))
    bits = 8 * struct.calcsize("<" + code)
    if code.islower():                               # signed: both ends and around 0
        lo, hi = -2**(bits - 1), 2**(bits - 1) - 1
        return st.one_of(st.sampled_from([lo, lo + 1, -1, 0, 1, hi - 1, hi]),
                         st.integers(lo, hi))
    return st.one_of(st.sampled_from(INTS[code]), st.integers(0, 2**bits - 1))


def packed(fmt: str) -> st.SearchStrategy[bytes]:
    """A struct of format ``fmt`` (repeat counts allowed), each field at an extreme."""
    codes = "".join(c * int(n or 1) for n, c in re.findall(r"(\d*)(\D)", fmt.lstrip("<")))
    return st.tuples(*[field(c) for c in codes]).map(lambda v: struct.pack("<" + codes, *v))


def text() -> st.SearchStrategy[bytes]:
    """A text field: a length byte (0..255, 64 the longest allowed) and bytes (UTF-8 or not)."""
    body = st.one_of(st.text(max_size=70).map(lambda t: t.encode()[:255]), st.binary(max_size=80))
    return st.tuples(st.one_of(st.none(), st.integers(0, 255)), body).map(
        lambda t: bytes([len(t[1]) if t[0] is None else t[0]]) + t[1])


def counted(head: str, count, item: str) -> st.SearchStrategy[bytes]:
    """A header ``head`` followed by ``count(values)`` items of ``item`` (+-1 now and then)."""
    @st.composite
    def make(draw):
        h = draw(packed(head))
        n = max(0, min(count(struct.unpack("<" + head.lstrip("<"), h)), 600)
                + draw(st.sampled_from([0, 0, 0, -1, 1])))
        return h + b"".join(draw(st.lists(packed(item), min_size=n, max_size=n)))
    return make()


def cut_or_grow(payload: st.SearchStrategy[bytes]) -> st.SearchStrategy[bytes]:
    return st.tuples(payload, st.sampled_from(["as is"] * 6 + ["cut", "grow"]),
                     st.binary(min_size=1, max_size=3)).map(
        lambda t: t[0] if t[1] == "as is" else (t[0][:-1] if t[1] == "cut" else t[0] + t[2]))


def info_payload() -> st.SearchStrategy[bytes]:
    """INFO: one constant at an extreme on a valid INFO, or every field drawn."""
    good = m.Info(boot_nonce=0x5EED1234, firmware_version="fw", board_id="B").encode()
    head = good[:1 + 3 + 2]                             # version, "fw", "B"
    codes = m.Info._FMT_B.lstrip("<")
    values = struct.unpack("<" + codes, good[len(head):])

    def with_one(i: int, v) -> bytes:
        vals = list(values)
        vals[i] = v
        return head + struct.pack("<" + codes, *vals)

    single = st.integers(0, len(codes) - 1).flatmap(
        lambda i: field(codes[i]).map(lambda v: with_one(i, v)))
    whole = st.tuples(packed(m.Info._FMT_A), text(), text(), packed(m.Info._FMT_B)).map(
        b"".join)
    return cut_or_grow(st.one_of(single, whole))


@st.composite
def window_reply_payload(draw) -> bytes:
    """DECISION_WINDOW's reply: any header byte (candidates, TRACE, MOTOR_SPIKES and the
    reserved bits), counts at extremes, a trace of any length, motor spikes for the counts."""
    head = draw(field("B"))
    n = head & 0x07
    counts = [draw(field("H")) for _ in range(n)]
    out = bytes([head]) + struct.pack("<H", draw(field("H"))) + struct.pack(f"<{n}H", *counts)
    if head & 0x08:
        points = draw(st.one_of(st.sampled_from([0, 1, 2, 65535]), st.integers(0, 20)))
        out += struct.pack("<H", points) + draw(st.binary(max_size=4 * n * min(points, 20)))
    if head & 0x10:
        out += draw(st.binary(max_size=2 * min(sum(counts), 300)))
    return out


@st.composite
def learn_apply_reply_payload(draw) -> bytes:
    """LEARN_APPLY's reply: flags, trial, counter, orders (any count byte, polarity bit and
    zero counts), touched synapses."""
    head = draw(packed("<BHIB"))
    out = head + b"".join(draw(st.lists(packed("<BB"), min_size=min(head[-1], 20),
                                        max_size=min(head[-1], 20))))
    n = draw(field("B"))
    return out + bytes([n]) + b"".join(draw(st.lists(packed("<Bii"), min_size=min(n, 20),
                                                     max_size=min(n, 20))))


REPLY_PAYLOADS = {
    m.Info: info_payload(),
    m.DecisionWindowReply: cut_or_grow(window_reply_payload()),
    lm.LearnWindowReply: cut_or_grow(window_reply_payload()),
    lm.LearnApplyReply: cut_or_grow(learn_apply_reply_payload()),
    lm.LearnStateReply: cut_or_grow(counted("<HIBBB", lambda v: v[4], "<BiiHH")),
    m.ErrorReply: cut_or_grow(st.tuples(packed("<BBI"), text()).map(b"".join)),
    m.SpikeBatchReply: cut_or_grow(counted("<IHB", lambda v: v[1] * v[2], "<H")),
    **{cls: cut_or_grow(packed(cls.FMT)) for cls in m.MESSAGE_TYPES.values()
       if cls.TYPE >= 0x80 and cls.FMT is not None},
}


def test_every_reply_type_is_fuzzed():
    assert set(REPLY_PAYLOADS) == {c for c in m.MESSAGE_TYPES.values() if c.TYPE >= 0x80}


@QUICK
@given(st.sampled_from(sorted(REPLY_PAYLOADS, key=lambda c: c.TYPE)).flatmap(
    lambda cls: st.tuples(st.just(cls), REPLY_PAYLOADS[cls])))
def test_host_decoders_give_a_message_or_a_malformed_payload_error(case):
    cls, payload = case
    try:
        msg = m.decode_message(cls.TYPE, payload)
    except E.MessageError:
        return
    assert isinstance(msg, cls)
    assert msg.decode(msg.encode()) == msg or isinstance(msg, m.ErrorReply)
    if isinstance(msg, m.Info):        # what a host derives from it can be derived
        for value in (msg.read_code, msg.max_write_code, msg.v_read_v, msg.cell_scale(),
                      msg.column_scale(), msg.max_cell_read_code, msg.max_row_read_code):
            assert math.isfinite(value) and value >= 0
        assert msg.cell_conductance(1000) >= 0 and msg.max_payload >= len(payload)
    if isinstance(msg, m.ClockReply):
        assert math.isfinite(msg.energy_j) and msg.energy_j >= 0


@pytest.mark.parametrize("change", [{"max_read_v": 1e308}, {"max_write_v": math.nan},
                                    {"adc_vref_v": 5e-324}, {"gain": 1e308},
                                    {"compliance_a": -1.0}, {"r_load_ohm": math.inf}])
def test_an_info_of_extreme_constants_is_a_malformed_reply_for_the_link(change):
    """Issue 27, item 5: a CRC-valid INFO with a read limit of 1e308 V (its read code left at
    245) raised an untyped OverflowError in the host's decoder."""
    good = m.Info(boot_nonce=0x5EED1234).encode()
    fmt = "<" + m.Info._FMT_B.lstrip("<")
    head = good[:1 + 1 + 1]                              # version, two empty texts
    values = list(struct.unpack(fmt, good[len(head):]))
    order = ["rows", "cols", "dac_bits", "dac_vref_v", "write_dac_bits", "write_dac_vref_v",
             "adc_bits", "adc_vref_v", "adc_averages", "r_load_ohm", "r_switch_ohm", "gain",
             "sum_gain_ohm", "v_read_v", "max_read_v", "max_write_v", "compliance_a"]
    for name, value in change.items():
        values[order.index(name)] = value
    payload = head + struct.pack(fmt, *values)
    with pytest.raises(E.MalformedPayloadError):
        m.Info.decode(payload)
    frame = encode_frame(Frame(m.Info.TYPE, 0x0101, payload, 0x5EED1234))
    client = LinkClient(CallbackTransport(lambda data: frame), first_seq=0x0101, timeout=0.01,
                        give_up_s=0.1, retries=1)
    with pytest.raises(E.ProtocolError):
        client.hello()
    assert client.counters.unexpected_replies >= 1


# --------------------------------------------------------------------------- board side
@st.composite
def spike_payload(draw) -> bytes:
    """SPIKE_BATCH: its header at extremes, groups with any row counts, rows and bitmaps."""
    head = draw(packed("<IHHIBB"))
    n_bins = struct.unpack_from("<H", head, 4)[0]
    nbytes = min((n_bins + 7) // 8, 600)
    out = head
    for _ in range(min(head[13], 4) + draw(st.sampled_from([0, 0, 1]))):
        rows = draw(st.lists(packed("<BH"), max_size=5))
        out += bytes([len(rows) if draw(st.booleans()) else draw(field("B"))])
        out += b"".join(rows) + draw(st.binary(min_size=nbytes, max_size=nbytes))
    return out


@st.composite
def window_payload(draw) -> bytes:
    """DECISION_WINDOW: any flag byte, a parameter block of extreme fields when PARAMS is set,
    the key, a trace stride, a layout byte of any row / candidate counts, rows, candidate
    cells with interneuron lists of any length and LEB128 gaps (valid or not)."""
    flags = draw(field("B"))
    out = bytes([flags])
    if flags & 0x01:
        out += draw(packed(m.DecisionParams.FMT))
    out += draw(packed("<Q"))
    if flags & 0x04:
        out += draw(packed("<H"))
    layout = draw(field("B"))
    out += bytes([layout]) + draw(st.binary(min_size=layout & 0x07, max_size=layout & 0x07))
    for _ in range(min(layout >> 4, 7)):
        cell = draw(field("B"))
        out += bytes([cell])
        if cell & 0x80:
            k = draw(st.one_of(st.sampled_from([0, 1, 255]), st.integers(0, 6)))
            out += bytes([k]) + draw(st.binary(max_size=4 * min(k, 6)))
    return out


@st.composite
def learn_setup_payload(draw) -> bytes:
    """LEARN_SETUP: its head at extremes (any flags and table_bits), the decay tables, step
    tables for the head's table_bits (capped), synapses for any count byte."""
    head = draw(packed("<BBBHHHHQQii"))
    bits = min(head[1], 7)
    out = head + draw(packed("<32Q"))
    out += draw(st.binary(min_size=8 * ((1 << bits) + 1), max_size=8 * ((1 << bits) + 1)))
    n = draw(field("B"))
    return out + bytes([n]) + b"".join(draw(st.lists(packed("<Bii"), min_size=min(n, 40),
                                                     max_size=min(n, 40))))


REQUEST_PAYLOADS = {
    m.DecisionWindow: window_payload(),
    lm.LearnWindow: st.tuples(packed("<HHB"), window_payload()).map(b"".join),
    lm.LearnSetup: learn_setup_payload(),
    lm.LearnApply: packed(lm.LearnApply.FMT),
    lm.LearnState: packed(lm.LearnState.FMT),
    m.Hello: packed(m.Hello.FMT),
    m.ReadCell: packed(m.ReadCell.FMT),
    m.ReadColumn: counted("<BB", lambda v: v[1], "<H"),
    m.WritePulse: packed(m.WritePulse.FMT),
    m.SpikeBatch: spike_payload(),
    m.ProgramCell: packed(m.ProgramCell.FMT),
    m.Status: st.just(b""), m.Clock: st.just(b""), m.Reset: st.just(b""),
}
REQUESTS = {k: cut_or_grow(v) for k, v in REQUEST_PAYLOADS.items()}
REQUEST_CASES = st.sampled_from(sorted(REQUESTS, key=lambda c: c.TYPE)).flatmap(
    lambda cls: st.tuples(st.just(cls), REQUESTS[cls]))


def test_every_request_type_is_fuzzed():
    assert set(REQUESTS) == set(m.REQUEST_TYPES.values())


@QUICK
@given(REQUEST_CASES)
def test_board_request_decoders_give_a_request_or_a_malformed_payload_error(case):
    cls, payload = case
    try:
        msg = cls.decode(payload)
    except E.MessageError:
        return
    assert isinstance(msg, cls)


DOCUMENTED = {E.ErrorCode.MALFORMED, E.ErrorCode.OUT_OF_RANGE, E.ErrorCode.SAFETY_LIMIT,
              E.ErrorCode.BAD_VERSION, E.ErrorCode.BAD_FRAME}
NOT_SERVED = (lm.LearnSetup, lm.LearnWindow, lm.LearnApply, lm.LearnState)
"""Optional requests the twin's boards do not serve (no LEARN capability, issue 34: the C
firmware has none yet): UNKNOWN_TYPE is their documented answer."""


@pytest.fixture(scope="module")
def twin(tmp_path_factory):
    """Both MCUs on one chip (Python model and C firmware), kept across the examples."""
    pytest.importorskip("unicorn")
    from snan_hil.firmware_emu.fw_image import default_elf_path
    if not default_elf_path().is_file():
        pytest.skip("firmware ELF not built")
    from snan_hil.firmware_emu.twin import TwinBoards
    boards = TwinBoards(tmp_path_factory.mktemp("fuzz"))
    boards.nonce = boards.boot_nonces[0]
    boards.send(b"\x00" + encode_frame(Frame.of(m.Hello(), 1, 0)), "HELLO")
    yield boards
    boards.close()


@settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
@given(case=REQUEST_CASES, seq=st.integers(0, 0xFFFF))
def test_both_mcus_answer_extreme_requests_alike_with_a_documented_answer(twin, case, seq):
    cls, payload = case
    out = twin.send(encode_frame(Frame(cls.TYPE, seq, payload, twin.nonce)), cls.__name__)
    (reply,) = [f for f in frames_of(out) if isinstance(f, Frame)]
    if reply.type == m.ErrorReply.TYPE:
        err = reply.message()
        assert err.code in DOCUMENTED or (cls in NOT_SERVED
                                          and err.code == E.ErrorCode.UNKNOWN_TYPE), err
    else:
        assert reply.type == cls.TYPE | 0x80
        msg = reply.message()
        if isinstance(msg, m.ResetReply):
            twin.nonce = msg.new_nonce
