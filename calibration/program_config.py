"""The settings of one programming run (:class:`ProgramConfig`).

Its own module because the programmer (:mod:`snan_hil.calibration.programmer`, which runs with
it) and the report (:mod:`snan_hil.calibration.program_report`, which records it) both take it;
:mod:`~snan_hil.calibration.programmer` re-exports it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Annotated, Any

from annotated_types import Ge, Gt, Interval

from snan_hil.calibration.mapping import WeightMap
from snan_hil.calibration.wv import WVConfig
from snan_hil.config import loader as configio

__all__ = ["ProgramConfig"]


@dataclass(frozen=True)
class ProgramConfig:
    """Settings of one programming run (conductances in S, voltages in V)."""

    wv: WVConfig = field(default_factory=WVConfig)
    weight_map: WeightMap = field(default_factory=WeightMap)
    spares: bool = True               # move failing synapses to spare cells
    max_attempts: Annotated[int, Ge(1)] = 3   # cells tried per synapse (1 + relocations)
    screen: bool = True
    screen_g_min_s: Annotated[float, Ge(0)] = 15e-6   # below: stuck low / open, S
    #: above: stuck high / shorted (compliance at 1.4 V), S
    screen_g_max_s: Annotated[float, Gt(0)] = 1.4e-3
    calibrate: bool = True
    calib_reads: Annotated[int, Ge(1)] = 8    # reads averaged per read-chain calibration read
    verify_reads: Annotated[int, Ge(1)] = 3   # reads averaged for the final conductance
    #: fraction of the compliance current a write may drive
    compliance_margin: Annotated[float, Interval(gt=0, le=1)] = 0.95
    max_resyncs: Annotated[int, Ge(0)] = 3    # board resets survived per run (resync policy)
    fresh_layout: bool = False        # ignore an existing layout file
    checkpoint_s: Annotated[float, Ge(0)] = 1.0
    """Least wall time between two saves of the layout during programming (0: after every
    synapse). Each save is a full atomic rewrite (JSON, fsync, rename: ~10 ms, more on a busy
    disk); the layout is always saved before the first pulse, at the end, and when the run
    stops on an error or interrupt, so only a hard kill loses up to this much progress (a rerun
    re-verifies those cells)."""

    def __post_init__(self) -> None:
        configio.check_bounds(self)

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["wv"] = self.wv.to_dict()
        d["weight_map"] = self.weight_map.to_dict()
        return d

    def within(self, limit_v: float) -> ProgramConfig:
        """This config with its write-and-verify amplitudes (``wv.v_max``, ``fine_v_max``,
        ``v_floor``; V) at most ``limit_v`` (a board session's write limit)."""
        wv = self.wv
        if wv.v_max <= limit_v:
            return self
        return dataclasses.replace(self, wv=dataclasses.replace(
            wv, v_max=limit_v, fine_v_max=min(wv.fine_v_max, limit_v),
            v_floor=min(wv.v_floor, limit_v)))
