"""`snan-hil experiment`: files per figure, atomic replacement, reports that put the paper's
numbers next to ours, exit code 2 on bad input."""

import json

import pytest

from snan_hil.host.intervals import format_interval, inside_text, paper_inside, wilson
from snan_hil.tools.cli import main


@pytest.fixture(scope="module")
def out_all(tmp_path_factory):
    out = tmp_path_factory.mktemp("exp")
    assert main(["experiment", "all", "--trials", "2", "--workers", "1", "--seed", "3",
                 "--out", str(out)]) == 0
    return out


@pytest.mark.parametrize("fig", ["fig3", "fig4", "fig5", "fig6", "fig7"])
def test_every_figure_writes_its_files(out_all, fig):
    folder = out_all / fig
    names = sorted(p.name for p in folder.iterdir())
    assert names == sorted(f"{fig}.{e}" for e in ("csv", "json", "md", "png"))
    assert (folder / f"{fig}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    data = json.loads((folder / f"{fig}.json").read_text())
    assert data["master_seed"] == 3 and data["options"]["trials"] == 2
    assert data["configs"] and data["condition_seeds"]
    csv_lines = (folder / f"{fig}.csv").read_text().splitlines()
    assert len(csv_lines) >= 3
    assert not [p for p in out_all.iterdir() if p.name.startswith(".")]  # no temp folders


def _pct(x):
    return f"{100 * x:.1f} %"


def test_fig3_report_puts_paper_numbers_next_to_ours(out_all):
    data = json.loads((out_all / "fig3" / "fig3.json").read_text())
    report = (out_all / "fig3" / "fig3.md").read_text()
    main_rows = [r for r in data["rows"] if r["part"] == "main"]
    for r in main_rows:
        paper = "63.1 %" if not r["astro"] else "100.0 %"
        line = next(ln for ln in report.splitlines()
                    if ln.startswith(f"| {'with' if r['astro'] else 'without'} astrocytes"))
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert cells[1] == paper and cells[2] == _pct(r["success_rate"])
        assert cells[3] == ("10" if not r["astro"] else "4")
        med = r["median_steps"]
        assert cells[4] == ("–" if med is None else
                            f"{med:.0f}" if float(med).is_integer() else f"{med:.1f}")


def test_fig3_reports_intervals_and_whether_the_paper_lies_inside(out_all):
    data = json.loads((out_all / "fig3" / "fig3.json").read_text())
    report = (out_all / "fig3" / "fig3.md").read_text()
    assert "Wilson" in report and "bootstrap" in report        # the method is named
    for r in (r for r in data["rows"] if r["part"] == "main"):
        assert r["success_rate_ci"] == pytest.approx(list(wilson(r["successes"], r["trials"])))
        line = next(ln for ln in report.splitlines()
                    if ln.startswith(f"| {'with' if r['astro'] else 'without'} astrocytes"))
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert cells[5] == format_interval(r["success_rate_ci"], percent=True)
        assert cells[6] == inside_text(paper_inside(r["paper_success_rate"],
                                                    r["success_rate_ci"]))
        assert cells[8] == inside_text(paper_inside(r["paper_median_steps"],
                                                    r["median_steps_ci"]))
    header = (out_all / "fig3" / "fig3.csv").read_text().splitlines()[0].split(",")
    assert {"success_rate_ci_low", "success_rate_ci_high", "median_steps_ci_low",
            "median_steps_ci_high", "ci_method"} <= set(header)


def test_fig7_report_lists_paper_and_our_learning_curves(out_all):
    data = json.loads((out_all / "fig7" / "fig7.json").read_text())
    report = (out_all / "fig7" / "fig7.md").read_text()
    line = next(ln for ln in report.splitlines() if ln.startswith("| 10x10 |"))
    assert "389 → 38" in line and "40.4 % → 99.0 %" in line
    c = data["curves"]["main 10x10"]
    assert _pct(c["success"][0]) in line and _pct(c["success"][-1]) in line
    assert len(c["success"]) == 21


def test_a_reused_out_is_resumed_or_refused_and_figure_folders_replaced_atomically(tmp_path,
                                                                                    capsys):
    argv = ["experiment", "fig3", "--trials", "2", "--workers", "1", "--out", str(tmp_path)]
    old = tmp_path / "fig3"
    old.mkdir()
    (old / "stale.txt").write_text("old")
    assert main(argv) == 2                       # not the figure's folder: refused, kept
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "fig3: folder exists and is not the output" in err
    assert (old / "stale.txt").read_text() == "old"
    (old / "stale.txt").unlink()
    old.rmdir()
    assert main(argv) == 0
    capsys.readouterr()
    assert main(argv) == 2                       # a complete run: refused without --resume
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--resume" in err
    assert main([*argv, "--seed", "5", "--resume"]) == 2      # another run: refused, named
    assert "seed" in capsys.readouterr().err
    assert main([*argv, "--resume"]) == 0        # written again from the checkpoint
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint", "fig3"]
    capsys.readouterr()
    # a file of the user's in the figure's folder: refused before any trial, also with
    # --resume; --force replaces the folder as a whole
    (old / "notes.txt").write_text("mine")
    assert main([*argv, "--resume"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "fig3: folder exists and is not the output" in err
    assert (old / "notes.txt").read_text() == "mine"
    assert main([*argv, "--resume", "--force"]) == 0
    assert sorted(p.name for p in old.iterdir()) == [
        "fig3.csv", "fig3.json", "fig3.md", "fig3.png"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["checkpoint", "fig3"]


@pytest.mark.parametrize("argv", [
    ["experiment", "fig9"],
    ["experiment", "fig3", "--trials", "0"],
    ["experiment", "fig3", "--workers", "0"],
    ["experiment", "fig3", "--plasticity", "hebb"],
    ["experiment", "fig3", "--set", "astro.nonsense=1"],
    ["experiment", "fig3", "--set", "grid.max_steps=-5"],
    ["experiment", "fig5", "--maze-rule", "walls", "--trials", "1", "--workers", "1"],
    ["experiment", "fig3", "--dask", "tcp://127.0.0.1:9", "--workers", "2"],
])
def test_bad_input_exits_2(argv, tmp_path, capsys):
    try:
        code = main([*argv, "--out", str(tmp_path)])
    except SystemExit as exc:   # argparse
        code = exc.code
    assert code == 2
    assert not list(tmp_path.glob("fig*"))
