"""Load and validate the input->motor weights of a grid SNAN for programming into the crossbar.

Accepted files (``W[pre, post]`` is the weight of the synapse from input neuron ``pre`` to motor
neuron ``post``; neurons are grid cells numbered row-major, ``cell = row * cols + col``):

* ``.npy`` with a dense ``N x N`` matrix (N a perfect square: a square grid of side sqrt(N)),
  or a stack ``K x N x N`` of weight sets (pick one with ``set_index``);
* ``.npz`` written by ``snan-hil train``: ``weights`` (K x N x N float), ``grid`` (rows, cols),
  and optionally ``start``, ``goal``, ``seeds`` (K ints), ``config`` (JSON text), ``cycles``.

Checks: shape, finite values, range [0, 1], and adjacency (non-zero weights only between
4-neighbours of the grid; self-connections are not synapses). Any failure raises
:class:`WeightFileError` (a :class:`~snan_hil.common.errors.UserError`) with one line naming
the file
and the problem. The synapses to program are *all* directed neighbour pairs (a zero weight is a
synapse at G_min), so a 6x6 grid gives exactly 120 of them — the paper's 15x8 block.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from snan_hil.common.errors import UserError

Floats = NDArray[np.float64]
"""A float64 array (shape and unit in each docstring)."""

__all__ = ["WeightFileError", "load_weight_set", "weights_fingerprint", "validate_weights",
           "grid_synapses", "synapse_count", "weights_to_vector", "vector_to_weights",
           "dense_to_compact",
           "compact_to_dense"]

# The host's direction order (host/grid.py): up, down, left, right.
_DIRS = ((-1, 0), (1, 0), (0, -1), (0, 1))


class WeightFileError(UserError):
    """A weights file that cannot be programmed (missing, unreadable, wrong shape or values)."""


def grid_synapses(rows: int, cols: int) -> list[tuple[int, int]]:
    """All directed 4-neighbour pairs ``(pre, post)`` of a rows x cols grid, sorted."""
    out: list[tuple[int, int]] = []
    for pre in range(rows * cols):
        r, c = divmod(pre, cols)
        posts = []
        for dr, dc in _DIRS:
            r2, c2 = r + dr, c + dc
            if 0 <= r2 < rows and 0 <= c2 < cols:
                posts.append(r2 * cols + c2)
        out.extend((pre, post) for post in sorted(posts))
    return out


def synapse_count(rows: int, cols: int) -> int:
    """Number of directed neighbour synapses: 2 * (rows*(cols-1) + cols*(rows-1))."""
    return 2 * (rows * (cols - 1) + cols * (rows - 1))


def weights_to_vector(w: Floats, synapses: list[tuple[int, int]]) -> Floats:
    """The weights of ``synapses`` (list of (pre, post)) from a dense matrix, in that order."""
    return np.array([w[pre, post] for pre, post in synapses], dtype=float)


def vector_to_weights(values: Floats, synapses: list[tuple[int, int]], n: int) -> Floats:
    """Dense n x n matrix with ``values[k]`` at ``synapses[k]`` and zeros elsewhere."""
    w = np.zeros((n, n), dtype=float)
    for (pre, post), v in zip(synapses, values):
        w[pre, post] = v
    return w


def dense_to_compact(w: Floats, rows: int, cols: int) -> Floats:
    """Dense N x N -> the host agent's float[N, 4] (directions up, down, left, right; 0 where
    off the grid)."""
    out = np.zeros((rows * cols, 4))
    for pre in range(rows * cols):
        r, c = divmod(pre, cols)
        for d, (dr, dc) in enumerate(_DIRS):
            r2, c2 = r + dr, c + dc
            if 0 <= r2 < rows and 0 <= c2 < cols:
                out[pre, d] = w[pre, r2 * cols + c2]
    return out


def compact_to_dense(compact: Floats, rows: int, cols: int) -> Floats:
    """The host agent's float[N, 4] -> dense N x N (inverse of :func:`dense_to_compact`)."""
    n = rows * cols
    w = np.zeros((n, n))
    for pre in range(n):
        r, c = divmod(pre, cols)
        for d, (dr, dc) in enumerate(_DIRS):
            r2, c2 = r + dr, c + dc
            if 0 <= r2 < rows and 0 <= c2 < cols:
                w[pre, r2 * cols + c2] = compact[pre, d]
    return w


def validate_weights(w: Floats, rows: int, cols: int, what: str = "weights") -> Floats:
    """Check one dense weight matrix of a rows x cols grid; returns it as float64."""
    n = rows * cols
    if w.ndim != 2 or w.shape != (n, n):
        raise WeightFileError(f"{what}: expected a {n} x {n} matrix for a {rows}x{cols} grid, "
                              f"got shape {tuple(w.shape)}")
    if not np.issubdtype(w.dtype, np.number) or np.issubdtype(w.dtype, np.complexfloating):
        raise WeightFileError(f"{what}: weights must be real numbers, got dtype {w.dtype}")
    w = w.astype(np.float64)
    bad = ~np.isfinite(w)
    if bad.any():
        i, j = map(int, np.argwhere(bad)[0])
        raise WeightFileError(f"{what}: {int(bad.sum())} non-finite value(s), first at "
                              f"[{i}, {j}]; weights must be finite numbers in [0, 1]")
    out = (w < 0.0) | (w > 1.0)
    if out.any():
        i, j = map(int, np.argwhere(out)[0])
        raise WeightFileError(f"{what}: {int(out.sum())} value(s) outside [0, 1], first "
                              f"W[{i}, {j}] = {w[i, j]:.6g}; rescale the weights to [0, 1]")
    allowed = np.zeros((n, n), dtype=bool)
    for pre, post in grid_synapses(rows, cols):
        allowed[pre, post] = True
    stray = (w != 0.0) & ~allowed
    if stray.any():
        i, j = map(int, np.argwhere(stray)[0])
        raise WeightFileError(
            f"{what}: {int(stray.sum())} non-zero weight(s) between cells that are not grid "
            f"neighbours, first W[{i}, {j}] = {w[i, j]:.6g} (cells {divmod(i, cols)} and "
            f"{divmod(j, cols)} of the {rows}x{cols} grid); only 4-neighbour synapses exist")
    return w


def _square_side(n: int, path: Path) -> int:
    side = math.isqrt(n)
    if side * side != n or n < 4:
        raise WeightFileError(f"{path}: {n} neurons is not a square grid (N must be a perfect "
                              "square >= 4); save the weights from 'snan-hil train' (.npz) to "
                              "give the grid size")
    return side


def _nonempty(stack: Floats, path: Path) -> None:
    if stack.shape[0] == 0:
        raise WeightFileError(f"{path}: holds no weight sets (shape "
                              f"{' x '.join(map(str, stack.shape))}); {_ADVICE}")


def _pick(stack: Floats, set_index: int | None, path: Path) -> tuple[Floats, int, int]:
    k = stack.shape[0]
    idx = 0 if set_index is None else int(set_index)
    if not 0 <= idx < k:
        raise WeightFileError(f"{path}: --weight-set {idx} out of range, the file holds {k} weight "
                              f"set(s) (0..{k - 1})")
    return stack[idx], idx, k


def _scalar_int(value: Any, key: str, path: Path) -> int:
    arr = np.asarray(value)
    if arr.size != 1 or not np.issubdtype(arr.dtype, np.integer):
        raise WeightFileError(f"{path}: key '{key}' must be one integer, got "
                              f"{_show(arr)}")
    return int(arr.reshape(()))


def _show(arr: NDArray[Any], limit: int = 40) -> str:
    """A short text of a metadata value for a message (its dtype and first values)."""
    text = repr(arr.tolist()) if arr.dtype.kind in "biufcUSb" else f"<{arr.dtype} array>"
    if len(text) > limit:
        text = text[:limit] + "..."
    return f"{text} (dtype {arr.dtype})"


_NPY_MAGIC = b"\x93NUMPY"
_ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")
_ADVICE = "give the output of 'snan-hil train' (.npz) or a .npy of numbers"


def _sniff(path: Path) -> str:
    """"npy" or "npz" from the file's first bytes; WeightFileError for anything else."""
    if path.is_dir():
        raise WeightFileError(f"weights file {path} is a folder; {_ADVICE}")
    if not path.exists():
        raise WeightFileError(f"weights file {path} does not exist")
    if not path.is_file():
        raise WeightFileError(f"weights file {path} is not a regular file; {_ADVICE}")
    try:
        with open(path, "rb") as fh:
            head = fh.read(64)
    except OSError as exc:
        raise WeightFileError(f"cannot read weights file {path}: {exc.strerror or exc}") \
            from None
    if not head:
        raise WeightFileError(f"weights file {path} is empty (0 bytes); {_ADVICE}")
    if head.startswith(_NPY_MAGIC):
        return "npy"
    if head.startswith(_ZIP_MAGIC):
        return "npz"
    try:
        text = head.decode("utf-8")
        looks = "text (" + repr(text.split("\n")[0][:24]) + "...)"
    except UnicodeDecodeError:
        looks = "binary data of another format"
    raise WeightFileError(f"{path} is not a .npy/.npz file (it holds {looks}); {_ADVICE}")


def _load_error(path: Path, exc: BaseException, member: str | None = None) -> WeightFileError:
    """One line for a numpy/zip failure while reading ``member`` (None: the .npy)."""
    where = f"member '{member}' of {path}" if member else str(path)
    text = str(exc)
    if "allow_pickle" in text or "pickle" in text.lower():
        return WeightFileError(f"{where} holds Python objects (a pickled array), not numbers; "
                               "snan-hil never unpickles files: save numeric arrays "
                               "(np.float64)")
    if isinstance(exc, (zipfile.BadZipFile, zlib.error, EOFError)) or "CRC" in text:
        return WeightFileError(f"{where} is damaged ({type(exc).__name__}: {text}); the file "
                               "is corrupt: restore a copy or run 'snan-hil train' again")
    return WeightFileError(f"{where} cannot be read as a numpy array ({type(exc).__name__}: "
                           f"{text}); the file is damaged or not numpy's format")


_READ_ERRORS = (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error, KeyError,
                TypeError)


def _read_npz(path: Path) -> dict[str, NDArray[Any]]:
    try:
        z = np.load(path, allow_pickle=False)
    except _READ_ERRORS as exc:
        raise _load_error(path, exc) from None
    data = {}
    with z:
        for key in z.files:
            try:
                data[key] = z[key]
            except _READ_ERRORS as exc:
                raise _load_error(path, exc, key) from None
    return data


def _seeds(value: NDArray[Any], k: int, path: Path) -> list[int]:
    seeds = np.asarray(value).ravel()
    if not np.issubdtype(seeds.dtype, np.integer) or seeds.size != k:
        raise WeightFileError(f"{path}: key 'seeds' must be {k} integers (one per weight set), "
                              f"got {_show(seeds)}")
    return [int(s) for s in seeds]


PROVENANCE_MEMBERS = ("provenance",)
"""Members of a ``snan-hil train`` file that record how it was made (tool version, wall time),
not what it holds: :func:`weights_fingerprint` leaves them out."""


def weights_fingerprint(path: str | os.PathLike[str]) -> str:
    """SHA-256 (16 hex digits) of what a weights file holds: every array of an ``.npz`` (name,
    dtype, shape, bytes; sorted by name) but its provenance (:data:`PROVENANCE_MEMBERS`), or
    the array of an ``.npy``. Training is deterministic, so training again with the same
    inputs gives the same fingerprint although the file's bytes differ (zip time stamps, wall
    time): a run keyed by it can be resumed on the re-trained file. Raises
    :class:`WeightFileError` (one line) when the file cannot be read."""
    path = Path(path)
    if _sniff(path) == "npz":
        data = _read_npz(path)
    else:
        try:
            data = {"": np.load(path, allow_pickle=False)}
        except _READ_ERRORS as exc:
            raise _load_error(path, exc) from None
    h = hashlib.sha256()
    for key in sorted(k for k in data if k not in PROVENANCE_MEMBERS):
        arr = np.ascontiguousarray(data[key])
        h.update(f"{key}|{arr.dtype.str}|{arr.shape}|".encode())
        h.update(arr.tobytes())
    return h.hexdigest()[:16]


_Picked = tuple[Floats, int, int, int, int]
"""What a loader of one format gives :func:`load_weight_set`: (W, set index, number of sets,
grid rows, grid cols)."""


def _npz_grid(data: dict[str, NDArray[Any]], n: int, path: Path) -> tuple[int, int]:
    if "grid" not in data:
        side = _square_side(n, path)
        return side, side
    grid = np.asarray(data["grid"]).ravel()
    if grid.size != 2 or not np.issubdtype(grid.dtype, np.integer) or (grid < 1).any():
        raise WeightFileError(f"{path}: 'grid' must be two positive integers (rows, "
                              f"cols), got {_show(grid)}")
    return int(grid[0]), int(grid[1])


def _npz_cells(data: dict[str, NDArray[Any]], meta: dict[str, Any], rows: int, cols: int,
               path: Path) -> None:
    for key in ("start", "goal", "cycles"):
        if key in data:
            meta[key] = _scalar_int(data[key], key, path)
    for key in ("start", "goal"):
        if key in meta and not 0 <= meta[key] < rows * cols:
            raise WeightFileError(f"{path}: '{key}' cell {meta[key]} is outside the "
                                  f"{rows}x{cols} grid (0..{rows * cols - 1})")
    if meta.get("cycles", 1) < 1:
        raise WeightFileError(f"{path}: 'cycles' must be >= 1, got {meta['cycles']}")


def _npz_config(raw_value: NDArray[Any], path: Path) -> Any:
    raw = np.asarray(raw_value)
    if raw.dtype.kind not in "US" or raw.size != 1:
        raise WeightFileError(f"{path}: key 'config' must be one text (the training "
                              f"config as JSON), got {_show(raw)}")
    text = str(raw.reshape(()))
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def _load_npz_set(path: Path, set_index: int | None, meta: dict[str, Any]) -> _Picked:
    data = _read_npz(path)
    if "weights" not in data:
        raise WeightFileError(f"{path}: .npz without a 'weights' array (keys: "
                              f"{', '.join(sorted(data)) or 'none'}); expected the output "
                              "of 'snan-hil train'")
    stack = np.asarray(data["weights"])
    if stack.ndim == 2:
        stack = stack[None]
    if stack.ndim != 3:
        raise WeightFileError(f"{path}: 'weights' must be K x N x N, got shape "
                              f"{tuple(stack.shape)}")
    _nonempty(stack, path)
    rows, cols = _npz_grid(data, stack.shape[-1], path)
    w, idx, k = _pick(stack, set_index, path)
    _npz_cells(data, meta, rows, cols, path)
    if "seeds" in data:
        meta["seeds"] = _seeds(data["seeds"], k, path)
        meta["seed"] = meta["seeds"][idx]
    if "config" in data:
        meta["config"] = _npz_config(data["config"], path)
    return w, idx, k, rows, cols


def _load_npy_set(path: Path, set_index: int | None) -> _Picked:
    try:
        loaded = np.load(path, allow_pickle=False)
    except _READ_ERRORS as exc:
        raise _load_error(path, exc) from None
    if loaded.ndim == 2:
        if set_index not in (None, 0):
            raise WeightFileError(f"{path}: holds one weight matrix; --weight-set {set_index} "
                                  "needs a K x N x N stack")
        stack = loaded[None]
    elif loaded.ndim == 3:
        stack = loaded
    else:
        raise WeightFileError(f"{path}: expected an N x N matrix or a K x N x N stack, got "
                              f"shape {tuple(loaded.shape)}")
    if stack.shape[1] != stack.shape[2]:
        raise WeightFileError(f"{path}: weight matrices must be square (N x N), got "
                              f"{stack.shape[1]} x {stack.shape[2]}")
    _nonempty(stack, path)
    side = _square_side(stack.shape[-1], path)
    w, idx, k = _pick(stack, set_index, path)
    return w, idx, k, side, side


def load_weight_set(path: str | os.PathLike[str],
                    set_index: int | None = None) -> tuple[Floats, dict[str, Any]]:
    """Load one dense weight matrix and its metadata from ``.npy`` or ``.npz``.

    Returns ``(W, meta)``: ``W`` float64 N x N, validated; ``meta`` has ``path``, ``format``,
    ``set_index``, ``n_sets``, ``grid`` [rows, cols], ``n_synapses`` and, from an ``.npz``,
    ``start``, ``goal``, ``seed`` (of the chosen set), ``seeds``, ``config`` (parsed JSON or the
    raw text), ``cycles`` where present. Raises :class:`WeightFileError` (one line) on any
    problem: a missing file, a folder, an empty file, text or another format, pickled
    (object) arrays (never unpickled), a damaged member, metadata of the wrong type, an
    empty stack, and the value checks of :func:`validate_weights`.
    """
    path = Path(path)
    kind = _sniff(path)
    meta: dict[str, Any] = {"path": str(path)}
    if kind == "npz":
        meta["format"] = "npz"
        w, idx, k, rows, cols = _load_npz_set(path, set_index, meta)
    else:
        meta["format"] = "npy"
        w, idx, k, rows, cols = _load_npy_set(path, set_index)
    w = validate_weights(np.asarray(w), rows, cols, what=f"{path} (set {idx})")
    meta.update({"set_index": idx, "n_sets": k, "grid": [rows, cols],
                 "n_synapses": synapse_count(rows, cols)})
    return w, meta
