"""A re-programming that is stopped part-way leaves no synapse marked ok that the chip does not
hold (issue 13 follow-up, docs/durability.md): the layout un-marks every synapse before the
first pulse, so neither a kill (what is on disk at that moment) nor Ctrl-C leaves the earlier
weights marked ok on a chip that now holds a mix, and ``run`` refuses the mixed chip."""

import numpy as np
import pytest

from snan_hil.calibration.layout import Layout, LayoutError
from snan_hil.calibration.observer import CellObserver
from snan_hil.calibration.programmer import program_weights
from snan_hil.calibration.testing import grid_weights, session_of
from snan_hil.firmware_emu.inprocess import emulator_of, open_inprocess_transport
from snan_hil.host.hil.runner import check_layout
from snan_hil.protocol.link import LinkClient

META = {"grid": [6, 6]}


class StopAt(CellObserver):
    """After the pulses of the ``n``-th programmed synapse (its write-and-verify done, the
    layout not yet updated): copy the layout file (what a SIGKILL leaves), then Ctrl-C."""

    def __init__(self, n, layout_path):
        self.n, self.layout_path, self.cells, self.on_disk = n, layout_path, 0, None

    def on_pulses(self, events):
        if events and self.cells == self.n - 1:
            self.on_disk = self.layout_path.read_bytes()
            raise KeyboardInterrupt

    def on_cell(self, event):
        if event.outcome in ("ok", "failed"):
            self.cells += 1


def program(state, layout, w, observer=None):
    transport = open_inprocess_transport(state_file=str(state), seed=0)
    emu = emulator_of(transport)
    client = LinkClient(transport)
    client.hello()
    try:
        program_weights(session_of(client, layout), w, META, observer=observer)
        return emu.array.effective_conductance(0.0).copy()
    finally:
        client.close()


def marked_ok_hold_their_weights(layout, w2, g):
    """Every synapse the layout marks ok records w2's weight and its cell is within 5 % of
    the conductance recorded."""
    ok = [s for s in layout.synapses if s.ok]
    for s in ok:
        assert s.weight == pytest.approx(w2[s.pre, s.post])
        assert abs(g[s.row, s.col] / s.final_s - 1.0) < 0.05, (s, g[s.row, s.col])
    return len(ok)


def test_an_interrupted_reprogramming_marks_ok_only_what_the_chip_holds(tmp_path):
    state, path = tmp_path / "chip.npz", tmp_path / "chip.layout.json"
    w1, w2 = grid_weights(6, 6, seed=1), grid_weights(6, 6, seed=2)
    program(state, path, w1)
    assert sum(1 for s in Layout.load(path).synapses if s.ok) == 120
    check_layout(Layout.load(path), w1, (6, 6), port="emu")        # the chip holds w1
    stop = StopAt(13, path)
    with pytest.raises(KeyboardInterrupt):
        program(state, path, w2, observer=stop)
    transport = open_inprocess_transport(state_file=str(state), seed=0)
    g = emulator_of(transport).array.effective_conductance(0.0).copy()
    transport.close()
    # a kill at that moment: the layout saved before the first pulse marks nothing ok
    killed = Layout.from_dict(__import__("json").loads(stop.on_disk))
    assert marked_ok_hold_their_weights(killed, w2, g) == 0
    # Ctrl-C: the 12 finished synapses are marked (with w2), the 13th is not
    after = Layout.load(path)
    assert marked_ok_hold_their_weights(after, w2, g) == 12
    assert after.synapses[12].ok is None
    for w in (w1, w2):       # run refuses the mixed chip and says to program it
        with pytest.raises(LayoutError, match=r"not completely programmed \(12 of 120.*"
                                              r"program-weights"):
            check_layout(after, w, (6, 6), port="emu")
        with pytest.raises(LayoutError, match="not completely programmed"):
            check_layout(killed, w, (6, 6), port="emu")


def test_run_refuses_a_chip_whose_programming_was_stopped(tmp_path, monkeypatch, capsys):
    from snan_hil.tools import cli
    state = tmp_path / "chip.npz"
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(state))
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    w = grid_weights(6, 6, seed=1)
    np.save(tmp_path / "w.npy", w)
    assert cli.main(["program-weights", str(tmp_path / "w.npy"), "--port", "emu",
                     "--json"]) == 0
    layout_path = tmp_path / "chip.layout.json"
    layout = Layout.load(layout_path)
    layout.synapses[40].ok = None            # what a stopped re-programming leaves
    layout.save(layout_path)
    capsys.readouterr()
    assert cli.main(["run", "--weights", str(tmp_path / "w.npy"), "--port", "emu",
                     "--scenario", "hw_astro", "--launches", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "not completely programmed (119 of 120" in err and "\n" not in err


def test_the_report_of_a_run_stopped_with_a_request_on_the_line_asks_the_board_nothing(tmp_path):
    # found by a trial: Ctrl-C during programming left a request outstanding, and the report
    # then asked the board its clock: a second request on a stop-and-wait link is a
    # RuntimeError, which ended the command with a traceback (exit 1) instead of exit 130
    from snan_hil.calibration.programmer import _clock_us_safe
    from snan_hil.firmware_emu.testing import lossy_inprocess_client
    from snan_hil.protocol.messages import Clock
    client, _emu = lossy_inprocess_client(tmp_path / "chip.npz")
    assert _clock_us_safe(client) is not None
    client.submit(Clock())                 # interrupted before its reply was collected
    assert client.outstanding == 1
    assert _clock_us_safe(client) is None
