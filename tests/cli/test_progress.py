"""Progress events: one event type, the tracker library code reports through, and the CLI's
two renderings (rich bars on a terminal, a plain line every few seconds otherwise)."""

from __future__ import annotations

import io

import numpy as np
from rich.console import Console
from rich.progress import Progress

from snan_hil.common.progress import ProgressEvent, ProgressTracker, track
from snan_hil.tools import cli
from snan_hil.tools.console import PlainProgress, _BarProgress, progress_display


def test_tracker_reports_absolute_counts_details_and_notes():
    got: list[ProgressEvent] = []
    bar = track(got.append, "launches", 5, "starting")
    bar.advance(detail="launch 0: 12 steps")
    bar.advance(2)
    bar.note("synapse 3->4 moved to a spare")
    bar.update(5, "done")
    assert [(e.task, e.done, e.total) for e in got] == [("launches", d, 5)
                                                        for d in (0, 1, 3, 3, 5)]
    assert got[0].detail == "starting" and got[1].detail == "launch 0: 12 steps"
    assert got[3].note == "synapse 3->4 moved to a spare" and not got[4].note


def test_tracker_without_callback_is_silent_and_still_counts():
    bar = ProgressTracker(None, "x", 3)
    bar.advance(2)
    assert bar.done == 2


def test_nested_job_advances_the_outer_task_from_where_it_stood():
    got: list[ProgressEvent] = []
    outer = track(got.append, "launches", 20)
    outer.advance(10)
    inner = track(outer.nested("set 1 sw_astro "), "sw_astro", 10)
    inner.advance(1, "launch 0: 9 steps")
    inner.note("a note")
    inner.advance(4)
    tail = got[2:]
    assert [(e.task, e.done) for e in tail] == [("launches", 10), ("launches", 11),
                                                ("launches", 11), ("launches", 15)]
    assert tail[1].detail == "set 1 sw_astro launch 0: 9 steps" and tail[2].note == "a note"


class Clock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def test_plain_lines_every_interval_then_completion_and_short_tasks_silent():
    lines: list[str] = []
    clock = Clock()
    plain = PlainProgress(lines.append, interval_s=5.0, clock=clock)
    ev = lambda done, task="training", **kw: ProgressEvent(task, done, 10, **kw)  # noqa: E731
    plain(ev(0))
    for done in range(1, 5):
        clock.t += 1.0
        plain(ev(done, detail=f"cycle {done}"))
    assert lines == []                                         # 4 s: nothing yet
    clock.t += 1.5
    plain(ev(5, detail="cycle 5"))
    assert lines == ["training: 5/10 (50 %) cycle 5, 6 s"]
    clock.t += 1.0
    plain(ev(6))                                               # 1 s after the last line
    plain(ProgressEvent("training", 6, 10, note="set 0 finished"))
    assert lines[-1] == "set 0 finished"                       # notes always
    clock.t += 5.0
    plain(ev(7))
    assert lines[-1] == "training: 7/10 (70 %), 12 s"
    plain(ev(10))
    plain(ev(10))                                              # completion shown once
    assert lines[-1] == "training: 10/10 (100 %), 12 s" and len(lines) == 4
    plain(ev(0))                                               # the task starts over:
    clock.t += 6.0                                             # its clock starts over too
    plain(ev(1))
    assert lines[-1] == "training: 1/10 (10 %), 6 s"
    plain(ev(0, task="short"))                                 # a short task: silent,
    plain(ev(10, task="short"))                                # also when it completes
    assert len(lines) == 5


def test_plain_lines_unknown_total_and_several_tasks():
    lines: list[str] = []
    plain = PlainProgress(lines.append, interval_s=0.0, clock=Clock())
    plain(ProgressEvent("reads", 7, None))
    plain(ProgressEvent("programming", 0, 24, detail="cell (0,0)"))
    assert lines == ["reads: 7, 0 s", "programming: 0/24 (0 %) cell (0,0), 0 s"]


def test_rich_bars_one_per_task_updated_in_place():
    out = io.StringIO()
    bar = Progress(console=Console(file=out, force_terminal=True, width=100))
    render = _BarProgress(bar)
    render(ProgressEvent("launches", 0, 40))
    render(ProgressEvent("programming", 3, 24, detail="cell (1,2)"))
    render(ProgressEvent("launches", 12, 40, detail="set 0 sw_astro"))
    render(ProgressEvent("launches", 12, 40, note="moved"))
    tasks = {t.description: t for t in bar.tasks}
    assert set(tasks) == {"launches set 0 sw_astro", "programming cell (1,2)"}
    assert tasks["launches set 0 sw_astro"].completed == 12
    assert tasks["programming cell (1,2)"].total == 24


def test_disabled_display_shows_nothing(capsys):
    with progress_display(enabled=False) as progress:
        progress(ProgressEvent("x", 1, 2))
    assert capsys.readouterr().err == ""


def test_sim_shows_progress_lines_when_stderr_is_not_a_terminal(capsys, monkeypatch):
    monkeypatch.setenv("SNAN_HIL_PROGRESS_INTERVAL_S", "30")   # (a busy machine: lines are
    assert cli.main(["sim", "--trials", "30", "--seed", "2"]) == 0  # due by the clock)
    assert capsys.readouterr().err == ""                     # shorter than the interval: none
    monkeypatch.setenv("SNAN_HIL_PROGRESS_INTERVAL_S", "0")
    assert cli.main(["sim", "--trials", "60", "--seed", "2"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert [line.split(" (")[0] for line in err] == [                # one line per chunk
        f"3x3 astro trials: {n}/60" for n in (0, 25, 50, 60)]
    assert cli.main(["sim", "--trials", "30", "--json"]) == 0
    assert capsys.readouterr().err == ""                     # --json: quiet


def test_compare_reports_launches_and_programming(tmp_path):
    """A library job reports through the protocol: compare's launches are one task across
    sets and scenarios, counted to the end."""
    from snan_hil.host.hil.compare import CompareJob, CompareRequest, run_software
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.hil.train import save_weights, train_sets

    hil = load_hil_config()
    trained = train_sets(hil.train_config(), sets=2, cycles=2, seed=1, start=hil.task.start,
                         goal=hil.task.goal)
    path = save_weights(trained, tmp_path / "w.npz")
    got: list[ProgressEvent] = []
    run_software(CompareJob(CompareRequest(str(path), hil, launches=2,
                                           scenarios=("sw_noastro", "sw_astro"))),
                 progress=got.append)
    launches = [e for e in got if e.task == "launches"]
    assert launches[0].done == 0 and launches[-1].done == launches[-1].total == 8
    assert np.all(np.diff([e.done for e in launches]) >= 0)
    assert any(e.detail.startswith("set 1 sw_astro launch 1") for e in launches)


def test_plain_lines_come_by_the_clock_during_a_long_step():
    """A task whose first step takes long (the kernel compiling) shows its state every
    interval without any event; the lines are throttled to one per interval across tasks."""
    lines: list[str] = []
    clock = Clock()
    plain = PlainProgress(lines.append, interval_s=1.0, clock=clock)
    plain(ProgressEvent("training", 0, 60, detail="set 0 cycle 1 (compiling)"))
    plain.tick()
    assert lines == []                                       # not due yet
    for _ in range(3):                                       # 3 s without an event
        clock.t += 0.5
        plain.tick()
        clock.t += 0.5
        plain.tick()
    assert lines == [f"training: 0/60 (0 %) set 0 cycle 1 (compiling), {s} s" for s in (1, 2, 3)]
    clock.t += 0.4
    plain(ProgressEvent("training", 1, 60, detail="set 0 cycle 1: 27 steps"))
    plain(ProgressEvent("other", 0, 5))
    clock.t += 0.6
    plain.tick()
    plain.tick()                                             # one line per interval
    assert lines[3:] == ["training: 1/60 (2 %) set 0 cycle 1: 27 steps, 4 s"]
    plain(ProgressEvent("training", 60, 60))
    assert lines[-1] == "training: 60/60 (100 %), 4 s"
    clock.t += 5
    plain.tick()                                             # a finished task says no more
    assert lines[-1].startswith("other: 0/5")
    plain(ProgressEvent("short", 0, 3))
    plain(ProgressEvent("short", 3, 3))
    clock.t += 5
    plain(ProgressEvent("other", 5, 5))
    plain.tick()
    assert not any(line.startswith("short") for line in lines)   # short tasks stay silent


def test_train_shows_a_start_line_at_once_and_lines_while_training(tmp_path):
    """A pipe sees the start line before any trial has run, and lines by the clock."""
    import os
    import subprocess
    import sys
    import time
    env = dict(os.environ, SNAN_HIL_PROGRESS_INTERVAL_S="0.2")
    proc = subprocess.Popen([sys.executable, "-m", "snan_hil.tools.cli", "train", "--sets", "1",
                             "--cycles", "3", "-o", str(tmp_path / "w.npz")], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    t0 = time.monotonic()
    first = proc.stderr.readline()
    t_first = time.monotonic() - t0
    rest = proc.stderr.read()
    proc.wait(timeout=300)
    assert proc.returncode == 0, rest
    assert first.startswith("training 1 set(s) x 3 cycles (on a first run"), first
    assert "training: 0/3 (0 %) set 0 cycle 1" in rest or "training: 3/3" in rest, rest
    assert t_first < 30, t_first                              # before the trials (start-up)
