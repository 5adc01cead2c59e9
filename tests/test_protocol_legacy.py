"""The old ASCII line protocol: codec both ways, board side, and the stricter host client."""

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from snan_hil.protocol import legacy as lg
from snan_hil.protocol import messages as m
from snan_hil.protocol.safety import HostSafetyError
from snan_hil.protocol.errors import (LinkTimeoutError, MalformedPayloadError,
                                      UnsupportedError)
from snan_hil.protocol.testing import FakeBoard, LossyTransport
from snan_hil.protocol.transport import CallbackTransport

SETTINGS = settings(max_examples=80, deadline=None, derandomize=True)
nat = st.integers(0, 100000)


def test_request_lines_match_the_reference_layout():
    assert lg.format_request(lg.LegacyPulse(2457, 0, 100, 0, 17, 3, 31)) == \
        b"7,2457,0,100,0,17,3,31\n"
    assert lg.format_request(lg.LegacyRead(246, 18, 3, 31)) == b"9,246,18,3,31\n"
    assert lg.format_request(lg.LegacyInfoRequest()) == b"100\n"
    assert lg.CONNECT_PROBE == lg.format_request(lg.LegacyPulse(0, 0, 0, 0, 0, 0, 0))
    assert lg.parse_reply(b"8191,17\r") == lg.LegacyReply(8191, 17)


@SETTINGS
@given(st.one_of(st.builds(lg.LegacyPulse, nat, nat, nat, nat, nat, nat, nat),
                 st.builds(lg.LegacyRead, nat, nat, nat, nat),
                 st.just(lg.LegacyInfoRequest())))
def test_request_round_trip(req):
    assert lg.parse_request(lg.format_request(req)) == req


@SETTINGS
@given(st.integers(-20, 16383), st.integers(0, 4096))
def test_reply_round_trip(adc, id_):
    assert lg.parse_reply(lg.format_reply(adc, id_)) == lg.LegacyReply(adc, id_)


@pytest.mark.parametrize("line", [b"", b"7,1,2", b"abc", b"9,1,2,3,4,5", b"10,1,2", b"\xff\xfe",
                                  b"7,a,0,0,0,0,0,0"])
def test_bad_request_lines_are_typed_errors(line):
    with pytest.raises(MalformedPayloadError):
        lg.parse_request(line)


def test_ids_count_1_to_4096_then_wrap_to_0():
    seq, cur = [], 4094
    for _ in range(4):
        cur = lg.next_id(cur)
        seq.append(cur)
    assert seq == [4095, 4096, 0, 1]


def test_info_line_round_trip_and_foreign_info():
    info = m.Info(board_id="MemriCore-7", firmware_version="2.1", rows=32, cols=8)
    back = lg.parse_info(lg.format_info(info))
    assert (back.board_id, back.firmware_version, back.rows, back.cols) == \
        ("MemriCore-7", "2.1", 32, 8)
    assert back.protocol_version == 0 and back.capabilities == 0
    other = lg.parse_info(b"MemriCore,v3,extra")
    assert other.board_id == "MemriCore" and other.firmware_version == "v3,extra"


def test_device_maps_modes_to_typed_requests():
    board = FakeBoard()
    dev = lg.LegacyDevice(board)
    assert dev.feed(b"9,246,5,3,31\n") == b"1313,5\n"
    # mode 9 above 0.3 V is clamped like the old firmware, not refused
    assert dev.feed(b"9,4000,6,3,31\r\n") == b"1313,6\n"
    # mode 7 with vol 0 is a read; with vol > 0 a pulse (sign 1 = SET) and the read after
    assert dev.feed(b"7,0,0,0,0,7,3,31\n") == b"1313,7\n"
    assert dev.feed(b"7,500,1,500,1,8,3,31\n") == b"1363,8\n"
    assert board.pulses == 1
    # a write above the limit: refused with this project's -CODE extension
    assert dev.feed(b"7,4000,0,100,0,9,3,31\n") == b"-5,9\n"
    # garbage, mode 10 and empty lines get no answer; split lines are reassembled
    assert dev.feed(b"hello\n10,1,2\n\n9,246,") == b""
    assert dev.feed(b"10,0,0\n") == b"1000,10\n"
    assert dev.counters.malformed == 2
    assert dev.feed(b"100\n").startswith(b"fake,fake-1,32,8,12,14")


def legacy_pair(board=None, *, drop_replies=(), **kw):
    board = board or FakeBoard()
    dev = lg.LegacyDevice(board)
    sent = []

    def respond(data: bytes) -> bytes:
        sent.append(data)
        out = dev.feed(data)
        return b"" if len(sent) in drop_replies else out

    return board, dev, sent, lg.LegacyClient(CallbackTransport(respond, name="old-board"),
                                             timeout=0.02, **kw)


def test_client_checks_ids_and_discards_stale_lines():
    board = FakeBoard()
    dev = lg.LegacyDevice(board)

    def respond(data: bytes) -> bytes:
        # a stale reply with a wrong id arrives before the real one
        return b"4444,4000\n" + dev.feed(data)

    client = lg.LegacyClient(CallbackTransport(respond), timeout=0.02, first_id=4096)
    assert client.read_cell(1, 1) == 1011
    assert client.counters.stale_lines == 1
    assert client.read_cell(1, 2) == 1012     # id wrapped to 0 and still matched


def test_lost_write_reply_is_verified_by_reading_not_resent():
    board, dev, sent, client = legacy_pair(drop_replies={1})
    adc = client.write_pulse(2, 2, m.Polarity.SET, 100, 100)
    assert board.pulses == 1                   # applied once, never resent
    assert adc == 1022 + 10                    # the verifying read sees the pulse
    assert sent[0].startswith(b"7,") and sent[1].startswith(b"9,")
    assert client.counters.uncertain_writes == 1


def test_lossy_line_never_duplicates_pulses():
    board = FakeBoard()
    dev = lg.LegacyDevice(board)
    lossy = LossyTransport(CallbackTransport(dev.feed), drop=0.01, seed=4)
    client = lg.LegacyClient(lossy, timeout=0.02, retries=8)
    for i in range(300):
        client.write_pulse(i % 32, 0, m.Polarity.SET, 40, 10)
    # every pulse line that reached the board intact was applied exactly once
    assert board.pulses <= 300
    assert board.pulses == dev.counters.requests - board.executed.get("ReadCell", 0)
    assert client.counters.uncertain_writes > 0
    assert board.pulses + client.counters.uncertain_writes >= 300


def test_read_retries_then_times_out():
    board, dev, sent, client = legacy_pair(drop_replies={1, 2})
    assert client.read_cell(0, 0) == 1000
    assert client.counters.retries == 2 and len(set(sent)) == 3   # new id each try
    mute = lg.LegacyClient(CallbackTransport(lambda d: b"", name="mute"), timeout=0.01,
                           retries=1)
    with pytest.raises(LinkTimeoutError, match="mute"):
        mute.read_cell(0, 0)
    with pytest.raises(LinkTimeoutError, match="connect probe"):
        mute.hello()


def test_client_raises_typed_errors():
    board, dev, sent, client = legacy_pair()
    client.hello()
    n_sent = len(sent)
    with pytest.raises(HostSafetyError):               # refused on the host, never sent
        client.write_pulse(0, 0, m.Polarity.RESET, 4000, 100)
    assert len(sent) == n_sent
    assert dev.feed(b"7,4000,0,100,0,77,0,0\n").startswith(b"-")   # the board refuses it too
    for call in (lambda: client.spike_batch([], [0]), lambda: client.read_column(0, [0] * 32),
                 client.status, client.clock, client.reset):
        with pytest.raises(UnsupportedError, match="--protocol framed"):
            call()
