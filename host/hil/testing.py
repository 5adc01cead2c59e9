"""Helpers for the HIL tests and benchmarks: a small trained weight file and a programmed
emulator chip in a temporary folder (the emulator's state file is always given explicitly, so
the user's chip is never touched)."""

from __future__ import annotations

import os
from typing import Any
from pathlib import Path

from snan_hil.calibration.layout import Layout
from snan_hil.calibration.programmer import program_weights
from snan_hil.calibration.testing import session_of
from snan_hil.calibration.weights_io import load_weight_set
from snan_hil.host.hil.config import HilConfig, load_hil_config
from snan_hil.host.hil.train import save_weights, train_sets
from snan_hil.protocol.client import BoardClient

STATE_ENV = "SNAN_HIL_EMU_STATE"


def small_hil_config(max_steps: int = 30) -> HilConfig:
    """The 6x6 HIL config with a short step limit (failed launches stay cheap)."""
    return load_hil_config(None, [f"grid.max_steps={max_steps}"])


def make_weights(path: str | os.PathLike, *, sets: int = 2, cycles: int = 2, seed: int = 1,
                 hil: HilConfig | None = None) -> Path:
    """Train ``sets`` small weight sets and save them (.npz)."""
    hil = hil or small_hil_config()
    res = train_sets(hil.train_config(), sets=sets, cycles=cycles, seed=seed,
                     start=hil.task.start, goal=hil.task.goal)
    return save_weights(res, path)


def program_set(client: BoardClient, weights_path: str | os.PathLike, set_index: int,
                layout_path: str | os.PathLike) -> Layout:
    """Program weight set ``set_index`` into the chip behind ``client``; returns the layout."""
    w, meta = load_weight_set(weights_path, set_index)
    result = program_weights(session_of(client, layout_path), w, meta)
    if not result.all_ok:
        raise RuntimeError(f"programming set {set_index} left cells outside their window")
    return result.layout


def program_session(client: BoardClient, task: Any, k: int, layout_path: str | os.PathLike
                    ) -> Layout:
    """Two-stage write-and-verify of session ``k``'s initial weights of the learning task
    ``task`` (a :class:`~snan_hil.host.hil.learn_arms.LearnTask`) into the chip behind
    ``client``; the layout (written to ``layout_path``)."""
    import numpy as np
    from snan_hil.calibration.weights_io import compact_to_dense
    grid = (task.cfg.grid.rows, task.cfg.grid.cols)
    dense = compact_to_dense(np.where(task.nbr >= 0, task.initial(k), 0.0), *grid)
    return program_weights(session_of(client, layout_path), dense,
                           {"grid": list(grid), "session": k}).layout
