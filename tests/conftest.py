"""Shared fixtures and session set-up.

``mcu`` / ``module_mcu``: the emulated board's MCU a test talks to through the framed protocol,
``"model"`` (the Python firmware model) and ``"firmware"`` (the C firmware ELF on the
instruction-level MCU, docs/firmware.md). Tests that take it run once per MCU; the firmware
case is skipped when ``unicorn`` is missing or the ELF or the native MCU core is not built
(``make firmware``, which ``make test`` runs first).
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
import tempfile
import time

import pytest

PY = [sys.executable, "-m", "snan_hil.tools.cli"]


def pytest_configure(config: pytest.Config) -> None:
    """The whole run (and every command it starts) uses a data folder of its own, never the
    user's ``~/.local/share/snan-hil``: commands record software runs and keep the default
    chip there, and a file left by another checkout (a newer history schema, a busy default
    chip) must not change a test's outcome. Tests that need a fresh one still set their own
    (``chip_home``)."""
    os.environ["XDG_DATA_HOME"] = tempfile.mkdtemp(prefix="snan-hil-test-data-")
    # one console width for every runner: pytest-xdist's workers inherit COLUMNS=80, which
    # rich takes over the CLI's plain width (tools/console.py PLAIN_WIDTH) and wraps the tables
    # and lines the tests read
    os.environ["COLUMNS"] = "250"
    os.environ.pop("SNAN_HIL_EMU_STATE", None)
SHORT = ["--set", "grid.max_steps=15"]

MCUS = ("model", "firmware")


def firmware_missing() -> str | None:
    """Why the firmware MCU cannot run here (None: it can)."""
    if importlib.util.find_spec("unicorn") is None:
        return "needs the 'unicorn' package (pip install -e '.[firmware]')"
    from snan_hil.firmware_emu.fw_image import default_elf_path
    if not default_elf_path().is_file():
        return "firmware ELF not built ('make firmware')"
    from snan_hil.firmware_emu import mik32_native
    if mik32_native.load() is None:       # the reference core alone is too slow for the suites
        return "native MCU core not built or stale ('make firmware')"
    return None


def _mcu(param: str) -> str:
    if param == "firmware":
        reason = firmware_missing()
        if reason:
            pytest.skip(reason)
    return param


@pytest.fixture(params=MCUS)
def mcu(request) -> str:
    """Each MCU model in turn (function scope)."""
    return _mcu(request.param)


@pytest.fixture
def firmware_mcu() -> str:
    """``"firmware"``, the C firmware MCU (skipped where it cannot run: ``firmware_missing``)."""
    return _mcu("firmware")


@pytest.fixture(scope="module", params=MCUS)
def module_mcu(request) -> str:
    """Each MCU model in turn, for module-scoped fixtures (e.g. a programmed chip)."""
    return _mcu(request.param)


@pytest.fixture(scope="session")
def cli_trained(tmp_path_factory):
    """A weights file written by ``snan-hil train`` (6x6 task, 2 sets, 2 cycles, seed 3, at most
    15 steps a launch): made once, read only."""
    from snan_hil.tools import cli
    path = tmp_path_factory.mktemp("cli-train") / "w.npz"
    assert cli.main(["train", "--grid", "6", "--start", "18", "--goal", "0", "--sets", "2",
                     "--cycles", "2", "--seed", "3", "-o", str(path), "--json", *SHORT]) == 0
    return path


@pytest.fixture
def start_emu_server():
    """``start(state, *extra, env=None) -> (process, url)``: ``snan-hil emu --socket`` on a free
    port of 127.0.0.1 with chip file ``state`` in a subprocess, once it serves."""
    def start(state, *extra, env=None):
        proc = subprocess.Popen([*PY, "emu", "--socket", "127.0.0.1:0", "--state", str(state),
                                 *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, env=env)
        line = proc.stdout.readline()
        match = re.search(r"serving on (\S+)", line)
        assert match, line + proc.stderr.read()
        return proc, match.group(1)
    return start


@pytest.fixture
def fake_board_link():
    """``make(wrap, *, handler=None, first_seq=None, **link) -> (board, endpoint, line,
    client)``: a FakeBoard answering in-process (each request through ``handler(board,
    request)`` when given), reached through the faulty line ``wrap(transport)`` (a
    ``protocol.faults.FaultyTransport`` or ``protocol.testing.LossyTransport``), by a
    LinkClient (``link``: its options) that has said HELLO."""
    from snan_hil.protocol.device import DeviceEndpoint
    from snan_hil.protocol.link import LinkClient
    from snan_hil.protocol.retry import RetryingClient
    from snan_hil.protocol.testing import FakeBoard
    from snan_hil.protocol.transport import CallbackTransport

    def make(wrap, *, handler=None, **link):
        board = FakeBoard()
        answer = board if handler is None else (lambda req: handler(board, req))
        endpoint = DeviceEndpoint(answer, boot_nonce=board.boot_nonce)
        line = wrap(CallbackTransport(endpoint.feed, name="fake"))
        client = LinkClient(line, **link)
        RetryingClient(client).hello()
        return board, endpoint, line, client
    return make


@pytest.fixture
def program_through_line(tmp_path):
    """``program(wrap, mcu="model")``: program the 3x3 grid's 24 synapses (no screening) into
    an in-process emulator chip reached through the faulty line ``wrap(transport)``; a
    namespace of ``result`` (the programmer's), ``applied`` (the pulses the board's front end
    counted), ``board`` (the board's link counters, its STATUS, after the run), ``line`` and
    ``client`` (closed)."""
    from types import SimpleNamespace

    from snan_hil.calibration.programmer import ProgramConfig, program_weights
    from snan_hil.calibration.testing import grid_weights, session_of
    from snan_hil.firmware_emu.inprocess import emulator_of, open_inprocess_transport
    from snan_hil.protocol.link import LinkClient
    from snan_hil.protocol.retry import RetryingClient

    def program(wrap, mcu="model"):
        transport = open_inprocess_transport(state_file=str(tmp_path / "chip.npz"), seed=0,
                                             mcu=mcu)
        emu = emulator_of(transport)
        line = wrap(transport)
        client = LinkClient(line)
        try:
            RetryingClient(client).hello()
            before = emu.board.front_end.pulses_applied
            result = program_weights(session_of(client, tmp_path / "layout.json"),
                                     grid_weights(3, 3, seed=2), {"grid": [3, 3]},
                                     config=ProgramConfig(screen=False))
            applied = emu.board.front_end.pulses_applied - before
            counters = RetryingClient(client).status()
        finally:
            client.close()
        return SimpleNamespace(result=result, applied=applied, board=counters, line=line,
                               client=client)
    return program


@pytest.fixture
def chip_home(tmp_path, monkeypatch):
    """A folder holding the emulator's default chip (``chip.npz``, not created) and the user's
    data folder (``xdg/``), and a 3x3 weight matrix ``w.npy``."""
    import numpy as np
    from snan_hil.calibration.testing import grid_weights
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    np.save(tmp_path / "w.npy", grid_weights(3, 3, seed=2))
    return tmp_path


@pytest.fixture
def emu(tmp_path, monkeypatch):
    """A folder holding the emulator's default chip (``chip.npz``, not created) and the user's
    data folder (``data/``); ``$SNAN_HIL_PORT`` and ``$SNAN_HIL_FIRMWARE_ELF`` unset."""
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    monkeypatch.delenv("SNAN_HIL_PORT", raising=False)
    monkeypatch.delenv("SNAN_HIL_FIRMWARE_ELF", raising=False)
    return tmp_path


@pytest.fixture
def programmed_emu(emu, capsys):
    """The ``emu`` folder with a 3x3 weight set (``w.npy``, seed 4) programmed on its chip
    (``chip.layout.json``, ``chip.program-report.json`` and ``chip.history.sqlite`` beside
    it); what the command printed is read away."""
    import numpy as np
    from snan_hil.calibration.testing import grid_weights
    from snan_hil.tools import cli
    np.save(emu / "w.npy", grid_weights(3, 3, seed=4))
    assert cli.main(["program-weights", str(emu / "w.npy"), "--port", "emu", "--json"]) == 0
    capsys.readouterr()
    return emu


@pytest.fixture
def one_line(capsys):
    """``one_line()``: the one line a command printed on stderr (no traceback)."""
    def line() -> str:
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and "Traceback" not in err, err
        return err
    return line


def pytest_collection_finish(session):
    """Compile (or load from numba's cache) the trial kernel once, before any test runs, if a
    collected test module uses it: a cold compile takes ~40 s (more on a busy machine) and
    must not count against the first test's timeout."""
    if "snan_hil.host.snan_kernel" not in sys.modules or not session.items:
        return
    from snan_hil.host.config import load_config
    from snan_hil.host.simulate import simulate

    t0 = time.perf_counter()
    simulate(load_config(preset="snan-3x3", overrides=["grid.max_steps=3"]), 1, 0)
    took = time.perf_counter() - t0
    if took > 5:
        session.config.get_terminal_writer().line(
            f"trial kernel compiled in {took:.0f} s (numba cache was cold)")


@pytest.fixture
def stop_after(monkeypatch):
    """``stop_after(stream, n)``: a stop of the running run is requested once its ``n``-th
    event of ``stream`` is recorded -- written into the run's history database through the
    recorder's own connection, as ``snan-hil watch`` writes it -- and the job polls its
    control channel at every board request (no throttle)."""
    import functools

    from snan_hil.lab import runner
    from snan_hil.records import history as H
    from snan_hil.records.control import RunControl

    def arm(stream: str, after: int) -> None:
        monkeypatch.setattr(runner, "RunControl", functools.partial(RunControl, poll_s=0.0))
        seen = [0]
        original = H.Recorder.__call__

        def spy(self, name, doc):
            original(self, name, doc)
            if name == "event" and self._streams.get(doc["descriptor"]) == stream:
                seen[0] += 1
                if seen[0] == after and self.active:
                    self.db.request_control(self.uid, "stop", "test")
        monkeypatch.setattr(H.Recorder, "__call__", spy)
    return arm
