"""A legacy board that misbehaves: never answers mode 100, answers garbage, answers with other
ids, or stops answering mid-run. Each time: one clear line, the layout and the report left
consistent, and a rerun on a healthy board resumes. The exit code says whose the failure is:
3 when the board or the line failed (garbage, other ids, silence), 2 when the board does not
behave like the firmware the command names (mode 100 unanswered: --protocol or --port)."""

import json
import threading

import pytest

from snan_hil.calibration.layout import Layout
from snan_hil.firmware_emu.emulator import Emulator
from snan_hil.host.hil.testing import make_weights, small_hil_config
from snan_hil.protocol.transport import open_pty_pair
from snan_hil.tools import cli


class FaultyBoard:
    """The legacy emulator behind a pty, with a switchable fault:

    ``healthy``; ``no_info`` (mode 100 never answered); ``garbage`` (every line answered with
    text that is not a reply); ``other_id`` (replies carry another id); ``mute`` (nothing).
    ``after`` request lines are answered healthily before the fault starts."""

    def __init__(self, state_file, fault="healthy", after=0):
        self.emu = Emulator(state_file, 0, protocol="legacy", wall_scale=0.0)
        self.fault, self.after, self.lines = fault, after, 0
        self.pair = open_pty_pair()
        self.port = self.pair.slave_path
        self._stop = threading.Event()
        self._buf = b""
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _answer(self, line: bytes) -> bytes:
        self.lines += 1
        out = self.emu.feed(line)
        fault = self.fault if self.lines > self.after else "healthy"
        if fault == "healthy" or (fault == "no_info" and line != b"100\n"):
            return out
        if fault == "garbage":
            return b"ERR?? bad command\r\n"
        if fault == "other_id" and out:
            adc, _id = out.rsplit(b",", 1)
            return adc + b"," + str((int(_id) + 1000) % 4097).encode() + b"\n"
        return b""

    def _serve(self):
        master = self.pair.master
        while not self._stop.is_set():
            data = master.read(4096, 0.02)
            if not data:
                continue
            self._buf += data
            while b"\n" in self._buf:
                line, self._buf = self._buf.split(b"\n", 1)
                out = self._answer(line + b"\n")
                if out:
                    master.write(out)

    def close(self):
        self._stop.set()
        self._thread.join()
        self.pair.close()
        self.emu.close()


@pytest.fixture
def board(tmp_path):
    made = []

    def make(fault="healthy", after=0):
        b = FaultyBoard(tmp_path / "chip.npz", fault, after)
        made.append(b)
        return b

    yield make
    for b in made:
        b.close()


def one_line_error(capsys, argv, *needles, code=cli.EXIT_BOARD_OR_LINK):
    assert cli.main(argv) == code
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in err, err
    return err


LEGACY = ["--protocol", "legacy", "--timeout", "0.05"]


@pytest.mark.parametrize("fault, code, needles", [
    ("no_info", cli.EXIT_USER_ERROR, ("mode 100", "--protocol framed")),
    ("garbage", cli.EXIT_BOARD_OR_LINK, ("connect probe", "not replies", "ERR?? bad command")),
    ("other_id", cli.EXIT_BOARD_OR_LINK, ("connect probe", "another id",
                                          "while waiting for id 0")),
    ("mute", cli.EXIT_BOARD_OR_LINK, ("no answer", "no byte at all", "check power")),
])
def test_a_board_that_does_not_answer_properly_is_one_line(board, capsys, fault, code,
                                                           needles):
    b = board(fault)
    err = one_line_error(capsys, ["info", "--port", b.port, *LEGACY], *needles, code=code)
    assert ("board or link failed" in err) is (code == cli.EXIT_BOARD_OR_LINK), err


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    d = tmp_path_factory.mktemp("badboard")
    return make_weights(d / "w.npz", sets=1, cycles=2, hil=small_hil_config(max_steps=15))


@pytest.mark.parametrize("fault", ["mute", "other_id"])
def test_programming_stopped_mid_run_leaves_layout_and_report_consistent_and_resumes(
        board, capsys, tmp_path, weights, fault):
    layout, report = tmp_path / "chip.layout.json", tmp_path / "report.json"
    argv = ["program-weights", str(weights), "--weight-set", "0", "--layout", str(layout),
            "--report", str(report), *LEGACY]
    b = board(fault, after=900)
    one_line_error(capsys, argv + ["--port", b.port], "no reply from board",
                   "run the command again")
    first = json.loads(report.read_text())
    assert first["complete"] is False and first["error"]
    done_first = [c for c in first["cells"] if c.get("ok")]
    assert 0 < len(done_first) < 120
    Layout.load(layout).check()                             # consistent, loadable
    b.close()
    healthy = board()                                       # the same chip, a healthy line
    assert cli.main(argv + ["--port", healthy.port, "--json"]) == 0
    capsys.readouterr()
    second = json.loads(report.read_text())
    assert second["complete"] is True and second["summary"]["failed"] == 0
    by_syn = {(c["pre"], c["post"]): c for c in second["cells"]}
    # the cells finished before the fault are inside their window: no stage-1 pulse again
    resumed = [by_syn[(c["pre"], c["post"])] for c in done_first]
    assert sum(c["pulses_stage1"] for c in resumed) == 0


def test_a_launch_that_loses_the_board_mid_run_is_one_line_and_writes_nothing(
        board, capsys, tmp_path, weights):
    layout = tmp_path / "chip.layout.json"
    b = board()
    assert cli.main(["program-weights", str(weights), "--weight-set", "0", "--layout",
                     str(layout), "--port", b.port, *LEGACY, "--json"]) == 0
    capsys.readouterr()
    b.fault, b.after = "mute", b.lines + 30
    before = layout.read_text()
    one_line_error(capsys, ["run", "--scenario", "hw_astro", "--weights", str(weights),
                            "--layout", str(layout), "--port", b.port, *LEGACY,
                            "--set", "grid.max_steps=15", "--accept-config-diff", "--json"],
                   "no reply from board")
    assert layout.read_text() == before                     # launches never touch the layout
    out = tmp_path / "cmp"
    b.after = b.lines + 30
    one_line_error(capsys, ["compare", "--weights", str(weights), "--layout", str(layout),
                            "--port", b.port, *LEGACY, "--no-program", "--launches", "2",
                            "--out", str(out), "--set", "grid.max_steps=15",
                            "--accept-config-diff"], "no reply from board")
    assert not (out / "compare.json").exists()
