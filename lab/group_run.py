"""A job on a chip group: several boards as one instrument (issue 35).

A network larger than one chip is spread over a group of boards (the 10x10 field's 360
synapses over 2-3 crossbars: :mod:`snan_hil.calibration.chip_group`). Unlike a run over
several *independent* boards (:mod:`snan_hil.lab.fanout`: each board runs whole groups of
units on its own chip), every unit of a group job needs every chip at once — a launch's
decision windows go to whichever chip holds the input neuron the agent stands on.

:func:`run_group_job` runs such a job with the runner's own pieces, once per chip
(:mod:`snan_hil.lab.runner`): each chip's run is opened as a one-board run is
(``_open_run``: its bench, its recorder in the chip's own history database, its pulse journal,
the control channel of ``snan-hil watch``), and one unit loop runs the job over all of them:
a unit of the run's checkpoint is restored, the others run on a :class:`GroupBench` of every
chip's bench (a ``restartable`` job's units each on fresh sessions of every chip, each chip's
emulated state saved before the unit and put back when the unit runs again: a resumed group
run gives the results of an uninterrupted one), a stop between units ends every chip's run
as interrupted. The job's ``plan`` gets the group's bench once (its refusals leave no run in
any history). Each chip's run records the pulses its chip took; the job's result goes to the
first chip's RunStop (the others get the same summary).
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator, Sequence
from typing import Any, TypeVar, cast

from snan_hil.board.session import BoardSession
from snan_hil.calibration.bench import CellBench
from snan_hil.calibration.chip_group import GroupBench
from snan_hil.calibration.job import BoardJob, Unit, UnitContext
from snan_hil.common.errors import UserError
from snan_hil.lab.boards import LinkOptions, check_ports
from snan_hil.lab.opener import BoardPlan
from snan_hil.lab.runner import (JobInterrupted, JobRun, RunOptions, _Boundary, _open_run,
                                 _partial, _progress, _Run, _summary, _unit_bench)

__all__ = ["ChipShare", "run_group_job", "check_group_ports"]

ResultT = TypeVar("ResultT")


def check_group_ports(ports: Sequence[str], link: LinkOptions) -> list[str]:
    """``--group``: the chips' ports, checked before any work (UserError, one line): at least
    two, no board twice, no empty entry (:func:`~snan_hil.lab.boards.check_ports`), and not
    over the legacy protocol (it has no DECISION_WINDOW; a group runs the on-board windows;
    the chips share the link options, so a group's protocols never mix)."""
    if link.protocol == "legacy":
        raise UserError("--group runs the on-board decision windows, which the legacy "
                        "protocol does not have (--protocol legacy); give boards with this "
                        "project's framed firmware")
    return check_ports(ports, link, option="--group")


class ChipShare:
    """A chip's run of a group job (the runner's ``_open_run`` plans the job on one bench):
    the group job's kind and description, no units of its own — the group's unit loop runs
    the job over every chip's bench."""

    restartable = False

    def __init__(self, job: BoardJob[Any, Any], chip: int) -> None:
        self.kind = job.kind
        self._describe = job.describe
        self.chip = chip
        self.restartable = bool(getattr(job, "restartable", False))
        self.bench: CellBench | None = None

    def describe(self) -> dict[str, Any]:
        return {**self._describe(), "chip": self.chip}

    def plan(self, bench: CellBench) -> list[Unit]:
        self.bench = bench
        return []


@contextlib.contextmanager
def _sessions(plans: Sequence[BoardPlan | BoardSession]) -> Iterator[list[BoardSession]]:
    """Every chip's session (plans opened here, in order, and closed on the way out)."""
    with contextlib.ExitStack() as stack:
        out = []
        for p in plans:
            if isinstance(p, BoardPlan):
                session = p.open()
                stack.callback(session.close)
            else:
                session = p
            out.append(session)
        yield out


def run_group_job(job: BoardJob[Any, ResultT], chips: Sequence[BoardPlan | BoardSession],
                  options: RunOptions | None = None) -> JobRun[ResultT]:
    """Run ``job`` on the chip group ``chips`` (opener plans: opened here, closed at the end;
    or open sessions) as one instrument (module doc). ``options`` as :func:`run_job`'s: the
    checkpoint (``folder``, or ``folder_of`` called with the first chip's session), record
    level, metadata, progress. The :class:`JobRun` of the first chip's run (its ``result``
    the job's). UserError for the job's refusals; :class:`JobInterrupted` after a stop or
    Ctrl-C (every chip's run ends as interrupted)."""
    options = options or RunOptions()
    owns = all(isinstance(p, BoardPlan) for p in chips)
    with _sessions(chips) as sessions:
        if options.folder_of is not None:
            options = dataclasses.replace(options, folder=options.folder_of(sessions[0]),
                                          folder_of=None)
        # the job's plan on bare benches first: its refusals leave no run in any history
        bare = [CellBench(session, layout_required=options.layout_required, warn=options.warn)
                for session in sessions]
        units = list(job.plan(GroupBench(bare)))   # type: ignore[arg-type]
        shares = [ChipShare(job, k) for k in range(len(sessions))]
        runs: list[_Run] = []
        try:
            for k, (share, session) in enumerate(zip(shares, sessions)):
                runs.append(_open_run(cast("BoardJob[Any, Any]", share), session, options,
                                      board=k))
        except BaseException as exc:
            for run in runs:
                run.finish("failed", {"error": f"{type(exc).__name__}: {exc}"},
                           reason=str(exc))
            raise
        return _run_all(job, units, runs, sessions, options, owns=owns)


def _run_all(job: BoardJob[Any, ResultT], units: Sequence[Unit], runs: list[_Run],
             sessions: list[BoardSession], options: RunOptions, *, owns: bool
             ) -> JobRun[ResultT]:
    first = runs[0]
    records: dict[str, dict[str, Any]] = {}

    def outcome(result: Any, status: str) -> JobRun[Any]:
        rec = first.rec
        return JobRun(result, status, sessions[0], rec.metadata,
                      rec.path if rec.run_id is not None else None, rec.run_id,
                      dict(rec.recorded), sum(r.recovered for r in runs), first.earlier)

    def finish(status: str, summary: Any, reason: str = "") -> None:
        for run in runs:
            run.finish(status, summary, reason=reason)
    try:
        if owns and getattr(job, "restartable", False) \
                and all(s.reopen_with is not None for s in sessions):
            for run, session in zip(runs, sessions):
                session.close()             # every unit on fresh connections from here
                run.fresh = True
        _group_units(job, units, runs, options, records, _progress(options, first.rec))
        result = job.result(records, "complete")
    except KeyboardInterrupt as exc:
        partial = _partial(job, records)
        finish("interrupted", _summary(job, partial), reason=str(exc) or "interrupted")
        raise JobInterrupted(outcome(partial, "interrupted"), exc) from exc
    except BaseException as exc:
        finish("failed", {"error": f"{type(exc).__name__}: {exc}"},
               reason=str(exc) if isinstance(exc, UserError)
               else f"{type(exc).__name__}: {exc}")
        raise
    finish("complete", _summary(job, result))
    return outcome(result, "complete")


def _group_units(job: BoardJob[Any, Any], units: Sequence[Unit], runs: list[_Run],
                 options: RunOptions, records: dict[str, dict[str, Any]],
                 progress: Any) -> None:
    """The unit loop of :func:`snan_hil.lab.runner.run_units` over every chip: boundaries
    (each chip's saved state) entered before a unit, the next unit's saved before this one
    is committed, left after it."""
    folder = options.folder
    ahead: str | None = None
    for i, unit in enumerate(units):
        saved = folder.done(unit.key) if folder is not None else None
        if saved is not None:
            job.restore(unit, saved)
            records[unit.key] = saved
            continue
        bounds = [_Boundary(job, run.session, folder, unit.key, k)
                  for k, run in enumerate(runs)]
        for b in bounds:
            b.enter(saved_here=ahead == unit.key)
        for run in runs:
            run.rec.check()
            if run.control is not None:
                run.control.check(force=True)
            if run.journal is not None:
                run.journal.unit = unit.key
        ctx = UnitContext(progress=progress, emit=runs[0].emit, store=folder)
        with contextlib.ExitStack() as stack:
            benches = [stack.enter_context(_unit_bench(run)) for run in runs]
            record = job.run_unit(unit, GroupBench(benches), ctx)  # type: ignore[arg-type]
        nxt = units[i + 1] if i + 1 < len(units) else None
        if nxt is not None and folder is not None and folder.done(nxt.key) is None:
            for k, run in enumerate(runs):
                _Boundary(job, run.session, folder, nxt.key, k).save()
            ahead = nxt.key
        if folder is not None:
            folder.commit(unit.key, record)
        for b in bounds:
            b.leave()
        records[unit.key] = record
