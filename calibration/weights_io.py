"""Load and validate the input->motor weights of a grid SNAN for programming into the crossbar.

Accepted files (``W[pre, post]`` is the weight of the synapse from input neuron ``pre`` to motor
neuron ``post``; neurons are grid cells numbered row-major, ``cell = row * cols + col``):

* ``.npy`` with a dense ``N x N`` matrix (N a perfect square: a square grid of side sqrt(N)),
  or a stack ``K x N x N`` of weight sets (pick one with ``set_index``);
* ``.npz`` written by ``snan-hil train``: ``weights`` (K x N x N float), ``grid`` (rows, cols),
  and optionally ``start``, ``goal``, ``seeds`` (K ints), ``config`` (JSON text), ``cycles``.

Checks: shape, finite values, range [0, 1], and adjacency (non-zero weights only between
4-neighbours of the grid; self-connections are not synapses). Any failure raises
:class:`WeightFileError` (a :class:`~snan_hil.errors.UserError`) with one line naming the file
and the problem. The synapses to program are *all* directed neighbour pairs (a zero weight is a
synapse at G_min), so a 6x6 grid gives exactly 120 of them — the paper's 15x8 block.
"""

from __future__ import annotations

import json
import math
import zipfile
import os
from pathlib import Path
from typing import Any

import numpy as np

from snan_hil.errors import UserError

__all__ = ["WeightFileError", "load_weight_set", "validate_weights", "grid_synapses",
           "synapse_count", "weights_to_vector", "vector_to_weights", "dense_to_compact",
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


def weights_to_vector(w: np.ndarray, synapses: list[tuple[int, int]]) -> np.ndarray:
    """The weights of ``synapses`` (list of (pre, post)) from a dense matrix, in that order."""
    return np.array([w[pre, post] for pre, post in synapses], dtype=float)


def vector_to_weights(values: np.ndarray, synapses: list[tuple[int, int]], n: int) -> np.ndarray:
    """Dense n x n matrix with ``values[k]`` at ``synapses[k]`` and zeros elsewhere."""
    w = np.zeros((n, n), dtype=float)
    for (pre, post), v in zip(synapses, values):
        w[pre, post] = v
    return w


def dense_to_compact(w: np.ndarray, rows: int, cols: int) -> np.ndarray:
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


def compact_to_dense(compact: np.ndarray, rows: int, cols: int) -> np.ndarray:
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


def validate_weights(w: np.ndarray, rows: int, cols: int, what: str = "weights") -> np.ndarray:
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


def _pick(stack: np.ndarray, set_index: int | None, path: Path) -> tuple[np.ndarray, int, int]:
    k = stack.shape[0]
    idx = 0 if set_index is None else int(set_index)
    if not 0 <= idx < k:
        raise WeightFileError(f"{path}: --weight-set {idx} out of range, the file holds {k} weight "
                              f"set(s) (0..{k - 1})")
    return stack[idx], idx, k


def _scalar_int(value: Any, key: str, path: Path) -> int:
    arr = np.asarray(value)
    if arr.size != 1 or not np.issubdtype(arr.dtype, np.integer):
        raise WeightFileError(f"{path}: key '{key}' must be one integer, got {arr.tolist()!r}")
    return int(arr.reshape(()))


def load_weight_set(path: str | os.PathLike[str],
                    set_index: int | None = None) -> tuple[np.ndarray, dict]:
    """Load one dense weight matrix and its metadata from ``.npy`` or ``.npz``.

    Returns ``(W, meta)``: ``W`` float64 N x N, validated; ``meta`` has ``path``, ``format``,
    ``set_index``, ``n_sets``, ``grid`` [rows, cols], ``n_synapses`` and, from an ``.npz``,
    ``start``, ``goal``, ``seed`` (of the chosen set), ``seeds``, ``config`` (parsed JSON or the
    raw text), ``cycles`` where present. Raises :class:`WeightFileError` on any problem.
    """
    path = Path(path)
    if not path.is_file():
        raise WeightFileError(f"weights file {path} does not exist")
    meta: dict[str, Any] = {"path": str(path)}
    try:
        loaded = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
        raise WeightFileError(f"{path}: not a readable .npy/.npz file ({exc})") from None
    if isinstance(loaded, np.lib.npyio.NpzFile):
        with loaded as z:
            meta["format"] = "npz"
            data = {k: z[k] for k in z.files}
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
        n = stack.shape[-1]
        if "grid" in data:
            grid = np.asarray(data["grid"]).ravel()
            if grid.size != 2 or not np.issubdtype(grid.dtype, np.integer) or (grid < 1).any():
                raise WeightFileError(f"{path}: 'grid' must be two positive integers (rows, "
                                      f"cols), got {grid.tolist()!r}")
            rows, cols = int(grid[0]), int(grid[1])
        else:
            rows = cols = _square_side(n, path)
        w, idx, k = _pick(stack, set_index, path)
        for key in ("start", "goal", "cycles"):
            if key in data:
                meta[key] = _scalar_int(data[key], key, path)
        if "seeds" in data:
            seeds = np.asarray(data["seeds"]).ravel()
            meta["seeds"] = [int(s) for s in seeds]
            if len(seeds) == k:
                meta["seed"] = int(seeds[idx])
        if "config" in data:
            raw = np.asarray(data["config"])
            text = str(raw.reshape(())) if raw.size == 1 else str(raw.tolist())
            try:
                meta["config"] = json.loads(text)
            except json.JSONDecodeError:
                meta["config"] = text
    elif isinstance(loaded, np.ndarray):
        meta["format"] = "npy"
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
        rows = cols = _square_side(stack.shape[-1], path)
        w, idx, k = _pick(stack, set_index, path)
    else:  # pragma: no cover - np.load returns one of the two
        raise WeightFileError(f"{path}: unsupported content")
    w = validate_weights(np.asarray(w), rows, cols, what=f"{path} (set {idx})")
    meta.update({"set_index": idx, "n_sets": k, "grid": [rows, cols],
                 "n_synapses": synapse_count(rows, cols)})
    return w, meta
