"""A line that stalls, echoes, floods stale replies or is held by another host (issue 27,
items 1, 2, 7, 12): through the fault-injecting line of ``protocol.faults``.

* a silence within ``--timeout`` (and the run's stall budget) never ends a run, whatever the
  adaptive retransmission timer measured; beyond it the run stops with one line saying the
  line went silent after N answered requests, for how long, and how to resume;
* nothing is applied twice: a pulse resent during a stall is answered from the board's cache;
* a port that echoes is recognised at its first echo, a board that floods stale replies after a
  few tries, each with a message that says what happened;
* a host waits for a board another host holds (``--wait``) and never interleaves with it.

Wall-clock figures (stall costs, damaged-link ratios, give-up times) are in bench/bench_link.py.
"""

import logging
import threading

import pytest

from snan_hil.common.errors import UserError
from snan_hil.firmware_emu.emulator import Emulator
from snan_hil.firmware_emu.server import TcpServer
from snan_hil.firmware_emu.testing import ideal_array
from snan_hil.protocol import messages as m
from snan_hil.protocol.device import DeviceEndpoint, DeviceServer
from snan_hil.protocol.errors import BoardBusyError, BusyError, LinkTimeoutError
from snan_hil.protocol.faults import FaultyLine, FaultyTransport, LineFaults, Stall
from snan_hil.protocol.frames import FrameDecoder
from snan_hil.protocol.link import LinkClient
from snan_hil.protocol.retry import RetryingClient
from snan_hil.protocol.testing import FakeBoard, StaleFloodBoard
from snan_hil.protocol.transport import SerialTransport, pipe_pair
from snan_hil.tools.ports import open_client


@pytest.fixture
def faulty_board(fake_board_link):
    """``(faults, **link) -> (board, endpoint, line transport, client)``: a FakeBoard behind
    a faulty line (conftest's ``fake_board_link``)."""
    return lambda faults, **link: fake_board_link(lambda line: FaultyTransport(line, faults),
                                                  first_seq=500, **link)


def pulses(client, n, start=0):
    for k in range(start, start + n):
        client.write_pulse(k % 32, (k // 32) % 8, m.Polarity.SET, 100 + k % 50, 10)


@pytest.mark.parametrize("lose", [False, True], ids=["held", "lost"])
def test_a_stall_within_the_timeout_survives_and_pulses_once(faulty_board, lose):
    # the line stalls for 0.7 s after 300 bytes from the board (~25 replies in), both ways
    stall = Stall(after_bytes=300, length_s=0.7, lose=lose)
    board, endpoint, line, client = faulty_board(LineFaults(stalls=(stall,)), timeout=2.0)
    pulses(client, 60)
    assert line.stats.stalls == 1
    assert board.pulses == 60                           # every pulse exactly once
    assert client.rtt.samples > 10      # the timer had adapted (the old link gave up after
    #                                     four of its short silent tries: about 0.2 s)
    assert client.stalls.count == 1 and 0.5 < client.stalls.longest_s < 1.5
    assert client.counters.retries >= 1                 # resent during the stall...
    if not lose:
        assert endpoint.counters.duplicates >= 1        # ...answered from the board's cache
    assert client.status().pulses_applied == 60


def test_a_stall_beyond_the_timeout_stops_with_one_line_that_says_so(faulty_board):
    stall = Stall(after_bytes=300, length_s=5.0, lose=True)
    board, _, _, client = faulty_board(LineFaults(stalls=(stall,)), timeout=0.4)
    with pytest.raises(LinkTimeoutError) as exc:
        pulses(client, 60)
    text = str(exc.value)
    assert exc.value.kind == "stalled" and not exc.value.retryable
    assert f"went silent after {client.answered} answered requests" in text
    assert client.answered > 5 and "no byte for 0.4 s" in text and "--timeout 0.4 s" in text
    assert "run the command again" in text and "--resume" in text
    assert "no byte at all" not in text and "--protocol legacy" not in text   # item 2
    assert "\n" not in text
    assert board.pulses <= client.answered              # the lost pulse ran once or not at all


def test_the_stall_budget_of_a_run_ends_it_when_stalls_add_up(faulty_board):
    stalls = (Stall(200, 0.35, lose=True), Stall(600, 0.35, lose=True))
    _, _, _, client = faulty_board(LineFaults(stalls=stalls), timeout=2.0, max_rto_s=0.1,
                                   stall_budget_s=0.5)
    with pytest.raises(LinkTimeoutError, match=r"stalls in this run, beyond its --stall-budget "
                                               r"of 0\.5 s") as exc:
        pulses(client, 100)
    assert exc.value.kind == "stalled" and client.stalls.count == 2
    assert client.stalls.longest_s >= 0.35              # the first stall was ridden out
    assert client.stalls.total_s - client.stalls.longest_s < 0.2    # the second cut short


def test_a_board_that_never_answered_is_silent_with_the_first_contact_hint():
    host, _board_end = pipe_pair("nobody")
    client = LinkClient(host, timeout=5.0, connect_timeout=0.2)
    with pytest.raises(LinkTimeoutError, match="no byte at all came back") as exc:
        client.hello()
    assert exc.value.kind == "silent" and "--protocol legacy" in str(exc.value)


def test_a_port_that_echoes_is_recognised_at_the_first_echo(tmp_path):
    client = LinkClient(SerialTransport("loop://"), timeout=5.0)
    with pytest.raises(LinkTimeoutError, match="sends back what this host sends") as exc:
        RetryingClient(client).hello()
    assert exc.value.kind == "echo" and client.counters.frames_sent == 1
    with pytest.raises(UserError, match="loop://.*loopback"):
        open_client("loop://")


def test_a_board_flooding_stale_replies_is_given_up_on_after_a_few_tries():
    host, board_end = pipe_pair("flood")
    with StaleFloodBoard(board_end):
        client = LinkClient(host, timeout=5.0, retries=3)
        retrying = RetryingClient(client)
        retrying.hello()
        with pytest.raises(LinkTimeoutError, match="only with replies to other requests") as exc:
            retrying.read_cell(0, 0)
    assert exc.value.kind == "stale" and "another program" in str(exc.value)
    assert retrying.lost_requests == 1                  # not sent again as a new request
    assert client.counters.frames_sent == 1 + 4         # HELLO, then 4 tries of READ_CELL
    assert client.counters.stale_replies >= 4


def test_the_faulty_line_is_seeded_and_independent_of_chunking():
    faults = LineFaults(rate=0.05, delay_rate=0.01, delay_s=(0.0, 0.0), seed=4)
    data = bytes(range(256)) * 8
    whole = b"".join(b for _t, b in FaultyLine(faults).streams["to_host"].feed(data, 0.0))
    line = FaultyLine(faults)
    parts = b"".join(b for k in range(0, len(data), 7)
                     for _t, b in line.streams["to_host"].feed(data[k:k + 7], 0.0))
    assert whole == parts != data
    assert line.stats.damaged_bytes > 40 and set(line.stats.damaged) == {"flip", "drop", "dup",
                                                                          "insert"}
    assert min(line.stats.damaged.values()) > 0 and line.stats.delays > 5
    other = FaultyLine(LineFaults(rate=0.05, seed=5)).streams["to_host"].feed(data, 0.0)
    assert b"".join(b for _t, b in other) != whole


def test_a_stall_holds_or_loses_the_bytes_of_its_directions():
    held = FaultyLine(LineFaults(stalls=(Stall(10, 2.0, trigger="to_host"),)))
    out = held.streams["to_host"].feed(bytes(20), 100.0)
    assert [(t, len(b)) for t, b in out] == [(100.0, 9), (102.0, 11)]   # held from byte 10
    assert held.streams["to_board"].feed(b"x", 101.0) == [(102.0, b"x")]   # "both" directions
    assert held.streams["to_board"].feed(b"y", 103.0) == [(103.0, b"y")]   # it is over
    lost = FaultyLine(LineFaults(stalls=(Stall(10, 2.0, directions="to_host", lose=True),)))
    assert sum(len(b) for _t, b in lost.streams["to_host"].feed(bytes(20), 0.0)) == 9
    assert lost.streams["to_board"].feed(b"z", 1.0) == [(1.0, b"z")]
    assert lost.stats.lost_in_stalls == 11


def test_programming_completes_through_damage_and_delays_and_pulses_once(program_through_line):
    run = program_through_line(lambda line: FaultyTransport(line, LineFaults(
        rate=0.01, delay_rate=2e-4, delay_s=(0.05, 0.3), seed=3)))
    result, applied, line = run.result, run.applied, run.line
    s = result.report["summary"]
    assert result.report["complete"] and s["ok"] == s["cells"] == 24
    assert line.stats.damaged_bytes > 50 and line.stats.delays >= 1
    assert applied == s["host_pulses"] == result.report["ledger"]["confirmed"]


def _served():
    emu = Emulator(None, 0, array=ideal_array(), adc_noise_lsb=0.0)
    fed: list[int] = []
    decoder = FrameDecoder()
    feed = emu.feed

    def recording(data: bytes) -> bytes:
        fed.extend(frame.seq for frame in decoder.feed(data))
        return feed(data)

    emu.feed = recording
    return emu, fed


def test_a_second_host_waits_for_the_board_and_never_interleaves(caplog):
    emu, fed = _served()
    with TcpServer(emu, "127.0.0.1", 0) as server:
        first = LinkClient(SerialTransport(server.url), timeout=2.0, first_seq=1000)
        first.hello()
        got: dict[str, object] = {}

        def second_host() -> None:
            try:
                client = open_client(server.url, 115200, "framed", timeout=2.0, wait_s=20.0)
                got["read"] = client.read_cell(1, 1)
                got["seq"] = client.next_seq()
                client.close()
            except Exception as exc:  # noqa: BLE001 - reported to the test below
                got["error"] = exc

        with caplog.at_level(logging.WARNING, logger="snan_hil.protocol.link"):
            other = threading.Thread(target=second_host)
            other.start()
            for k in range(30):             # the first host goes on while the second waits
                first.write_pulse(k % 32, 0, m.Polarity.SET, 300, 10)
            busy_seen = server.busy_answers
            first.close()
            other.join(timeout=30)
    assert "error" not in got, got.get("error")
    assert got["read"] and busy_seen >= 1
    assert any("is busy (serving 127.0.0.1:" in r.getMessage() and "--wait" in r.getMessage()
               for r in caplog.records)
    mine = [s for s in fed if 1000 <= s < 1100]
    assert len(mine) == 31                                   # HELLO + 30 pulses, each once
    last_mine = max(i for i, s in enumerate(fed) if 1000 <= s < 1100)
    assert all(not 1000 <= s < 1100 for s in fed[last_mine + 1:])
    assert all(1000 <= s < 1100 for s in fed[:last_mine + 1])  # nothing of the other between


def test_waiting_for_a_busy_board_has_a_bound():
    emu, _ = _served()
    with TcpServer(emu, "127.0.0.1", 0) as server:
        first = open_client(server.url, 115200, "framed", timeout=2.0)
        try:
            with pytest.raises(UserError, match=r"busy \(serving 127\.0\.0\.1:\d+ since .*\) "
                                                r"and stayed busy for the 0\.4 s"):
                open_client(server.url, 115200, "framed", timeout=2.0, wait_s=0.4)
            with pytest.raises(BoardBusyError, match="--wait SECONDS waits"):
                LinkClient(SerialTransport(server.url), timeout=2.0).hello()
        finally:
            first.close()


def test_random_holds_come_at_a_rate_in_time_and_are_seeded():
    def run(seed):
        line = FaultyLine(LineFaults(delays_per_s=10.0, delay_s=(0.02, 0.02), seed=seed))
        return [out for k in range(1000)
                for out in line.streams["to_host"].feed(b"x", k * 0.002)], line.stats
    first, stats = run(1)
    again, _ = run(1)
    assert first == again != run(2)[0]
    held = [t - k * 0.002 for k, (t, _b) in enumerate(first) if t > k * 0.002 + 1e-12]
    assert 8 <= stats.delays <= 35 and held and max(held) <= 0.02 + 1e-9  # ~20 in 2 s
    assert abs(stats.delay_s - 0.02 * stats.delays) < 1e-9


def test_a_long_wait_for_a_busy_board_is_not_taken_for_a_damaged_link():
    board = FakeBoard()

    def always_busy(req):
        if isinstance(req, m.Hello):
            return board(req)
        raise BusyError("serving 10.0.0.7:5000 since 09:00:00")

    host, board_end = pipe_pair("busy")
    server = DeviceServer(DeviceEndpoint(always_busy), board_end, poll_s=0.001)
    try:
        client = LinkClient(host, timeout=2.0, give_up_s=0.2, busy_wait_s=0.8)
        client.hello()
        with pytest.raises(BoardBusyError, match="stayed busy for the 0.8 s"):
            client.read_cell(0, 0)
        assert client.counters.busy > 5
    finally:
        server.stop()


def test_wait_also_waits_for_a_port_another_program_holds():
    from snan_hil.firmware_emu.server import PtyServer

    emu = Emulator(None, 0, array=ideal_array(), adc_noise_lsb=0.0)
    waiting = threading.Event()

    class Seen(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            if "in use by another program; waiting up to" in record.getMessage():
                waiting.set()

    handler = Seen()
    logging.getLogger("snan_hil.lab.ports").addHandler(handler)
    got: dict[str, object] = {}
    try:
        with PtyServer(emu) as server:
            first = open_client(server.slave_path, 115200, "framed", timeout=2.0)
            with pytest.raises(UserError, match="in use by another program"):
                open_client(server.slave_path, 115200, "framed", timeout=2.0)

            def second_program() -> None:
                try:
                    client = open_client(server.slave_path, 115200, "framed", timeout=2.0,
                                         wait_s=20.0)
                    got["read"] = client.read_cell(2, 2)
                    client.close()
                except Exception as exc:  # noqa: BLE001 - reported below
                    got["error"] = exc

            other = threading.Thread(target=second_program)
            other.start()
            assert waiting.wait(10)                 # it found the port held, and waits
            assert first.read_cell(2, 2) > 0
            first.close()
            other.join(timeout=30)
    finally:
        logging.getLogger("snan_hil.lab.ports").removeHandler(handler)
    assert "error" not in got, got.get("error")
    assert got["read"]
