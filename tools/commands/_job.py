"""The command line's door to the job runner: a command parses its options into a job's
config, plans the board (the opener checks the outputs), and calls :func:`run_on_board`; it
then writes its files and prints. The run's options come from the command line in one place
(:func:`run_options`): ``--record``, ``--history`` (resolved by the opener), the metadata
(``--sample`` ...), the command line for the runs table, the warning lines on stderr."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

from snan_hil.board.session import BoardSession
from snan_hil.calibration.job import BoardJob
from snan_hil.host.checkpoint import RunFolder
from snan_hil.lab.opener import BoardPlan
from snan_hil.lab.runner import JobRun, RunOptions, run_job
from snan_hil.tools.commands._history import recording
from snan_hil.tools.commands._run import CONTROL_LINES, command_text, metadata_from_args
from snan_hil.tools.console import note, progress_display, warn

__all__ = ["run_options", "run_on_board"]


def run_options(args: argparse.Namespace, *, progress: Any = None,
                folder: RunFolder | None = None,
                folder_of: Callable[[BoardSession], RunFolder] | None = None,
                observers: tuple[Any, ...] = (),
                subscribers: tuple[Any, ...] = (), seed: int | None = None) -> RunOptions:
    """The run's options from the command line (see the module doc)."""
    return RunOptions(record=args.record if recording(args) else "off",
                      metadata=metadata_from_args(args), command=command_text(args),
                      folder=folder, folder_of=folder_of, progress=progress,
                      subscribers=subscribers, seed=seed, warn=warn, observers=observers,
                      layout_required=bool(getattr(args, "layout", None)),
                      on_control=say_control)


def say_control(action: str) -> None:
    """A pause or resume from ``snan-hil watch``, said on the job's terminal (a stop ends the
    command with its own line)."""
    if action in CONTROL_LINES:
        note(CONTROL_LINES[action])


def run_on_board(args: argparse.Namespace, job: BoardJob[Any, Any],
                 plan: BoardPlan | BoardSession, *, transient: bool = False,
                 **options: Any) -> JobRun[Any]:
    """Run ``job`` on the board of ``plan`` (or on an open session: two jobs of one command
    on one connection, e.g. ``mac --weights``: the programming, then the multiplies) with a
    progress display (off with ``--json``); ``options``: :func:`run_options`' keywords."""
    with progress_display(transient=transient,
                          enabled=not getattr(args, "json", False)) as show:
        return run_job(job, plan, run_options(args, progress=show, **options))
