"""The raw command console of a board (``snan-hil console``): typed commands, replies decoded,
the host's safety policy on every request, on both protocols.

:class:`BoardConsole` turns one typed line into :class:`~snan_hil.protocol.client.BoardClient`
calls and a decoded reply (:class:`ConsoleReply`); it never sends what the host's policy
forbids and never raises for a bad line (the reply says what is wrong). Commands::

    read R,C [CODE]             READ_CELL / mode 9 (CODE: read DAC code, at most the read limit)
    pulse set|reset R,C V [US]  WRITE_PULSE / mode 7 and the read after it (compliance checked
                                against the cell's last read; the cell is read first if unknown)
    column C CODE0 CODE1 ...    READ_COLUMN (framed), one row-DAC code per row (missing: 0)
    info | status | clock       the board's INFO / STATUS / CLOCK (status and clock: framed)
    9,VOL,ID,WL,BL              a legacy mode-9 line: read cell (BL, WL) at code VOL
    7,VOL,T_MS,T_US,SIGN,ID,WL,BL   a legacy mode-7 line: pulse code VOL (SIGN 1 = SET,
                                0 = RESET), T_MS ms + T_US us, then a read
    100                         a legacy INFO line
    help

Legacy lines are accepted on both protocols and go through the same client calls (the client
assigns its own request ids; the ID typed is ignored), so the host's limits hold for them too:
a line the existing firmware would take at 1.7 V is refused here above the host's write limit.
"""

from __future__ import annotations

import dataclasses
import shlex
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

from snan_hil.calibration.bench import CellBench
from snan_hil.calibration.board_io import BoardCellIO
from snan_hil.calibration.job import ONE, SingleUnit, UnitContext
from snan_hil.calibration.observer import CellEvent, PulseEvent
from snan_hil.common.errors import UserError
from snan_hil.common.polarity import Polarity
from snan_hil.protocol.legacy_codec import LegacyInfoRequest, LegacyPulse, LegacyRead, parse_request
from snan_hil.protocol.messages import Info

__all__ = ["ConsoleReply", "BoardConsole", "ConsoleJob", "ConsoleTally", "run_lines", "HELP",
           "MAX_LINE_CHARS", "QUIT_WORDS"]

HELP = __doc__.split("Commands::", 1)[1].split("\n\nLegacy", 1)[0] if __doc__ else ""
MAX_LINE_CHARS = 4096
"""Longest line the console takes (characters): a longer one is refused at once, unparsed
(the longest command, ``column`` with 32 codes, is ~200 characters)."""
QUIT_WORDS = ("quit", "exit")
SHOWN_CHARS = 80
"""How much of a refused over-long line a reply repeats."""


@dataclass
class ConsoleReply:
    """The outcome of one typed line: ``ok``, the decoded reply (or why it was refused), the
    request as sent (client call), ADC code and conductance (S) of a read, the pulse applied."""

    command: str
    ok: bool
    text: str
    request: str = ""
    adc: int | None = None
    g_s: float | None = None
    pulse: PulseEvent | None = None


class _Refused(Exception):
    pass


class BoardConsole:
    """Typed commands on the board of ``bench`` (its client as the run controls it, its
    read chain converts reads, its one write limit and the compliance rule hold for every
    pulse, each pulse journalled and recorded as it is applied, stage "console")."""

    def __init__(self, bench: CellBench) -> None:
        self.bench = bench
        self.client, self.chain = bench.client, bench.chain
        self.limits = bench.limits_for()
        self.info = bench.info
        self.cells: dict[tuple[int, int], BoardCellIO] = {}

    def _cell(self, text: str) -> tuple[int, int]:
        try:
            r, c = (int(x) for x in text.split(","))
        except ValueError:
            raise _Refused(f"{text!r}: give a cell as R,C, e.g. 3,5") from None
        if not (0 <= r < self.info.rows and 0 <= c < self.info.cols):
            raise _Refused(f"cell ({r},{c}) is outside the {self.info.rows}x{self.info.cols} "
                           "array")
        return r, c

    def _io(self, cell: tuple[int, int], width_us: int = 100) -> BoardCellIO:
        io = self.cells.get(cell)
        if io is None:
            io = self.cells[cell] = self.bench.cell(cell[0], cell[1], stage="console",
                                                    limits=self.limits, chain=self.chain)
        io.width_us = int(width_us)
        return io

    def execute(self, line: str) -> ConsoleReply:
        """One typed line -> its reply; never raises for a bad line (the reply says what is
        wrong: ``refused: ...`` before anything is sent, ``error: ...`` from the board)."""
        text = line.strip()
        if len(text) > MAX_LINE_CHARS:
            return ConsoleReply(text[:SHOWN_CHARS] + "...", False,
                                f"refused: a line of {len(text)} characters; at most "
                                f"{MAX_LINE_CHARS} (nothing sent)")
        try:
            return self._execute(text)
        except _Refused as exc:
            return ConsoleReply(text, False, f"refused: {exc}")
        except UserError as exc:          # protocol errors, host safety: one line, go on
            return ConsoleReply(text, False, f"error: {exc}")

    def _execute(self, text: str) -> ConsoleReply:
        if not text:
            raise _Refused("empty line; type help")
        if text[0].isdigit():
            return self._legacy_line(text)
        try:
            words = shlex.split(text)
        except ValueError as exc:             # an unclosed quote
            raise _Refused(f"{exc} in {text!r}; nothing sent") from None
        if not words:
            raise _Refused("empty line; type help")
        cmd, rest = words[0].lower(), words[1:]
        if cmd == "help":
            return ConsoleReply(text, True, HELP.strip("\n"))
        if cmd == "read":
            return self._read_words(text, rest)
        if cmd == "pulse":
            return self._pulse_words(text, rest)
        if cmd == "column":
            if not rest:
                raise _Refused("column C CODE0 CODE1 ...")
            try:
                col, codes = int(rest[0]), [int(x) for x in rest[1:]]
            except ValueError:
                raise _Refused("column C CODE0 CODE1 ...: integers") from None
            return self._column(text, col, codes)
        if cmd in ("info", "status", "clock"):
            return self._query(text, cmd)
        raise _Refused(f"unknown command {cmd!r}; type help")

    def _read_words(self, text: str, rest: list[str]) -> ConsoleReply:
        if not 1 <= len(rest) <= 2:
            raise _Refused("read R,C [CODE]")
        try:
            code = int(rest[1]) if len(rest) == 2 else self.limits.read_code
        except ValueError:
            raise _Refused(f"read R,C [CODE]: CODE {rest[1]!r} is not an integer (a read DAC "
                           "code)") from None
        return self._read(text, self._cell(rest[0]), code)

    def _pulse_words(self, text: str, rest: list[str]) -> ConsoleReply:
        if not 3 <= len(rest) <= 4 or rest[0].lower() not in ("set", "reset"):
            raise _Refused("pulse set|reset R,C V [WIDTH_US]")
        try:
            volts = float(rest[2])
            width = int(rest[3]) if len(rest) == 4 else 100
        except ValueError:
            raise _Refused("pulse set|reset R,C V [WIDTH_US]: V in volts, WIDTH_US an "
                           "integer") from None
        return self._pulse(text, self._cell(rest[1]), Polarity.parse(rest[0]), volts, width)

    def _read(self, text: str, cell: tuple[int, int], code: int) -> ConsoleReply:
        top = self.limits.max_read_code
        if not 1 <= code <= top:
            raise _Refused(f"read code {code} outside 1..{top} (the board's read limit "
                           f"{self.info.max_read_v} V)")
        adc = int(self.client.read_cell(cell[0], cell[1], code))
        g = float(self.chain.cell_conductance(adc, code))
        io = self._io(cell)
        io.last_g, io.last_adc = g, adc
        r = f"{1 / g:.0f} Ohm" if g > 0 else "open"
        return ConsoleReply(text, True, f"cell ({cell[0]},{cell[1]}): ADC {adc} at code {code} "
                            f"({self.chain.cell_read_volts(code):.4f} V): G = {g * 1e6:.2f} uS, "
                            f"R = {r}", f"read_cell({cell[0]}, {cell[1]}, {code})", adc, g)

    def _pulse(self, text: str, cell: tuple[int, int], pol: Polarity, volts: float,
               width: int) -> ConsoleReply:
        if not 1 <= width <= 1_000_000:
            raise _Refused(f"width {width} us: give 1..1000000")
        if not volts > 0:
            raise _Refused(f"{volts} V: give a positive amplitude (the polarity gives the "
                           "direction)")
        if volts > self.limits.max_write_v + 1e-9:
            top = self.info.write_dac_floor_code(self.limits.max_write_v)
            raise _Refused(f"{volts:g} V is above the host's write limit "
                           f"{self.limits.max_write_v:g} V (--max-write-v sets it; the largest "
                           f"code at or below it is {top} = "
                           f"{self.info.write_dac_volts(top):.4f} V); nothing sent")
        io = self._io(cell, width)
        if io.last_g is None:
            io.read()                       # the compliance rule needs the cell's conductance
        g = io.last_g
        assert g is not None
        cap = io.amplitude_cap(pol, g) if g > 0 else volts
        if volts > cap + 1e-9:
            raise _Refused(f"a {volts:g} V {pol.name} pulse at G = {g * 1e6:.1f} uS would draw "
                           f"more than the {self.limits.compliance_a * 1e3:g} mA compliance "
                           f"limit (at most {cap:.2f} V now); nothing sent")
        n = len(io.applied)
        after = io.pulse(pol, volts)
        ev = io.applied[-1] if len(io.applied) > n else None
        applied = ev.amplitude_v if ev is not None else volts
        return ConsoleReply(text, True, f"{pol.name} {applied:.4f} V {width} us on "
                            f"({cell[0]},{cell[1]}): ADC {io.last_adc}, G {g * 1e6:.2f} -> "
                            f"{after * 1e6:.2f} uS",
                            f"write_pulse({cell[0]}, {cell[1]}, {pol.name}, code "
                            f"{self.info.write_dac_floor_code(applied)}, {width} us)",
                            io.last_adc, after, ev)

    def _column(self, text: str, col: int, codes: list[int]) -> ConsoleReply:
        """READ_COLUMN with one row-DAC code per row (missing: 0); the reply gives the ADC
        code, the column current (the read chain's column conversion) and, with one driven
        row, that cell's conductance (with several at one code: their summed conductance)."""
        rows, cols = self.info.rows, self.info.cols
        if not 0 <= col < cols:
            raise _Refused(f"column {col} is outside 0..{cols - 1}")
        if len(codes) > rows:
            raise _Refused(f"{len(codes)} row codes for {rows} rows")
        top = self.limits.max_read_code
        bad = [c for c in codes if not 0 <= c <= top]
        if bad:
            raise _Refused(f"row code {bad[0]} outside 0..{top} (the host's read limit "
                           f"{self.info.max_read_v} V); nothing sent")
        codes = (codes + [0] * rows)[:rows]
        adc = int(self.client.read_column(col, codes))
        current = float(self.chain.column_current_a(adc))
        driven = sorted({c for c in codes if c})
        where = [r for r, c in enumerate(codes) if c]
        g: float | None = None
        tail = ""
        if len(where) == 1:
            g = float(self.chain.column_cell_conductance(adc, driven[0]))
            tail = f", one row driven: G({where[0]},{col}) = {g * 1e6:.2f} uS"
        elif len(driven) == 1 and where:
            total = float(self.chain.column_effective_conductance(adc, driven[0]))
            tail = f", {len(where)} rows at code {driven[0]}: sum of G = {total * 1e6:.2f} uS"
        return ConsoleReply(text, True, f"column {col}: ADC {adc}, I = {current * 1e6:.2f} uA"
                            f"{tail}", f"read_column({col}, {rows} row codes)", adc, g)

    def _legacy_line(self, text: str) -> ConsoleReply:
        try:
            req = parse_request(text)
        except (ValueError, UserError) as exc:
            raise _Refused(f"not a legacy request line: {exc}") from None
        if isinstance(req, LegacyInfoRequest):
            return self._query(text, "info")
        if isinstance(req, LegacyRead):
            # typed codes are refused, never clamped: the line sent is the line typed
            if not 1 <= req.vol <= self.limits.max_read_code:
                raise _Refused(f"read code {req.vol} is outside 1..{self.limits.max_read_code} "
                               "(the host's read limit); nothing sent")
            return self._read(text, self._cell(f"{req.bl},{req.wl}"), req.vol)
        assert isinstance(req, LegacyPulse)
        cell = self._cell(f"{req.bl},{req.wl}")
        if req.vol == 0:                     # mode 7 with code 0: read only
            return self._read(text, cell, self.limits.read_code)
        if req.sign not in (0, 1):
            # the firmware takes any non-zero SIGN as SET (docs/protocol.md); a typo must not
            # pulse: only the two documented values are sent
            raise _Refused(f"SIGN {req.sign}: give 1 (SET) or 0 (RESET); nothing sent")
        pol = Polarity.SET if req.sign == 1 else Polarity.RESET
        width = req.t_ms * 1000 + req.t_us
        return self._pulse(text, cell, pol, self.info.write_dac_volts(req.vol), width)

    def _query(self, text: str, what: str) -> ConsoleReply:
        if what == "info":
            i = self.info
            return ConsoleReply(text, True, f"board {i.board_id or '-'}, firmware "
                                f"{i.firmware_version or '-'}, {i.rows}x{i.cols}, read limit "
                                f"{i.max_read_v} V, write limit {i.max_write_v} V, compliance "
                                f"{i.compliance_a * 1e3:g} mA", "info")
        reply = self.client.status() if what == "status" else self.client.clock()
        fields = ", ".join(f"{k} {v}" for k, v in dataclasses.asdict(reply).items())
        return ConsoleReply(text, True, f"{what}: {fields}", f"{what}()")


@dataclass
class ConsoleTally:
    """What a console session ran: commands, and how many were refused or failed."""

    commands: int = 0
    ok: int = 0

    @property
    def refused(self) -> int:
        return self.commands - self.ok


def run_lines(con: BoardConsole, lines: Iterable[str],
              on_reply: Callable[[ConsoleReply], object]) -> ConsoleTally:
    """Run typed ``lines`` one after the other until the end or ``quit`` / ``exit``: blank
    lines and ``#`` comments are skipped, every other line gives one reply to ``on_reply``
    (a refused or failed line too: the next lines still run)."""
    tally = ConsoleTally()
    for line in lines:
        word = line.strip()
        if word.lower() in QUIT_WORDS:
            break
        if not word or word.startswith("#"):
            continue
        reply = con.execute(line)
        tally.commands += 1
        tally.ok += reply.ok
        on_reply(reply)
    return tally


class ConsoleJob:
    """``snan-hil console`` as a board job (:mod:`snan_hil.calibration.job`): one unit, the
    lines of ``lines(info)`` (the front door's source, given the board's INFO: a terminal
    with a prompt, a pipe) executed one by one by a :class:`BoardConsole` until they end or
    a line says quit / exit (blank lines and ``#`` comments skipped); each reply handed to
    ``on_reply`` and recorded as an event of the run's ``console`` stream, a pulse's cell
    result as a cell result. ``protocol``: recorded with the run."""

    kind: ClassVar[str] = "console"
    restartable: ClassVar[bool] = False

    def __init__(self, lines: Callable[[Info], Iterable[str]],
                 on_reply: Callable[[ConsoleReply], object], *,
                 protocol: str = "framed") -> None:
        self.lines, self.on_reply, self.protocol = lines, on_reply, protocol
        self._counts: dict[str, int] = {"commands": 0, "ok": 0}

    def describe(self) -> dict[str, Any]:
        return {"protocol": self.protocol}

    def plan(self, bench: CellBench) -> Sequence[SingleUnit]:
        _ = bench.chain                    # the layout's chain: another board's refused here
        return ONE

    def run_unit(self, unit: SingleUnit, bench: CellBench, ctx: UnitContext) -> dict[str, Any]:
        def on_reply(reply: ConsoleReply) -> None:
            ctx.emit("console", {"command": reply.command, "request": reply.request,
                                 "reply": reply.text, "ok": reply.ok, "adc": reply.adc,
                                 "g_s": reply.g_s})
            if reply.pulse is not None:         # the pulse itself: recorded as applied
                bench.report(CellEvent(reply.pulse.row, reply.pulse.col, "console pulse",
                                       reply.g_s, pulses=1))
            self.on_reply(reply)
        tally = run_lines(BoardConsole(bench), self.lines(bench.info), on_reply)
        self._counts = {"commands": tally.commands, "ok": tally.ok}
        return dict(self._counts)

    def restore(self, unit: SingleUnit, record: dict[str, Any]) -> None:
        raise NotImplementedError("a console session is not resumed")

    def result(self, records: Mapping[str, dict[str, Any]], status: str) -> dict[str, int]:
        """Commands executed and how many of them were ok (so far, when interrupted)."""
        return dict(records.get(ONE[0].key, self._counts))

    def summary(self, result: dict[str, int]) -> dict[str, Any]:
        return dict(result)
