"""Launches interleaved on one board: the next window's request on the line while the board
runs the last one (issue 33).

A launch's next decision depends on its current one, so one launch keeps the board waiting for
the wire between windows; the launches of a scenario are independent, so :func:`run_interleaved`
keeps ``depth`` launches going and one window of each outstanding on the board: while the board
runs launch A's window, launch B's request is on the line (the link keeps two requests
outstanding, each with its own sequence number, resent with it; the board answers a resent one
from its cache, docs/protocol.md section 4), and A's next window is sent as soon as A's answer
is in. The board runs the windows in the order they were sent. A window's reads depend only on
the chip and the window (its noise is keyed by the window, docs/emulator.md), so every launch
takes the decisions it takes alone: interleaving changes when the board works, not what it
answers (``tests/hil/test_interleave.py``).

The first window of a board session carries the parameter block (too long for the board's
receive ring while it works): it runs alone, the others then two at a time.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from snan_hil.host.agent import BoardWindow, TrialResult, WindowTrial
from snan_hil.host.hil.board_window import OnBoardMotorNeurons
from snan_hil.host.hil.group_window import GroupMotorNeurons
from snan_hil.protocol.messages import DecisionWindow

log = logging.getLogger(__name__)

DEPTH = 2
"""Launches kept going at once (two requests outstanding on the link)."""


@dataclass
class _Launch:
    """One launch going: its trial, the window it has open (and that window's request and
    ticket once sent), when it started."""

    index: int
    run: WindowTrial
    t0: float
    window: BoardWindow | None = None
    req: DecisionWindow | None = None
    ticket: Any = None


def run_interleaved(backend: OnBoardMotorNeurons | GroupMotorNeurons,
                    launches: Iterator[tuple[int, WindowTrial]],
                    on_done: Callable[[int, TrialResult, float], None],
                    depth: int = DEPTH) -> None:
    """Run the trials of ``launches`` ((index, :class:`WindowTrial`) pairs, made only when a
    slot is free) ``depth`` at a time on ``backend``'s board; ``on_done(index, result,
    wall_s)`` as each finishes (in the order they finish)."""
    sent: deque[_Launch] = deque()         # windows on the board, in the order sent
    try:
        _run(backend, iter(launches), on_done, depth, sent)
    except BaseException:
        # a stop (or a failure) with windows on the board: their answers are read and dropped,
        # so the link holds no request outstanding and the board none half answered
        for ln in sent:
            try:
                backend.collect(ln.ticket)
            except Exception:              # the link is gone: the first error is the one
                log.debug("window of launch %d not collected after an error", ln.index)
        raise


def _run(backend: OnBoardMotorNeurons | GroupMotorNeurons,
         source: Iterator[tuple[int, WindowTrial]],
         on_done: Callable[[int, TrialResult, float], None], depth: int,
         sent: deque[_Launch]) -> None:
    going: deque[_Launch] = deque()        # launches without a window on the board
    more = True
    while True:
        while more and len(going) + len(sent) < depth:
            nxt = next(source, None)
            if nxt is None:
                more = False
                break
            going.append(_Launch(nxt[0], nxt[1], time.perf_counter()))
        while going:
            ln = going[0]
            if ln.window is None:
                ln.window = ln.run.open()
                ln.req = backend.request(ln.window)
            elif ln.req is not None and ln.req.params is not None:
                ln.req = backend.request(ln.window)   # the board may hold the block by now
            assert ln.req is not None
            if sent and not backend.pipelinable(ln.req):
                break                          # the board takes it once the other is back
            ln.ticket = backend.submit(ln.window, ln.req)
            sent.append(going.popleft())
        if not sent:
            if not going and not more:
                return
            continue
        ln = sent.popleft()                    # (a failed collect leaves nothing outstanding)
        counts, spikes = backend.collect(ln.ticket)
        ln.run.close(counts, spikes)
        ln.window = ln.req = ln.ticket = None
        if ln.run.done:
            on_done(ln.index, ln.run.result(), time.perf_counter() - ln.t0)
        else:
            going.append(ln)
