"""Measured data in (issue 36 point 1): ``snan-hil characterize --from FILE`` fits the device
model to a lab's pulse CSV, this project's history export or its characterise CSV, without a
board; a bad row is one line naming the file's line."""

import csv
import json
import math

import numpy as np
import pytest

from snan_hil.calibration.pulse_files import read_pulse_file, retention_pairs
from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.fitted import DeviceModel, LearningPulse
from snan_hil.tools import cli

TRUTH = {"up": 0.05, "xmax": math.log(1.3e-3), "down": 0.02, "xmin": math.log(30e-6)}


def _lab_rows(cells=4, pulses=400, sigma=0.003, seed=2):
    """Soft-bounds pulses of ``cells`` devices with separate noisy reads before and after."""
    rng = np.random.default_rng(seed)
    rows = []
    for cell in range(cells):
        g = 100e-6
        for k in range(pulses):
            pol = "SET" if (k // 50) % 2 == 0 else "RESET"
            x = math.log(g)
            mean = TRUTH["up"] * (TRUTH["xmax"] - x) if pol == "SET" \
                else -TRUTH["down"] * (x - TRUTH["xmin"])
            g2 = g * math.exp(mean * (1 + 0.2 * rng.standard_normal()))
            read = [v * math.exp(sigma * rng.standard_normal()) for v in (g, g2)]
            rows.append([f"dev-{cell}", pol.lower(), 1.1 if pol == "SET" else -0.9, 50,
                         f"{read[0]:.8g}", f"{read[1]:.8g}", f"{0.01 * k:.3f}"])
            g = g2
    return rows


def _write(path, header, rows):
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        w.writerows(rows)
    return path


HEADER = ["cell", "polarity", "amplitude_v", "width_us", "g_before_s", "g_after_s", "time_s"]


def test_a_labs_csv_is_read_in_order_with_names_and_wear(tmp_path):
    pf = read_pulse_file(_write(tmp_path / "lab.csv", HEADER, _lab_rows()))
    assert pf.form == "lab" and len(pf.rows) == 1600
    assert pf.cell_names == {"dev-0": (0, 0), "dev-1": (0, 1), "dev-2": (0, 2),
                             "dev-3": (0, 3)}
    pulse = pf.most_common_pulse()
    assert (pulse.set_v, pulse.reset_v, pulse.width_us) == (1.1, 0.9, 50)
    samples = pf.samples(pulse)
    assert len(samples) == 1600 and samples[0].polarity == Polarity.SET
    one = [s for s in samples if (s.row, s.col) == (0, 2)]
    assert one[0].swing_before == 0 and all(
        b.swing_before > a.swing_before for a, b in zip(one, one[1:]))
    assert len(retention_pairs(pf)) == 1596          # consecutive pulses of each cell


def test_characterize_from_a_labs_csv_fits_the_generating_device(tmp_path, capsys):
    path = _write(tmp_path / "lab.csv", HEADER, _lab_rows(cells=6, pulses=600))
    rc = cli.main(["characterize", "--from", str(path), "--model", str(tmp_path / "m.json"),
                   "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["form"] == "lab"
    model = DeviceModel.from_dict(json.loads((tmp_path / "m.json").read_text()))
    assert model.up_rate == pytest.approx(TRUTH["up"], rel=0.15)
    assert model.down_rate == pytest.approx(TRUTH["down"], rel=0.2)
    assert model.g_max_s == pytest.approx(1.3e-3, rel=0.15)
    # no repeated reads in the file: the read noise comes from the steps' scatter
    assert model.read_noise == pytest.approx(0.003, rel=0.35)
    assert model.meta["read_noise_source"].startswith("estimated")
    assert out["holdout"]["n"] > 1000
    assert model.aging is not None and model.aging.wear_source.startswith("assumption")


@pytest.mark.parametrize("bad, line, text", [
    ({4: "-1e-4"}, 3, "g_before_s -1e-4 must be above 0"),
    ({5: "abc"}, 4, "g_after_s 'abc' is not a number"),
    ({1: "sideways"}, 2, "polarity 'sideways' is not SET or RESET"),
    ({2: "0"}, 5, "amplitude_v is 0"),
    ({0: ""}, 3, "cell is empty"),
])
def test_a_bad_row_is_one_line_naming_it(tmp_path, capsys, bad, line, text):
    rows = _lab_rows(cells=1, pulses=6)
    for k, v in bad.items():
        rows[line - 2][k] = v
    path = _write(tmp_path / "lab.csv", HEADER, rows)
    with pytest.raises(UserError, match=f"line {line}: "):
        read_pulse_file(path)
    assert cli.main(["characterize", "--from", str(path), "--model",
                     str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err
    assert f"lab.csv line {line}: " in err and text in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "m.json").exists()


def test_bad_files_are_one_line(tmp_path, capsys):
    (tmp_path / "empty.csv").write_text("")
    _write(tmp_path / "header.csv", ["cell", "polarity", "g_after_s"], [["1:1", "SET", "1"]])
    short = _write(tmp_path / "short.csv", HEADER, [["1:1", "SET", "0.8", "100"]])
    for path, text in ((tmp_path / "empty.csv", "is empty"),
                       (tmp_path / "header.csv", "header lacks amplitude_v, width_us, "
                                                 "g_before_s"),
                       (short, "line 2: 4 fields"),
                       (tmp_path / "none.csv", "does not exist")):
        assert cli.main(["characterize", "--from", str(path)]) == 2
        err = capsys.readouterr().err
        assert text in err and "Traceback" not in err, err
        assert len(err.strip().splitlines()) == 1


def test_a_pulse_the_file_does_not_hold_is_named_with_what_it_holds(tmp_path, capsys):
    path = _write(tmp_path / "lab.csv", HEADER, _lab_rows(cells=1, pulses=120))
    assert cli.main(["characterize", "--from", str(path), "--set-v", "0.8"]) == 2
    err = capsys.readouterr().err
    assert "no SET pulse" in err and "SET 1.1 V / 50 us: 70" in err


def test_history_export_and_characterize_csv_round_trip(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    assert cli.main(["characterize", "--port", "emu", "--cells", "2,2;3,3;4,1", "--repeats",
                     "2", "--csv", str(tmp_path / "c.csv"), "--json"]) == 0
    board = json.loads(capsys.readouterr().out)["model"]
    assert cli.main(["history", "--port", "emu", "--export", "pulses", "-o",
                     str(tmp_path / "p.csv")]) == 0
    capsys.readouterr()
    for name, form in (("p.csv", "history"), ("c.csv", "characterize")):
        assert cli.main(["characterize", "--from", str(tmp_path / name), "--json"]) == 0
        out = json.loads(capsys.readouterr().out)
        assert out["form"] == form and out["samples"] == board["points"]
        m = out["model"]
        assert m["dw_min"] == pytest.approx(board["dw_min"], rel=0.02)
        assert m["up_down"] == pytest.approx(board["up_down"], abs=0.02)
        # the board measured its read noise with repeated reads; the file has none
        assert m["read_noise"] == pytest.approx(board["read_noise"], rel=0.5)
    pf = read_pulse_file(tmp_path / "p.csv")
    assert all(r.time_s is not None for r in pf.rows)


def test_from_refuses_the_options_of_a_sweep(tmp_path, capsys):
    path = _write(tmp_path / "lab.csv", HEADER, _lab_rows(cells=1, pulses=60))
    assert cli.main(["characterize", "--from", str(path), "--repeats", "3"]) == 2
    assert "--repeats sets a sweep on a board" in capsys.readouterr().err
    assert LearningPulse(0.8, 0.6, 100).width_us == 100
