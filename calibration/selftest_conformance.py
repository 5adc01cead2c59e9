"""The conformance vectors that change nothing on the chip, run against a live board.

The vectors (``conformance/v1/framed/*.jsonl``, :mod:`snan_hil.protocol.conformance`) state the
boot nonces the board draws; a real board draws its own. So each session is replayed on the
live board with the nonces *mapped*: the board is RESET first (counters 0, reply cache empty,
as after the power-on the session assumes), a vector nonce is tied to the live one the first
time an expected reply carries it, and every request frame carrying a tied vector nonce is
re-sent with the live one (re-framed, new CRC). Damaged frames go out as they are. Replies are
compared frame by frame: header (the nonce through the map), type, and every payload field
except the free ones (docs/protocol.md section 7) and, in steps whose reply carries chip
measurements (``analog``), all payload fields.

Left out, so the chip is not changed: the sessions about pulses (``write_pulse``,
``program_cell``, ``learn``: on-board learning applies pulses and needs its capability) and
any step of another session that sends a WRITE_PULSE or PROGRAM_CELL frame (the rest of that
session is skipped: its replies depend on the pulse).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path

from snan_hil.protocol.conformance import Session, Step, frames_of, load_session
from snan_hil.protocol.errors import FrameError, MessageError
from snan_hil.protocol.frames import Frame, cobs_encode, decode_frame, pack_frame
from snan_hil.protocol.messages import ProgramCell, WritePulse
from snan_hil.protocol.transport import Transport

__all__ = ["DEFAULT_VECTORS", "SKIPPED_SESSIONS", "LIVE_FREE", "LiveResult", "run_live_conformance"]

DEFAULT_VECTORS = Path(__file__).resolve().parent.parent / "conformance" / "v1" / "framed"
"""The framed vectors of this source tree."""
SKIPPED_SESSIONS = ("write_pulse", "program_cell", "learn")
"""Sessions left out: every one of their steps is about a pulse."""
LIVE_FREE = ("StatusReply.frames_out",)
"""Fields free in a live replay as well: the RESET sent before each session is counted."""
_PULSES = (WritePulse.TYPE, ProgramCell.TYPE)
_NOT_SESSIONS = ("replies", "sequences")      # other kinds of vector file


@dataclass
class LiveResult:
    """What the replay found: steps compared, steps skipped (pulses), sessions run, problems
    (one line each: session, step, what differs)."""

    compared: int = 0
    skipped: int = 0
    sessions: list[str] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)


def _sends_pulse(step: Step) -> bool:
    return any(isinstance(f, Frame) and f.type in _PULSES for f in frames_of(step.send))


def _rewrite(data: bytes, nonces: dict[int, int]) -> bytes:
    """``data`` with every frame that carries a tied vector nonce re-encoded with the live one
    (delimiters, damaged and partial frames kept as they are; a frame shorter than 254 bytes
    keeps its length, so a request split over steps can be split at the same place)."""
    segments = data.split(b"\x00")
    for k, seg in enumerate(segments[:-1]):        # the last segment has no delimiter yet
        if not seg:
            continue
        try:
            frame = decode_frame(seg)
        except FrameError:
            continue
        if frame.nonce in nonces:
            segments[k] = cobs_encode(pack_frame(dataclasses.replace(
                frame, nonce=nonces[frame.nonce])))
    return b"\x00".join(segments)


def _pieces(steps: tuple[Step, ...], i: int, nonces: dict[int, int]) -> list[bytes]:
    """The bytes to send for step ``i`` and the steps after it that finish a frame it
    starts (a request split over steps), rewritten together and split where they were."""
    group = [steps[i].send]
    while not b"".join(group).endswith(b"\x00") and i + len(group) < len(steps):
        group.append(steps[i + len(group)].send)
    joined = b"".join(group)
    whole = _rewrite(joined, nonces)
    if len(whole) != len(joined):
        return [whole] + [b""] * (len(group) - 1)
    out, at = [], 0
    for part in group:
        out.append(whole[at:at + len(part)])
        at += len(part)
    return out


def _compare(step: Step, got: bytes, nonces: dict[int, int]) -> str | None:
    want, have = frames_of(step.expect), frames_of(got)
    if len(want) != len(have):
        return f"{len(have)} reply frames instead of {len(want)}"
    for k, (a, b) in enumerate(zip(want, have)):
        if not isinstance(a, Frame):
            continue                                   # the vector itself states a damaged frame
        if not isinstance(b, Frame):
            return f"frame {k}: damaged"
        live = nonces.setdefault(a.nonce, b.nonce) if a.nonce else 0
        if (a.version, a.flags, a.type, a.seq) != (b.version, b.flags, b.type, b.seq) \
                or b.nonce != live:
            return f"frame {k}: header {b.header()} instead of {a.header()} (nonce mapped)"
        if step.analog or a.payload == b.payload:
            continue
        try:
            ma, mb = a.message(), b.message()
        except MessageError as exc:
            return f"frame {k}: payload does not decode ({exc})"
        name = type(ma).__name__
        diffs = []
        for f in dataclasses.fields(ma):
            va, vb = getattr(ma, f.name), getattr(mb, f.name)
            if f"{name}.{f.name}" in step.free + LIVE_FREE or va == vb:
                continue
            if isinstance(va, int) and nonces.get(va) == vb:       # a nonce in a detail
                continue
            diffs.append(f"{f.name} = {vb!r}, expected {va!r}")
        if diffs:
            return f"frame {k} ({name}): " + ", ".join(diffs)
    return None


def _exchange(transport: Transport, data: bytes, frames: int, wait_s: float) -> bytes:
    """Send ``data``; collect reply bytes until ``frames`` frames have ended (a 0x00 each) or
    ``wait_s`` passed (a synchronous in-process board answers inside the write)."""
    transport.write(data)
    got = bytearray()
    deadline = time.monotonic() + wait_s
    while True:
        chunk = transport.read(4096, timeout=0.0 if transport.synchronous else 0.02)
        got += chunk
        ended = got.count(0) - (1 if got[:1] == b"\x00" else 0)
        if frames and ended >= frames:
            break
        if transport.synchronous and not chunk:
            break
        if time.monotonic() >= deadline:
            break
    return bytes(got)


def run_live_conformance(transport: Transport, reset: object, *,
                         folder: Path = DEFAULT_VECTORS, wait_s: float = 10.0) -> LiveResult:
    """Replay the non-destructive framed vectors of ``folder`` on the board behind
    ``transport`` (module docstring). ``reset``: a callable that RESETs the board (through the
    caller's link client) before each session. ``wait_s``: the longest wait for a step's
    replies (s; a step returns as soon as they are in: a DECISION_WINDOW runs for a good part
    of a second on a real board); a step that expects no reply waits 50 ms. The caller's link
    client must HELLO again afterwards."""
    result = LiveResult()
    files = sorted(p for p in folder.glob("*.jsonl")
                   if p.stem not in _NOT_SESSIONS + SKIPPED_SESSIONS)
    for path in files:
        session: Session = load_session(path)
        assert callable(reset)
        reset()
        transport.reset_input_buffer()
        nonces: dict[int, int] = {}
        result.sessions.append(session.name)
        queued: list[bytes] = []
        for i, step in enumerate(session.steps, 1):
            if _sends_pulse(step):
                result.skipped += len(session.steps) - i + 1
                break
            if not queued:
                queued = _pieces(session.steps, i - 1, nonces)
            n_frames = len(frames_of(step.expect))
            got = _exchange(transport, queued.pop(0), n_frames,
                            wait_s if n_frames else min(wait_s, 0.05))
            why = _compare(step, got, nonces)
            result.compared += 1
            if why:
                result.problems.append(f"{session.name} step {i} ({step.name}): {why}")
    return result
