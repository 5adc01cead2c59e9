"""snan_hil.files.atomicio: a write replaces the target completely or leaves it untouched."""

from __future__ import annotations

import json
import math
import signal
import stat

import numpy as np
import pytest

from snan_hil.files.atomicio import (atomic_path, atomic_write_bytes, atomic_write_json,
                               atomic_write_text, current_umask, signals_deferred)


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


# ---- permissions, links, signals -------------------------------------------------------------
@pytest.fixture
def umask():
    """Set the process umask for a test, restore it after."""
    import os
    old = os.umask(0o022)
    os.umask(old)
    yield lambda mask: os.umask(mask)
    os.umask(old)


@pytest.mark.parametrize("mask,mode", [(0o022, 0o644), (0o002, 0o664), (0o077, 0o600)])
def test_new_files_get_the_umask_permissions(tmp_path, umask, mask, mode):
    umask(mask)
    assert current_umask() == mask
    atomic_write_text(tmp_path / "a.json", "{}\n")
    with atomic_path(tmp_path / "b.npy", suffix=".tmp.npy") as tmp:
        np.save(tmp, np.zeros(2))
    for name in ("a.json", "b.npy"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == mode


def test_a_replaced_file_keeps_its_permissions(tmp_path, umask):
    umask(0o022)
    target = tmp_path / "layout.json"
    target.write_text("old")
    target.chmod(0o640)
    atomic_write_text(target, "new")
    assert target.read_text() == "new" and stat.S_IMODE(target.stat().st_mode) == 0o640


def test_a_symbolic_link_stays_and_its_file_is_replaced(tmp_path):
    real = tmp_path / "real.json"
    real.write_text("old")
    link = tmp_path / "link.json"
    link.symlink_to(real)
    atomic_write_text(link, "new")
    assert link.is_symlink() and real.read_text() == "new"
    assert _only(tmp_path) == ["link.json", "real.json"]


def _interrupt_during_mkstemp(monkeypatch):
    import tempfile
    real = tempfile.mkstemp

    def mkstemp(*args, **kwargs):
        out = real(*args, **kwargs)
        signal.raise_signal(signal.SIGINT)        # Ctrl-C the moment the file exists
        return out
    monkeypatch.setattr(tempfile, "mkstemp", mkstemp)


def test_ctrl_c_while_the_temporary_file_is_created_leaves_nothing(tmp_path, monkeypatch):
    target = tmp_path / "layout.json"
    target.write_text("old")
    _interrupt_during_mkstemp(monkeypatch)
    # Python's own Ctrl-C handler, as at a terminal (a job started in the background by a
    # shell inherits SIGINT ignored, and raise_signal would then do nothing)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            atomic_write_text(target, "new")
    finally:
        signal.signal(signal.SIGINT, previous)
    assert target.read_text() == "old" and _only(tmp_path) == ["layout.json"]


def test_signals_deferred_delivers_afterwards_to_the_previous_handler():
    got = []
    old = signal.signal(signal.SIGTERM, lambda signum, frame: got.append(signum))
    try:
        with signals_deferred():
            signal.raise_signal(signal.SIGTERM)
            assert got == []                         # held back inside the block
        assert got == [signal.SIGTERM]
    finally:
        signal.signal(signal.SIGTERM, old)
