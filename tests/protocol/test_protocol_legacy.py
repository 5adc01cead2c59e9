"""The old ASCII line protocol: codec both ways, the existing firmware's line handling, and the
stricter host client."""

from types import SimpleNamespace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from snan_hil.protocol import legacy_client
from snan_hil.protocol import legacy_codec as lg
from snan_hil.protocol.legacy_client import LegacyClient, LegacyInfoError, LegacyTimeoutError
from snan_hil.protocol.legacy_device import LegacyDevice
from snan_hil.protocol import messages as m
from snan_hil.protocol.board import MEMRICORE
from snan_hil.protocol.errors import (BoardError, FieldRangeError, LinkTimeoutError,
                                      MalformedPayloadError, SafetyLimitError, UnsupportedError)
from snan_hil.protocol.safety import HostSafetyError
from snan_hil.protocol.testing import FakeBoard, LossyTransport
from snan_hil.protocol.transport import CallbackTransport

SETTINGS = settings(max_examples=80, deadline=None, derandomize=True)
u16, u8 = st.integers(0, 0xFFFF), st.integers(0, 0xFF)


def old_board(**kw):
    """A fake board with the existing firmware's (absent) interlocks."""
    return FakeBoard(interlocks=False, **kw)


class Recorder:
    """A handler that records the typed requests a LegacyDevice makes of a line."""

    def __init__(self, board=None):
        self.board = board or old_board()
        self.requests = []

    def __call__(self, req):
        if not isinstance(req, m.Hello):
            self.requests.append(req)
        return self.board(req)


def test_request_lines_match_the_reference_layout():
    assert lg.format_request(lg.LegacyPulse(2457, 0, 100, 0, 17, 3, 31)) == \
        b"7,2457,0,100,0,17,3,31\n"
    assert lg.format_request(lg.LegacyRead(246, 18, 3, 31)) == b"9,246,18,3,31\n"
    assert lg.format_request(lg.LegacyInfoRequest()) == b"100\n"
    assert lg.CONNECT_PROBE == lg.format_request(lg.LegacyPulse(0, 0, 0, 0, 0, 0, 0))
    assert lg.parse_reply(b"8191,17\r") == lg.LegacyReply(8191, 17)


@SETTINGS
@given(st.one_of(st.builds(lg.LegacyPulse, u16, u16, u16, u8, u16, u8, u8),
                 st.builds(lg.LegacyRead, u16, u16, u8, u8),
                 st.just(lg.LegacyInfoRequest())))
def test_request_round_trip(req):
    assert lg.parse_request(lg.format_request(req)) == req


@pytest.mark.parametrize("req", [lg.LegacyPulse(65536, 0, 0, 0, 1, 0, 0),
                                 lg.LegacyPulse(1, 0, 0, 256, 1, 0, 0),
                                 lg.LegacyRead(245, 65536, 0, 0), lg.LegacyRead(245, 1, 0, -1)])
def test_the_host_never_formats_a_field_wider_than_the_firmwares(req):
    with pytest.raises(FieldRangeError, match="bit field"):
        lg.format_request(req)


@SETTINGS
@given(st.integers(0, 16383), st.integers(0, 4096))
def test_reply_round_trip(adc, id_):
    assert lg.parse_reply(lg.format_reply(adc, id_)) == lg.LegacyReply(adc, id_)


# Issue 17 point 7: fields are unsigned decimals of ASCII digits within their C type; the
# existing firmware does not take a sign, spaces, '_' or other digits (docs/protocol.md s. 9).
NOT_REQUESTS = [b"", b"7,1,2", b"abc", b"9,1,2,3,4,5", b"10,1,2", b"\xff\xfe", b"7,a,0,0,0,0,0,0",
                b"9,1_0,1,0,0", b"9,+3,1,0,0", b"9, 7,1,0,0", b"9,7 ,1,0,0", b"9,,1,0,0",
                b"9,-1,1,0,0", b"9,245,1,0,0,", b" 9,245,1,0,0", b"9,65536,1,0,0",
                b"9,245,1,256,0", b"7,1,0,0,256,1,0,0", "9,\u0663,1,0,0".encode(),
                b"9\t,245,1,0,0", b"100,", b"9;245;1;0;0"]


@pytest.mark.parametrize("line", NOT_REQUESTS)
def test_lines_the_existing_firmware_does_not_read_are_not_requests(line):
    with pytest.raises(MalformedPayloadError):
        lg.parse_request(line)
    dev = LegacyDevice(old_board())
    assert dev.feed(line + b"\n") == b""                 # no reply, as the old firmware
    assert dev.counters.malformed == (1 if line.strip(b"\r") else 0)


def test_leading_zeros_and_crlf_are_read_as_the_firmware_reads_digits():
    assert lg.parse_request(b"9,0245,00001,0,00\r\n") == lg.LegacyRead(245, 1, 0, 0)


@pytest.mark.parametrize("line", [b"-5,9", b"5,-9", b"+5,9", b" 5,9", b"5,9,1", b"5", b"x,9"])
def test_replies_are_strict_and_refusals_only_with_the_opt_in(line):
    with pytest.raises(MalformedPayloadError):
        lg.parse_reply(line)
    if line == b"-5,9":
        assert lg.parse_reply(line, refusals=True) == lg.LegacyReply(-5, 9)


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


def test_device_maps_lines_as_the_existing_firmware():
    rec = Recorder()
    dev = LegacyDevice(rec)
    read_code, clamp = MEMRICORE.legacy_read_code, MEMRICORE.reset_clamp_code
    assert (read_code, clamp) == (246, 2457)
    assert dev.feed(b"9,200,5,3,31\n") == b"1313,5\n"
    assert rec.requests[-1] == m.ReadCell(31, 3, 200)
    # mode 9 above the read code is clamped to it (0.3004 V), not refused
    assert dev.feed(b"9,4000,6,3,31\r\n") == b"1313,6\n"
    assert rec.requests[-1] == m.ReadCell(31, 3, read_code)
    # mode 7 with vol 0 is a read at the same fixed code
    assert dev.feed(b"7,0,0,0,0,7,3,31\n") == b"1313,7\n"
    assert rec.requests[-1] == m.ReadCell(31, 3, read_code)
    # a pulse: sign 0 RESET, clamped at 3.0 V; any other sign SET, not clamped; width ms + us
    dev.feed(b"7,4000,2,500,0,8,3,31\n")
    assert rec.requests[-1] == m.WritePulse(31, 3, m.Polarity.RESET, clamp, 2500, read_code)
    dev.feed(b"7,4000,0,100,1,9,3,31\n")
    assert rec.requests[-1] == m.WritePulse(31, 3, m.Polarity.SET, 4000, 100, read_code)
    dev.feed(b"7,1147,0,1500,7,10,3,31\n")
    assert rec.requests[-1] == m.WritePulse(31, 3, m.Polarity.SET, 1147, 1500, read_code)
    assert rec.board.pulses == 3
    # garbage, mode 10 and empty lines get no answer; split lines are reassembled
    assert dev.feed(b"hello\n10,1,2\n\n9,246,") == b""
    assert dev.feed(b"10,0,0\n") == b"1000,10\n"
    assert dev.counters.malformed == 2
    assert dev.feed(b"100\n").startswith(b"fake,fake-1,32,8,12,14")


def test_requests_the_board_cannot_execute_get_silence_unless_opted_in():
    quiet, loud = LegacyDevice(old_board()), LegacyDevice(old_board(), refusals=True)
    for line, reply in ((b"9,245,11,8,0\n", b"-4,11\n"), (b"7,500,0,100,1,12,0,32\n", b"-4,12\n"),
                        (b"7,500,0,100,1,13,0,255\n", b"-4,13\n")):
        assert quiet.feed(line) == b""                     # a cell outside the array
        assert loud.feed(line) == reply                    # -OUT_OF_RANGE,id
    assert quiet.counters.refusals == 3 and loud.counters.refusals == 3
    # a board with interlocks (this project's firmware behind the line protocol) refuses a
    # write: silence by default, -SAFETY_LIMIT with the opt-in
    strict = LegacyDevice(FakeBoard(), refusals=True)
    assert strict.feed(b"7,1500,0,100,1,14,0,0\n") == b"-5,14\n"
    assert LegacyDevice(FakeBoard()).feed(b"7,1500,0,100,1,14,0,0\n") == b""


def legacy_pair(board=None, *, drop_replies=(), **kw):
    board = board or old_board()
    dev = LegacyDevice(board, refusals=kw.pop("device_refusals", False))
    sent = []

    def respond(data: bytes) -> bytes:
        sent.append(data)
        out = dev.feed(data)
        return b"" if len(sent) in drop_replies else out

    return board, dev, sent, LegacyClient(CallbackTransport(respond, name="old-board"),
                                             timeout=0.02, **kw)


def test_client_checks_ids_and_discards_stale_lines():
    board = old_board()
    dev = LegacyDevice(board)

    def respond(data: bytes) -> bytes:
        # a stale reply with a wrong id arrives before the real one
        return b"4444,4000\n" + dev.feed(data)

    client = LegacyClient(CallbackTransport(respond), timeout=0.02, first_id=4096)
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


def test_a_write_reply_with_another_id_is_never_used_as_data():
    board = old_board()
    dev = LegacyDevice(board)
    sent = []

    def respond(data: bytes) -> bytes:
        sent.append(data)
        out = dev.feed(data)
        if data.startswith(b"7,"):                      # the id of the pulse's reply is damaged
            adc, _id = out.split(b",")
            return adc + b",3999\n"
        return out

    client = LegacyClient(CallbackTransport(respond), timeout=0.02)
    adc = client.write_pulse(2, 2, m.Polarity.SET, 100, 100)
    assert board.pulses == 1 and [s[:2] for s in sent] == [b"7,", b"9,"]
    assert adc == 1032 and client.counters.uncertain_writes == 1
    assert client.counters.stale_lines == 1


def test_a_read_after_the_pulse_at_another_code_costs_one_mode_9_read():
    board, dev, sent, client = legacy_pair()
    client.hello()
    n = len(sent)
    assert client.post_pulse_read_code == MEMRICORE.legacy_read_code
    client.write_pulse(0, 0, m.Polarity.SET, 500, 100)              # the board's own read
    assert [s[:2] for s in sent[n:]] == [b"7,"]
    client.write_pulse(0, 0, m.Polarity.SET, 500, 100, read_code=MEMRICORE.read_code)
    assert [s[:2] for s in sent[n + 1:]] == [b"7,", b"9,"]
    assert sent[-1].startswith(f"9,{MEMRICORE.read_code},".encode())


def test_lossy_line_never_duplicates_pulses():
    board = old_board()
    dev = LegacyDevice(board)
    lossy = LossyTransport(CallbackTransport(dev.feed), drop=0.01, seed=4)
    client = LegacyClient(lossy, timeout=0.02, retries=8)
    for i in range(300):
        client.write_pulse(i % 32, 0, m.Polarity.SET, 40, 10)
    # every pulse line that reached the board intact was applied exactly once
    assert board.pulses <= 300
    assert board.pulses == dev.counters.requests - board.executed.get("ReadCell", 0)
    assert client.counters.uncertain_writes > 0
    assert board.pulses + client.counters.uncertain_writes >= 300


def test_read_retries_then_times_out_saying_what_came_instead():
    board, dev, sent, client = legacy_pair(drop_replies={1, 2})
    assert client.read_cell(0, 0) == 1000
    assert client.counters.retries == 2 and len(set(sent)) == 3   # new id each try
    mute = LegacyClient(CallbackTransport(lambda d: b"", name="mute"), timeout=0.01,
                           retries=1)
    with pytest.raises(LinkTimeoutError, match="mute"):
        mute.read_cell(0, 0)
    with pytest.raises(LinkTimeoutError, match="connect probe"):
        mute.hello()
    noisy = LegacyClient(CallbackTransport(lambda d: b"\x00garbage\n", name="noisy"),
                            timeout=0.01)
    with pytest.raises(LegacyTimeoutError, match="not replies.*garbage") as exc:
        noisy.hello()
    assert "garbage" in exc.value.heard
    other = LegacyClient(CallbackTransport(lambda d: b"1234,77\n", name="other"),
                            timeout=0.01)
    with pytest.raises(LegacyTimeoutError, match="another id.*'1234,77'"):
        other.hello()


def test_a_board_that_never_answers_mode_100_is_an_error():
    dev = LegacyDevice(old_board())

    def respond(data: bytes) -> bytes:
        return b"" if data == b"100\n" else dev.feed(data)

    client = LegacyClient(CallbackTransport(respond, name="half"), timeout=0.01)
    with pytest.raises(LegacyInfoError, match="mode 100"):
        client.hello()


def test_refusal_replies_only_with_the_opt_in_on_both_sides():
    import dataclasses
    # a board that refuses over 1.0 V while the host allows its 1.4 V (the host may only
    # lower a limit, issue 32): the request leaves the host and the board refuses it
    strict = FakeBoard(board=dataclasses.replace(MEMRICORE, max_write_v=1.0))
    code = MEMRICORE.write_dac_floor_code(1.2)
    _b, _d, _s, client = legacy_pair(strict, device_refusals=True, refusals=True)
    with pytest.raises(SafetyLimitError):
        client.write_pulse(0, 0, m.Polarity.SET, code, 100)
    # without the client's opt-in "-5,id" is garbage: never data, the write is verified
    _b, _d, _s, plain = legacy_pair(strict, device_refusals=True)
    assert plain.write_pulse(0, 0, m.Polarity.SET, code, 100) == 1000
    assert plain.counters.malformed == 1 and plain.counters.uncertain_writes == 1
    assert isinstance(SafetyLimitError("x"), BoardError)


def test_host_write_limit_is_policy_and_configurable():
    board, dev, sent, client = legacy_pair()
    client.hello()
    n = len(sent)
    with pytest.raises(HostSafetyError, match="1.4 V.*--max-write-v.*not sent"):
        client.write_pulse(0, 0, m.Polarity.RESET, 1147, 100)      # the old host's "1.4 V"
    client.write_pulse(0, 0, m.Polarity.RESET, 1146, 100)
    client.host_max_write_v = 1.0                       # the host may lower the limit ...
    top = MEMRICORE.write_dac_floor_code(1.0)
    assert client.limits.max_write_code == top
    client.write_pulse(0, 0, m.Polarity.RESET, top, 100)
    with pytest.raises(HostSafetyError, match="1 V"):
        client.write_pulse(0, 0, m.Polarity.RESET, top + 1, 100)
    with pytest.raises(HostSafetyError, match="read limit 0.3 V"):
        client.read_cell(0, 0, MEMRICORE.legacy_read_code)          # 0.3004 V: host refuses
    client.host_max_write_v = 1.7                       # ... never raise it (issue 32)
    with pytest.raises(HostSafetyError, match="can only lower it"):
        client.write_pulse(0, 0, m.Polarity.RESET, 1146, 100)
    assert len(sent) == n + 2 and board.pulses == 2
    client.host_max_write_v = 9.0
    with pytest.raises(HostSafetyError, match="--max-write-v 9.0"):
        client.write_pulse(0, 0, m.Polarity.RESET, 100, 100)


def test_client_raises_typed_errors():
    board, dev, sent, client = legacy_pair()
    client.hello()
    for call in (lambda: client.spike_batch([], [0]), lambda: client.read_column(0, [0] * 32),
                 client.status, client.clock, client.reset):
        with pytest.raises(UnsupportedError, match="--protocol framed"):
            call()
    with pytest.raises(FieldRangeError):
        client.write_pulse(0, 0, m.Polarity.SET, 100, 65536 * 1000)    # t_ms > 16 bit


def test_an_over_long_line_is_dropped_whole_even_in_pieces():
    dev = LegacyDevice(old_board())
    assert dev.feed(b"x" * 200) == b"" and dev.feed(b"y" * 100) == b""
    assert dev.feed(b"9,245,1,0,0\n") == b""              # the tail of the long line
    assert dev.feed(b"9,245,2,0,0\n") == b"1000,2\n"      # the next line is read again
    assert dev.counters.overlong == 1 and dev.counters.requests == 1


def test_a_host_that_loses_the_cpu_past_every_wait_still_reads_a_synchronous_board(
        monkeypatch):
    """On a loaded host the wall clock can pass a whole wait between sending a line and
    reading its reply; an in-process (synchronous) board's reply is buffered all the same, so
    it is read - not resent, and a pulse's reply is not taken as lost."""
    now = [0.0]

    def monotonic() -> float:
        now[0] += 1.0                        # every look at the clock: a second later
        return now[0]

    monkeypatch.setattr(legacy_client, "time",
                        SimpleNamespace(monotonic=monotonic, sleep=lambda s: None))
    board, dev, sent, client = legacy_pair()
    client.hello()
    n_hello = len(sent)
    assert client.read_cell(1, 2) == 1012
    assert client.write_pulse(2, 2, m.Polarity.SET, 100, 100) == 1022 + 10
    assert len(sent) == n_hello + 2 and board.pulses == 1
    assert client.counters.timeouts == 0 and client.counters.uncertain_writes == 0
