"""snan_hil.files.outputs: the checks every command runs on its outputs before any long work, and
how it recognises its own files."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from snan_hil.files.outputs import (OutputError, Outputs, check_output_file, check_output_folder,
                              csv_kind, json_kind, npz_kind, png_kind, png_metadata)

LAYOUT = json_kind("snan-hil-layout/1", "a snan-hil layout")


def refused(fn, *needles):
    with pytest.raises(OutputError) as exc:
        fn()
    text = str(exc.value)
    assert "\n" not in text and all(n in text for n in needles), text
    return text


def test_new_file_in_a_writable_folder_passes_and_is_returned_expanded(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))
    assert check_output_file("-o", "~/x.json", LAYOUT) == tmp_path / "x.json"
    assert not list(tmp_path.iterdir())                      # the probe leaves nothing


def test_json_kind_recognises_any_version_of_its_format(tmp_path):
    p = tmp_path / "l.json"
    for data, mine in (({"format": "snan-hil-layout/1"}, True),
                       ({"format": "snan-hil-layout/7"}, True),
                       ({"format": "snan-hil-program-report/1"}, False),
                       ([1, 2], False), ({"grid": [3, 3]}, False)):
        p.write_text(json.dumps(data))
        assert LAYOUT.owns(p) is mine, data
    p.write_text('{"format": "snan-hil-layout/1"')               # truncated
    assert not LAYOUT.owns(p)
    p.write_bytes(b"\xff\xfe binary")
    assert not LAYOUT.owns(p)


def test_npz_kind_reads_only_the_format_member(tmp_path):
    kind = npz_kind("snan-hil-weights/1", "weights")
    np.savez(tmp_path / "a.npz", weights=np.zeros(3), format=np.array("snan-hil-weights/1"))
    np.savez(tmp_path / "b.npz", weights=np.zeros(3))
    np.savez(tmp_path / "c.npz", format=np.array([1, 2]))
    np.savez(tmp_path / "d.npz", format=np.array(["x"], dtype=object))    # pickled: not read
    (tmp_path / "e.npz").write_text("text")
    assert [kind.owns(tmp_path / f"{c}.npz") for c in "abcde"] == [True] + [False] * 4


def test_csv_kind_by_header_and_png_kind_by_text_tag(tmp_path):
    csv = csv_kind("row,col,adc", "a map CSV")
    (tmp_path / "a.csv").write_text("row,col,adc\r\n1,2,3\r\n")
    (tmp_path / "b.csv").write_text("row,col,adc,extra\n")
    assert csv.owns(tmp_path / "a.csv") and not csv.owns(tmp_path / "b.csv")
    # a file written before columns were added stays ours; a longer unknown header does not
    grown = csv_kind("row,col,adc,adc_ci_low", "a map CSV", earlier=("row,col,adc",))
    assert grown.owns(tmp_path / "a.csv") and not grown.owns(tmp_path / "b.csv")
    plt = pytest.importorskip("matplotlib.pyplot")
    png = png_kind("snan-hil-sim-plot/1", "a plot")
    fig, ax = plt.subplots()
    ax.plot([0, 1])
    fig.savefig(tmp_path / "mine.png", metadata=png_metadata("snan-hil-sim-plot/1"))
    fig.savefig(tmp_path / "other.png")
    fig.savefig(tmp_path / "map.png", metadata=png_metadata("snan-hil-map/1"))
    plt.close(fig)
    assert png.owns(tmp_path / "mine.png")
    assert not png.owns(tmp_path / "other.png") and not png.owns(tmp_path / "map.png")
    assert not png.owns(tmp_path / "a.csv")


def test_existing_file_of_another_kind_needs_force(tmp_path):
    p = tmp_path / "x.json"
    p.write_text("{}")
    refused(lambda: check_output_file("--layout", p, LAYOUT), "--layout", "is not a snan-hil "
            "layout", "--force")
    assert check_output_file("--layout", p, LAYOUT, force=True) == p
    refused(lambda: check_output_file("-o", p, None), "cannot tell", "--force")
    p.write_text('{"format": "snan-hil-layout/1"}')
    assert check_output_file("--layout", p, LAYOUT) == p


def test_inputs_are_found_by_inode_under_any_name_even_with_force(tmp_path, monkeypatch):
    w = tmp_path / "w.npy"
    np.save(w, np.zeros(3))
    os.link(w, tmp_path / "hard.npy")
    (tmp_path / "soft.npy").symlink_to(w)
    outs = Outputs({"weights": w}, force=True)
    for name in ("w.npy", "hard.npy", "soft.npy", "./w.npy"):
        path = tmp_path / name
        refused(lambda path=path: outs.file("--report", path, None), "--report",
                "input of this command (weights")
    monkeypatch.chdir(tmp_path)
    refused(lambda: outs.file("-o", "w.npy", None), "input")


def test_an_updated_input_may_be_its_own_output_but_not_another(tmp_path):
    layout = tmp_path / "l.json"
    layout.write_text('{"format": "snan-hil-layout/1"}')
    outs = Outputs({"--layout": layout})
    assert outs.file("--layout", layout, LAYOUT, updates=True) == layout
    refused(lambda: Outputs({"--layout": layout}).file("--layout", layout, LAYOUT),
            "input")
    refused(lambda: outs.file("--report", layout, LAYOUT), "is also", "input")


def test_two_outputs_must_differ(tmp_path):
    outs = Outputs()
    outs.file("--layout", tmp_path / "a.json", LAYOUT)
    refused(lambda: outs.file("--report", tmp_path / "a.json", None),
            "--report", "is also the output --layout")


@pytest.mark.parametrize("where,needle", [
    ("folder", "is a folder"), ("/dev/null", "is a device"),
    ("afile/x.json", "afile is not a folder"), ("nope/x.json", "does not exist"),
    ("/proc/x.json", "cannot write in folder /proc"),
])
def test_places_a_file_cannot_go(tmp_path, where, needle):
    (tmp_path / "folder").mkdir()
    (tmp_path / "afile").write_text("")
    path = where if where.startswith("/") else tmp_path / where
    refused(lambda: check_output_file("-o", path, LAYOUT), "-o", needle)


def test_missing_folder_may_be_created_where_allowed(tmp_path):
    p = tmp_path / "a" / "b" / "x.json"
    assert check_output_file("--layout", p, LAYOUT, create_folder=True) == p
    assert not (tmp_path / "a").exists()                     # checked, not created
    (tmp_path / "afile").write_text("")
    refused(lambda: check_output_file("--layout", tmp_path / "afile" / "b" / "x.json", LAYOUT,
                                      create_folder=True), "afile is not a folder")


def test_fifo_is_refused(tmp_path):
    os.mkfifo(tmp_path / "pipe")
    refused(lambda: check_output_file("-o", tmp_path / "pipe", None), "is a pipe")


def test_folders_and_the_files_planned_in_them(tmp_path):
    kind = csv_kind("a,b", "a table")
    out = tmp_path / "res"
    files = {"t.csv": kind, "sub/r.json": LAYOUT}
    assert check_output_folder("--out", out, files=files) == out and not out.exists()
    out.mkdir()
    (out / "t.csv").write_text("a,b\n1,2\n")                  # its own: fine
    check_output_folder("--out", out, files=files)
    (out / "t.csv").write_text("mine\n")
    refused(lambda: check_output_folder("--out", out, files=files), "--out", "t.csv",
            "is not a table", "--force")
    check_output_folder("--out", out, files=files, force=True)
    refused(lambda: check_output_folder("--out", tmp_path / "res" / "t.csv"),
            "exists and is not a folder")
    refused(lambda: check_output_folder("--out", "/proc/x"), "cannot create folder /proc/x")
    refused(lambda: check_output_folder("--out", ""), "empty")
    w = out / "w.npy"
    np.save(w, np.zeros(2))
    refused(lambda: check_output_folder("--out", out, inputs={"--weights": w},
                                        files={"w.npy": None}, force=True), "input")


def test_replaced_sub_folders_judged_as_a_whole(tmp_path):
    from snan_hil.files.outputs import OutputKind
    kind = OutputKind("a figure folder", lambda p: (p / "fig.json").exists())
    out = tmp_path / "res"
    (out / "fig").mkdir(parents=True)
    check_output_folder("--out", out)
    outs = Outputs()
    refused(lambda: outs.folder("--out", out, folders={"fig": kind}), "fig: folder exists "
            "and is not a figure folder", "--force")
    (out / "fig" / "fig.json").write_text("{}")
    Outputs().folder("--out", out, folders={"fig": kind})
    w = out / "fig" / "w.npy"
    np.save(w, np.zeros(2))
    refused(lambda: Outputs({"--weights": w}, force=True).folder("--out", out,
                                                                folders={"fig": kind}),
            "holds the input --weights")


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write into a 0555 folder")
def test_read_only_folder(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        refused(lambda: check_output_file("-o", ro / "x.json", LAYOUT), "cannot write in "
                "folder", "ro")
        refused(lambda: check_output_folder("--out", ro / "sub"), "cannot create folder")
    finally:
        ro.chmod(0o755)
