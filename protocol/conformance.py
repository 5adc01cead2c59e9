"""Conformance vectors of the framed protocol as data: read, write, describe, check.

The vectors live in ``conformance/v1/framed/*.jsonl`` (``conformance/README.md`` describes the
layout; ``conformance/generate.py`` makes them from the Python board model). A file is one
**session**: a board in a stated start state (chip, seed, line rate, the boot nonces it will
draw), then **steps** in order, each the exact bytes the host sends and the exact bytes the
board answers (possibly nothing, possibly several frames). A second kind of file holds
**reply vectors**: frames a board (or the server in front of it) may send and what a host must
do with them.

What a conforming implementation may choose (documented in docs/protocol.md) is named per step
in ``free`` as ``Message.field`` (an ERROR's message text, INFO's firmware version and board id,
CLOCK's time and energy); :func:`compare_replies` compares every other byte.

A third kind, **sequences** (``sequences.jsonl``), carries state across power cycles: each
sequence starts a board on a named chip (seed and serial) and interleaves exchanges with
restarts of the board - a clean stop or a kill, after which an emulated board replays its
journal - so what one request leaves behind (a compliance basis, the reply cache, the
registers after a boot) is checked by the requests after it (:func:`run_sequence`).

Pure data and byte comparison: no board, no I/O beyond reading and writing the files.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from snan_hil.protocol.errors import FrameError, MessageError
from snan_hil.protocol.frames import Frame, FrameDecoder, pack_frame
from snan_hil.protocol.messages import MESSAGE_TYPES, Message

__all__ = ["FORMAT", "FREE_FIELDS", "BoardSetup", "Step", "Session", "ReplyVector",
           "SequenceBoardSetup", "SequenceStep", "Sequence", "SequenceBoard",
           "describe_wire", "compare_replies", "run_session", "load_session", "dump_session",
           "load_replies", "dump_replies", "run_sequence", "load_sequences", "dump_sequences",
           "frames_of", "message_fields", "describe_frame"]

FORMAT = "snan-hil-conformance/1"
"""Format marker of every vector file (first line)."""

FREE_FIELDS: dict[str, tuple[str, ...]] = {
    "ErrorReply": ("message",),
    "Info": ("firmware_version", "board_id"),
    "ClockReply": ("time_us", "energy_j"),
}
"""Reply fields an implementation chooses itself (docs/protocol.md, section 7)."""


@dataclass(frozen=True)
class BoardSetup:
    """The start state of a session's board."""

    chip: str = "emulator default chip (crossbar_model defaults, stuck cells, noise)"
    chip_seed: int = 0
    baud: int = 115200
    boot_nonces: tuple[int, ...] = ()
    """The nonces the board draws, in order: at power-on, then at each RESET."""
    needs: tuple[str, ...] = ()
    """Optional capabilities (``Capability`` names) the session's board must have, e.g.
    ``LEARN`` (on-board learning, issue 34: the Python MCU with ``on_board_learning``); a board
    without them skips the session. Written only when not empty."""

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {"chip": self.chip, "chip_seed": self.chip_seed, "baud": self.baud,
                             "boot_nonces": [f"0x{n:08x}" for n in self.boot_nonces]}
        if self.needs:
            d["needs"] = list(self.needs)
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "BoardSetup":
        return cls(d["chip"], int(d["chip_seed"]), int(d["baud"]),
                   tuple(int(n, 16) for n in d["boot_nonces"]),
                   tuple(str(x) for x in d.get("needs", ())))


@dataclass(frozen=True)
class Step:
    """Bytes in, bytes out. ``analog``: the reply carries values measured on the chip (ADC
    codes, counters that depend on them): exact only on this project's emulated chip."""

    name: str
    send: bytes
    expect: bytes
    note: str = ""
    doc: str = ""
    free: tuple[str, ...] = ()
    analog: bool = False

    def to_json(self, index: int) -> dict[str, Any]:
        out: dict[str, Any] = {"step": index, "name": self.name}
        if self.note:
            out["note"] = self.note
        if self.doc:
            out["doc"] = self.doc
        out.update(_exchange_json(self.send, self.expect, self.free, self.analog))
        return out

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "Step":
        return cls(d["name"], bytes.fromhex(d["send"]), bytes.fromhex(d["expect"]),
                   d.get("note", ""), d.get("doc", ""), tuple(d.get("free", ())),
                   bool(d.get("analog", False)))


@dataclass(frozen=True)
class Session:
    """A board from power-on and the exchanges with it, in order."""

    name: str
    title: str
    board: BoardSetup
    steps: tuple[Step, ...] = ()


@dataclass(frozen=True)
class ReplyVector:
    """A frame a host may receive and what it must do: ``host`` is one of ``resend``
    (at once), ``resend_after_backoff``, ``raise:<ErrorClass>``, ``accept``."""

    name: str
    wire: bytes
    host: str
    note: str = ""

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "note": self.note, "wire": self.wire.hex(),
                "host": self.host, "frames": describe_wire(self.wire)}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "ReplyVector":
        return cls(d["name"], bytes.fromhex(d["wire"]), d["host"], d.get("note", ""))


@dataclass(frozen=True)
class SequenceBoardSetup:
    """The start state of a sequence's board: a chip made from ``chip_seed`` that carries the
    serial ``chip_serial`` (the C firmware reads it from its EEPROM identity record and reports
    it in INFO's board id, so its INFO has the length of a real board's), kept durable (a
    state file and its journal), first booted drawing ``boot_nonces``."""

    chip: str = "emulator default chip (crossbar_model defaults, stuck cells, noise)"
    chip_seed: int = 0
    chip_serial: str | None = None
    baud: int = 115200
    boot_nonces: tuple[int, ...] = ()

    def to_json(self) -> dict[str, Any]:
        return {"chip": self.chip, "chip_seed": self.chip_seed, "chip_serial": self.chip_serial,
                "baud": self.baud, "boot_nonces": [f"0x{n:08x}" for n in self.boot_nonces]}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "SequenceBoardSetup":
        return cls(d["chip"], int(d["chip_seed"]), d.get("chip_serial"), int(d["baud"]),
                   tuple(int(n, 16) for n in d["boot_nonces"]))


@dataclass(frozen=True)
class SequenceStep:
    """One step of a sequence: ``do`` = ``send`` (bytes in, the expected bytes out, as a
    :class:`Step`) or ``restart`` (power-cycle the board: ``kill`` True = without a clean stop,
    so an emulated board replays its journal; the new boot draws ``boot_nonces``)."""

    name: str
    do: str
    send: bytes = b""
    expect: bytes = b""
    note: str = ""
    free: tuple[str, ...] = ()
    analog: bool = False
    kill: bool = False
    boot_nonces: tuple[int, ...] = ()

    DOS = ("send", "restart")

    def to_json(self, sequence: str, index: int) -> dict[str, Any]:
        out: dict[str, Any] = {"sequence": sequence, "step": index, "name": self.name,
                               "do": self.do}
        if self.note:
            out["note"] = self.note
        if self.do == "restart":
            out.update({"kill": self.kill,
                        "boot_nonces": [f"0x{n:08x}" for n in self.boot_nonces]})
            return out
        out.update(_exchange_json(self.send, self.expect, self.free, self.analog))
        return out

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "SequenceStep":
        if d.get("do") not in cls.DOS:
            raise ValueError(f"step {d.get('step')}: 'do' is {d.get('do')!r}, not one of "
                             f"{', '.join(cls.DOS)}")
        if d["do"] == "restart":
            return cls(d["name"], "restart", note=d.get("note", ""), kill=bool(d["kill"]),
                       boot_nonces=tuple(int(n, 16) for n in d["boot_nonces"]))
        return cls(d["name"], "send", bytes.fromhex(d["send"]), bytes.fromhex(d["expect"]),
                   d.get("note", ""), tuple(d.get("free", ())), bool(d.get("analog", False)))


@dataclass(frozen=True)
class Sequence:
    """A board on a named chip from power-on, exchanges and restarts, in order."""

    name: str
    title: str
    board: SequenceBoardSetup
    steps: tuple[SequenceStep, ...] = ()


class SequenceBoard(Protocol):
    """What :func:`run_sequence` drives: a board started in the sequence's start state."""

    def feed(self, data: bytes) -> bytes: ...

    def restart(self, *, kill: bool, boot_nonces: tuple[int, ...]) -> None: ...


# --------------------------------------------------------------------------- describing bytes
def _jsonable(value: Any) -> Any:
    if isinstance(value, (bytes, bytearray)):
        return value.hex()
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, float):
        return value
    if isinstance(value, int):       # IntEnum, bool
        return value if isinstance(value, bool) else int(value)
    return value


def message_fields(msg: Message) -> dict[str, Any]:
    """Every field of a message (JSON-ready)."""
    return {f.name: _jsonable(getattr(msg, f.name)) for f in dataclasses.fields(msg)}


def describe_frame(frame: Frame) -> dict[str, Any]:
    """Header, CRC and decoded message of a checked frame."""
    raw = pack_frame(frame)
    cls = MESSAGE_TYPES.get(frame.type)
    out: dict[str, Any] = {
        "type": f"0x{frame.type:02x}", "message": cls.__name__ if cls else None,
        "version": frame.version, "flags": frame.flags, "seq": frame.seq,
        "nonce": f"0x{frame.nonce:08x}", "length": len(frame.payload),
        "crc": f"0x{int.from_bytes(raw[-2:], 'little'):04x}",
    }
    try:
        out["fields"] = message_fields(frame.message())
    except MessageError as exc:
        out["fields"] = None
        out["undecodable"] = str(exc)
    return out


def describe_wire(wire: bytes) -> list[dict[str, Any]]:
    """Each delimited frame of ``wire``: decoded, or why it is damaged (empty frames are
    skipped, a trailing part without delimiter is reported as ``unterminated``)."""
    out: list[dict[str, Any]] = []
    for event in frames_of(wire):
        if isinstance(event, Frame):
            out.append(describe_frame(event))
        else:
            out.append({"damaged": event.kind, "why": str(event)})
    tail = wire.rsplit(b"\x00", 1)[-1] if b"\x00" in wire else wire
    if tail:
        out.append({"unterminated": len(tail)})
    return out


def _exchange_json(send: bytes, expect: bytes, free: tuple[str, ...],
                   analog: bool) -> dict[str, Any]:
    """The JSON fields of one exchange of a session or sequence step: its bytes, its free
    fields, whether it is analog, and both sides described frame by frame."""
    return {"send": send.hex(), "expect": expect.hex(), "free": list(free), "analog": analog,
            "send_frames": describe_wire(send), "expect_frames": describe_wire(expect)}


def frames_of(wire: bytes) -> list[Frame | FrameError]:
    """The frames (or errors of damaged ones) a fresh receiver makes of ``wire``."""
    return FrameDecoder().feed_events(bytes(wire))


# --------------------------------------------------------------------------- checking
def compare_replies(expected: bytes, got: bytes, free: Iterable[str] = ()) -> str | None:
    """None when ``got`` conforms to ``expected``: the same bytes, or the same frames whose
    only differences are in the ``free`` fields (``Message.field``). Else what differs."""
    if got == expected:
        return None
    free_set = set(free)
    want, have = frames_of(expected), frames_of(got)
    if len(want) != len(have):
        return (f"{len(have)} frames instead of {len(want)} (got {got.hex()}, expected "
                f"{expected.hex()})")
    for k, (a, b) in enumerate(zip(want, have)):
        if not isinstance(a, Frame) or not isinstance(b, Frame):
            return f"frame {k}: damaged (got {got.hex()}, expected {expected.hex()})"
        if a.header() != b.header():
            return f"frame {k}: header {b.header()} instead of {a.header()}"
        if a.payload == b.payload:
            continue
        try:
            ma, mb = a.message(), b.message()
        except MessageError as exc:
            return f"frame {k}: payload differs and does not decode ({exc})"
        name = type(ma).__name__
        diffs = [f.name for f in dataclasses.fields(ma)
                 if getattr(ma, f.name) != getattr(mb, f.name)
                 and f"{name}.{f.name}" not in free_set]
        if diffs:
            return (f"frame {k} ({name}): " + ", ".join(
                f"{d} = {getattr(mb, d)!r}, expected {getattr(ma, d)!r}" for d in diffs))
    return None


def run_session(session: Session, feed: Callable[[bytes], bytes], *,
                analog: bool = True) -> list[str]:
    """Feed every step's bytes to a board (``feed``: bytes in -> bytes out) in order and
    compare the answers; the list of mismatches (empty: the board conforms). ``analog=False``
    skips the comparison of steps whose replies carry chip measurements (they are still
    sent, so the board's state follows the session)."""
    problems: list[str] = []
    for i, step in enumerate(session.steps, 1):
        _check_exchange(f"{session.name} step {i} ({step.name})", step, feed, analog, problems)
    return problems


def _check_exchange(label: str, step: Step | SequenceStep, feed: Callable[[bytes], bytes],
                    analog: bool, problems: list[str]) -> None:
    """Send one step's bytes to the board (``feed``) and add to ``problems`` how its answer
    differs from the step's expected bytes (``label: why``); an analog step's answer is not
    compared when ``analog`` is False (it is still sent, so the board's state follows)."""
    got = feed(step.send)
    if step.analog and not analog:
        return
    why = compare_replies(step.expect, got, step.free)
    if why:
        problems.append(f"{label}: {why}")


def run_sequence(sequence: Sequence, board: SequenceBoard, *, analog: bool = True) -> list[str]:
    """Run a sequence on ``board`` (started in ``sequence.board``'s state): send each
    exchange's bytes and compare the answer (as :func:`run_session`), restart the board where
    the sequence does; the list of mismatches (empty: the board conforms)."""
    problems: list[str] = []
    for i, step in enumerate(sequence.steps, 1):
        if step.do == "restart":
            board.restart(kill=step.kill, boot_nonces=step.boot_nonces)
            continue
        _check_exchange(f"{sequence.name} step {i} ({step.name})", step, board.feed, analog,
                        problems)
    return problems


# --------------------------------------------------------------------------- files
def dump_session(session: Session) -> str:
    """The JSONL text of a session: a header line, then one line per step."""
    head = {"format": FORMAT, "kind": "session", "protocol": "framed", "version": 1,
            "session": session.name, "title": session.title, "board": session.board.to_json(),
            "steps": len(session.steps)}
    lines = [json.dumps(head, ensure_ascii=False)]
    lines += [json.dumps(s.to_json(i), ensure_ascii=False)
              for i, s in enumerate(session.steps, 1)]
    return "\n".join(lines) + "\n"


def load_session(path: str | Path) -> Session:
    """Read a session file (ValueError naming the file when it is not one)."""
    lines = Path(path).read_text(encoding="utf-8").splitlines()
    head = json.loads(lines[0]) if lines else {}
    if head.get("format") != FORMAT or head.get("kind") != "session":
        raise ValueError(f"{path}: not a {FORMAT} session file")
    steps = tuple(Step.from_json(json.loads(line)) for line in lines[1:] if line.strip())
    if len(steps) != head["steps"]:
        raise ValueError(f"{path}: {len(steps)} steps, the header says {head['steps']}")
    return Session(head["session"], head["title"], BoardSetup.from_json(head["board"]), steps)


def dump_replies(name: str, title: str, vectors: Iterable[ReplyVector]) -> str:
    """The JSONL text of a reply-vector file."""
    vecs = list(vectors)
    head = {"format": FORMAT, "kind": "replies", "protocol": "framed", "version": 1,
            "session": name, "title": title, "vectors": len(vecs)}
    return "\n".join([json.dumps(head, ensure_ascii=False)]
                     + [json.dumps(v.to_json(), ensure_ascii=False) for v in vecs]) + "\n"


def load_replies(path: str | Path) -> list[ReplyVector]:
    """Read a reply-vector file."""
    lines = Path(path).read_text(encoding="utf-8").splitlines()
    head = json.loads(lines[0]) if lines else {}
    if head.get("format") != FORMAT or head.get("kind") != "replies":
        raise ValueError(f"{path}: not a {FORMAT} reply-vector file")
    return [ReplyVector.from_json(json.loads(line)) for line in lines[1:] if line.strip()]



def dump_sequences(title: str, sequences: Iterable[Sequence]) -> str:
    """The JSONL text of a sequence-vector file: a header line, then per sequence a line
    naming it and its board, followed by one line per step."""
    seqs = list(sequences)
    lines = [json.dumps({"format": FORMAT, "kind": "sequences", "protocol": "framed",
                         "version": 1, "title": title, "sequences": len(seqs)},
                        ensure_ascii=False)]
    for seq in seqs:
        lines.append(json.dumps({"sequence": seq.name, "title": seq.title,
                                 "board": seq.board.to_json(), "steps": len(seq.steps)},
                                ensure_ascii=False))
        lines += [json.dumps(s.to_json(seq.name, i), ensure_ascii=False)
                  for i, s in enumerate(seq.steps, 1)]
    return "\n".join(lines) + "\n"


def load_sequences(path: str | Path) -> list[Sequence]:
    """Read a sequence-vector file (ValueError naming the file when it is not one)."""
    lines = [json.loads(line) for line in
             Path(path).read_text(encoding="utf-8").splitlines() if line.strip()]
    head = lines[0] if lines else {}
    if head.get("format") != FORMAT or head.get("kind") != "sequences":
        raise ValueError(f"{path}: not a {FORMAT} sequence-vector file")
    out: list[Sequence] = []
    current: dict[str, Any] | None = None
    steps: list[SequenceStep] = []

    def finish() -> None:
        if current is None:
            return
        if len(steps) != current["steps"]:
            raise ValueError(f"{path}: sequence {current['sequence']} has {len(steps)} steps, "
                             f"its line says {current['steps']}")
        out.append(Sequence(current["sequence"], current["title"],
                            SequenceBoardSetup.from_json(current["board"]), tuple(steps)))

    try:
        for d in lines[1:]:
            if "step" not in d:
                finish()
                current, steps = d, []
            elif current is None or d.get("sequence") != current["sequence"]:
                raise ValueError(f"step {d.get('step')} of {d.get('sequence')!r} outside its "
                                 "sequence")
            else:
                steps.append(SequenceStep.from_json(d))
        finish()
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: {exc}") from None
    if len(out) != head.get("sequences"):
        raise ValueError(f"{path}: {len(out)} sequences, the header says {head.get('sequences')}")
    return out
