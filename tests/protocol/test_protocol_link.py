"""Reliable link: retransmit with the same seq, dedupe on the board, nonce checks, errors."""

import dataclasses
import random
import time

import pytest

from snan_hil.protocol import messages as m
from snan_hil.protocol.device import DeviceEndpoint
from snan_hil.protocol.errors import (BoardBusyError, BoardResetError, BusyError, ErrorCode,
                                      LinkTimeoutError, NakReason, OutOfRangeError,
                                      SafetyLimitError, UnsupportedError, VersionMismatchError)
from snan_hil.protocol.frames import (FLAG_FROM_CACHE, FLAG_RETRANSMIT, Frame, FrameDecoder,
                                      encode_frame)
from snan_hil.protocol.link import LinkClient
from snan_hil.protocol.testing import FakeBoard, LossyTransport
from snan_hil.protocol.transport import CallbackTransport


def make(board=None, *, drop=0.0, corrupt=0.0, seed=0, retries=3, **kw):
    board = board or FakeBoard()
    endpoint = DeviceEndpoint(board, boot_nonce=lambda: board.boot_nonce)
    transport = CallbackTransport(endpoint.feed, name="test-board")
    if drop or corrupt:
        transport = LossyTransport(transport, drop=drop, corrupt=corrupt, seed=seed)
    client = LinkClient(transport, timeout=0.05, retries=retries, first_seq=100, **kw)
    return board, endpoint, client


def test_hello_learns_info_and_nonce():
    board, endpoint, client = make()
    info = client.hello()
    assert info.board_id == "fake" and info.boot_nonce == board.boot_nonce
    assert client.boot_nonce == board.boot_nonce
    assert client.read_cell(2, 3) == 1000 + 23
    assert client.write_pulse(2, 3, m.Polarity.SET, 100, 50) == 1000 + 23 + 10
    assert client.counters.requests == 3 and client.counters.retries == 0


def test_lossy_link_completes_and_never_applies_a_pulse_twice():
    board, endpoint, client = make(drop=0.005, corrupt=0.005, seed=3, retries=10)
    client.hello()
    n = 400
    expected = [row[:] for row in board.codes]
    for i in range(n):
        pol = m.Polarity.SET if i % 3 else m.Polarity.RESET
        adc = client.write_pulse(i % 32, i % 8, pol, 50, 100)
        expected[i % 32][i % 8] += 5 if pol == m.Polarity.SET else -5
        assert adc == expected[i % 32][i % 8]   # the read-after reflects exactly one pulse
    assert board.pulses == n
    assert board.codes == expected
    # the damage really caused retransmissions that the board answered from its cache
    assert client.counters.retries > 20
    assert endpoint.counters.duplicates > 5
    assert endpoint.counters.crc_errors + endpoint.counters.framing_errors > 0
    retries_before = client.counters.retries
    status = client.status()
    assert status.pulses_applied == n
    # Retransmissions of STATUS itself are answered from the cache after the snapshot.
    status_retries = client.counters.retries - retries_before
    assert status.duplicates >= endpoint.counters.duplicates - status_retries


def test_retransmission_uses_the_same_seq_and_gets_cached_reply():
    board = FakeBoard()
    endpoint = DeviceEndpoint(board, boot_nonce=board.boot_nonce)
    seen, replies = [], []

    def respond(data: bytes) -> bytes:
        seen.extend(FrameDecoder().feed(data))
        out = endpoint.feed(data)
        replies.append(out)
        return b"" if len(replies) == 1 else out   # lose the first reply

    client = LinkClient(CallbackTransport(respond), timeout=0.05, first_seq=7)
    assert client.write_pulse(1, 1, m.Polarity.SET, 100, 10) == 1011 + 10
    assert [f.seq for f in seen] == [7, 7]
    assert seen[1].flags & FLAG_RETRANSMIT and not seen[0].flags & FLAG_RETRANSMIT
    assert board.pulses == 1
    assert endpoint.counters.duplicates == 1 and endpoint.counters.executed == 1
    assert FrameDecoder().feed(replies[1])[0].flags & FLAG_FROM_CACHE


def test_stale_and_duplicated_replies_are_discarded():
    board = FakeBoard()
    endpoint = DeviceEndpoint(board, boot_nonce=board.boot_nonce)
    old = encode_frame(Frame.of(m.ReadCellReply(9999), 1, board.boot_nonce))

    def respond(data: bytes) -> bytes:
        out = endpoint.feed(data)
        return old + out + out  # a late reply to seq 1 before, a duplicate after

    client = LinkClient(CallbackTransport(respond), timeout=0.05, first_seq=50)
    client.hello()
    assert client.read_cell(0, 0) == 1000
    assert client.counters.stale_replies >= 2


def test_silent_board_times_out_with_clear_error():
    client = LinkClient(CallbackTransport(lambda data: b"", name="mute"), timeout=0.01,
                        retries=2)
    with pytest.raises(LinkTimeoutError, match="mute.*3 tries"):
        client.hello()
    assert client.counters.timeouts == 3 and client.counters.retries == 2


def test_nonce_change_is_an_error_and_request_not_executed():
    board, endpoint, client = make()
    client.hello()
    old = board.boot_nonce
    board.boot_nonce = 0xCAFE0001          # the board rebooted under the host
    with pytest.raises(BoardResetError) as info:
        client.write_pulse(0, 0, m.Polarity.SET, 100, 10)
    assert (info.value.old_nonce, info.value.new_nonce) == (old, 0xCAFE0001)
    assert board.pulses == 0               # the stale request was refused, not executed
    assert endpoint.counters.nonce_mismatches == 1
    with pytest.raises(BoardResetError):   # stays an error until the caller resynchronises
        client.read_cell(0, 0)
    client.hello()
    assert client.boot_nonce == 0xCAFE0001
    assert client.write_pulse(0, 0, m.Polarity.SET, 100, 10) == 1010
    assert client.counters.resets_detected >= 2


def test_reply_with_new_nonce_is_an_error():
    board = FakeBoard()

    def rebooting(req):
        reply = board(req)
        if isinstance(req, m.ReadCell):
            board.boot_nonce ^= 0xFFFF     # reset between executing and replying
        return reply

    endpoint = DeviceEndpoint(rebooting, boot_nonce=lambda: board.boot_nonce)
    client = LinkClient(CallbackTransport(endpoint.feed), timeout=0.05)
    client.hello()
    with pytest.raises(BoardResetError):
        client.read_cell(0, 0)


def test_reset_request_changes_nonce_without_error():
    board, endpoint, client = make()
    client.hello()
    client.read_cell(0, 0)
    old = client.boot_nonce
    reply = client.reset()
    assert reply.old_nonce == old and reply.new_nonce == board.boot_nonce != old
    assert client.boot_nonce == board.boot_nonce
    assert client.read_cell(0, 0) == 1000
    assert client.status().frames_in == 2  # counters restarted at the reset


def test_board_refusals_raise_typed_errors():
    board, endpoint, client = make()
    client.hello()
    with pytest.raises(SafetyLimitError, match="refused ReadCell"):
        client.request(m.ReadCell(0, 0, 300))        # raw: read_cell() refuses it host-side
    with pytest.raises(OutOfRangeError) as info:
        client.read_cell(40, 0)
    assert info.value.code == ErrorCode.OUT_OF_RANGE and info.value.detail == 40
    with pytest.raises(UnsupportedError):      # FakeBoard's Info lacks PROGRAM_CELL
        client.program_cell(0, 0, 1000, 10)
    assert client.counters.board_errors == 2
    assert endpoint.counters.refusals == 2


def test_busy_board_is_retried_then_reported():
    board = FakeBoard()
    calls = {"n": 0}

    def sometimes_busy(req):
        calls["n"] += 1
        if isinstance(req, m.ReadCell) and calls["n"] < 4:
            raise BusyError("array busy")
        return board(req)

    endpoint = DeviceEndpoint(sometimes_busy, boot_nonce=board.boot_nonce)
    client = LinkClient(CallbackTransport(endpoint.feed), timeout=0.05, retries=3,
                        busy_backoff_s=0.0)
    client.hello()
    assert client.read_cell(0, 0) == 1000     # 2 BUSY replies, then executed (not cached)
    assert client.counters.busy == 2

    def always_busy(req):
        if isinstance(req, m.Hello):
            return board(req)
        raise BusyError("array busy")

    client2 = LinkClient(CallbackTransport(DeviceEndpoint(always_busy).feed), timeout=0.05,
                         retries=2, busy_backoff_s=0.0)
    client2.hello()
    with pytest.raises(BoardBusyError, match="busy .array busy."):
        client2.read_cell(0, 0)
    assert client2.counters.busy == 3


def test_version_mismatch():
    board = FakeBoard()

    def newer(req):
        reply = board(req)
        return dataclasses.replace(reply, protocol_version=2) if isinstance(reply, m.Info) \
            else reply

    client = LinkClient(CallbackTransport(DeviceEndpoint(newer).feed), timeout=0.05)
    with pytest.raises(VersionMismatchError, match="version 2"):
        client.hello()

    endpoint = DeviceEndpoint(board)
    frame = Frame(m.Hello.TYPE, 1, m.Hello().encode(), version=9)
    reply = FrameDecoder().feed(endpoint.feed(encode_frame(frame)))[0].message()
    assert isinstance(reply, m.ErrorReply) and reply.code == ErrorCode.BAD_VERSION


def test_device_answers_protocol_errors():
    board = FakeBoard()
    ep = DeviceEndpoint(board, boot_nonce=5)

    def ask(frame):
        return [f.message() for f in FrameDecoder().feed(ep.feed(encode_frame(frame)))]

    assert ask(Frame(0x42, 1))[0].code == ErrorCode.UNKNOWN_TYPE
    assert ask(Frame(m.ReadCellReply.TYPE, 2, b"\x00\x00"))[0].code == ErrorCode.UNKNOWN_TYPE
    assert ask(Frame(m.ReadCell.TYPE, 3, b"\x01"))[0].code == ErrorCode.MALFORMED
    assert ask(Frame(m.ReadCell.TYPE, 4, m.ReadCell().encode(), nonce=6))[0].code == \
        ErrorCode.NONCE_MISMATCH
    # a damaged frame gets a NAK: BAD_FRAME, seq 0, request type 0, detail = the reason
    wire = bytearray(encode_frame(Frame(m.ReadCell.TYPE, 77, m.ReadCell(1, 2, 3).encode())))
    wire[-3] ^= 0x10
    frames = FrameDecoder().feed(ep.feed(bytes(wire)))
    nak = frames[0].message()
    assert frames[0].seq == 0 and (nak.code, nak.request_type, nak.detail) == \
        (ErrorCode.BAD_FRAME, 0, NakReason.CRC)
    for damaged, reason in ((wire[:5] + wire[6:], NakReason.LENGTH),      # a byte dropped
                            (b"\x09\x01\x02\x00", NakReason.COBS),        # group past the end
                            (b"\x03\x01\x02\x00", NakReason.LENGTH),      # shorter than 14
                            (b"\x11" * 5000 + b"\x00", NakReason.LENGTH)):  # over-long run
        (frame,) = FrameDecoder().feed(ep.feed(bytes(damaged)))
        assert frame.seq == 0 and frame.message().detail == reason
    assert ep.counters.crc_errors == 1 and ep.counters.framing_errors == 4
    assert ep.counters.executed == 0
    assert ep.counters.unknown_types == 2 and ep.counters.malformed == 1


def test_hello_clears_the_reply_cache():
    board = FakeBoard()
    ep = DeviceEndpoint(board, boot_nonce=board.boot_nonce)
    req = encode_frame(Frame.of(m.WritePulse(0, 0, m.Polarity.SET, 100, 10), 5))
    ep.feed(req)
    ep.feed(req)
    assert board.pulses == 1                 # same seq and bytes: cached
    ep.feed(encode_frame(Frame.of(m.Hello(), 6)))
    ep.feed(req)
    assert board.pulses == 2                 # a new session: seq 5 is a new request


def test_spike_batch_splits_window_under_max_payload():
    board, endpoint, client = make(max_payload=200)
    client.hello()
    rng = random.Random(1)
    rows = tuple((r, 245) for r in range(15))
    bins = tuple(b for b in range(1000) if rng.random() < 0.15)
    other = tuple(b for b in range(1000) if rng.random() < 0.05)
    groups = [m.SpikeGroup(rows, bins), m.SpikeGroup(((20, 100),), other)]
    result = client.spike_batch(groups, range(8))
    order = sorted([(b, 0) for b in bins] + [(b, 1) for b in other])
    assert list(result.spikes) == order
    assert result.round_trips > 1
    for (_b, g), codes in zip(result.spikes, result.codes):
        want = tuple(sum(board.codes[r][c] * d // 4095 for r, d in groups[g].rows)
                     for c in range(8))
        assert codes == want
    # one request when the payload allows it
    _, _, big = make()
    big.hello()
    assert big.spike_batch(groups, range(8)).round_trips == 1


def test_device_refuses_oversized_spike_batch_reply():
    board = FakeBoard()
    ep = DeviceEndpoint(board, max_payload=100)
    sb = m.SpikeBatch((m.SpikeGroup(((0, 10),), tuple(range(50))),), tuple(range(8)), 50)
    reply = FrameDecoder(max_payload=100).feed(ep.feed(encode_frame(Frame.of(sb, 1))))
    assert reply[0].message().code == ErrorCode.OUT_OF_RANGE
    assert board.executed.get("SpikeBatch", 0) == 0


def test_handler_bug_becomes_internal_error_not_a_crash():
    def broken(req):
        raise ZeroDivisionError("oops")

    client = LinkClient(CallbackTransport(DeviceEndpoint(broken).feed), timeout=0.05)
    with pytest.raises(Exception) as info:
        client.hello()
    assert getattr(info.value, "code", None) == ErrorCode.INTERNAL


def test_hello_gets_through_junk_left_by_an_earlier_session():
    board, endpoint, client = make(retries=0)
    assert endpoint.feed(b"100\n7,0,0,0\n\x05\x01\x02") == b""   # e.g. a legacy host's lines
    info = client.hello()                                        # no retry needed
    assert info.boot_nonce == board.boot_nonce
    assert client.counters.timeouts == 0 and endpoint.counters.framing_errors == 1


def test_a_slow_in_process_board_is_waited_for_not_resent():
    """A synchronous board answers inside write(); on a loaded host that can take longer than
    the wait per try. Its reply is buffered all the same: the link must read it, not resend on
    wall time (a resend puts extra frames - UART time - on an emulator's virtual clock)."""
    board = FakeBoard()
    endpoint = DeviceEndpoint(board, boot_nonce=lambda: board.boot_nonce)
    frames = []

    def slow(data: bytes) -> bytes:
        frames.append(data)
        time.sleep(0.03)                         # longer than timeout + min RTO
        return endpoint.feed(data)

    client = LinkClient(CallbackTransport(slow, name="slow"), timeout=0.01, min_rto_s=0.001,
                        first_seq=100)
    client.hello()
    assert client.read_cell(2, 3) == 1000 + 23
    assert client.write_pulse(2, 3, m.Polarity.SET, 100, 50) == 1000 + 23 + 10
    assert board.pulses == 1
    assert len(frames) == 3 and client.counters.retries == 0 and client.counters.timeouts == 0
    assert endpoint.counters.duplicates == 0
    assert client.rtt.samples == 0               # emulation time is no line's round trip
    # a reply that really is lost (fault injection) is still known at once and resent
    lossy = LossyTransport(CallbackTransport(endpoint.feed), drop=1.0, directions="read")
    mute = LinkClient(lossy, timeout=0.01, retries=2, first_seq=7)
    with pytest.raises(LinkTimeoutError):
        mute.read_cell(0, 0)
    assert mute.counters.frames_sent == 3
