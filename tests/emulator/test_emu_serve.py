"""The emulator answering over a real pseudo-terminal (pyserial on the slave end) and TCP."""

import sys

import pytest

from snan_hil.firmware_emu.emulator import Emulator
from snan_hil.firmware_emu.server import PtyServer, TcpServer, parse_host_port
from snan_hil.firmware_emu.testing import ideal_array
from snan_hil.common.errors import UserError
from snan_hil.protocol.messages import Polarity
from snan_hil.tools.ports import open_client

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="needs POSIX ptys")


def emulator(protocol="framed", mcu="model"):
    return Emulator(None, 0, array=ideal_array(), protocol=protocol, adc_noise_lsb=0.0, mcu=mcu)


def test_framed_protocol_over_a_real_pty(mcu):
    events = []
    with PtyServer(emulator(mcu=mcu), on_event=events.append) as server:
        assert server.slave_path.startswith("/dev/")
        client = open_client(server.slave_path, 115200, "framed", timeout=1.0)
        try:
            assert client.info.rows == 32 and client.info.boot_nonce != 0
            before = client.read_cell(4, 4)
            after = client.write_pulse(4, 4, Polarity.SET, 900, 100)
            assert after > before
            assert client.status().pulses_applied == 1
        finally:
            client.close()
    assert any("opened" in e for e in events)


def test_legacy_protocol_over_a_real_pty():
    with PtyServer(emulator("legacy")) as server:
        client = open_client(server.slave_path, 115200, "legacy", timeout=1.0)
        try:
            assert client.info.board_id.startswith("EMU-")
            assert (client.info.rows, client.info.cols) == (32, 8)
            first = client.read_cell(1, 2)
            assert abs(client.read_cell(1, 2) - first) <= 2
            assert client.write_pulse(1, 2, Polarity.SET, 900, 200) > first
            assert client.counters.stale_lines == 0
        finally:
            client.close()


def test_tcp_loopback_with_pyserial_socket_url(mcu):
    events = []
    with TcpServer(emulator(mcu=mcu), "127.0.0.1", 0, on_event=events.append) as server:
        assert server.url.startswith("socket://127.0.0.1:")
        for _ in range(2):                       # two connections, one after the other
            client = open_client(server.url, 115200, "framed", timeout=1.0)
            try:
                assert client.read_cell(0, 0) > 0
            finally:
                client.close()
    assert sum("connection" in e and "from" in e and "closed" not in e for e in events) == 2


def test_parse_host_port():
    assert parse_host_port("127.0.0.1:5555") == ("127.0.0.1", 5555)
    assert parse_host_port("[::1]:0") == ("::1", 0)
    for bad in ("5555", "host:port", "h:70000"):
        with pytest.raises(UserError):
            parse_host_port(bad)


def test_second_tcp_client_is_told_at_once_that_the_board_is_busy(mcu):
    events = []
    with TcpServer(emulator(mcu=mcu), "127.0.0.1", 0, on_event=events.append) as server:
        first = open_client(server.url, 115200, "framed", timeout=1.0)
        try:
            assert first.read_cell(0, 0) > 0
            with pytest.raises(UserError, match=r"busy \(serving 127\.0\.0\.1:\d+ since "
                                                r"\d\d:\d\d:\d\d[+-]\d\d:\d\d\)") as exc:
                open_client(server.url, 115200, "framed", timeout=1.0)
            assert "stop it" in str(exc.value)
            assert first.read_cell(0, 0) > 0               # the first client is unaffected
        finally:
            first.close()
        # the first client left: the next one is served
        second = open_client(server.url, 115200, "framed", timeout=1.0)
        try:
            assert second.read_cell(0, 0) > 0
            assert second.counters.busy == 0
        finally:
            second.close()
    assert server.busy_answers == 4                     # 1 + 3 retries of the refused HELLO
    assert any("busy serving" in e for e in events)


def test_a_waiting_clients_damaged_frame_gets_a_nak_then_busy():
    """docs/protocol.md, section 4 (issue 27, item 6): a client waiting behind BUSY whose frame
    arrives damaged gets a NAK (nonce 0: from the server, the board never saw it), so it
    resends at once and hears BUSY; the BUSY message gives the time with its UTC offset."""
    import socket
    from datetime import datetime
    from snan_hil.protocol import messages as m
    from snan_hil.protocol.errors import ErrorCode, NakReason
    from snan_hil.protocol.frames import Frame, FrameDecoder, encode_frame
    with TcpServer(emulator(), "127.0.0.1", 0) as server:
        first = open_client(server.url, 115200, "framed", timeout=1.0)
        try:
            hello = encode_frame(Frame.of(m.Hello(), 7, 0))
            damaged = bytearray(hello)
            damaged[5] ^= 0x10                               # a CRC error
            with socket.create_connection(server.address, timeout=5.0) as other:
                other.sendall(bytes(damaged) + hello)
                dec, got = FrameDecoder(), []
                while len(got) < 2:
                    got += dec.feed(other.recv(4096))
            nak, busy = (f.message() for f in got)
            assert (got[0].seq, got[0].nonce, nak.code, nak.detail) == \
                (0, 0, ErrorCode.BAD_FRAME, NakReason.CRC)
            assert (got[1].seq, got[1].nonce, busy.code) == (7, 0, ErrorCode.BUSY)
            since = busy.message.rsplit(" since ", 1)[1]
            offset = datetime.now().astimezone().isoformat(timespec="seconds")[19:]
            assert len(since) == 14 and since.endswith(offset)
            assert first.read_cell(0, 0) >= 0                 # the served client is unaffected
        finally:
            first.close()
    assert server.busy_answers == 1


def test_busy_answer_counts_no_timeout_and_reaches_no_board(mcu):
    from snan_hil.protocol.errors import BoardBusyError
    from snan_hil.protocol.link import LinkClient
    from snan_hil.protocol.transport import SerialTransport
    with TcpServer(emulator(mcu=mcu), "127.0.0.1", 0) as server:
        first = open_client(server.url, 115200, "framed", timeout=1.0)
        frames_in = first.status().frames_in
        other = LinkClient(SerialTransport(server.url), timeout=1.0, retries=2)
        try:
            with pytest.raises(BoardBusyError):
                other.hello()
            assert other.counters.busy == 3 and other.counters.timeouts == 0
        finally:
            other.close()
        assert first.status().frames_in == frames_in + 1   # only the first client's STATUS
        first.close()


def test_silent_tcp_client_is_dropped_after_the_idle_timeout():
    import socket
    import time
    events = []
    with TcpServer(emulator(), "127.0.0.1", 0, on_event=events.append,
                   idle_timeout_s=0.3) as server:
        host, port = server.address
        silent = socket.create_connection((host, port))
        try:
            silent.settimeout(5.0)
            t0 = time.monotonic()
            assert silent.recv(10) == b""                  # closed by the server
            assert time.monotonic() - t0 < 4.0
        finally:
            silent.close()
        client = open_client(server.url, 115200, "framed", timeout=1.0)
        try:
            assert client.read_cell(0, 0) > 0
        finally:
            client.close()
    assert server.dropped_idle == 1
    assert any("--idle-timeout" in e for e in events)


@pytest.mark.parametrize("argv,needle", [
    (["--seed", "-1"], "--seed must be a whole number >= 0"),
    (["--socket", "256.1.1.1:5000"], "cannot listen on 256.1.1.1:5000"),
    (["--socket", "127.0.0.1:99999"], "port must be 0..65535"),
])
def test_a_refused_emu_start_makes_no_chip_file(tmp_path, capsys, argv, needle):
    """Issue 27 item 13: a refused `snan-hil emu` (bad seed, an address it cannot listen on)
    says so in one line and leaves no chip file behind."""
    from snan_hil.tools import cli
    state = tmp_path / "chip.npz"
    assert cli.main(["emu", "--state", str(state), *argv]) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1, err
    assert list(tmp_path.iterdir()) == []
