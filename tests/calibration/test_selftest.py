"""The board self-test (calibration/selftest.py) on healthy and faulty emulated boards.

Each fault of the emulated hardware (firmware_emu/faults.py) must fail the item that measures
it, naming the likely cause, on both MCUs (the Python model and the C firmware); a healthy
board passes every item on both, and over the legacy protocol.
"""

from __future__ import annotations

import numpy as np
import pytest

from snan_hil import lab
from snan_hil.calibration import selftest_checks as chk
from snan_hil.calibration.selftest import ITEMS, SelfTest, SelfTestConfig
from snan_hil.common.errors import UserError

FAULTS = {
    # fault SPEC: (the item that must fail, words its cause must contain)
    "adc-stuck-bit:6:1": ("adc_bits", "bit 6 stuck at 1"),
    "adc-stuck-bit:5:0": ("adc_bits", "bit 5 stuck at 0"),
    "adc-stuck-bit:2:1": ("adc_bits", "bit 2 stuck at 1"),
    "gain:0.85": ("gain", "wrong amplifier gain"),
    "swap-col-lines": ("column_path", "column-register lines swapped"),
    "slow-dac:DAC2:40": ("row_dacs", "row DAC 2 (rows 16-23)"),
    "uart-drop:0.01": ("link", "UART that drops bytes"),
    "dead-cells:4-9:5-6": ("cell_reads", "rows 4-9, columns 5-6"),
}


def _run(tmp_path, mcu: str = "model", fault: str = "", protocol: str = "framed",
         **cfg: object):
    url = f"emu://?state={tmp_path}/chip.npz&seed=2" + (f"&mcu={mcu}" if mcu != "model" else "") \
        + (f"&fault={fault}" if fault else "")
    with lab.plan_board(lab.BoardAddress(url, protocol=protocol)).open() as session:
        return SelfTest(session, SelfTestConfig(**cfg)).run()  # type: ignore[arg-type]


def test_a_healthy_board_passes_every_item(tmp_path, mcu):
    res = _run(tmp_path, mcu, allow_pulses=((3, 5),))
    failed = {i.item: i.cause for i in res.items if i.failed}
    assert not failed
    ran = [i.item for i in res.items if i.status == "pass"]
    assert ran == [n for n in ITEMS if n != "mac"]          # no layout on a fresh chip
    assert res.item("conformance").data["compared"] > 100
    assert res.item("clock").data["read_us"] > 67
    assert res.session["mcu"] in (None, mcu) and res.session["info"]["rows"] == 32


@pytest.mark.parametrize("fault", sorted(FAULTS))
def test_each_fault_fails_its_item_and_names_the_cause(tmp_path, mcu, fault):
    item, words = FAULTS[fault]
    res = _run(tmp_path, mcu, fault)
    got = res.item(item)
    assert got.failed, (item, got)
    assert words in got.cause
    assert got.measured and got.expected
    # the other measurements of the read chain still pass where they do not depend on it
    assert res.item("identity").status == "pass"


def test_the_legacy_protocol_runs_the_items_it_can(tmp_path):
    res = _run(tmp_path, protocol="legacy")
    status = {i.item: i.status for i in res.items}
    assert status["cell_reads"] == status["noise"] == status["adc_bits"] == "pass"
    assert status["link"] == status["identity"] == "pass"
    for name in ("clock", "zero_reads", "column_path", "row_dacs", "gain", "conformance"):
        assert status[name] == "skip"
        assert "legacy protocol" in res.item(name).cause
    assert res.passed


def test_a_dead_region_is_found_over_the_legacy_protocol_too(tmp_path):
    res = _run(tmp_path, fault="dead-cells:0-3:0-7", protocol="legacy")
    assert res.item("cell_reads").failed and "rows 0-3, columns 0-7" in \
        res.item("cell_reads").cause


def test_no_pulse_and_no_change_of_the_chip_without_allowed_cells(tmp_path, mcu):
    from snan_hil.firmware_emu.inprocess import emulator_of
    url = f"emu://?state={tmp_path}/chip.npz&seed=2" + (f"&mcu={mcu}" if mcu != "model" else "")
    with lab.plan_board(lab.BoardAddress(url)).open() as session:
        emu = emulator_of(session.client.transport)
        g0 = np.array(emu.array.conductance(), copy=True)
        res = SelfTest(session, SelfTestConfig()).run()
        assert res.item("pulses").status == "skip"
        assert emu.board.front_end.pulses_applied == 0
        assert np.array_equal(np.array(emu.array.conductance()), g0)


def test_config_refuses_unknown_items():
    with pytest.raises(UserError, match="unknown self-test item 'nosuch'"):
        SelfTestConfig(only=("nosuch",))


# ---- the judgements alone -------------------------------------------------------------
def test_stuck_bits_finds_a_bit_stuck_either_way_and_not_on_healthy_codes():
    quiet = np.concatenate([np.zeros(100, int), np.arange(0, 4000, 7)])
    assert chk.stuck_bits(quiet) == []
    assert [(b, v) for b, v, _ in chk.stuck_bits(quiet | (1 << 4))] == [(4, 1)]
    assert [(b, v) for b, v, _ in chk.stuck_bits(quiet & ~(1 << 7))] == [(7, 0)]
    assert chk.stuck_bits(quiet[:30] | 16) == []              # too few readings to judge


def test_dead_regions_are_rectangles_and_lines_not_scattered_cells():
    mask = np.zeros((32, 8), bool)
    mask[3, 1] = mask[20, 6] = mask[21, 7] = True               # scattered: the chip's yield
    assert chk.dead_regions(mask) == []
    mask[8:12, 2:4] = True
    assert chk.dead_regions(mask) == [(8, 11, 2, 3, 8)]
    line = np.zeros((32, 8), bool)
    line[:, 5] = True
    assert chk.dead_regions(line) == [(0, 31, 5, 5, 32)]


def test_row_dac_judgement_tells_slow_settling_from_a_weak_dac():
    flat = [1.0] * 8
    ok, _ = chk.judge_row_dacs({0: flat, 1: flat, 2: flat, 3: flat}, 0.1, 0.05)
    assert ok.ok
    slow, _ = chk.judge_row_dacs({0: flat, 1: [0.4, 0.8, 0.95, 1, 1, 1, 1, 1], 2: flat,
                                  3: flat}, 0.1, 0.05)
    assert not slow.ok and "settle slowly" in slow.cause and "row DAC 1" in slow.cause
    common, _ = chk.judge_row_dacs({0: [1.07, 1.1, 1.14], 1: [1.13] * 3, 2: [1.12, 1.05, 1.1, 1.3],
                                    3: [1.15, 1.1, 1.1]}, 0.1, 0.05)
    assert common.ok                                            # a gain error of every DAC
    weak, _ = chk.judge_row_dacs({0: flat, 1: flat, 2: [0.7] * 8, 3: flat}, 0.1, 0.05)
    assert not weak.ok and "row DAC 2" in weak.cause and "slowly" not in weak.cause


def test_column_ratio_judgement_names_the_load_path():
    assert chk.judge_column_ratio(1.02, 0.8, 1.25, 3000, 330).ok
    v = chk.judge_column_ratio(9.0, 0.8, 1.25, 3000, 330)
    assert not v.ok and "load resistor" in v.cause


def test_the_self_test_runs_on_the_job_runner_recorded_and_stopped_from_watch(tmp_path):
    """SelfTestJob: every item a unit of the job runner, so the run is recorded (kind
    selftest) and ``snan-hil watch`` can stop it (the controlled client): a stop asked for as
    the second item begins ends the run as interrupted with the items that finished: the
    first, and the second if it ended before the control channel's next poll (the client
    looks at most every ``poll_s``; the runner always between two items)."""
    from snan_hil.board.files import BoardFiles
    from snan_hil.calibration.selftest import SelfTestJob
    from snan_hil.lab.opener import FileUse, plan_board
    from snan_hil.lab.ports import BoardAddress
    from snan_hil.lab.runner import JobInterrupted, RunOptions, run_job
    from snan_hil.records.documents import RunMetadata
    from snan_hil.records.history import History

    chip = tmp_path / "chip.npz"
    history = BoardFiles.beside_chip(chip).history
    assert history is not None

    def board():
        return plan_board(BoardAddress(f"emu://?state={chip}&seed=3"), FileUse(record=True))

    cfg = SelfTestConfig(only=("identity", "link", "cell_reads"))
    done = run_job(SelfTestJob(cfg), board())
    assert [i.item for i in done.result.items] == list(ITEMS)
    assert done.result.passed and done.result.item("cell_reads").status == "pass"
    assert done.result.session["identity"]["board_id"].startswith("EMU-")

    meta = RunMetadata()

    def stop_at_the_second(event):
        if event.done == 1 and event.task == "self-test":
            with History.open(history) as db:           # as snan-hil watch writes it
                db.request_control(meta.uid, "stop", "test")
    with pytest.raises(JobInterrupted) as stop:
        run_job(SelfTestJob(cfg), board(), RunOptions(metadata=meta, progress=stop_at_the_second))
    items = stop.value.run.result.items
    assert [i.item for i in items] in (["identity"], ["identity", "link"])   # no cell_reads
    assert all(i.status == "pass" for i in items)
    with History.open(history, create=False) as db:
        assert sorted((r.kind, r.status) for r in db.runs()) == [("selftest", "complete"),
                                                                ("selftest", "interrupted")]
