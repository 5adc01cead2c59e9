"""The live view of a run in the terminal (``snan-hil watch``), built on Textual: works over
SSH, tested headless with Textual's pilot and snapshot tests.

Panels: the run (kind, uid, sample, operator, status), the conductance heat map of the
32 x 8 array (log-shaded, a cell's last conductance; cells pulsed in this run marked), the
progress of each task and the cell outcomes so far, the conductance trace of the cell the run
works on now (a bar per pulse or read, SET / RESET / read coloured apart: MemriBoard's live
plot, in the terminal), the pulse log (newest last), and for
hardware runs the 6 x 6 grid of the last launch (each cell shaded by its astrocyte's calcium,
the agent's path drawn) with the running median path length per scenario.

Keys: ``p`` pause / resume, ``s`` stop (the job stops before its next pulse:
:mod:`snan_hil.records.control`), ``q`` quit the view (the job goes on).
"""

from __future__ import annotations

import math
from typing import Any

from rich.console import Group
from rich.table import Table
from rich.text import Text
from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal, Vertical
from textual.widgets import Footer, RichLog, Static

from snan_hil.tools.watch_state import RunView

__all__ = ["WatchApp", "heat_map", "hil_grid", "cell_trace"]

POLL_S = 0.25

_RAMP = [(68, 1, 84), (59, 82, 139), (33, 145, 140), (94, 201, 98), (253, 231, 37)]


def _shade(t: float) -> str:
    t = min(max(t, 0.0), 1.0)
    x = t * (len(_RAMP) - 1)
    i = min(int(x), len(_RAMP) - 2)
    f = x - i
    r, g, b = (round(a + (c - a) * f) for a, c in zip(_RAMP[i], _RAMP[i + 1]))
    return f"rgb({r},{g},{b})"


def heat_map(view: RunView) -> Text:
    """The array's conductances (uS), log-shaded; ``*`` marks cells pulsed in this run."""
    values = [g for g in view.g.values() if g > 0 and math.isfinite(g)]
    lo, hi = (math.log10(min(values)), math.log10(max(values))) if values else (0.0, 1.0)
    out = Text(no_wrap=True, overflow="crop")
    out.append("row " + "".join(f"  WL{c:<2}" for c in range(view.cols)) + "\n", style="bold")
    for r in range(view.rows):
        out.append(f"{r:>3} ", style="bold")
        for c in range(view.cols):
            g = view.g.get((r, c))
            mark = "*" if (r, c) in view.pulses else " "
            if g is None or not g > 0:
                out.append("   · " + mark, style="grey50")
                continue
            t = 0.0 if hi <= lo else (math.log10(g) - lo) / (hi - lo)
            us = g * 1e6
            text = f"{us:5.1f}" if us < 100 else f"{us:5.0f}"
            out.append(text + mark, style=("black" if t > 0.55 else "white") + " on " + _shade(t))
        out.append("\n")
    span = (f"{10 ** lo * 1e6:.1f}..{10 ** hi * 1e6:.1f} uS" if values else "no reads yet")
    out.append(f"G in uS, log colour {span}\n* pulsed in this run", style="italic")
    return out


def hil_grid(view: RunView) -> Text:
    """The last launch on its grid: each cell shaded by its astrocyte's calcium after the
    launch (scale 0..max, '!' above Ca_thr), the path's cells numbered by visit (mod 10),
    S start, G the last cell."""
    if not view.launches:
        return Text("no launches yet", style="italic")
    L = view.launches[-1]
    top = max(L.calcium) if L.calcium else 0.0
    order: dict[int, int] = {}
    for k, cell in enumerate(L.path):
        order.setdefault(cell, k)
    where = f" set {L.set_index}" if len(view.sets) > 1 else ""
    out = Text(f"{L.scenario}{where} launch {L.launch}: {L.steps} steps, "
               f"{'goal reached' if L.success else 'failed'}\n", style="bold")
    for r in range(L.rows):
        for c in range(L.cols):
            i = r * L.cols + c
            ca = L.calcium[i] if i < len(L.calcium) else 0.0
            t = ca / top if top > 0 else 0.0
            if i == (L.path[0] if L.path else -1):
                mark = " S "
            elif L.path and i == L.path[-1]:
                mark = " G "
            elif i in order:
                mark = f" {order[i] % 10} "
            else:
                mark = "   "
            if ca > L.ca_thr > 0:
                mark = mark[:2] + "!"
            out.append(mark, style=("black" if t > 0.55 else "white") + " on " + _shade(t))
        out.append("\n")
    out.append(f"calcium 0..{top:.3g} (! above Ca_thr {L.ca_thr:g})", style="italic")
    return out


_BLOCKS = " ▁▂▃▄▅▆▇█"
TRACE_COLORS = {"SET": "rgb(31,119,180)", "RESET": "rgb(255,127,14)", "read": "grey62"}
"""The trace's colours: the bench figures' SET blue and RESET orange, reads grey."""


def cell_trace(view: RunView, width: int = 60, height: int = 8) -> Text:
    """The running cell's conductance after each of its pulses and reads in this run (the
    newest ``width`` of them; one column each, bars ``height`` lines high, SET blue, RESET
    orange, reads grey; log scale when it spans more than a factor 5): MemriBoard's live
    plot, in the terminal."""
    if view.trace_cell is None or not view.trace:
        return Text("no pulse yet", style="italic")
    pts = list(view.trace)[-width:]
    values = [g for g, _w in pts if g > 0 and math.isfinite(g)]
    if not values:
        return Text("no conductance yet", style="italic")
    lo, hi = min(values), max(values)
    log = hi / lo > 5
    f = (lambda g: math.log10(g)) if log else (lambda g: g)
    a, b = f(lo), f(hi)
    levels = [0 if not (g > 0 and math.isfinite(g)) else
              (height * 8 if b <= a else 1 + round((f(g) - a) / (b - a) * (height * 8 - 1)))
              for g, _w in pts]
    r, c = view.trace_cell
    out = Text(f"cell ({r},{c}): {view.trace_total} pulses and reads in this run, the last "
               f"{len(pts)} shown; now {pts[-1][0] * 1e6:.2f} uS\n", style="bold",
               no_wrap=True, overflow="crop")
    for row in range(height - 1, -1, -1):
        label = (f"{hi * 1e6:8.1f} " if row == height - 1 else
                 f"{lo * 1e6:8.1f} " if row == 0 else " " * 9)
        out.append(label, style="grey62")
        for level, (_g, what) in zip(levels, pts):
            fill = min(8, max(0, level - row * 8))
            out.append(_BLOCKS[fill], style=TRACE_COLORS.get(what, "white"))
        out.append("\n")
    out.append(f"uS{' (log)' if log else ''}; ", style="italic")
    for what, color in TRACE_COLORS.items():
        out.append("█ ", style=color)
        out.append(f"{what}  ", style="italic")
    return out


def _run_text(view: RunView, controllable: bool) -> Text:
    s = view.start or {}
    meta = "  ".join(f"{k}: {s[k]}" for k in ("sample", "operator", "note") if s.get(k))
    tags = ", ".join(s.get("tags") or [])
    t = Text()
    t.append(f"{view.kind} run {str(s.get('uid', '-'))[:8]}", style="bold")
    t.append(f"  [{view.status}]", style="bold yellow" if view.stop is None else "bold green")
    t.append(f"  board {s.get('board_id', '-')}  port {s.get('port', '-')}\n")
    if meta or tags:
        t.append(meta + (f"  tags: {tags}" if tags else "") + "\n")
    t.append(str(s.get("command", "")), style="grey62")
    if not controllable:
        t.append("\n(pause/stop: only for a running run of this database)", style="grey50")
    return t


def _progress_table(view: RunView) -> Table:
    t = Table(show_header=True, header_style="bold", expand=True, box=None)
    t.add_column("task")
    t.add_column("done", justify="right")
    t.add_column("", ratio=1)
    for task, d in view.progress.items():
        total = d.get("total") or 0
        done = int(d.get("done") or 0)
        frac = done / total if total else 0.0
        bar = "█" * int(round(20 * frac)) + "░" * (20 - int(round(20 * frac)))
        t.add_row(task, f"{done}/{total or '?'}", f"{bar} {str(d.get('detail') or '')[:40]}")
    counts = view.outcome_counts()
    if counts:
        t.add_row("cells", str(sum(counts.values())),
                  ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))[:60])
    t.add_row("pulses", str(view.total_pulses), "")
    return t


def _medians_table(view: RunView) -> Table:
    t = Table(show_header=True, header_style="bold", box=None, title="running medians",
              title_justify="left")
    for col in ("scenario", "runs", "ok", "median"):
        t.add_column(col, justify="right" if col != "scenario" else "left")
    for scen, (med, ok, n) in view.medians().items():
        t.add_row(scen, str(n), str(ok), "-" if med is None else f"{med:g}")
    return t


def _pulse_line(d: dict[str, Any]) -> str:
    gb, ga = d.get("g_before_s"), d.get("g_after_s")
    before = "-" if gb is None else f"{gb * 1e6:7.2f}"
    after = "-" if ga is None else f"{ga * 1e6:7.2f}"
    return (f"({d['row']:>2},{d['col']}) #{d['n']:<3} {d['polarity']:<5} "
            f"{d['amplitude_v']:.3f} V {d['width_us']:>5} us  {before} -> {after} uS  "
            f"{d.get('stage') or ''}")


class WatchApp(App[None]):
    """Follows ``source`` (:class:`~snan_hil.tools.watch_state.HistorySource` or
    :class:`~snan_hil.tools.watch_state.ReplaySource`), polling every ``poll_s``."""

    CSS = """
    #left { width: 58; }
    #right { width: 1fr; }
    .panel { border: round $accent; padding: 0 1; }
    #log { height: 1fr; }
    """
    BINDINGS = [Binding("p", "pause", "pause / resume"), Binding("s", "stop", "stop the job"),
                Binding("q", "quit", "quit the view")]
    TITLE = "snan-hil watch"

    def __init__(self, source: Any, *, poll_s: float = POLL_S) -> None:
        super().__init__()
        self.source = source
        self.view = RunView()
        self.poll_s = poll_s
        self.paused = False
        self._logged = 0

    def compose(self) -> ComposeResult:
        with Horizontal():
            with Vertical(id="left"):
                yield Static(id="map", classes="panel")
            with Vertical(id="right"):
                yield Static(id="run", classes="panel")
                yield Static(id="progress", classes="panel")
                yield Static(id="hil", classes="panel")
                yield Static(id="trace", classes="panel")
                yield RichLog(id="log", classes="panel", max_lines=200, wrap=False)
        yield Footer()

    def on_mount(self) -> None:
        self.query_one("#map", Static).border_title = "conductance map"
        self.query_one("#run", Static).border_title = "run"
        self.query_one("#progress", Static).border_title = "progress"
        self.query_one("#hil", Static).border_title = "hardware run: grid and medians"
        self.query_one("#trace", Static).border_title = "conductance of the running cell"
        self.query_one("#log", RichLog).border_title = "pulse log"
        self.refresh_view()
        self.set_interval(self.poll_s, self.refresh_view)

    def refresh_view(self) -> None:
        """Poll the source and redraw what changed."""
        docs = self.source.poll()
        first = self.view.start is None
        if docs:
            self.view.feed(docs)
        if not docs and not first:
            return
        controllable = bool(getattr(self.source, "controllable", False)) and \
            self.view.stop is None
        self.query_one("#run", Static).update(_run_text(self.view, controllable))
        self.query_one("#map", Static).update(heat_map(self.view))
        self.query_one("#progress", Static).update(_progress_table(self.view))
        trace = self.query_one("#trace", Static)
        trace.display = self.view.trace_cell is not None
        if self.view.trace_cell is not None:
            trace.update(cell_trace(self.view, width=max(20, self.size.width - 58 - 16)))
        hil = self.query_one("#hil", Static)
        hil.display = bool(self.view.launches)
        if self.view.launches:
            lines = hil_grid(self.view).split("\n", allow_blank=True)
            title, body = lines[0], Text("\n").join(lines[1:])
            grid = Table.grid(padding=(0, 3))
            grid.add_row(body, _medians_table(self.view))
            hil.update(Group(title, grid))
        log = self.query_one("#log", RichLog)
        total = self.view.total_pulses
        new = list(self.view.log)[-(total - self._logged):] if total > self._logged else []
        for d in new:
            log.write(_pulse_line(d))
        self._logged = total

    def _control(self, action: str) -> bool:
        if not getattr(self.source, "controllable", False) or self.view.stop is not None:
            self.notify("nothing to control: this run is a replay or finished",
                        severity="warning")
            return False
        self.source.request(action)
        return True

    def action_pause(self) -> None:
        action = "resume" if self.paused else "pause"
        if self._control(action):
            self.paused = not self.paused
            self.notify(f"{action} requested (the job acts between pulses)")

    def action_stop(self) -> None:
        if self._control("stop"):
            self.notify("stop requested: the job stops before its next pulse")
