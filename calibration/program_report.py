"""The record of a programming run: the report's format, its entries, and how it is written.

The report (JSON, ``snan-hil-program-report/1``; fields in docs/calibration.md) records what a
run did: the board and the session it ran in (:meth:`~snan_hil.board.session.BoardSession.
snapshot`), the configuration, the read chain, the screen, the response model, the pulse
ledger, every synapse's cell entry and a summary. :func:`write_report` keeps a failed run
from hiding or losing the last complete report (docs/durability.md).
"""

from __future__ import annotations

import json
import logging
import math
import os
import statistics
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from snan_hil.common.version import __version__
from snan_hil.board.files import previous_report_path
from snan_hil.calibration.board_io import PulseLedger
from snan_hil.calibration.layout import Layout, Synapse
from snan_hil.calibration.program_config import ProgramConfig
from snan_hil.calibration.wv import CellOutcome, ResponseModel
from snan_hil.files.atomicio import atomic_write_json

if TYPE_CHECKING:
    from snan_hil.board.session import BoardSession

__all__ = ["REPORT_FORMAT", "WEIGHT_META_KEYS", "finite", "cell_entry", "build_report",
           "failed_report", "write_report", "write_failed_report", "previous_report_path"]

log = logging.getLogger(__name__)

REPORT_FORMAT = "snan-hil-program-report/1"
WEIGHT_META_KEYS = ("path", "format", "set_index", "n_sets", "grid", "seed", "start", "goal")
"""What a report records of the weights file (from ``load_weight_set``'s meta)."""


def finite(x: float | None, digits: int = 9) -> float | None:
    """``x`` rounded to ``digits`` significant digits, None for None / NaN / inf (JSON)."""
    if x is None or not math.isfinite(x):
        return None
    return float(f"{x:.{digits}g}")


def cell_entry(syn: Synapse, weight: float, o: CellOutcome,
               attempts: list[dict[str, Any]]) -> dict[str, Any]:
    """The report's entry of one programmed synapse: its cell, target and final conductance
    (S), pulses of both stages, and the cells it failed on before (``attempts``)."""
    failed_pulses = sum(a["pulses"] for a in attempts[:len(attempts) - (0 if o.ok else 1)]) \
        if attempts else 0
    return {
        "row": syn.row, "col": syn.col, "weight": weight, "target_s": finite(o.target_s),
        "final_s": finite(o.final_s), "rel_error": finite(o.rel_error, 6),
        "pulses_stage1": o.pulses_stage1, "pulses_stage2": o.pulses_stage2, "ok": o.ok,
        "pre": syn.pre, "post": syn.post, "initial_s": finite(o.initial_s),
        "stage1_s": finite(o.stage1_s), "stage1_ok": o.stage1_ok,
        "stage1_rel_error": finite(o.stage1_s / o.target_s - 1.0, 6),
        "pulses_total": o.pulses + failed_pulses, "rounds": o.rounds,
        "not_applied": o.not_applied, "reason": o.reason,
        "moved_from": [list(m) for m in syn.moved_from], "failed_attempts": attempts
        if o.ok else attempts[:-1],
    }


def _summary(done: list[dict[str, Any]], layout: Layout, ledger: PulseLedger,
             virtual_s: float | None, wall_s: float, fw_delta: int | None) -> dict[str, Any]:
    ok = [e for e in done if e["ok"]]
    errs = [abs(e["rel_error"]) for e in done if e["rel_error"] is not None]
    pulses = [e["pulses_total"] for e in done]
    host_pulses = ledger.host_pulses
    return {
        "cells": layout.n_synapses,
        "ok": len(ok),
        "failed": len(done) - len(ok),
        "median_abs_rel_error": finite(statistics.median(errs), 6) if errs else None,
        "median_pulses": statistics.median(pulses) if pulses else None,
        "virtual_s": finite(virtual_s, 6),
        "wall_s": finite(wall_s, 6),
        # extras
        "programmed": len(done),
        "stage1_ok": sum(1 for e in done if e["stage1_ok"]),
        "max_abs_rel_error": finite(max(errs), 6) if errs else None,
        "mean_pulses": finite(statistics.fmean(pulses), 6) if pulses else None,
        "max_pulses": max(pulses) if pulses else None,
        "pulses_total": ledger.confirmed,
        "relocated": sum(1 for s in layout.synapses if s.moved_from),
        "bad_cells": len(layout.bad_cells),
        "host_pulses": host_pulses,
        "firmware_pulses": fw_delta,
        "pulses_match": None if fw_delta is None else fw_delta == host_pulses,
    }


def build_report(session: BoardSession, entries: list[dict[str, Any] | None], layout: Layout,
                 cfg: ProgramConfig, meta: Mapping[str, Any], ledger: PulseLedger,
                 model: ResponseModel, state: Mapping[str, Any], *, virtual_s: float | None,
                 wall_s: float) -> dict[str, Any]:
    """The report of a run that reached the board (``state``: complete, error, screen,
    link counters, board resets, the board's pulse counter delta ``fw_delta``)."""
    done = [e for e in entries if e is not None]
    fw_delta = state.get("fw_delta")
    return {
        "format": REPORT_FORMAT,
        "version": __version__,
        "complete": bool(state.get("complete")),
        "error": state.get("error"),
        "port": session.port,
        "board": session.identity.to_dict(),
        "weights": {k: meta.get(k) for k in WEIGHT_META_KEYS if k in meta},
        "config": cfg.to_dict(),
        "read_chain": layout.read_chain.to_dict() if layout.read_chain else None,
        "screen": state.get("screen"),
        "response_model": model.state(),
        "ledger": ledger.to_dict(),
        "link": state.get("link"),
        "board_resets": state.get("board_resets", 0),
        "bad_cells": [{"row": r, "col": c, "reason": why}
                      for (r, c), why in sorted(layout.bad_cells.items())],
        "summary": _summary(done, layout, ledger, virtual_s, wall_s, fw_delta),
        "cells": done,
        "session": session.snapshot(),
    }


def failed_report(error: BaseException | str, *, config: ProgramConfig, port: str = "",
                  meta: Mapping[str, Any] | None = None,
                  wall_s: float | None = None) -> dict[str, Any]:
    """The report of a run that failed before programming started (no board state known):
    ``complete: false``, the error, the run's ``config``, no cells. Same format marker and
    top-level keys as a full report, so readers need no special case."""
    meta = meta or {}
    err = error if isinstance(error, str) else (
        "interrupted" if isinstance(error, KeyboardInterrupt)
        else f"{type(error).__name__}: {error}")
    return {
        "format": REPORT_FORMAT, "complete": False, "error": err, "port": port, "board": None,
        "weights": {k: meta.get(k) for k in WEIGHT_META_KEYS if k in meta},
        "config": config.to_dict(), "read_chain": None, "screen": None,
        "response_model": None, "ledger": None, "link": None, "board_resets": 0,
        "bad_cells": [],
        "summary": {"cells": None, "ok": 0, "failed": 0, "median_abs_rel_error": None,
                    "median_pulses": None, "virtual_s": None, "wall_s": finite(wall_s, 6),
                    "programmed": 0, "host_pulses": 0, "firmware_pulses": None,
                    "pulses_match": None},
        "cells": [], "session": None,
    }


def _is_report(path: Path, *, complete: bool | None = None) -> bool:
    """Whether ``path`` holds a programming report (and, given, one with that ``complete``)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return False
    return (isinstance(data, dict) and data.get("format") == REPORT_FORMAT
            and (complete is None or bool(data.get("complete")) == complete))


def write_report(report_path: str | os.PathLike[str], report: Mapping[str, Any]) -> None:
    """Write ``report`` to ``report_path`` atomically. The path always holds the last run's
    report (so no earlier ``complete: true`` report stays beside a layout a failed run has
    changed), and a failed run never loses the last good one: when ``report`` is incomplete
    and ``report_path`` holds a complete report, that one is first moved to
    :func:`previous_report_path` (replacing an older report there; a file there that is not a
    programming report is left alone and the complete report is then overwritten, logged).
    Raises OSError."""
    p = Path(report_path)
    if not report.get("complete") and _is_report(p, complete=True):
        prev = previous_report_path(p)
        if not prev.exists() or _is_report(prev):
            os.replace(p, prev)
            log.info("kept the last complete report as %s", prev)
        else:
            log.error("%s is not a programming report: the complete report %s is replaced "
                      "by this run's incomplete one", prev, p)
    atomic_write_json(p, report, indent=1, allow_nan=False)


def write_failed_report(report_path: str | os.PathLike[str], error: BaseException | str,
                        **kwargs: Any) -> None:
    """Write :func:`failed_report` to ``report_path`` with :func:`write_report` (an earlier
    complete report is kept as ``<name>.prev.json``); an unwritable path is logged, never
    raised over the original error."""
    try:
        write_report(report_path, failed_report(error, **kwargs))
    except OSError as exc:
        log.error("cannot write report %s: %s", report_path, exc)
