"""Loopback over real pseudo-terminals and pyserial URLs: the same client code everywhere."""

import random
import threading

import pytest

from snan_hil.protocol import messages as m
from snan_hil.protocol.device import DeviceEndpoint, DeviceServer
from snan_hil.protocol.legacy_client import LegacyClient
from snan_hil.protocol.legacy_device import LegacyDevice
from snan_hil.protocol.link import LinkClient
from snan_hil.protocol.testing import FakeBoard, LossyTransport
from snan_hil.protocol.transport import (PacedTransport, PtyTransport, SerialTransport,
                                         open_pty_pair, pipe_pair)


@pytest.fixture
def pty_board():
    """A FakeBoard served on the master end of a pty; yields (board, endpoint, slave path)."""
    board = FakeBoard()
    endpoint = DeviceEndpoint(board, boot_nonce=lambda: board.boot_nonce)
    pair = open_pty_pair()
    server = DeviceServer(endpoint, pair.master)
    yield board, endpoint, pair.slave_path
    server.stop()
    pair.close()


def test_pyserial_opens_the_slave_and_talks(pty_board):
    board, endpoint, path = pty_board
    with LinkClient(SerialTransport(path, 115200), timeout=0.5) as client:
        info = client.hello()
        assert info.board_id == "fake" and client.boot_nonce == board.boot_nonce
        assert client.read_cell(5, 6) == 1056
        assert client.write_pulse(5, 6, m.Polarity.RESET, 100, 100) == 1046
        rng = random.Random(2)
        bins = tuple(b for b in range(1000) if rng.random() < 0.15)
        res = client.spike_batch([m.SpikeGroup(tuple((r, 245) for r in range(15)), bins)],
                                 range(8))
        assert len(res.codes) == len(bins) and res.round_trips == 1
        clock = client.clock()
        assert clock.time_us == 100 * sum(board.executed.values())
        status = client.status()
        assert status.frames_in == endpoint.counters.frames_in
        assert status.pulses_applied == 1
    assert board.pulses == 1


def test_pty_link_survives_byte_loss_without_double_pulses(pty_board):
    board, endpoint, path = pty_board
    lossy = LossyTransport(SerialTransport(path), drop=0.01, seed=5, directions="write")
    client = LinkClient(lossy, timeout=0.1, retries=10, first_seq=1)
    client.hello()
    for _ in range(40):
        client.write_pulse(1, 2, m.Polarity.SET, 30, 10)
    assert board.pulses == 40 and board.codes[1][2] == 1012 + 40 * 3
    assert lossy.stats.dropped_write > 0 and client.counters.retries > 0
    client.close()


def test_legacy_over_pty():
    board = FakeBoard(interlocks=False)
    device = LegacyDevice(board)
    pair = open_pty_pair()
    stop = threading.Event()

    def serve():
        while not stop.is_set():
            data = pair.master.read(4096, 0.02)
            if data:
                out = device.feed(data)
                if out:
                    pair.master.write(out)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        with LegacyClient(SerialTransport(pair.slave_path), timeout=0.5) as client:
            info = client.hello()
            assert info.board_id == "fake" and info.protocol_version == 0
            assert client.read_cell(3, 4) == 1034
            assert client.write_pulse(3, 4, m.Polarity.SET, 200, 1500) == 1054
    finally:
        stop.set()
        thread.join()
        pair.close()
    assert board.pulses == 1


def test_loop_url_and_pipes_carry_frames():
    # loop:// echoes our own bytes: the framed client must not mistake its request for a reply
    with SerialTransport("loop://") as loop:
        loop.write(b"abc")
        assert loop.read(10, 0.5) == b"abc"
    host, dev = pipe_pair()
    board = FakeBoard()
    server = DeviceServer(DeviceEndpoint(board, boot_nonce=1), dev)
    client = LinkClient(host, timeout=0.5)
    assert client.hello().boot_nonce == 1
    assert client.read_cell(0, 7) == 1007
    server.stop()


def test_paced_transport_takes_wire_time():
    import time

    host, dev = pipe_pair()
    paced = PacedTransport(dev, baud=9600)
    start = time.monotonic()
    paced.write(bytes(96))          # 96 bytes at 9600 baud = 0.1 s on the line
    elapsed = time.monotonic() - start
    assert host.read(200, 0) == bytes(96)
    assert elapsed >= 0.099


def test_pty_transport_reads_what_slave_writes():
    pair = open_pty_pair()
    try:
        with SerialTransport(pair.slave_path) as ser:
            ser.write(b"\x00\x01\x02\x0a\x0d\xff")
            got = b""
            while len(got) < 6:
                chunk = pair.master.read(16, 1.0)
                assert chunk, "pty delivered nothing"
                got += chunk
            assert got == b"\x00\x01\x02\x0a\x0d\xff"   # raw mode: no newline translation
            assert isinstance(pair.master, PtyTransport)
    finally:
        pair.close()


def test_vanished_board_is_a_transport_error_naming_the_port():
    from snan_hil.protocol.errors import TransportError
    pair = open_pty_pair()
    ser = SerialTransport(pair.slave_path)
    try:
        pair.close()                     # the board side goes away (emulator killed, unplugged)
        with pytest.raises(TransportError, match="went away") as exc:
            for _ in range(3):           # flush, write and read all must fail cleanly
                ser.reset_input_buffer()
                ser.write(b"\x00")
                ser.read(1, 0.05)
        assert pair.slave_path in str(exc.value)
    finally:
        ser.close()
