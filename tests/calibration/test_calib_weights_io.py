"""Weights files: loading, validation (shape, finite, range, adjacency), the CLI refusal path."""

import json

import numpy as np
import pytest

from snan_hil.calibration.testing import grid_weights
from snan_hil.calibration.weights_io import (WeightFileError, compact_to_dense, dense_to_compact,
                                             grid_synapses, load_weight_set, synapse_count)
from snan_hil.common.errors import UserError
from snan_hil.tools import cli


def _neighbours(a, b, cols):
    (ra, ca), (rb, cb) = divmod(a, cols), divmod(b, cols)
    return abs(ra - rb) + abs(ca - cb) == 1


@pytest.mark.parametrize("rows,cols", [(6, 6), (3, 3), (2, 5), (1, 4)])
def test_grid_synapses_are_exactly_the_directed_neighbour_pairs(rows, cols):
    pairs = grid_synapses(rows, cols)
    n = rows * cols
    brute = [(a, b) for a in range(n) for b in range(n) if _neighbours(a, b, cols)]
    assert pairs == sorted(brute)
    assert len(pairs) == synapse_count(rows, cols)


def test_six_by_six_grid_has_the_papers_120_synapses():
    pairs = grid_synapses(6, 6)
    assert len(pairs) == 120
    degree = np.bincount([a for a, _ in pairs], minlength=36)
    assert sorted(np.bincount(degree)[2:5]) == [4, 16, 16]   # corners 2, borders 3, inner 4


def test_compact_dense_roundtrip():
    w = grid_weights(4, 5, seed=3)
    back = compact_to_dense(dense_to_compact(w, 4, 5), 4, 5)
    np.testing.assert_array_equal(back, w)


def test_npy_matrix_and_stack(tmp_path):
    w = grid_weights(6, 6, seed=1, k=3)
    np.save(tmp_path / "one.npy", w[0])
    np.save(tmp_path / "stack.npy", w)
    got, meta = load_weight_set(tmp_path / "one.npy")
    np.testing.assert_array_equal(got, w[0])
    assert meta["grid"] == [6, 6] and meta["n_synapses"] == 120 and meta["n_sets"] == 1
    got, meta = load_weight_set(tmp_path / "stack.npy", 2)
    np.testing.assert_array_equal(got, w[2])
    assert meta["set_index"] == 2 and meta["n_sets"] == 3


def test_npz_from_train_with_metadata_and_non_square_grid(tmp_path):
    w = grid_weights(2, 3, seed=2, k=2)
    path = tmp_path / "trained.npz"
    np.savez(path, weights=w, grid=np.array([2, 3]), start=np.int64(5), goal=np.int64(0),
             seeds=np.array([11, 12]), config=np.array(json.dumps({"cycles": 20})),
             cycles=np.int64(20))
    got, meta = load_weight_set(path, 1)
    np.testing.assert_array_equal(got, w[1])
    assert meta["grid"] == [2, 3] and meta["seed"] == 12 and meta["start"] == 5
    assert meta["config"] == {"cycles": 20} and meta["cycles"] == 20


@pytest.mark.parametrize("mutate,needle", [
    (lambda w: w.__setitem__((0, 1), np.nan), "non-finite"),
    (lambda w: w.__setitem__((0, 1), 1.5), "outside [0, 1]"),
    (lambda w: w.__setitem__((0, 1), -0.1), "outside [0, 1]"),
    (lambda w: w.__setitem__((0, 7), 0.5), "not grid neighbours"),   # diagonal neighbour
    (lambda w: w.__setitem__((3, 3), 0.5), "not grid neighbours"),   # self-connection
    (lambda w: w.__setitem__((5, 6), 0.5), "not grid neighbours"),   # row wrap-around
])
def test_invalid_values_are_refused_with_one_line(tmp_path, mutate, needle):
    w = grid_weights(6, 6, seed=0)
    mutate(w)
    np.save(tmp_path / "w.npy", w)
    with pytest.raises(WeightFileError) as exc:
        load_weight_set(tmp_path / "w.npy")
    assert needle in str(exc.value) and "\n" not in str(exc.value)
    assert isinstance(exc.value, UserError)


@pytest.mark.parametrize("array,needle", [
    (np.zeros((35, 35)), "not a square grid"),
    (np.zeros((36, 35)), "square"),
    (np.zeros((2, 2, 2, 2)), "expected an N x N"),
    (np.full((4, 4), "a"), "real numbers"),
])
def test_bad_shapes_are_refused(tmp_path, array, needle):
    np.save(tmp_path / "w.npy", array)
    with pytest.raises(WeightFileError, match=needle):
        load_weight_set(tmp_path / "w.npy")


def test_missing_unreadable_and_incomplete_files(tmp_path):
    with pytest.raises(WeightFileError, match="does not exist"):
        load_weight_set(tmp_path / "nope.npy")
    (tmp_path / "junk.npy").write_bytes(b"not numpy at all")
    with pytest.raises(WeightFileError, match="not a .npy/.npz file"):
        load_weight_set(tmp_path / "junk.npy")
    np.savez(tmp_path / "x.npz", other=np.zeros(3))
    with pytest.raises(WeightFileError, match="without a 'weights'"):
        load_weight_set(tmp_path / "x.npz")
    np.save(tmp_path / "w.npy", grid_weights(3, 3))
    with pytest.raises(WeightFileError, match="--weight-set 1"):
        load_weight_set(tmp_path / "w.npy", 1)


def test_cli_refuses_a_bad_file_before_touching_the_chip(tmp_path, monkeypatch, capsys):
    state = tmp_path / "chip.npz"
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(state))
    w = grid_weights(6, 6)
    w[0, 1] = 2.0
    np.save(tmp_path / "bad.npy", w)
    code = cli.main(["program-weights", str(tmp_path / "bad.npy"), "--port", "emu"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count("\n") == 1 and "outside [0, 1]" in err and "Traceback" not in err
    assert not state.exists()                      # the emulator was never even started
    assert not list(tmp_path.glob("*.json"))       # no layout, no report


# ---- damaged and wrong files: one correct line, exit 2, for every command that reads weights --
@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A real 'snan-hil train' output (2 sets of the 6x6 task)."""
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.hil.train import save_weights, train_sets
    hil = load_hil_config()
    res = train_sets(hil.train_config(), sets=2, cycles=2, seed=1, start=hil.task.start,
                     goal=hil.task.goal)
    return save_weights(res, tmp_path_factory.mktemp("trained") / "weights.npz")


def _with(trained, **changes):
    """The trained file's members with some replaced (None: removed)."""
    with np.load(trained) as z:
        data = {k: z[k] for k in z.files}
    data.update(changes)
    return {k: v for k, v in data.items() if v is not None}


def _damaged(trained, path):
    data = bytearray(trained.read_bytes())
    for i in range(2000, 2100):                    # the reproducer
        data[i] ^= 0xFF
    path.write_bytes(bytes(data))


BAD_FILES = {
    # name: (writer(trained, path), words the one line must hold)
    "objects.npz": (lambda t, p: np.savez(p, weights=np.array([None, 1], dtype=object)),
                    ("member 'weights'", "Python objects", "never unpickles")),
    "objects.npy": (lambda t, p: np.save(p, np.array([None, 1], dtype=object),
                                         allow_pickle=True), ("Python objects",)),
    "damaged.npz": (_damaged, ("is damaged", "corrupt")),
    "truncated.npz": (lambda t, p: p.write_bytes(t.read_bytes()[:3000]), ("damaged",)),
    "seeds-text.npz": (lambda t, p: np.savez(p, **_with(t, seeds=np.array(["1", "2"]))),
                       ("'seeds' must be 2 integers", "<U1")),
    "seeds-nan.npz": (lambda t, p: np.savez(p, **_with(t, seeds=np.array([np.nan, 2.0]))),
                      ("'seeds' must be 2 integers", "nan")),
    "seeds-short.npz": (lambda t, p: np.savez(p, **_with(t, seeds=np.array([1]))),
                        ("'seeds' must be 2 integers",)),
    "start-float.npz": (lambda t, p: np.savez(p, **_with(t, start=np.float64(18.5))),
                        ("'start' must be one integer",)),
    "goal-outside.npz": (lambda t, p: np.savez(p, **_with(t, goal=np.int64(99))),
                         ("'goal' cell 99 is outside the 6x6 grid",)),
    "config-number.npz": (lambda t, p: np.savez(p, **_with(t, config=np.array([1.5]))),
                          ("'config' must be one text",)),
    "grid-text.npz": (lambda t, p: np.savez(p, **_with(t, grid=np.array(["6", "6"]))),
                      ("'grid' must be two positive integers",)),
    "text.npy": (lambda t, p: p.write_text("0.1, 0.2\n0.3, 0.4\n"),
                 ("not a .npy/.npz file", "text")),
    "folder.npz": (lambda t, p: p.mkdir(), ("is a folder",)),
    "empty-stack.npy": (lambda t, p: np.save(p, np.zeros((0, 36, 36))),
                        ("holds no weight sets", "0 x 36 x 36")),
    "empty-stack.npz": (lambda t, p: np.savez(p, **_with(t, weights=np.zeros((0, 36, 36)))),
                        ("holds no weight sets",)),
    "zero-bytes.npy": (lambda t, p: p.write_bytes(b""), ("empty (0 bytes)",)),
    "strings.npy": (lambda t, p: np.save(p, np.full((36, 36), "x")), ("real numbers",)),
}

READERS = {
    "program-weights": ["program-weights", "{f}", "--port", "emu"],
    "read-weights": ["read-weights", "--port", "emu", "--layout", "{d}/l.json", "--weights",
                     "{f}"],
    "run": ["run", "--scenario", "hw_astro", "--weights", "{f}", "--launches", "1"],
    "compare": ["compare", "--weights", "{f}", "--launches", "1", "--out", "{d}/out"],
}


@pytest.mark.parametrize("reader", list(READERS))
def test_bad_weights_files_get_one_line_in_every_command(tmp_path, monkeypatch, capsys,
                                                         trained, reader):
    from snan_hil.calibration.layout import Layout
    state = tmp_path / "chip.npz"
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(state))
    Layout.place((6, 6), (32, 8)).save(tmp_path / "l.json")
    for name, (write, needles) in BAD_FILES.items():
        path = tmp_path / name
        write(trained, path)
        argv = [a.format(f=path, d=tmp_path) for a in READERS[reader]]
        code = cli.main(argv)
        err = capsys.readouterr().err
        assert code == 2, (name, err)
        assert err.count("\n") == 1 and "Traceback" not in err, (name, err)
        assert name in err and all(n in err for n in needles), (name, err)
    assert not state.exists() and not (tmp_path / "out").exists()   # nothing started


def test_the_trained_file_itself_loads(trained):
    w, meta = load_weight_set(trained, 1)
    assert meta["n_sets"] == 2 and meta["grid"] == [6, 6] and meta["seeds"] == [1, 2]
    assert meta["seed"] == 2 and isinstance(meta["config"], dict)
