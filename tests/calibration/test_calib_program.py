"""program_weights on the real emulator through the protocol client.

Covers the issue's acceptance on the default chip (seed 0), idempotence, interruption and
resume, a board reset midway, a 1 %-lossy link (pulse counts proven with the emulator's
counter), host-side safety limits, and moving a failing cell to a spare row.
"""

import json
import math
import shutil
import statistics

import numpy as np
import pytest

from snan_hil.calibration.layout import Layout, LayoutError
from snan_hil.calibration.programmer import ProgramConfig, program_weights
from snan_hil.calibration.readback import (read_weight_matrix, retention_run, retention_stats,
                                           summarize_retention, weight_errors)
from snan_hil.calibration.testing import grid_weights, session_of
from snan_hil.protocol import messages as m
from snan_hil.calibration.wv import WVConfig
from snan_hil.firmware_emu.testing import lossy_inprocess_client
from snan_hil.protocol.messages import SpikeGroup

REQUIRED_CELL = {"row", "col", "weight", "target_s", "final_s", "rel_error", "pulses_stage1",
                 "pulses_stage2", "ok"}
REQUIRED_SUMMARY = {"cells", "ok", "failed", "median_abs_rel_error", "median_pulses",
                    "virtual_s", "wall_s"}
META = {"grid": [6, 6]}
STUCK = (12, 4)      # stuck-high cell of the default chip (seed 0) inside the 15x8 block


def connect(state, **kw):
    """(client, emulator) on the in-process emulator with chip file ``state``."""
    return lossy_inprocess_client(state, **kw)


def run(state, layout, weights, report=None, config=None, **kw):
    client, emu = connect(state, **kw.pop("connect", {}))
    try:
        return program_weights(session_of(client, layout, report), weights, META,
                               config=config, **kw), emu
    finally:
        client.close()


@pytest.fixture(scope="module")
def weights():
    return grid_weights(6, 6, seed=11)


@pytest.fixture(scope="module")
def programmed(tmp_path_factory, weights, module_mcu):
    d = tmp_path_factory.mktemp("programmed")
    result, emu = run(d / "chip.npz", d / "layout.json", weights, report=d / "report.json",
                      connect={"mcu": module_mcu})
    return d, result, emu


def test_acceptance_on_default_chip(programmed):
    _, result, _ = programmed
    s = result.report["summary"]
    assert result.report["complete"] and result.all_ok
    assert s["cells"] == 120 and s["ok"] == 120 and s["failed"] == 0
    assert s["stage1_ok"] == 120                             # all inside +-10 % after stage 1
    assert s["median_abs_rel_error"] <= 0.03                 # after stage 2
    assert s["median_pulses"] <= 30
    assert s["virtual_s"] > 0 and s["wall_s"] > 0
    assert s["pulses_match"] and s["firmware_pulses"] == s["host_pulses"] > 0


def test_stuck_cell_is_skipped_and_its_synapse_uses_a_spare_row(programmed):
    _, result, _ = programmed
    layout = result.layout
    assert STUCK in layout.bad_cells
    assert STUCK not in layout.used_cells()
    moved = [s for s in layout.synapses if s.moved_from]
    assert [m for s in moved for m in s.moved_from] == [list(STUCK)]
    assert all(s.row >= 15 for s in moved)
    # every other synapse keeps its nominal place in the 15 x 8 block
    assert sum(1 for s in layout.synapses if s.row < 15) == 119


def test_report_and_layout_files(programmed, weights):
    d, result, _ = programmed
    report = json.loads((d / "report.json").read_text())
    assert REQUIRED_SUMMARY <= set(report["summary"])
    assert len(report["cells"]) == 120
    for cell in report["cells"]:
        assert REQUIRED_CELL <= set(cell)
        assert cell["ok"] is True
        assert abs(cell["rel_error"]) <= 0.10
        assert cell["final_s"] == pytest.approx(cell["target_s"], rel=0.10)
        assert cell["weight"] == pytest.approx(weights[cell["pre"], cell["post"]])
    assert not list(d.glob(".*.tmp"))                        # atomic writes left no temp file
    layout = Layout.load(d / "layout.json")
    assert layout.read_chain is not None and layout.read_chain.calibrated
    assert [(s.pre, s.post, s.row, s.col) for s in layout.synapses] == \
        [(s.pre, s.post, s.row, s.col) for s in result.layout.synapses]


def test_read_back_weights_match(programmed, weights, module_mcu):
    d, result, _ = programmed
    client, _ = connect(d / "chip.npz", mcu=module_mcu)
    try:
        layout = Layout.load(d / "layout.json")
        w_cell, g_cell = read_weight_matrix(client, layout, n_reads=3, path="cell")
        w_col, g_col = read_weight_matrix(client, layout, n_reads=3, path="column")
        err = weight_errors(w_cell, weights, layout)
        assert err["synapses"] == 120
        assert err["max_abs"] < 0.06 and err["median_abs"] < 0.02
        np.testing.assert_allclose(g_col, g_cell, rtol=0.02)
        # the HIL conversion: a spike on one row, column codes -> weights
        s = layout.synapses[5]
        res = client.spike_batch([SpikeGroup(((s.row, layout.chain.read_code),), (0,))],
                                 [s.col], n_bins=1)
        w = layout.weight_from_column_code(res.codes[0][0])
        assert w == pytest.approx(weights[s.pre, s.post], abs=0.05)
    finally:
        client.close()


def test_retention_reads_do_not_change_cells(programmed, module_mcu):
    d, _, _ = programmed
    client, _ = connect(d / "chip.npz", mcu=module_mcu)
    try:
        layout = Layout.load(d / "layout.json")
        layout.synapses = layout.synapses[:16]
        before = client.status().pulses_applied
        cells = retention_run(client, layout, 300, "column")
        assert client.status().pulses_applied == before
    finally:
        client.close()
    summary = summarize_retention(cells)
    assert summary["stable"] == 16
    assert summary["max_abs_drift_rel"] < 0.005            # well below 1 % read noise


def test_retention_statistics_flag_real_drift():
    layout = Layout.place((2, 2), (32, 8))
    rng = np.random.default_rng(0)
    n = 2000
    series = 5e-4 * (1 + 0.003 * rng.standard_normal((n, layout.n_synapses)))
    series[:, 0] *= np.linspace(1.0, 0.97, n)               # 3 % relaxation on one cell
    cells = retention_stats(series, layout)
    assert not cells[0].stable and cells[0].drift_rel < -0.02
    assert all(c.stable for c in cells[1:])


def test_rerun_is_idempotent(programmed, weights, tmp_path, module_mcu):
    d, first, _ = programmed
    shutil.copy(d / "chip.npz", tmp_path / "chip.npz")
    shutil.copy(d / "layout.json", tmp_path / "layout.json")
    again, _ = run(tmp_path / "chip.npz", tmp_path / "layout.json", weights,
                   connect={"mcu": module_mcu})
    s = again.report["summary"]
    assert again.all_ok
    assert s["median_pulses"] == 0
    assert s["host_pulses"] < 0.15 * first.report["summary"]["host_pulses"]
    assert s["relocated"] == 1 and again.layout.cell_of(*_moved(again.layout)) == \
        first.layout.cell_of(*_moved(first.layout))          # same spare as before


def _moved(layout):
    s = next(s for s in layout.synapses if s.moved_from)
    return s.pre, s.post


def test_lossy_link_completes_and_no_pulse_runs_twice(tmp_path, weights, mcu):
    loss = {"drop": 0.005, "corrupt": 0.005, "loss_seed": 3}     # 1 % of bytes damaged
    client, emu = connect(tmp_path / "chip.npz", mcu=mcu, **loss)
    try:
        fw_before = emu.board.front_end.pulses_applied
        result = program_weights(session_of(client, tmp_path / "layout.json"), weights, META)
        fw_pulses = emu.board.front_end.pulses_applied - fw_before
        stats = client.transport.stats
        link = client.counters
    finally:
        client.close()
    s = result.report["summary"]
    ledger = result.report["ledger"]
    assert result.all_ok and s["ok"] == 120
    assert stats.dropped_write + stats.corrupted_write > 100   # the link really was lossy
    assert link.retries > 100
    assert fw_pulses == s["host_pulses"] == ledger["confirmed"]            # each exactly once
    assert ledger["decided"] == ledger["confirmed"] + ledger["not_applied"]
    assert s["median_abs_rel_error"] <= 0.03


def test_interrupted_run_resumes(tmp_path, weights):
    state, layout_path, report = tmp_path / "chip.npz", tmp_path / "l.json", tmp_path / "r.json"

    def stop_after_30(ev):
        if ev.task == "programming" and ev.done == 30:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run(state, layout_path, weights, report=report, progress=stop_after_30)
    partial = json.loads(report.read_text())
    assert partial["complete"] is False and partial["error"] == "interrupted"
    assert len(partial["cells"]) == 30 and partial["summary"]["ok"] == 30
    layout = Layout.load(layout_path)
    assert sum(s.final_s is not None for s in layout.synapses) == 30
    result, _ = run(state, layout_path, weights, report=report)
    assert result.all_ok and json.loads(report.read_text())["complete"] is True
    first30 = [c["pulses_stage1"] + c["pulses_stage2"] for c in result.report["cells"][:30]]
    rest = [c["pulses_stage1"] + c["pulses_stage2"] for c in result.report["cells"][30:]]
    assert statistics.median(first30) == 0 and statistics.median(rest) > 0


def test_layout_checkpoints_write_the_states_a_save_per_synapse_writes(tmp_path, weights,
                                                                       monkeypatch):
    """Every layout file written is the layout as of a finished synapse (or before the first
    pulse); with checkpoint_s the run writes fewer of them and ends with the same layout."""
    import snan_hil.calibration.layout as layout_mod

    writes = []
    real = layout_mod.atomic_write_json

    def recording(path, obj, **kw):
        if str(path).endswith("layout.json"):
            writes.append(json.loads(json.dumps(obj)))
        return real(path, obj, **kw)

    monkeypatch.setattr(layout_mod, "atomic_write_json", recording)
    finals = {}
    for interval in (0.0, 3600.0):
        writes.clear()
        d = tmp_path / f"every-{interval}"
        result, _ = run(d / "chip.npz", d / "layout.json", weights,
                        config=ProgramConfig(checkpoint_s=interval))
        assert result.all_ok
        done = [sum(s["final_s"] is not None for s in w["synapses"]) for w in writes]
        if interval == 0.0:
            assert done == list(range(121))       # before the first pulse, then per synapse
        else:
            assert done == [0, 120]                # before the first pulse and at the end
        final = json.loads((d / "layout.json").read_text())
        assert final == writes[-1]
        final.pop("updated")
        final["board"].pop("board_id")       # two fresh chips: two chip serials
        finals[interval] = final
    assert finals[0.0] == finals[3600.0]


def test_board_reset_midway_is_survived(tmp_path, weights, mcu):
    client, emu = connect(tmp_path / "chip.npz", mcu=mcu)
    # the board reboots: new nonce, counters 0 (the model's RESET; the MCU's reset pin)
    reboot = emu.firmware.reset if emu.firmware is not None else emu.backend.mcu.press_reset
    at_reset = []

    def reset_at_20(ev):
        if ev.task == "programming" and ev.done == 21 and not ev.detail.startswith("cell"):
            reboot()
            at_reset.append(emu.board.front_end.pulses_applied)   # 0 after the model's boot

    try:
        result = program_weights(session_of(client, tmp_path / "l.json"), weights, META,
                                 progress=reset_at_20)
        fw_since_reset = emu.board.front_end.pulses_applied - at_reset[0]
    finally:
        client.close()
    assert result.all_ok
    assert result.report["ledger"]["resyncs"] == 1 and result.report["board_resets"] == 1
    assert result.report["summary"]["pulses_match"]
    assert fw_since_reset == result.report["summary"]["host_pulses"]


class Recorder:
    """Client proxy recording every read code and write amplitude the host sends (the
    requests: every command of a client, and of a RetryingClient around it, goes through
    ``request``)."""

    def __init__(self, inner):
        self.inner, self.read_codes, self.writes = inner, [], []

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def request(self, req):
        if isinstance(req, m.ReadCell):
            self.read_codes.append(req.dac_code)
        elif isinstance(req, m.ReadColumn):
            self.read_codes.extend(req.row_codes)
        elif isinstance(req, m.WritePulse):
            self.writes.append(req.amplitude_code)
            self.read_codes.append(req.read_code)
        return self.inner.request(req)


def test_host_never_exceeds_read_or_configured_write_limits(tmp_path):
    client, _ = connect(tmp_path / "chip.npz")
    rec = Recorder(client)
    cfg = ProgramConfig(wv=WVConfig(v_max=1.1, fine_v_max=1.0))
    w = grid_weights(3, 3, seed=2)
    w[w > 0] = np.where(np.arange((w > 0).sum()) % 2, 0.02, 0.98)   # big moves: ramps hit 1.1 V
    try:
        result = program_weights(session_of(rec, tmp_path / "l.json"), w, {"grid": [3, 3]},
                                 config=cfg)
    finally:
        client.close()
    info = client.info
    assert None not in rec.read_codes
    assert max(rec.read_codes) == 245 and info.dac_volts(max(rec.read_codes)) <= 0.3
    volts = [info.write_dac_volts(c) for c in rec.writes]
    assert max(volts) <= 1.1 and max(volts) > 1.09           # the cap was reached, not passed
    assert len(rec.writes) == result.report["summary"]["host_pulses"]


def test_failing_cell_is_moved_to_a_spare_or_reported(tmp_path, weights):
    no_screen = ProgramConfig(screen=False)
    result, _ = run(tmp_path / "a.npz", tmp_path / "a.json", weights, config=no_screen)
    assert result.all_ok
    layout = result.layout
    assert "programming" in layout.bad_cells[STUCK]
    moved = next(c for c in result.report["cells"] if c["moved_from"])
    assert moved["moved_from"] == [list(STUCK)] and moved["row"] >= 15
    assert moved["failed_attempts"][0]["row"] == STUCK[0]

    no_spares = ProgramConfig(screen=False, spares=False)
    result, _ = run(tmp_path / "b.npz", tmp_path / "b.json", weights, config=no_spares)
    assert not result.all_ok and result.report["summary"]["failed"] == 1
    bad = [c for c in result.report["cells"] if not c["ok"]]
    assert (bad[0]["row"], bad[0]["col"]) == STUCK and bad[0]["reason"]


def test_layout_placement_and_persistence(tmp_path):
    layout = Layout.place((6, 6), (32, 8), bad_cells={(0, 3): "test", (15, 0): "test"})
    assert layout.block_rows == 15
    cells = layout.used_cells()
    assert len(cells) == 120 and (0, 3) not in cells and (15, 0) not in cells
    assert layout.cell_of(*_moved(layout)) == (15, 1)           # first healthy spare
    groups = layout.groups()
    assert len(groups) == 36
    assert sum(len(c["cells"]) for g in groups for c in g["rows"]) == 120
    assert all(len(g["rows"]) <= 2 for g in groups)            # a neuron spans <= 2 rows
    layout.save(tmp_path / "l.json")
    back = Layout.load(tmp_path / "l.json")
    assert back.to_dict()["synapses"] == layout.to_dict()["synapses"]
    assert back.bad_cells == layout.bad_cells
    data = json.loads((tmp_path / "l.json").read_text())
    data["synapses"][1]["row"], data["synapses"][1]["col"] = 0, 0      # a cell used twice
    (tmp_path / "bad.json").write_text(json.dumps(data))
    with pytest.raises(LayoutError, match="two synapses"):
        Layout.load(tmp_path / "bad.json")
    with pytest.raises(LayoutError, match="does not exist"):
        Layout.load(tmp_path / "missing.json")
    with pytest.raises(LayoutError, match="/dev/null is not a regular file"):
        Layout.load("/dev/null")                     # it exists: not "does not exist"
    with pytest.raises(LayoutError, match="is a folder"):
        Layout.load(tmp_path)
    with pytest.raises(LayoutError, match="need"):
        Layout.place((10, 10), (32, 8))                         # 360 synapses do not fit


def test_open_and_unreadable_cells_move_their_synapse_to_a_spare(tmp_path, weights, monkeypatch):
    """An open cell (G = 0 on the chip: reads of a few ADC LSB; the screen is off so
    write-and-verify meets it) and one whose reads are NaN end as failed cells with a named
    reason, no pulse applied; their synapses move to spares."""
    from snan_hil.calibration import bench
    from snan_hil.calibration.programmer import ProgramConfig

    open_cell, nan_cell = (5, 3), (7, 6)

    class NaNAt(bench.BoardCellIO):
        def read(self):
            g = super().read()
            return math.nan if (self.row, self.col) == nan_cell else g
    monkeypatch.setattr(bench, "BoardCellIO", NaNAt)     # the cells the bench makes
    client, emu = connect(tmp_path / "chip.npz")
    emu.array.stuck_mask[open_cell] = True
    emu.array.stuck_g[open_cell] = 0.0
    emu.array._refresh()
    try:
        result = program_weights(session_of(client, tmp_path / "l.json"), weights, META,
                                 config=ProgramConfig(screen=False))
    finally:
        client.close()
    layout = result.layout
    assert result.all_ok                                     # every synapse found a good cell
    assert layout.bad_cells[open_cell].startswith("programming: open cell: reads")
    assert layout.bad_cells[nan_cell].startswith("programming: no valid read")
    moved = {tuple(m) for s in layout.synapses for m in s.moved_from}
    assert {open_cell, nan_cell} <= moved
    assert not {open_cell, nan_cell} & layout.used_cells()
