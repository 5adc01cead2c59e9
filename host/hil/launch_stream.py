"""Each launch of the agent as an event of the run's ``launches`` stream (the fields and units
of :data:`snan_hil.records.documents.STREAMS`): what ``snan-hil run`` and ``snan-hil compare``
emit per launch, what ``snan-hil watch`` draws (the 6 x 6 grid with the agent's path and the
calcium per cell, the running medians per scenario) and what ``history --export documents``
exports.

The calcium is that of every grid cell's astrocyte after the launch, from the trial's traced
re-run (:func:`~snan_hil.host.calcium_trace.calcium_trace`: the calcium depends only on the
path and the trial's input spikes, so a hardware launch and a software one get it the same
way); compiled, about 5 ms for a 100-step launch of the 6 x 6 task (the plain reference
took ~1 s), small beside the launch itself.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from snan_hil.host.calcium_trace import calcium_trace
from snan_hil.host.config import SnanConfig
from snan_hil.host.hil.runner import LaunchResult

__all__ = ["STREAM", "launch_event", "launch_feed", "LaunchSink"]

STREAM = "launches"

LaunchSink = Callable[[str, dict[str, Any]], object]
"""``sink(stream, data)``: where the events go (a run publisher's ``event``)."""


def launch_event(scenario: str, set_index: int, launch: LaunchResult, cfg: SnanConfig, *,
                 seed: int) -> dict[str, Any]:
    """The ``launches`` event of ``launch`` (weight set ``set_index``, a run seeded ``seed``,
    launched with ``cfg``: the scenario's launch config): scenario, set, launch number, steps,
    success, the visited cells (``path``, grid cell indices row-major), the astrocyte calcium
    of each of the rows x cols cells after the launch (``calcium_final``, model units) and
    the threshold ``ca_thr`` above which an astrocyte acts."""
    trace = calcium_trace(cfg, launch.path, seed=seed, trial=launch.trial)
    return {"scenario": scenario, "set_index": int(set_index), "launch": int(launch.launch),
            "steps": int(launch.steps), "success": bool(launch.success),
            "path": [int(c) for c in launch.path],
            "calcium_final": [float(x) for x in trace.ca[-1]],
            "grid_rows": int(cfg.grid.rows), "grid_cols": int(cfg.grid.cols),
            "ca_thr": float(trace.ca_thr)}


def launch_feed(sink: LaunchSink, scenario: str, set_index: int, cfg: SnanConfig, *,
                seed: int, after: Callable[[], object] | None = None
                ) -> Callable[[LaunchResult], None]:
    """An ``on_launch`` callback (:func:`~snan_hil.host.hil.runner.run_scenario`) sending
    each launch to ``sink`` as it ends; ``after()`` then (e.g. the recorder's flush, so a
    live view sees the launch at once)."""
    def feed(launch: LaunchResult) -> None:
        sink(STREAM, launch_event(scenario, set_index, launch, cfg, seed=seed))
        if after is not None:
            after()
    return feed
