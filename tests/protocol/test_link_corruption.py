"""A damaged link (issue 13, section 6): bytes flipped, dropped, duplicated and inserted.

Programming completes at 1 % and 5 % damaged bytes with every pulse applied exactly once;
retransmissions under damage are answered from the board's reply cache; the board NAKs damaged
frames; the link's errors say which failure it is (no byte at all, bytes that never form a
frame, a link too damaged, a busy board); the retransmission timeout follows the measured
round trip. Wall-clock figures are in ``bench/bench_link.py``.
"""

import pytest

from snan_hil.protocol import messages as m
from snan_hil.protocol.device import DeviceEndpoint, DeviceServer
from snan_hil.protocol.errors import LinkTimeoutError
from snan_hil.protocol.link import DEFAULT_RETRIES, LinkClient
from snan_hil.protocol.testing import ByteCorrupter, FakeBoard, LossyTransport
from snan_hil.protocol.transport import CallbackTransport, pipe_pair


@pytest.mark.parametrize("rate", [0.01, 0.05])
def test_programming_completes_on_a_damaged_link_and_pulses_once(program_through_line, rate,
                                                                 mcu):
    run = program_through_line(lambda line: LossyTransport.uniform(line, rate, seed=7), mcu)
    result, applied, counters, lossy, client = (run.result, run.applied, run.board, run.line,
                                                run.client)
    report = result.report
    s, ledger = report["summary"], report["ledger"]
    assert report["complete"] and s["ok"] == s["cells"] == 24
    assert lossy.stats.damaged > 200 * rate / 0.01            # the link really was damaged
    assert min(lossy.stats.dropped_write, lossy.stats.corrupted_read,
               lossy.stats.duplicated_write, lossy.stats.inserted_read) > 0
    # each pulse the host decided ran at most once, and the board's count proves it
    assert applied == s["host_pulses"] == ledger["confirmed"]
    assert ledger["decided"] == ledger["confirmed"] + ledger["not_applied"]
    assert counters.duplicates > 0                   # retransmissions answered from the cache
    assert counters.crc_errors + counters.framing_errors > 0      # and damaged frames NAKed
    assert client.counters.bad_crc_reported > 0


def test_retransmitted_pulses_under_damage_are_never_executed_twice(fake_board_link):
    executed: list[tuple[int, int, int]] = []

    def handler(board, req):
        if isinstance(req, m.WritePulse):
            executed.append((req.row, req.col, req.amplitude_code))
        return board(req)

    _, endpoint, _, client = fake_board_link(
        lambda line: LossyTransport.uniform(line, 0.05, seed=3), handler=handler)
    asked, answered = [], 0
    for k in range(300):
        pulse = (k % 32, (k // 32) % 8, 10 + k)           # every request unique
        asked.append(pulse)
        try:
            client.write_pulse(pulse[0], pulse[1], m.Polarity.SET, pulse[2], 10)
            answered += 1
        except LinkTimeoutError:
            pass
    assert len(executed) == len(set(executed))            # no pulse twice
    assert set(executed) <= set(asked) and len(executed) >= answered > 250
    assert endpoint.counters.duplicates > 50 and client.counters.retries > 300


def test_error_kinds_say_which_failure_it_is():
    # no byte at all
    mute = LinkClient(CallbackTransport(lambda data: b"", name="mute"), timeout=0.01)
    with pytest.raises(LinkTimeoutError, match="no byte at all") as exc:
        mute.hello()
    assert exc.value.kind == "silent"
    # bytes that never form a frame (a wrong baud rate looks like this)
    junk = ByteCorrupter(1.0, seed=1, kinds=("flip",))
    garbled = LinkClient(CallbackTransport(lambda data: junk(b"\x05\x11\x22\x33\x44\x00" * 3),
                                           name="noise"), timeout=0.01)
    with pytest.raises(LinkTimeoutError, match="none formed a valid frame") as exc:
        garbled.hello()
    assert exc.value.kind == "garbled"
    # the board answers (NAKs) but nothing intact gets through: every request damaged
    endpoint = DeviceEndpoint(FakeBoard())

    def flip_one_bit(data: bytes) -> bytes:              # the delimiters survive
        damaged = bytearray(data)
        damaged[-4] ^= 0x04 if damaged[-4] != 0x04 else 0x08
        return endpoint.feed(bytes(damaged))

    noisy = LinkClient(CallbackTransport(flip_one_bit), timeout=0.01, give_up_s=0.2)
    with pytest.raises(LinkTimeoutError, match="too damaged") as exc:
        noisy.hello()
    assert exc.value.kind == "corrupting" and noisy.counters.bad_crc_reported > 10


def test_retransmission_timeout_follows_the_measured_round_trip():
    host, board_side = pipe_pair("rtt")
    server = DeviceServer(DeviceEndpoint(FakeBoard()), board_side, poll_s=0.001)
    try:
        client = LinkClient(host, timeout=0.5)
        assert client._rto(0) == 0.5                     # nothing measured yet
        client.hello()
        for _ in range(30):
            client.status()
        assert client.rtt.samples == 31
        assert client.min_rto_s <= client._rto(0) < 0.1   # a few ms measured
        assert client._rto(3) <= 0.5                      # backs off, never beyond --timeout
    finally:
        server.stop()


def test_a_flood_of_bytes_that_never_form_a_frame_gives_up():
    # a board at the wrong baud or a noisy line streaming 0x55: no delimiter, so the decoder
    # reports over-long frames (damaged, none from a board), which must count towards giving up
    writes = []

    def flood(data: bytes) -> bytes:        # more than one frame's worth per try (4127 B)
        writes.append(data)
        if len(writes) > 50:
            raise RuntimeError("the link never gave up on a flood")
        return b"\x55" * 5000

    client = LinkClient(CallbackTransport(flood, name="flood"), timeout=0.05)
    with pytest.raises(LinkTimeoutError, match="none formed a valid frame") as exc:
        client.hello()
    assert exc.value.kind == "garbled" and len(writes) == client.retries + 1


def test_a_garbled_first_hello_is_not_asked_again_above_the_link():
    from snan_hil.protocol.retry import RetryingClient
    writes = []

    def flood(data: bytes) -> bytes:
        writes.append(data)
        return b"\x55" * 5000

    client = RetryingClient(LinkClient(CallbackTransport(flood, name="flood"), timeout=0.05))
    with pytest.raises(LinkTimeoutError, match="none formed a valid frame"):
        client.hello()
    assert len(writes) == DEFAULT_RETRIES + 1              # one request: nothing ever answered


def test_info_on_a_socket_flooding_garbage_is_one_line(capsys):
    import socket
    import threading

    from snan_hil.tools import cli
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    stop = threading.Event()

    def serve() -> None:
        conn, _ = srv.accept()
        with conn:
            try:
                while not stop.is_set():
                    conn.sendall(b"\x55" * 4096)
            except OSError:
                pass

    server = threading.Thread(target=serve, daemon=True)
    server.start()
    try:
        code = cli.main(["info", "--port", f"socket://127.0.0.1:{srv.getsockname()[1]}"])
    finally:
        stop.set()
        srv.close()
    err = capsys.readouterr().err.strip()
    assert code == 3 and "\n" not in err and "none formed a valid frame" in err, err
