"""`snan-hil info` and tools/ports.py: real clients over a pty, one-line errors: exit 2 for a
port that cannot be opened, 3 when the board or its link fails."""

import dataclasses
import json
import subprocess
import sys
import threading

import pytest

from snan_hil.common.errors import UserError
from snan_hil.protocol import messages as m
from snan_hil.protocol.device import DeviceEndpoint, DeviceServer
from snan_hil.protocol.legacy_client import LegacyClient
from snan_hil.protocol.legacy_device import LegacyDevice
from snan_hil.protocol.link import LinkClient
from snan_hil.protocol.testing import FakeBoard
from snan_hil.protocol.transport import SerialTransport, open_pty_pair
from snan_hil.tools import cli, ports


@pytest.fixture(autouse=True)
def _user_data(tmp_path, monkeypatch):
    """Board commands on a pty record into the board's history in the user's data folder:
    keep it in the test's folder."""
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))


@pytest.fixture
def served():
    """Serve a handler on a pty; yields a function handler -> slave path."""
    started = []

    def serve(handler, legacy=False):
        pair = open_pty_pair()
        if legacy:
            device = LegacyDevice(handler)
            stop = threading.Event()

            def loop():
                while not stop.is_set():
                    data = pair.master.read(4096, 0.02)
                    out = device.feed(data) if data else b""
                    if out:
                        pair.master.write(out)

            thread = threading.Thread(target=loop, daemon=True)
            thread.start()
            started.append((pair, lambda: (stop.set(), thread.join())))
        else:
            server = DeviceServer(DeviceEndpoint(handler, boot_nonce=0xABCD), pair.master)
            started.append((pair, lambda: server.stop(close_transport=False)))
        return pair.slave_path

    yield serve
    for pair, stop in started:
        stop()
        pair.close()


def test_info_json_over_pty(served, capsys):
    path = served(FakeBoard())
    assert cli.main(["info", "--port", path, "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["info"]["board_id"] == "fake"
    assert data["info"]["boot_nonce"] == 0xABCD
    assert data["info"]["rows"] == 32 and data["info"]["cols"] == 8
    assert "SPIKE_BATCH" in data["info"]["capabilities_names"]
    assert data["status"]["frames_in"] >= 2
    assert data["link_counters"]["requests"] == 3        # hello, status, clock
    assert data["clock"]["time_us"] == 300


def test_info_table_over_pty(served, capsys):
    path = served(FakeBoard())
    assert cli.main(["info", "--port", path]) == 0
    out = capsys.readouterr().out
    assert "fake" in out and "link counters" in out and "0x0000abcd" in out


def test_info_legacy_protocol(served, capsys):
    path = served(FakeBoard(interlocks=False), legacy=True)
    assert cli.main(["info", "--port", path, "--protocol", "legacy", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["info"]["board_id"] == "fake" and data["info"]["protocol_version"] == 0
    assert "status" not in data                           # not available over legacy
    assert data["link_counters"]["lines_out"] >= 2


def test_open_client_returns_connected_clients(served):
    framed = ports.open_client(served(FakeBoard()), 921600)
    assert isinstance(framed, LinkClient) and framed.info.board_id == "fake"
    assert framed.transport.baud == 921600
    framed.close()
    old = ports.open_client(served(FakeBoard(interlocks=False), legacy=True), protocol="legacy")
    assert isinstance(old, LegacyClient) and old.read_cell(0, 1) == 1001
    old.close()


def _one_line_error(capsys, argv, *needles, code=cli.EXIT_USER_ERROR):
    assert cli.main(argv) == code
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for needle in needles:
        assert needle in err, err
    return err


def test_missing_port_is_one_line_exit_2(capsys):
    _one_line_error(capsys, ["info", "--port", "/dev/no-such-board-xyz"],
                    "/dev/no-such-board-xyz", "no such device", "--port emu")


@pytest.mark.parametrize("command", ["map", "ping"])
def test_other_board_commands_report_a_bad_port_in_one_line(capsys, command, tmp_path):
    _one_line_error(capsys, [command, "--port", "/dev/no-such-board-xyz"],
                    "/dev/no-such-board-xyz", "no such device")
    _one_line_error(capsys, [command, "--port", str(tmp_path)], str(tmp_path),
                    "not a serial device")


def test_vanished_board_during_a_command_is_one_line(served, capsys, monkeypatch):
    path = served(FakeBoard())
    from snan_hil.lab import opener
    real_open = opener.connect

    def open_then_lose_the_line(*args, **kwargs):
        client = real_open(*args, **kwargs)
        client.transport.serial.close()          # as if the adapter were unplugged
        client.transport.serial.port = None
        return client

    monkeypatch.setattr(opener, "connect", open_then_lose_the_line)
    _one_line_error(capsys, ["map", "--port", path], path, "board or link failed",
                    code=cli.EXIT_BOARD_OR_LINK)


def test_busy_port(capsys):
    pair = open_pty_pair()
    try:
        with SerialTransport(pair.slave_path):        # another program holds the port
            _one_line_error(capsys, ["info", "--port", pair.slave_path], pair.slave_path,
                            "in use")
    finally:
        pair.close()


def test_silent_board(capsys):
    pair = open_pty_pair()                            # nobody answers on the master end
    try:
        _one_line_error(capsys, ["info", "--port", pair.slave_path, "--timeout", "0.02"],
                        pair.slave_path, "no answer", "--protocol legacy",
                        code=cli.EXIT_BOARD_OR_LINK)
        _one_line_error(capsys, ["info", "--port", pair.slave_path, "--timeout", "0.01",
                                 "--protocol", "legacy"], "no answer", "--protocol framed",
                        code=cli.EXIT_BOARD_OR_LINK)
    finally:
        pair.close()


def test_version_mismatch(served, capsys):
    board = FakeBoard()

    def newer(req):
        reply = board(req)
        return dataclasses.replace(reply, protocol_version=3) if isinstance(reply, m.Info) \
            else reply

    path = served(newer)
    _one_line_error(capsys, ["info", "--port", path], path, "version 3", "update",
                    code=cli.EXIT_BOARD_OR_LINK)


def test_socket_refused(capsys):
    _one_line_error(capsys, ["info", "--port", "socket://127.0.0.1:9"], "socket://127.0.0.1:9",
                    "cannot open")


@pytest.mark.parametrize("url,what", [("emu://?seed=x", "seed must be an integer"),
                                      ("emu://?colour=red", "unknown option 'colour'"),
                                      ("emu://?protocol=morse", "protocol must be one of"),
                                      ("emu://somewhere", "of the form"),
                                      ("emu://?seed=1&seed=2", "'seed' is given twice")])
def test_bad_emu_url_is_one_user_error(url, what, tmp_path, monkeypatch):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    with pytest.raises(UserError, match=what) as err:
        ports.open_transport(url)
    assert url in str(err.value) and "\n" not in str(err.value)
    assert not (tmp_path / "chip.npz").exists()          # nothing was created


def test_bad_option_values(capsys):
    with pytest.raises(UserError, match="baud"):
        ports.open_transport("loop://", baud=0)
    with pytest.raises(UserError, match="protocol"):
        ports.open_transport("loop://", protocol="smoke-signals")
    for bad in ("0", "-1", "nan"):
        _one_line_error(capsys, ["info", "--port", "loop://", "--timeout", bad], "--timeout")


def test_cli_subprocess_has_no_traceback():
    proc = subprocess.run([sys.executable, "-m", "snan_hil.tools.cli", "info", "--port",
                           "/dev/no-such-board-xyz"], capture_output=True, text=True,
                          check=False, timeout=60)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr and proc.stderr.count("\n") == 1


def test_ping_over_pty(served, capsys):
    board = FakeBoard()
    path = served(board)
    assert cli.main(["ping", "--port", path, "-n", "5", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["count"] == 5 and data["link_counters"]["requests"] == 6   # hello + 5
    assert board.executed["Status"] == 5 and board.pulses == 0
    assert cli.main(["ping", "--port", path, "-n", "0"]) == 2
