"""snan_hil.atomicio: a write replaces the target completely or leaves it untouched."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from snan_hil.atomicio import (atomic_path, atomic_write_bytes, atomic_write_json,
                               atomic_write_text)


class Boom(Exception):
    pass


def _only(folder):
    return sorted(p.name for p in folder.iterdir())


def test_text_replaces_and_creates_folder(tmp_path):
    target = tmp_path / "sub" / "a.csv"
    assert atomic_write_text(target, "x,y\n1,2\n") == target
    assert target.read_bytes() == b"x,y\n1,2\n"
    atomic_write_text(target, "new\r\n")
    assert target.read_bytes() == b"new\r\n"        # newline="" by default: no translation
    assert _only(target.parent) == ["a.csv"]


def test_bytes_and_str_path(tmp_path):
    target = tmp_path / "b.bin"
    target.write_bytes(b"old")
    atomic_write_bytes(str(target), b"\x00\x01\xff")
    assert target.read_bytes() == b"\x00\x01\xff"
    assert _only(tmp_path) == ["b.bin"]


def test_json_round_trip_and_kwargs(tmp_path):
    target = tmp_path / "c.json"
    atomic_write_json(target, {"a": [1, 2.5], "b": None}, indent=1)
    text = target.read_text()
    assert text.endswith("}\n") and "\n " in text
    assert json.loads(text) == {"a": [1, 2.5], "b": None}


def test_json_error_leaves_old_file(tmp_path):
    target = tmp_path / "c.json"
    target.write_text("old")
    with pytest.raises(ValueError):
        atomic_write_json(target, {"x": math.nan}, allow_nan=False)
    with pytest.raises(TypeError):
        atomic_write_json(target, {"x": object()})
    assert target.read_text() == "old"
    assert _only(tmp_path) == ["c.json"]


def test_failure_inside_block_keeps_old_file_and_no_temp(tmp_path):
    target = tmp_path / "d.txt"
    target.write_text("old")
    with pytest.raises(Boom):
        with atomic_path(target) as tmp:
            assert tmp.parent == tmp_path and tmp != target
            tmp.write_text("half")
            raise Boom
    assert target.read_text() == "old"
    assert _only(tmp_path) == ["d.txt"]


def test_failure_when_target_did_not_exist(tmp_path):
    target = tmp_path / "e.txt"
    with pytest.raises(Boom):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise Boom
    assert _only(tmp_path) == []


def test_temp_name_suffix_and_prefix(tmp_path):
    target = tmp_path / "f.npz"
    with atomic_path(target, suffix=".tmp.npz") as tmp:
        assert tmp.name.startswith(".f.npz.") and tmp.name.endswith(".tmp.npz")
        tmp.write_bytes(b"")
    with atomic_path(target, prefix="f.npz.") as tmp:
        assert tmp.name.startswith("f.npz.") and tmp.name.endswith(".tmp")
        tmp.write_bytes(b"")
    assert _only(tmp_path) == ["f.npz"]


def test_writer_callback_np_savez(tmp_path):
    target = tmp_path / "w.npz"
    target.write_bytes(b"old")
    a = np.arange(12.0).reshape(3, 4)
    with atomic_path(target, suffix=".tmp.npz") as tmp:
        np.savez(tmp, a=a)
    with np.load(target) as d:
        np.testing.assert_array_equal(d["a"], a)
    assert _only(tmp_path) == ["w.npz"]


def test_writer_callback_savefig(tmp_path):
    plt = pytest.importorskip("matplotlib.pyplot")
    target = tmp_path / "p.png"
    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    try:
        with atomic_path(target, suffix=".tmp") as tmp:
            fig.savefig(tmp, format="png")
    finally:
        plt.close(fig)
    assert target.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert _only(tmp_path) == ["p.png"]
