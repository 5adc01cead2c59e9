"""``snan-hil pulse`` on the in-process emulator: the ticket's write limit (--max-write-v),
the volts it applied and its named ramp, recorded pulse by pulse; a pulse on a programmed
synapse marks that synapse stale (read-weights names it, programming clears it), one on an
unused cell leaves the layout alone."""

from __future__ import annotations

import json

import pytest

from snan_hil.calibration.layout import Layout
from snan_hil.records.history import History
from snan_hil.tools import cli


@pytest.mark.parametrize("protocol", ("framed", "legacy"))
def test_max_write_v_above_the_boards_limit_is_refused_before_a_pulse(emu, capsys, protocol):
    """One rule (issue 32): --max-write-v may lower the board's 1.4 V, never raise it -- on
    the legacy protocol too, whose firmware has no interlock; nothing is sent."""
    assert cli.main(["pulse", "--port", "emu", "--protocol", protocol, "--cell", "3,5",
                     "--polarity", "set", "--amplitude", "1.3", "--max-write-v", "1.7",
                     "--record", "off", "--json"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "can only lower it" in err, err


def test_pulse_on_programmed_synapse_marks_it_stale(programmed_emu, capsys):
    d = programmed_emu
    layout = Layout.load(d / "chip.layout.json")
    syn = layout.synapses[1]
    assert cli.main(["pulse", "--port", "emu", "--cell", f"{syn.row},{syn.col}", "--polarity",
                     "reset", "--amplitude", "0.8", "--count", "3", "--json"]) == 0
    cap = capsys.readouterr()
    assert f"holds synapse {syn.pre}->{syn.post}" in cap.err
    res = json.loads(cap.out)
    assert res["stale_synapse"]["pre"] == syn.pre
    after = Layout.load(d / "chip.layout.json")
    stale = after.stale_synapses()
    assert [(s.pre, s.post) for s in stale] == [(syn.pre, syn.post)]
    assert "pulse ticket RESET" in (stale[0].stale or "")
    # read-weights names it
    assert cli.main(["read-weights", "--port", "emu", "--json"]) == 0
    cap = capsys.readouterr()
    assert "changed by a pulse ticket" in cap.err
    assert json.loads(cap.out)["stale_synapses"][0]["post"] == syn.post
    # programming again clears it
    assert cli.main(["program-weights", str(d / "w.npy"), "--port", "emu", "--json"]) == 0
    capsys.readouterr()
    assert Layout.load(d / "chip.layout.json").stale_synapses() == []


def test_pulse_on_unused_cell_does_not_touch_layout(programmed_emu, capsys):
    d = programmed_emu
    before = (d / "chip.layout.json").read_bytes()
    assert cli.main(["pulse", "--port", "emu", "--cell", "30,7", "--polarity", "set",
                     "--amplitude", "0.6"]) == 0
    assert "warning" not in capsys.readouterr().err
    assert (d / "chip.layout.json").read_bytes() == before


def test_ticket_reports_applied_volts_and_a_named_ramp(emu, capsys):
    assert cli.main(["pulse", "--port", "emu", "--cell", "30,5", "--polarity", "set",
                     "--amplitude", "0.6:1.0:0.1", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    t = res["ticket"]
    assert (t["start_v"], t["stop_v"], t["step_v"], t["steps"]) == (0.6, 1.0, 0.1, 5)
    assert "amplitudes_v" not in t
    lsb = 5.0 / 4095
    for s, planned in zip(res["steps"], (0.6, 0.7, 0.8, 0.9, 1.0)):
        code = round(s["amplitude_v"] / lsb)
        assert s["amplitude_v"] == pytest.approx(code * lsb)         # a DAC code's voltage
        assert planned - lsb < s["amplitude_v"] <= planned + 1e-12
    with History.open(emu / "chip.history.sqlite", create=False) as db:
        pulses = [e.amplitude_v for e in db.cell_life(30, 5) if e.event == "pulse"]
    assert pulses == pytest.approx([s["amplitude_v"] for s in res["steps"]])
