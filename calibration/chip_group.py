"""One network over a group of chips: which chip holds which input neuron's synapses.

A grid SNAN's input->motor synapses are the directed 4-neighbour pairs ``pre -> post``
(:func:`~snan_hil.calibration.weights_io.grid_synapses`): 120 on the 6x6 field, 360 on the
paper's 10x10 field, more than one 32x8 crossbar (256 cells) holds. The agent's decision
window is that of **one** input neuron, the cell it stands on (``MotorBackend.motor_window``,
host/agent.py): the window drives that neuron's rows and reads its candidates' cells, nothing
else. So a window touches one chip exactly when every input neuron's synapses stay on one
chip — which any partition of the input neurons gives. :func:`window_chips` states it for a
plan; the tests check it for every input neuron of the 10x10 field.

:func:`plan_group` splits the input neurons into contiguous runs (row-major order) with
synapse counts as even as the neurons allow, one run a chip; each chip places its share as
one chip places a whole network (:meth:`~snan_hil.calibration.layout.Layout.place`: block
row-major from row 0, the rows below are its spares). Its refusals are one line
(:class:`~snan_hil.common.errors.UserError`): a group too small for the network with at least
:data:`MIN_SPARE_ROWS` spare rows per chip.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from snan_hil.calibration.bench import CellBench
from snan_hil.calibration.weights_io import grid_synapses
from snan_hil.common.errors import UserError

__all__ = ["MIN_SPARE_ROWS", "GroupPlan", "GroupBench", "plan_group", "window_chips",
           "min_chips", "merge_programming"]

MIN_SPARE_ROWS = 1
"""Spare rows each chip keeps below its block (a stated choice: a bad cell moves to a spare
of its own chip, so a pre's synapses stay together; one row of 8 cells is what the 6x6 task's
first failures used, docs/calibration.md)."""


@dataclass(frozen=True)
class GroupPlan:
    """Input neurons per chip of a group: ``shares[k]`` the sorted input neurons whose
    synapses chip ``k`` holds; ``grid`` (rows, cols) of the field, ``array`` (rows, cols) of
    each chip's crossbar."""

    grid: tuple[int, int]
    array: tuple[int, int]
    shares: tuple[tuple[int, ...], ...]

    @property
    def chips(self) -> int:
        return len(self.shares)

    def chip_of(self, pre: int) -> int:
        """The chip holding input neuron ``pre``'s synapses (KeyError if none)."""
        for k, share in enumerate(self.shares):
            if pre in share:
                return k
        raise KeyError(f"input neuron {pre} is on no chip of the group")

    def synapses(self, chip: int) -> int:
        """Synapses chip ``chip`` holds."""
        keep = set(self.shares[chip])
        return sum(1 for pre, _post in grid_synapses(*self.grid) if pre in keep)

    def block_rows(self, chip: int) -> int:
        return math.ceil(self.synapses(chip) / self.array[1])

    def spare_cells(self, chip: int) -> int:
        """Cells of chip ``chip`` below its block (its spares)."""
        return (self.array[0] - self.block_rows(chip)) * self.array[1]

    def to_dict(self) -> dict[str, object]:
        return {"grid": list(self.grid), "array": list(self.array),
                "chips": [{"pres": [min(s), max(s)], "inputs": len(s),
                           "synapses": self.synapses(k), "block_rows": self.block_rows(k),
                           "spare_cells": self.spare_cells(k)}
                          for k, s in enumerate(self.shares)]}


def min_chips(grid: tuple[int, int], array: tuple[int, int],
              spare_rows: int = MIN_SPARE_ROWS) -> int:
    """The fewest chips of ``array`` cells that hold the grid's synapses with ``spare_rows``
    spare rows each (a lower bound from the cell count; :func:`plan_group` checks the split)."""
    per_chip = (array[0] - spare_rows) * array[1]
    if per_chip <= 0:
        raise UserError(f"a {array[0]}x{array[1]} crossbar has no room left after "
                        f"{spare_rows} spare rows")
    return max(1, math.ceil(len(grid_synapses(*grid)) / per_chip))


def plan_group(grid: tuple[int, int], array: tuple[int, int], chips: int,
               spare_rows: int = MIN_SPARE_ROWS) -> GroupPlan:
    """Split the grid's input neurons over ``chips`` chips of ``array`` (see module doc).
    UserError (one line) when a chip's share leaves it fewer than ``spare_rows`` spare rows."""
    if chips < 1:
        raise UserError(f"a chip group needs at least one chip, got {chips}")
    pairs = grid_synapses(*grid)
    fan_out = Counter(pre for pre, _post in pairs)
    n_in = grid[0] * grid[1]
    if chips > n_in:
        raise UserError(f"{chips} chips for {n_in} input neurons: a chip would hold none; "
                        "give fewer chips")
    total = len(pairs)
    split: list[list[int]] = [[] for _ in range(chips)]
    cum = 0
    for pre in range(n_in):                 # the chip of a neuron's synapses' midpoint
        split[min(chips - 1, int((cum + fan_out[pre] / 2) * chips / total))].append(pre)
        cum += fan_out[pre]
    if any(not s for s in split):
        raise UserError(f"{chips} chips for {n_in} input neurons leave a chip empty; give "
                        "fewer chips")
    shares = [tuple(s) for s in split]
    plan = GroupPlan((int(grid[0]), int(grid[1])), (int(array[0]), int(array[1])),
                     tuple(shares))
    need = min_chips(grid, array, spare_rows)
    for k in range(plan.chips):
        if plan.block_rows(k) > array[0] - spare_rows:
            raise UserError(
                f"{len(pairs)} synapses of the {grid[0]}x{grid[1]} network do not fit "
                f"{chips} chip(s) of {array[0]}x{array[1]} cells with {spare_rows} spare "
                f"row(s) each (chip {k} would need {plan.block_rows(k)} rows); give at least "
                f"{need} chips")
    return plan


def window_chips(plan: GroupPlan, pre: int) -> set[int]:
    """The chips the decision window of input neuron ``pre`` touches: those holding a synapse
    ``pre -> post`` (one chip under any :class:`GroupPlan`; stated so a test can check it)."""
    return {plan.chip_of(p) for p, _post in grid_synapses(*plan.grid) if p == pre}


@dataclass
class GroupBench:
    """The benches of a chip group for one unit of a job (the job runner's,
    :mod:`snan_hil.lab.group_run`: each chip's bench with its run's recorder, journal and
    control channel): ``benches[k]`` chip ``k``'s."""

    benches: Sequence[CellBench]

    @property
    def chips(self) -> int:
        return len(self.benches)

    @property
    def array(self) -> tuple[int, int]:
        """The crossbar (rows, cols) every chip of the group has (UserError when they
        differ: one plan places every chip's share alike)."""
        arrays = {(int(b.info.rows), int(b.info.cols)) for b in self.benches}
        if len(arrays) != 1:
            raise UserError("the chips of a group have crossbars of different sizes ("
                            + ", ".join(f"{r}x{c}" for r, c in sorted(arrays))
                            + "): give chips of one kind")
        return arrays.pop()

    def plan(self, grid: tuple[int, int]) -> GroupPlan:
        """:func:`plan_group` of ``grid`` over these chips."""
        return plan_group(grid, self.array, self.chips)


_SUMMED = ("cells", "ok", "failed", "programmed", "stage1_ok", "pulses_total", "relocated",
           "bad_cells", "host_pulses", "firmware_pulses", "virtual_s", "wall_s")


def merge_programming(per_chip: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """One programming summary of a group's chips (each a program report's ``summary`` with
    ``all_ok``): counts, pulses and times summed (a None anywhere: None), ``all_ok`` of all,
    ``pulses_match`` of all, ``chips`` the per-chip summaries."""
    out: dict[str, Any] = {}
    for key in _SUMMED:
        values = [c.get(key) for c in per_chip]
        out[key] = None if any(v is None for v in values) else sum(values)
    out["all_ok"] = all(bool(c.get("all_ok")) for c in per_chip)
    matches = [c.get("pulses_match") for c in per_chip]
    out["pulses_match"] = None if any(m is None for m in matches) else all(matches)
    out["chips"] = [dict(c) for c in per_chip]
    return out
