"""What every command that touches a board or runs an experiment shares about *the run*: the
user's metadata (``--sample``, ``--operator``, ``--note``, ``--tag``), its UUID, and the
control channel a live view pauses and stops it through (docs/bench.md, "Runs").

* :func:`add_run_metadata_options` -- the four options (``add_history_arguments`` adds them to
  every recording board command; the experiment commands add them themselves);
* :func:`metadata_from_args` -- a :class:`~snan_hil.records.documents.RunMetadata` (a new
  UUID4 per run);
* :func:`command_text` -- the command line of the run, as the runs table records it;
* :func:`software_run` -- the record of a software command's invocation in the user's runs
  database (not a board job: no board, no pulses; board jobs are recorded, paused and
  stopped by the job runner, :mod:`snan_hil.lab.runner`).
"""

from __future__ import annotations

import argparse
import contextlib
import shlex
from collections.abc import Iterator
from typing import Any

from snan_hil.common.errors import UserError
from snan_hil.files.userdata import user_data_dir
from snan_hil.records.documents import RunMetadata, check_tag, control_character
from snan_hil.records.history import Recorder
from snan_hil.tools.console import progress_sink, warn

__all__ = ["add_run_metadata_options", "metadata_from_args", "run_block", "progress_to",
           "event_sink", "software_run"]

MAX_TEXT = 2000


def check_text(value: str) -> str:
    """A ``--sample`` / ``--operator`` / ``--note`` value, stripped; ValueError (its text
    names what is wrong, without the option) for a blank one, one with a control character
    (printed raw later by ``history``: an escape sequence would act on the terminal) or one
    longer than :data:`MAX_TEXT`."""
    text = str(value).strip()
    if not text:
        raise ValueError("a blank value; give some text, or leave the option out")
    bad = control_character(text)
    if bad is not None:
        raise ValueError(f"holds the control character {bad!r}; give plain text (no escape "
                         "sequences, tabs or line breaks)")
    if len(text) > MAX_TEXT:
        raise ValueError(f"at most {MAX_TEXT} characters, got {len(text)}")
    return text


def _checked(check: Any) -> Any:
    """An argparse ``type``: ``check`` with its ValueError as argparse's one-line error."""
    def parse(value: str) -> str:
        try:
            return str(check(value))
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    parse.__name__ = check.__name__
    return parse


def add_run_metadata_options(parser: argparse.ArgumentParser) -> None:
    """``--sample``, ``--operator``, ``--note``, ``--tag`` (repeatable); each value is
    checked as it is parsed (:func:`check_text`, :func:`~snan_hil.records.documents.check_tag`):
    a bad one is one line before any work."""
    if "--sample" in parser._option_string_actions:
        return
    g = parser.add_argument_group("run metadata (recorded with the run, in its RunStart "
                                  "document and JSON report)")
    text = _checked(check_text)
    g.add_argument("--sample", default=None, type=text,
                   help="what is measured: chip, wafer, die ... (default: none)")
    g.add_argument("--operator", default=None, type=text, help="who runs it (default: none)")
    g.add_argument("--note", default=None, type=text, help="a free note (default: none)")
    g.add_argument("--tag", dest="tags", action="append", default=[], metavar="TAG",
                   type=_checked(check_tag), help="a tag (repeatable)")


def command_text(args: argparse.Namespace) -> str:
    """The command line of this run (for the runs table)."""
    argv = getattr(args, "_argv", None)
    return "snan-hil " + shlex.join(argv) if argv else f"snan-hil {args.command}"


def metadata_from_args(args: argparse.Namespace) -> RunMetadata:
    """The run's metadata from the options, with a new uid (UserError, one line, for a bad
    value)."""
    fields: dict[str, Any] = {}
    for key in ("sample", "operator", "note"):
        value = getattr(args, key, None)
        if value is not None:
            try:
                fields[key] = check_text(value)
            except ValueError as exc:
                raise UserError(f"--{key}: {exc}") from None
    try:
        tags = tuple(dict.fromkeys(check_tag(t) for t in getattr(args, "tags", []) or []))
    except ValueError as exc:
        raise UserError(f"--tag: {exc}") from None
    return RunMetadata(tags=tags, **fields)       # a new uid: a command may record two runs


CONTROL_LINES = {
    "pause": "paused from snan-hil watch before the next pulse or read; resume or stop it there "
             "(p / s), or Ctrl-C here",
    "resume": "resumed from snan-hil watch",
}
"""What the job's terminal prints when ``snan-hil watch`` pauses or resumes it (a stop ends
the command with its own line)."""


def event_sink(rec: Recorder) -> Any:
    """``sink(stream, data)``: an event of the run's stream, written at once (a live view
    sees it as it happens; e.g. each launch of a comparison)."""
    def sink(stream: str, data: dict[str, Any]) -> None:
        rec.publisher.event(stream, data)
        rec.flush()
    return sink


def run_block(rec: Recorder | None, args: argparse.Namespace) -> dict[str, Any]:
    """The run's identity for a JSON report: uid, history run id, metadata."""
    rec = rec if rec is not None else getattr(args, "_recorder", None)
    meta = rec.metadata if rec is not None else metadata_from_args(args)
    return {**meta.to_dict(), "history_run_id": None if rec is None else rec.run_id}


def progress_to(show: Any, rec: Recorder) -> Any:
    """A progress callback feeding both the terminal display and the run's document stream."""
    def progress(event: Any) -> None:
        show(event)
        rec.progress(event)
    return progress


SOFTWARE_COMMANDS = ("demo", "experiment", "sim", "train", "readings", "read-weights")
"""Commands that run an experiment (or read a board) without a board history run of their
own: the CLI gives them the metadata options and records each invocation as a run of kind
``experiment`` in the user's runs database (:func:`software_run`)."""
RUNS_DATABASE = "runs.history.sqlite"


def runs_database() -> Any:
    """The user's runs database (software runs): ``<user data>/runs.history.sqlite``."""
    return user_data_dir() / RUNS_DATABASE


class _LazyRun:
    """The software run's recorder, made at its first progress event (work has begun), or
    at a clean end: bad input refused before any work leaves no record (nothing written)."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.rec: Recorder | None = None

    def get(self) -> Recorder:
        if self.rec is None:
            self.rec = Recorder(runs_database(), "experiment", command=command_text(self.args),
                                level="runs", warn=warn, metadata=metadata_from_args(self.args),
                                config={"command": self.args.command})
            self.args._recorder = self.rec
        return self.rec

    def progress(self, event: Any) -> None:
        self.get().progress(event)


@contextlib.contextmanager
def software_run(args: argparse.Namespace) -> Iterator[_LazyRun]:
    """Record one invocation of a software command: RunStart (metadata, command, uid), its
    progress events, RunStop with the exit status; never fails the command (a database
    problem is one warning line). Nothing is recorded for a command refused before it began
    (no progress yet and a UserError)."""
    metadata_from_args(args)                  # a bad --tag: refused before anything
    lazy = _LazyRun(args)
    try:
        with progress_sink(lazy.progress):
            yield lazy
    except UserError as exc:
        if lazy.rec is not None:
            lazy.rec.finish("failed", reason=str(exc))
        raise
    except KeyboardInterrupt as exc:
        if lazy.rec is not None:
            lazy.rec.finish("interrupted", reason=str(exc) or "interrupted")
        raise
    except BaseException as exc:
        if lazy.rec is not None:
            lazy.rec.finish("failed", reason=f"{type(exc).__name__}: {exc}")
        raise
    else:
        lazy.get().finish("complete")
