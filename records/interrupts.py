"""What stops a running job before its next board request, other than Ctrl-C: a stop asked
through the run's control channel (:class:`StopRequested`, :mod:`snan_hil.records.control`) and
a history database that cannot record the run any more (:class:`RecordingStopped`,
:class:`snan_hil.records.history.Recorder`). Both are KeyboardInterrupts, so the job's usual
interrupt clean-up runs.

A base module: it imports no layer.
"""

from __future__ import annotations

__all__ = ["StopRequested", "RecordingStopped"]


class StopRequested(KeyboardInterrupt):
    """A stop requested through the control channel, raised before the next pulse; handled
    like Ctrl-C (the interrupt clean-up runs), exit code 130."""

    signum = 2


class RecordingStopped(StopRequested):
    """The run's history database cannot record it any more (damaged, full disk; never
    another program's lock, which only delays the records:
    :class:`~snan_hil.records.history.Recorder`): raised before the next pulse like a stop,
    so the job's interrupt clean-up runs; the command says why in one line, exit code 2."""

    exit_code = 2
