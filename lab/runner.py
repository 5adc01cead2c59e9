"""The job runner: the one engine every board job runs on (the bluesky RunEngine idea).

:func:`run_job` takes a job (:class:`~snan_hil.calibration.job.BoardJob`: a small typed class
with plan / run-a-unit / result seams), the board (an opener's plan or an open session) and the
run's options (:class:`RunOptions`), and owns everything a long board job used to wire itself:

* **recording**: the run's :class:`~snan_hil.records.history.Recorder` in the board's history
  database (the document stream: RunStart with the job's config and the run's metadata, the
  ``pulses`` and ``cells`` streams, any stream the job emits, RunStop with its summary and
  exit status);
* **the pulse journal** (:class:`~snan_hil.records.journal.PulseJournal`): every pulse written
  down before it is sent and after its reply; at the start of a run the journals of earlier
  runs on this board that were killed are **reconciled** with the history (the pulses their
  recorder had not written yet are recorded into those runs, stage ``recovered``), and a
  resumed unit is told which of its pulses ran in earlier attempts;
* **pause / stop**: the bench's client polls the run's control channel before every board
  request (``snan-hil watch``), and the runner looks between units; a stop ends the run as
  ``interrupted`` (:class:`JobInterrupted` carries the partial result);
* **progress**: the caller's callback and the run's documents;
* **resume**: with a run folder (:class:`~snan_hil.host.checkpoint.RunFolder`) every finished
  unit is committed and a resumed run takes it from there; a ``restartable`` job's unit that
  was cut is run again from the emulated chip saved before it;
* **the cell bench** (:class:`~snan_hil.calibration.bench.CellBench`): built once from the
  session, the one write limit with it.

Several boards go through :func:`snan_hil.lab.fanout.run_on_boards`, which runs the same unit
loop (:func:`run_units`) on each board's worker.
"""

from __future__ import annotations

import contextlib
import dataclasses
import datetime as _dt
import logging
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Generic, TypeVar

from snan_hil.board.session import BoardSession
from snan_hil.calibration.bench import CellBench
from snan_hil.calibration.control import ControlledClient
from snan_hil.calibration.job import BoardJob, Unit, UnitContext
from snan_hil.common.errors import UserError
from snan_hil.common.progress import ProgressCallback, ProgressEvent
from snan_hil.files.atomicio import atomic_write_bytes, atomic_write_text
from snan_hil.host.checkpoint import RunFolder
from snan_hil.lab.opener import BoardPlan
from snan_hil.records.control import RunControl
from snan_hil.records.documents import RunMetadata
from snan_hil.records.history import History, Recorder
from snan_hil.records.journal import JournalPulse, PulseJournal, read_journal, settle_torn

__all__ = ["RunOptions", "JobRun", "JobInterrupted", "HostRun", "run_job", "run_units",
           "journal_dir", "reconcile_journals", "RECOVERED_STAGE"]

log = logging.getLogger(__name__)

ResultT = TypeVar("ResultT")

RECOVERED_STAGE = "recovered"
"""History stage of a pulse a killed run applied (its journal says so) but had not recorded
yet, recorded into that run when a later run on the board reconciles its journal."""


@dataclass(frozen=True)
class RunOptions:
    """How a job is run (decided by the front door: the CLI's options, the notebook's
    keywords). ``record``: "pulses" (default), "cells", "runs" or "off" (nothing recorded;
    no control channel); ``history``: another database than the board's own; ``metadata``:
    sample, operator, note, tags and the run's uid; ``command``: the command line (the runs
    table's); ``folder``: the run's checkpoint (resumable units), None for a job that is not
    resumed; ``folder_of``: instead, a function of the opened session giving it (a checkpoint
    whose identity names the board: called once the board answered, before the job's plan);
    ``progress``: the caller's progress callback; ``subscribers``: more document
    subscribers (a live view, a JSON report); ``seed``: recorded with the run; ``warn``: where
    a database problem's one line goes; ``observers``: more cell observers (a trace figure's
    collector); ``port_label``: the port as the run records it."""

    record: str = "pulses"
    history: Path | None = None
    metadata: RunMetadata | None = None
    command: str = "snan-hil"
    folder: RunFolder | None = None
    progress: ProgressCallback | None = None
    subscribers: tuple[Callable[[str, dict[str, Any]], None], ...] = ()
    seed: int | None = None
    warn: Callable[[str], object] | None = None
    observers: tuple[Any, ...] = ()
    layout_required: bool = False
    folder_of: Callable[[BoardSession], RunFolder] | None = None
    control: tuple[str, str] | None = None
    """The run's control channel when it lives in another database (history path, run uid):
    a board's share of a run over several boards polls the host's run."""
    on_control: Callable[[str], object] | None = None
    """Told each control action taken ("pause", "resume", "stop" from ``snan-hil watch``):
    the CLI says it on the job's terminal, so a paused job does not look hung."""


@dataclass
class JobRun(Generic[ResultT]):
    """A finished (or interrupted) run: the job's ``result``, ``status`` ("complete",
    "interrupted"), the session it ran on (closed; it still describes the board), the run's
    metadata (its uid) and where it was recorded (``history``, ``history_run_id``,
    ``recorded``: pulses and cells written)."""

    result: ResultT
    status: str
    session: BoardSession
    metadata: RunMetadata
    history: Path | None = None
    history_run_id: int | None = None
    recorded: dict[str, int] = field(default_factory=dict)
    recovered: int = 0
    """Pulses of earlier killed runs on this board recorded from their journals."""
    earlier_runs: list[dict[str, Any]] = field(default_factory=list)
    """The history runs of the earlier attempts of this run's checkpoint (a resumed run):
    ``[{"run": id, "uid": uid, "pulses": recorded}]``, in the order they started."""

    def run_block(self) -> dict[str, Any]:
        """The run's identity for a JSON report: uid, history run id, metadata."""
        return {**self.metadata.to_dict(), "history_run_id": self.history_run_id}


class JobInterrupted(KeyboardInterrupt):
    """A stop from ``snan-hil watch`` or Ctrl-C ended the run (recorded as interrupted);
    ``run`` holds the result of the units that finished. Handled like Ctrl-C (exit 130)."""

    def __init__(self, run: JobRun[Any], cause: BaseException) -> None:
        super().__init__(str(cause) or "interrupted")
        self.run = run
        self.cause = cause
        self.signum = getattr(cause, "signum", 2)
        code = getattr(cause, "exit_code", None)
        if isinstance(code, int):
            self.exit_code = code             # RecordingStopped: the command's error line


# -- the journal ----------------------------------------------------------------------------

def journal_dir(history: Path) -> Path:
    """Where the runs recorded in ``history`` keep their pulse journals (one file a run)."""
    return history.with_name(history.name + ".journal")


def _journal_path(history: Path | None, folder: RunFolder | None, uid: str,
                  board: int | None) -> Path | None:
    """A run with a checkpoint keeps its journal there (its resumed runs append to it: a
    resumed unit reads its earlier attempts); a recorded run without one beside the history
    (removed when the run ends: only a killed run leaves it)."""
    suffix = "" if board is None else f"-board-{board}"
    if folder is not None:
        return folder.path(f"pulses{suffix}.jsonl")
    if history is not None:
        return journal_dir(history) / f"{uid}.jsonl"
    return None


def reconcile_journals(db: History, paths: Sequence[Path],
                       warn: Callable[[str], object], *, boot: int | None = None,
                       counter: Callable[[], int | None] | None = None) -> int:
    """Record into their own history runs the pulses that the journals at ``paths`` mark
    done beyond what those runs recorded (a run killed with its recorder's buffer unwritten);
    stage :data:`RECOVERED_STAGE`. A journal's line cut by the kill is decided and named, one
    line each (``warn``; :func:`~snan_hil.records.journal.settle_torn`: ``boot`` and
    ``counter()``, the board's boot nonce and pulse counter now, asked only then). The
    number of pulses recorded."""
    total = 0
    for path in paths:
        got = read_journal(path)
        if got.torn:
            for line in settle_torn(got, boot=boot,
                                    counter=counter() if counter is not None else None):
                warn(line)
        for uid in got.runs():
            run = db.run(uid)
            if run is None or run.status == "running" or run.record_level != "pulses":
                continue                  # not recorded there, still running, or no pulses
            done = [p for p in got.of_run(uid) if p.state == "done"]
            have = run.pulses
            if have >= len(done):
                continue
            missing = done[have:]
            db.write_batch(run.id, pulses=[_pulse_row(p, have + i) for i, p in enumerate(missing)])
            total += len(missing)
            log.info("recorded %d pulse(s) of run %s from its journal %s", len(missing), uid,
                     path)
    return total


def _pulse_counter(session: BoardSession) -> int | None:
    """The board's pulse counter now (STATUS), None where it has none."""
    from snan_hil.protocol.errors import UnsupportedError
    try:
        return int(session.client.status().pulses_applied)
    except UnsupportedError:
        return None


def _running(db: History, uid: str) -> bool:
    """Whether the run ``uid`` is still running (its process alive, or on another host)."""
    run = db.run(uid)
    return run is not None and run.status == "running"


def _pulse_row(p: JournalPulse, n: int) -> tuple[Any, ...]:
    now = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="milliseconds")
    return (p.row, p.col, n, now, RECOVERED_STAGE, p.polarity, p.amplitude_v,
            p.width_us, p.g_before_s, p.g_after_s)


# -- one board ------------------------------------------------------------------------------

@dataclass
class _Run:
    """A recorder, control channel, journal and bench of one board for one run; ``emit``:
    an event of one of the run's document streams, written at once."""

    session: BoardSession
    rec: Recorder
    control: RunControl | None
    journal: PulseJournal | None
    bench: CellBench
    units: list[Unit] = field(default_factory=list)
    recovered: int = 0
    emit: Callable[[str, dict[str, Any]], None] = field(default=lambda _s, _d: None)
    earlier: list[dict[str, Any]] = field(default_factory=list)
    told_torn: bool = False
    """Whether the cut lines of the run's journals were decided and named at its start."""
    fresh: bool = False
    """Each unit runs on a fresh session (a restartable job on a session the runner opened
    and closed once the job was planned: its chip can be saved and put back between units,
    which an open connection to an in-process emulated chip forbids)."""

    def finish(self, status: str, summary: Any = None, reason: str = "") -> None:
        """End the run: the recorder's RunStop with ``status`` (everything it buffered
        written), the journal closed (removed beside the history: only a killed run leaves
        one there; kept in a checkpoint, whose resumed units read it)."""
        self.rec.finish(status, summary, reason=reason)
        _close_journal(self)


def _open_run(job: BoardJob[Any, Any], session: BoardSession, options: RunOptions,
              board: int | None = None) -> _Run:
    """The bench of ``job`` on ``session``, the job's plan made on it (a refusal there leaves
    no run in the history: nothing was done), then the run's recorder, control channel and
    journal wired into the bench (``run.units``: the plan)."""
    bench = CellBench(session, layout_required=options.layout_required, warn=options.warn)
    units = list(job.plan(bench))
    level = options.record if options.record != "off" else "runs"
    history = None if options.record == "off" else (options.history or session.files.history)
    fields: dict[str, Any] = {"port": session.port, "protocol": session.protocol,
                              "seed": options.seed, "config": job.describe(),
                              **session.identity.to_dict()}
    rec = Recorder(history, job.kind, command=options.command, level=level,
                   warn=options.warn, metadata=options.metadata or RunMetadata(),
                   subscribers=options.subscribers, **fields)
    control = None
    client: Any = session.client              # the session's client, controlled below
    recovered = 0
    earlier: list[dict[str, Any]] = []
    tell = _teller(rec, options.on_control)
    if options.control is not None:               # the host's run over several boards
        control = RunControl(options.control[0], options.control[1], on_action=tell,
                             warn=options.warn)
    elif rec.path is not None and rec.active and rec.db is not None:
        control = RunControl(rec.path, rec.uid, db=rec.db, on_action=tell, warn=options.warn)
    if control is not None:
        rec.control = control                         # closed with the run
    if rec.path is not None:                      # before every board request: stop once
        client = ControlledClient(client, _checks(rec, control))  # the run cannot be recorded
    told = rec.path is not None and rec.active and rec.db is not None
    if told and rec.db is not None:
        recovered = _reconcile_board(rec, options, session, board)
        earlier = _folder_runs(rec.db, options.folder, rec.uid)
    jpath = _journal_path(rec.path if rec.active else None, options.folder, rec.uid, board)
    journal = PulseJournal(jpath, rec.uid, board=board) if jpath is not None else None
    bench.attach(client=client, observer=_observers(rec, options.observers), journal=journal)
    if journal is not None:
        journal.baseline(bench.ledger.fw_baseline, session.info.boot_nonce)
    return _Run(session, rec, control, journal, bench, units, recovered, _emitter(rec),
                earlier, told_torn=told)


def _folder_runs(db: History, folder: RunFolder | None, uid: str) -> list[dict[str, Any]]:
    """The history runs (in ``db``) of the earlier attempts of the checkpoint ``folder``: the
    runs its pulse journals name, but ``uid``'s (this run)."""
    if folder is None:
        return []
    uids: list[str] = []
    for path in sorted(folder.dir.glob("pulses*.jsonl")):
        uids += [r for r in read_journal(path).runs() if r != uid and r not in uids]
    out = []
    for r in uids:
        row = db.run(r)
        if row is not None:
            out.append({"run": row.id, "uid": r, "pulses": row.pulses})
    return out


def _observers(rec: Recorder, extra: Sequence[Any]) -> Any:
    from snan_hil.calibration.observer import Observers
    return Observers(rec, *extra) if extra else rec


def _teller(rec: Recorder, also: Callable[[str], object] | None) -> Callable[[str], None]:
    """Each control action taken: into the run's ``control`` stream, and to ``also``."""
    def tell(action: str) -> None:
        if not rec.publisher.stopped:
            rec.publisher.event("control", {"action": action, "detail": "snan-hil watch"})
            rec.flush()
        if also is not None:
            also(action)
    return tell


def _checks(rec: Recorder, control: RunControl | None) -> Callable[[], None]:
    """What the controlled client runs before every board request: RecordingStopped once the
    run's recording failed (:meth:`Recorder.check`: no pulse goes unrecorded), then the
    control channel's pause/stop."""
    def check() -> None:
        rec.check()
        if control is not None:
            control.check()
    return check


def _reconcile_board(rec: Recorder, options: RunOptions, session: BoardSession,
                     board: int | None = None) -> int:
    """The journals killed runs left beside this history, and the run folder's journal of
    this board (a resumed run; ``board``: its number in a run over several boards, whose
    other boards' journals hold no run of this history), reconciled with the history before
    the first pulse of this run."""
    assert rec.path is not None and rec.db is not None
    paths = sorted(journal_dir(rec.path).glob("*.jsonl")) if journal_dir(rec.path).is_dir() \
        else []
    if options.folder is not None:
        paths += sorted(options.folder.dir.glob("pulses*.jsonl") if board is None
                        else [options.folder.path(f"pulses-board-{board}.jsonl")])
        paths = [p for p in paths if p.is_file()]
    if not paths:
        return 0
    warn = options.warn or (lambda line: log.warning("%s", line))
    n = reconcile_journals(rec.db, paths, warn, boot=session.info.boot_nonce,
                           counter=lambda: _pulse_counter(session))
    for p in paths:                   # a finished run's own journal beside the history: gone
        if p.parent == journal_dir(rec.path) and not _running(rec.db, p.stem):
            p.unlink(missing_ok=True)
    if n:
        warn(f"recorded {n} pulse(s) that a killed run had applied but not written to the "
             f"history {rec.path} (stage {RECOVERED_STAGE}, from its pulse journal)")
    return n


def run_units(job: BoardJob[Any, Any], units: Sequence[Unit], run: _Run, options: RunOptions,
              *, board: int | None = None, records: dict[str, dict[str, Any]] | None = None,
              progress: ProgressCallback | None = None) -> dict[str, dict[str, Any]]:
    """Run ``units`` of ``job`` on the bench of ``run``, in order: a unit the checkpoint holds
    is restored, the others run and are committed; the control channel is looked at between
    units. The records by unit key (``records``, filled as units end: what finished is there
    when a stop cuts the loop)."""
    out = records if records is not None else {}
    folder = options.folder
    earlier = _earlier_pulses(run, options) if run.journal is not None \
        and folder is not None else None
    ahead: str | None = None          # the unit whose boundary this loop saved already
    for i, unit in enumerate(units):
        saved = folder.done(unit.key) if folder is not None else None
        if saved is not None:
            job.restore(unit, saved)
            out[unit.key] = saved
            continue
        boundary = _Boundary(job, run.session, folder, unit.key, board)
        boundary.enter(saved_here=ahead == unit.key)     # first: a stop here resumes from it
        run.rec.check()                       # the run can still be recorded
        if run.control is not None:
            run.control.check(force=True)
        if run.journal is not None:
            run.journal.unit = unit.key
        past = [p for p in earlier if p.unit == unit.key] if earlier is not None else []
        ctx = UnitContext(progress=progress, emit=run.emit, store=folder,
                          board=board, earlier=past,
                          attempt=len({p.run for p in past}))
        with _unit_bench(run) as bench:
            record = job.run_unit(unit, bench, ctx)
        nxt = units[i + 1] if i + 1 < len(units) else None
        if boundary.active and nxt is not None and folder is not None \
                and folder.done(nxt.key) is None:     # before the commit: never a gap
            _Boundary(job, run.session, folder, nxt.key, board).save()
            ahead = nxt.key
        if folder is not None:
            folder.commit(unit.key, record)
        boundary.leave()
        out[unit.key] = record
    return out


def _earlier_pulses(run: _Run, options: RunOptions) -> list[JournalPulse]:
    """The pulses of every journal in the run's checkpoint (this board's, and on several
    boards every other board's: a group moved here from a lost board learns what that board
    did), in the order of their files; the cut lines of this board's journal decided by its
    pulse counter at the start, those of another board's named as undecided (nothing of that
    board can be asked)."""
    assert run.journal is not None and options.folder is not None
    warn = options.warn or (lambda line: log.warning("%s", line))
    own = run.journal.path
    paths = sorted(set(options.folder.dir.glob("pulses*.jsonl")) | {own})
    out: list[JournalPulse] = []
    for path in paths:
        got = read_journal(path)
        if got.torn:
            if path == own:
                lines = settle_torn(got, boot=run.session.info.boot_nonce,
                                    counter=run.bench.ledger.fw_baseline)
                lines = [] if run.told_torn else lines
            else:
                lines = settle_torn(got)
            for line in lines:
                warn(line)
        out += got.pulses
    return out


@contextlib.contextmanager
def _unit_bench(run: _Run) -> Iterator[CellBench]:
    """The bench a unit runs on: the run's, or for a job whose units each run on their own
    connection (``run.fresh``) the run's bench on a fresh session, closed after the unit."""
    if not run.fresh:
        yield run.bench
        return
    with run.bench.reopened() as bench:
        yield bench


def _emitter(rec: Recorder) -> Callable[[str, dict[str, Any]], None]:
    def emit(stream: str, data: dict[str, Any]) -> None:
        rec.publisher.event(stream, data)
        rec.flush()
    return emit


class _Boundary:
    """A ``restartable`` job's unit on an emulated chip: the chip and its layout saved before
    the unit and, when the unit runs again (it was cut), put back first, so the rerun gives
    what an uninterrupted run gives. Nothing for a real chip (it cannot be put back) or a run
    without a checkpoint."""

    def __init__(self, job: BoardJob[Any, Any], session: BoardSession,
                 folder: RunFolder | None, key: str, board: int | None) -> None:
        self.active = bool(getattr(job, "restartable", False)) and folder is not None \
            and session.snapshots is not None
        self.session = session
        where = f"board-{board}/" if board is not None else ""
        self.dir = folder.path(f"boundaries/{where}before-{key}") if folder is not None \
            else Path()

    def enter(self, *, saved_here: bool = False) -> None:
        """Before the unit: put the chip and layout back when they were saved before an
        earlier attempt (not ``saved_here``: by this run, right after the unit before),
        else save them."""
        if not self.active:
            return
        snapshots, layout = self.session.snapshots, self.session.files.layout
        assert snapshots is not None
        chip, saved, mark = self.dir / "chip", self.dir / "layout.json", self.dir / "saved"
        if mark.is_file():
            if saved_here:
                return
            snapshots.check(chip)
            snapshots.restore(chip)
            if layout is not None:
                if saved.is_file():
                    atomic_write_bytes(layout, saved.read_bytes())
                else:
                    layout.unlink(missing_ok=True)
            log.info("chip and layout put back from %s", self.dir)
            return
        self.save()

    def save(self) -> None:
        """Save the chip and layout as they are now (after the unit before this one: saved
        before that unit is committed, so a committed unit always leaves the next one's
        boundary behind)."""
        if not self.active:
            return
        snapshots, layout = self.session.snapshots, self.session.files.layout
        assert snapshots is not None
        chip, saved, mark = self.dir / "chip", self.dir / "layout.json", self.dir / "saved"
        mark.unlink(missing_ok=True)
        self.dir.mkdir(parents=True, exist_ok=True)
        snapshots.save(chip)
        if layout is not None and layout.is_file():
            atomic_write_bytes(saved, layout.read_bytes())
        else:
            saved.unlink(missing_ok=True)
        atomic_write_text(mark, "chip and layout saved before the unit\n")

    def leave(self) -> None:
        if self.active:
            import shutil
            (self.dir / "saved").unlink(missing_ok=True)    # first: never a mark without
            shutil.rmtree(self.dir, ignore_errors=True)     # its chip (a kill in between)


def _progress(options: RunOptions, rec: Recorder) -> ProgressCallback:
    def progress(event: ProgressEvent) -> None:
        if options.progress is not None:
            options.progress(event)
        rec.progress(event)
    return progress


def run_job(job: BoardJob[Any, ResultT], board: BoardPlan | BoardSession,
            options: RunOptions | None = None) -> JobRun[ResultT]:
    """Run ``job`` on ``board`` (an opener's plan: opened here and closed at the end; or an
    open session: left open, e.g. a notebook's). See the module docstring. UserError (one
    line) for the job's refusals (before anything is sent where the job checks its input in
    :meth:`~snan_hil.calibration.job.BoardJob.plan`); :class:`JobInterrupted` when a stop or
    Ctrl-C ends it."""
    options = options or RunOptions()
    owns = isinstance(board, BoardPlan)
    session = board.open() if isinstance(board, BoardPlan) else board
    try:
        if options.folder_of is not None:
            options = dataclasses.replace(options, folder=options.folder_of(session),
                                          folder_of=None)
        return _run_on(job, session, options, owns=owns)
    finally:
        if owns:
            session.close()


def _run_on(job: BoardJob[Any, ResultT], session: BoardSession,
            options: RunOptions, *, owns: bool = False) -> JobRun[ResultT]:
    run = _open_run(job, session, options)             # the plan's refusals: nothing run
    rec = run.rec
    records: dict[str, dict[str, Any]] = {}

    def outcome(result: Any, status: str) -> JobRun[Any]:
        return JobRun(result, status, session, rec.metadata,
                      rec.path if rec.run_id is not None else None, rec.run_id,
                      dict(rec.recorded), run.recovered, run.earlier)
    try:
        if owns and getattr(job, "restartable", False) and session.reopen_with is not None:
            session.close()                   # every unit on its own connection from here
            run.fresh = True
        run_units(job, run.units, run, options, records=records,
                  progress=_progress(options, rec))
        result = job.result(records, "complete")
    except KeyboardInterrupt as exc:          # Ctrl-C, SIGTERM, a stop from snan-hil watch
        partial = _partial(job, records)
        run.finish("interrupted", _summary(job, partial), reason=str(exc) or "interrupted")
        raise JobInterrupted(outcome(partial, "interrupted"), exc) from exc
    except BaseException as exc:
        run.finish("failed", {"error": f"{type(exc).__name__}: {exc}"},
                   reason=str(exc) if isinstance(exc, UserError)
                   else f"{type(exc).__name__}: {exc}")
        raise
    run.finish("complete", _summary(job, result))
    return outcome(result, "complete")


def _partial(job: BoardJob[Any, Any], records: Mapping[str, dict[str, Any]]) -> Any:
    try:
        return job.result(records, "interrupted")
    except Exception:                       # noqa: BLE001 - the stop is what is reported
        log.debug("no partial result", exc_info=True)
        return None


def _summary(job: BoardJob[Any, Any], result: Any) -> dict[str, Any] | None:
    if result is None:
        return None
    return job.summary(result)


def _close_journal(run: _Run) -> None:
    """Close the run's journal; a journal beside the history is removed once the recorder
    has written every pulse (a run that ended and whose recording did not fail), kept in a
    checkpoint (its resumed units read it)."""
    journal = run.journal
    if journal is None:
        return
    journal.close()
    beside = run.rec.path is not None and journal.path.parent == journal_dir(run.rec.path)
    if beside and run.rec.failed is None:
        journal.path.unlink(missing_ok=True)
        try:
            journal.path.parent.rmdir()         # only when no other run's journal is there
        except OSError:
            pass


# -- the host side of a run without a board of its own ----------------------------------------

class HostRun:
    """A run recorded where the command runs, without a board of its own: a comparison of
    software scenarios, or the host side of a run over several boards
    (:func:`snan_hil.lab.fanout.run_on_boards`: each board's history records its pulses, this
    run records the whole). ``options``: ``record`` ("off": nothing recorded), ``history``
    (the database: the user's runs database, ``--history``), metadata, command line,
    progress, subscribers, seed, warning line, checkpoint (``folder``); ``fields``: more of
    the RunStart (e.g. the boards). The recorder is the run's only one: :meth:`emit` writes
    an event of its document stream at once, :meth:`progress` reports to the caller and the
    run's documents, :meth:`stop_requested` looks at its control channel (``snan-hil
    watch``), :meth:`run_units` runs units that need no board (committed to the checkpoint,
    a committed one restored, the control channel looked at between them), :meth:`finish`
    ends it. As a context manager: a Ctrl-C or a stop ends it as interrupted, an error as
    failed (a run not finished on the way out: as complete without a summary)."""

    def __init__(self, job: BoardJob[Any, Any], options: RunOptions, **fields: Any) -> None:
        self.job, self.options = job, options
        level = options.record if options.record != "off" else "runs"
        history = None if options.record == "off" else options.history
        self.rec = Recorder(history, job.kind, command=options.command, level=level,
                            warn=options.warn, metadata=options.metadata or RunMetadata(),
                            subscribers=options.subscribers,
                            **{"seed": options.seed, "config": job.describe(), **fields})
        self.control: RunControl | None = None
        rec = self.rec
        if rec.path is not None and rec.active and rec.db is not None:
            self.control = RunControl(rec.path, rec.uid, db=rec.db,
                                      on_action=_teller(rec, options.on_control),
                                      warn=options.warn)
            rec.control = self.control                    # closed with the run
        self.emit = _emitter(rec)
        self.progress = _progress(options, rec)
        self.finished = False

    @property
    def path(self) -> Path | None:
        """The database the run is recorded in (None: not recorded)."""
        return self.rec.path if self.rec.active else None

    @property
    def uid(self) -> str:
        return self.rec.uid

    @property
    def metadata(self) -> RunMetadata:
        return self.rec.metadata

    def stop_requested(self) -> bool:
        """Whether a stop is waiting in the run's control channel."""
        return self.control is not None and self.control.stop_requested()

    def run_block(self) -> dict[str, Any]:
        """The run's identity for a JSON report: uid, history run id, metadata."""
        return {**self.rec.metadata.to_dict(), "history_run_id": self.rec.run_id}

    def run_units(self, units: Sequence[Unit], records: dict[str, dict[str, Any]]
                  ) -> dict[str, dict[str, Any]]:
        """Run ``units`` (none uses a board: the job gets no bench) in order into
        ``records``: a unit the checkpoint holds restored, the others run and committed."""
        folder = self.options.folder
        for unit in units:
            saved = folder.done(unit.key) if folder is not None else None
            if saved is not None:
                self.job.restore(unit, saved)
                records[unit.key] = saved
                continue
            if self.control is not None:
                self.control.check(force=True)
            ctx = UnitContext(progress=self.progress, emit=self.emit, store=folder)
            # a unit that needs no board (its job takes None: LearnJob's arms without one)
            record = self.job.run_unit(unit, None, ctx)  # type: ignore[arg-type]
            if folder is not None:
                folder.commit(unit.key, record)
            records[unit.key] = record
        return records

    def finish(self, status: str, result: Any = None, reason: str = "",
               extra: Mapping[str, Any] | None = None) -> None:
        """End the run: ``status``, its summary from ``result`` (the job's) and ``extra``."""
        self.finished = True
        summary = _summary(self.job, result)
        if extra:
            summary = {**(summary or {}), **extra}
        self.rec.finish(status, summary, reason=reason)

    def __enter__(self) -> HostRun:
        return self

    def __exit__(self, kind: Any, exc: BaseException | None, _tb: Any) -> None:
        if self.finished:
            return
        if exc is None:
            self.finish("complete")
        elif isinstance(exc, KeyboardInterrupt):
            self.finish("interrupted", reason=str(exc) or "interrupted")
        else:
            self.finish("failed", reason=str(exc) if isinstance(exc, UserError)
                        else f"{type(exc).__name__}: {exc}")
