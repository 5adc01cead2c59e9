"""Imported once by the forkserver the board workers of :func:`snan_hil.lab.boards.local_boards`
are forked from: SIGINT ignored there, so the workers inherit it.

A Ctrl-C at the terminal goes to the whole process group: without this every Dask worker
process got its own KeyboardInterrupt and printed two tracebacks (asyncio's runner) beside the
command's one "interrupted" line. The command's own process handles the Ctrl-C (the run stops,
its finished sets are committed, ``--resume`` goes on) and closes the cluster, which ends the
workers. Python's asyncio runner installs its own SIGINT handler only over the default one,
so the ignored disposition stays.
"""

from __future__ import annotations

import signal

signal.signal(signal.SIGINT, signal.SIG_IGN)
