"""User screening criteria (R_min, R_max, R_max/R_min of the switching window, measured with
full SET and RESET ramps) on top of the fixed classes; good / bad cell lists, the heat map,
and program-weights --cells-only / --cells-avoid using them; the layout marks of cell tests
(the last class counts: a good re-test clears a mark, program-weights drops the mark of a
cell last found good)."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from snan_hil.calibration.layout import USER_LIST_MARK, Layout
from snan_hil.calibration.screening import ScreenConfig, UserCriteria, screen_cell
from snan_hil.calibration.testing import ArrayCellIO, grid_weights
from snan_hil.crossbar_model.array import CrossbarArray
from snan_hil.files.outputs import PNG_KEY
from snan_hil.tools import cli


def test_judge_names_every_failed_criterion():
    c = UserCriteria(rmin_below_ohm=2000, rmax_above_ohm=5000, ratio_above=2)
    assert c.judge("good", 1000, 6000) == []
    why = c.judge("good", 3000, 4000)
    assert len(why) == 3 and "R_min 3000" in why[0] and "R_max 4000" in why[1]
    assert c.judge("noisy", 1000, 6000) == ["class noisy"]
    assert UserCriteria(ratio_above=1.5).judge("good", 1000, 1400) == \
        ["R_max/R_min 1.40 <= 1.5"]
    with pytest.raises(ValueError):
        UserCriteria(ratio_above=0.9)


def test_the_window_is_measured_with_full_ramps_on_the_device_model():
    arr = CrossbarArray(seed=5)
    io = ArrayCellIO(arr, 4, 3)
    res = screen_cell(io, ScreenConfig(), 4, 3, UserCriteria(ratio_above=2))
    assert res.cls == "good" and res.r_min_ohm is not None and res.r_max_ohm is not None
    # the ON/OFF window of a YSZ cell spans its G range (25 uS .. ~1.4 mS on the model), far
    # beyond one pulse pair's step (1.05..1.6): a lab's threshold of 2 passes a healthy cell
    assert res.ratio > 10 and res.verdict == "good" and not res.reasons
    assert 0 < res.window_pulses <= 2 * UserCriteria().max_ramp_pulses
    assert res.r_min_ohm < 1 / 600e-6 and res.r_max_ohm > 1 / 60e-6
    plain = screen_cell(ArrayCellIO(CrossbarArray(seed=5), 4, 3), ScreenConfig(), 4, 3)
    assert plain.verdict is None and plain.r_min_ohm is None and plain.window_pulses == 0
    assert res.pulses > res.probe_pulses + res.window_pulses        # and the restore's
    assert res.restored and abs(res.final_s / res.g0_s - 1) <= 0.10   # written back


def test_a_ramp_that_does_not_settle_says_the_window_is_at_least_that_wide():
    crit = UserCriteria(ratio_above=2, max_ramp_pulses=6, settle=0.001, settle_pulses=5)
    res = screen_cell(ArrayCellIO(CrossbarArray(seed=5), 4, 3), ScreenConfig(), 4, 3, crit)
    assert res.window_pulses == 12
    assert any("not settled in 6 pulses" in r for r in res.reasons)


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def test_cells_test_writes_good_and_bad_lists_and_the_heat_map(emu, capsys):
    cells = ["0,0", "1,1", "2,2", "3,3", "4,4", "5,5"]
    good, bad, png = emu / "good.csv", emu / "bad.csv", emu / "crit.png"
    assert cli.main(["cells", "test", "--port", "emu", "--cells", *cells, "--ratio-above",
                     "1.15", "--good-csv", str(good), "--bad-csv", str(bad),
                     "--criteria-png", str(png), "--json", "--sample", "die 3",
                     "--ramp-reset-v", "1.1"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["criteria"]["reset_v"] == 1.1 and data["criteria"]["set_v"] == 1.2
    verdicts = {(c["row"], c["col"]): c["verdict"] for c in data["cells"]}
    assert set(verdicts.values()) <= {"good", "bad"}
    listed = {(int(r["row"]), int(r["col"])): r["verdict"] for r in _rows(good) + _rows(bad)}
    assert listed == verdicts
    for c in data["cells"]:
        if c["ratio"] is not None:
            assert (c["verdict"] == "good") == (c["class"] == "good" and c["ratio"] > 1.15)
    s = data["summary"]
    assert s["criteria_good"] + s["criteria_bad"] == len(cells)
    assert data["run"]["sample"] == "die 3"
    from PIL import Image
    with Image.open(png) as im:
        assert str(im.text.get(PNG_KEY, "")).startswith("snan-hil-criteria-figure/")


def test_criteria_outputs_need_a_criterion(emu, capsys):
    assert cli.main(["cells", "test", "--port", "emu", "--cells", "0,0", "--good-csv",
                     str(emu / "g.csv")]) == 2
    assert "give --rmin-below" in capsys.readouterr().err
    assert cli.main(["cells", "test", "--port", "emu", "--cells", "0,0", "--ratio-above",
                     "0.5"]) == 2
    assert "above 1" in capsys.readouterr().err
    # found by a fresh-user pass: the ramps' amplitudes were silently ignored without criteria
    for opt in ("--ramp-set-v", "--ramp-reset-v"):
        assert cli.main(["cells", "test", "--port", "emu", "--cells", "0,0", opt, "1.0"]) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and f"{opt} is the top of a ramp of the user criteria's" in err
        assert "give --rmin-below" in err
    for old in ("--pair-set-v", "--pair-reset-v"):        # the one-pair spelling: its new name
        assert cli.main(["cells", "test", "--port", "emu", "--cells", "0,0", "--ratio-above",
                         "2", old, "1.0"]) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and f"{old} is now --ramp-" in err
    assert not (emu / "chip.npz").exists()


def test_a_labs_on_off_threshold_of_2_passes_healthy_cells(emu, capsys):
    # issue 38 item 12: R_max/R_min of one SET/RESET pair (1.17-1.31) marked every healthy
    # cell bad at the usual ON/OFF threshold of 2
    assert cli.main(["cells", "test", "--port", "emu", "--cells", "0,0", "1,1", "2,2",
                     "--ratio-above", "2", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert [c["verdict"] for c in data["cells"]] == ["good"] * 3
    assert all(c["ratio"] > 10 and c["window_pulses"] > 0 for c in data["cells"])
    assert all(c["restored"] for c in data["cells"])


def test_program_weights_avoids_listed_cells_for_one_run(emu, capsys):
    np.save(emu / "w.npy", grid_weights(3, 3, seed=2))
    base = ["program-weights", str(emu / "w.npy"), "--port", "emu", "--json"]
    assert cli.main(base) == 0
    layout = Layout.load(emu / "chip.layout.json")
    used = sorted({(s.row, s.col) for s in layout.synapses})[:3]
    avoid = emu / "avoid.csv"
    avoid.write_text("row,col\n" + "".join(f"{r},{c}\n" for r, c in used))
    capsys.readouterr()
    assert cli.main([*base, "--cells-avoid", str(avoid)]) in (0, 1)
    layout = Layout.load(emu / "chip.layout.json")
    now = {(s.row, s.col) for s in layout.synapses}
    assert not now & set(used)
    assert all(layout.bad_cells[c].startswith(USER_LIST_MARK) for c in used)
    capsys.readouterr()
    assert cli.main(base) in (0, 1)                   # the next run drops the run's marks
    layout = Layout.load(emu / "chip.layout.json")
    assert not [w for w in layout.bad_cells.values() if w.startswith(USER_LIST_MARK)]
    bad = emu / "bad.csv"
    bad.write_text("row,col\n40,1\n")
    assert cli.main([*base, "--cells-only", str(bad)]) == 2
    assert "outside the 32x8 array" in capsys.readouterr().err


@pytest.mark.parametrize("lo, hi", [(1.1, 1.5), (1.02, 1.08), (1.5, 40.0), (2.0, 3000.0)])
def test_the_heat_maps_colour_bar_labels_each_tick_once(tmp_path, monkeypatch, lo, hi):
    # found by a fresh-user pass: a screening's R_max/R_min (1.1..1.5) was labelled
    # 1.1, 1.2, 1.2, 1.2, 1.3, 1.4, 1.4, 1.5, 1.5 (the log locator's minor ticks at %.2g)
    from types import SimpleNamespace

    from snan_hil.tools import bench_figures as bf
    seen: list[list[str]] = []
    save = bf._save

    def spy(plt, fig, path, fmt, dpi=110):
        fig.canvas.draw()
        axis = fig.axes[-1].yaxis                       # the colour bar
        v0, v1 = sorted(axis.get_view_interval())
        seen.append([t.get_text() for t in axis.get_ticklabels(which="both")
                     if t.get_text() and v0 * 0.999 <= t.get_position()[1] <= v1 * 1.001])
        return save(plt, fig, path, fmt, dpi)
    monkeypatch.setattr(bf, "_save", spy)
    cells = [SimpleNamespace(row=r, col=c, ratio=lo + (hi - lo) * ((r * 8 + c) % 17) / 16,
                             verdict="good") for r in range(32) for c in range(8)]
    bf.plot_criteria(cells, (32, 8), tmp_path / "c.png", title="t",
                     criteria=UserCriteria(ratio_above=1.01))
    [labels] = seen
    assert len(labels) >= 3 and len(set(labels)) == len(labels), labels
    assert all(lo * 0.999 <= float(x) <= hi * 1.001 for x in labels), labels


def test_the_heat_maps_caption_fits_the_figure(tmp_path, monkeypatch):
    # issue 38 item 13: with three criteria the caption ran past the figure's edge
    from types import SimpleNamespace

    from snan_hil.tools import bench_figures as bf
    boxes = []
    save = bf._save

    def spy(plt, fig, path, fmt, dpi=110):
        fig.canvas.draw()
        r = fig.canvas.get_renderer()
        boxes.append((fig.legends[0].get_window_extent(r), fig.bbox,
                      fig.legends[0].get_title().get_text()))
        return save(plt, fig, path, fmt, dpi)
    monkeypatch.setattr(bf, "_save", spy)
    cells = [SimpleNamespace(row=r, col=c, ratio=40.0 + r, verdict="bad" if r % 3 else "good")
             for r in range(32) for c in range(8)]
    bf.plot_criteria(cells, (32, 8), tmp_path / "c.png", title="t", criteria=UserCriteria(
        rmin_below_ohm=123456, rmax_above_ohm=9876543, ratio_above=12.5))
    [(box, fig_box, caption)] = boxes
    assert fig_box.x0 <= box.x0 and box.x1 <= fig_box.x1 and fig_box.y0 <= box.y0
    assert "R_min < 123456 Ohm" in caption and "R_max/R_min > 12.5" in caption


def test_good_retest_clears_cell_test_marks(programmed_emu, capsys):
    d = programmed_emu
    cells = ["30,0", "30,1"]
    assert cli.main(["cells", "test", "--port", "emu", "--cells", *cells, "--noise-limit",
                     "0.001", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert {c["class"] for c in res["cells"]} == {"noisy"}
    assert sorted(map(tuple, res["layout_marked"])) == [(30, 0), (30, 1)]
    assert {(30, 0), (30, 1)} <= set(Layout.load(d / "chip.layout.json").bad_cells)
    assert cli.main(["cells", "test", "--port", "emu", "--cells", *cells, "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert {c["class"] for c in res["cells"]} == {"good"}
    assert sorted(map(tuple, res["layout_cleared"])) == [(30, 0), (30, 1)]
    assert not {(30, 0), (30, 1)} & set(Layout.load(d / "chip.layout.json").bad_cells)


def test_program_weights_drops_marks_of_cells_last_found_good(programmed_emu, capsys):
    """A layout mark from an older cell test is dropped by program-weights when the
    database's last class of the cell is good."""
    d = programmed_emu
    assert cli.main(["cells", "test", "--port", "emu", "--cells", "30,2", "--json"]) == 0
    capsys.readouterr()
    layout = Layout.load(d / "chip.layout.json")
    layout.mark_bad(30, 2, "cell test: noisy")
    layout.mark_bad(30, 3, "cell test: noisy")          # never tested: the mark stays
    layout.save(d / "chip.layout.json")
    assert cli.main(["program-weights", str(d / "w.npy"), "--port", "emu", "--json"]) == 0
    capsys.readouterr()
    bad = Layout.load(d / "chip.layout.json").bad_cells
    assert (30, 2) not in bad and (30, 3) in bad


def test_noise_limit_note_shows_its_digits(emu, capsys):
    assert cli.main(["cells", "test", "--port", "emu", "--cells", "0,0", "--noise-limit",
                     "0.001", "--record", "off", "--json"]) == 0
    cell = json.loads(capsys.readouterr().out)["cells"][0]
    assert cell["class"] == "noisy" and "> 0.1%" in cell["note"]
