"""Differential testing of the two MCUs: generated request sequences, the same bytes to both.

:class:`DifferentialMachine` is a hypothesis rule-based state machine over
:class:`~snan_hil.firmware_emu.twin.TwinBoards` (the Python firmware model and the C firmware on
the instruction-level MCU, on copies of one chip with one serial and the same forced boot
nonces). Its rules are what a host, a line and a lab do to a board:

* ``request`` - a request of any kind (:data:`REQUEST_KINDS`: every message at every code class,
  0 V reads included, refusals, malformed payloads and unknown types), with the board's nonce,
  0, a stale or a random one, any header flags, version or reserved byte now and then, the next
  sequence number or one used before;
* ``on_one_cell`` - several requests on one cell (0 V and other reads, pulses, write-and-verify,
  a column read), as the calibration does;
* ``retransmit`` - one of the last requests again (same seq, RETRANSMIT, a leading 0x00);
* ``damaged`` - a request frame with a flipped, dropped or inserted byte, cut short, split by a
  0x00, an over-long run, a legacy line, junk;
* ``split`` / ``two_in_one`` - a frame in several writes, two frames in one write;
* ``reconnect`` - a host dies mid-frame and a new one starts a session (``00`` + HELLO);
* ``restart`` - the board is power-cycled: a clean stop, or a kill (the journal is replayed).

After every step both boards must answer the same bytes, drive the same SPI frames and hold the
same chip (:class:`~snan_hil.firmware_emu.twin.TwinBoards`); hypothesis shrinks a failing
sequence to a minimal one, which becomes a sequence vector
(``conformance/v1/framed/sequences.jsonl``, :func:`findings_dir`).

**Adding a request kind** (a new framed message): register a strategy that draws it from the
board's constants, e.g. ``register_request_kind("window", lambda b: st.builds(Window, ...))``;
the machine draws every registered kind. Needs ``hypothesis`` (the ``test`` extra).

Documented differences the generator respects (docs/firmware.md): the C firmware keeps only the
most recent SPIKE_BATCH or DECISION_WINDOW reply, so only the latest of those is retransmitted.
"""

from __future__ import annotations

import dataclasses
import math
import shutil
import struct
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, precondition, rule

from snan_hil.firmware_emu.config import BoardConfig
from snan_hil.firmware_emu.twin import Divergence, TwinBoards, scratch_folder
from snan_hil.protocol import messages as m
from snan_hil.protocol.conformance import dump_sequences, frames_of
from snan_hil.protocol.crc import crc16
from snan_hil.protocol.frames import FLAG_RETRANSMIT, Frame, cobs_encode
from snan_hil.protocol.board import BoardConstants

__all__ = ["RawRequest", "REQUEST_KINDS", "register_request_kind", "DifferentialMachine",
           "Stats", "STATS", "findings_dir"]


@dataclass(frozen=True)
class RawRequest:
    """A request frame's type code and payload bytes, whatever they are (malformed payloads,
    unknown and reply types)."""

    type: int
    payload: bytes

    def encode(self) -> bytes:
        return self.payload


Outgoing = m.Request | RawRequest
KindStrategy = Callable[[BoardConstants], st.SearchStrategy[Outgoing]]

REQUEST_KINDS: dict[str, KindStrategy] = {}
"""Request kind -> strategy factory (board constants -> strategy of requests)."""


def register_request_kind(name: str, strategy: KindStrategy) -> None:
    """Let the machine draw requests of kind ``name`` from ``strategy(board)``."""
    REQUEST_KINDS[name] = strategy


# --------------------------------------------------------------------------- field classes
# Each strategy lists the valid, common values first: hypothesis shrinks towards them.
# Cells: a few of them often (so that what one request leaves on a cell - a compliance basis,
# a programmed state - meets the next request on it), any cell, or one outside the array.
def rows(b: BoardConstants) -> st.SearchStrategy[int]:
    return st.one_of(st.sampled_from([0, 1, b.rows - 1]), st.integers(0, b.rows - 1),
                     st.sampled_from([b.rows, 255]))


def cols(b: BoardConstants) -> st.SearchStrategy[int]:
    return st.one_of(st.sampled_from([0, 1, b.cols - 1]), st.integers(0, b.cols - 1),
                     st.sampled_from([b.cols, 31, 255]))


def nonce32() -> st.SearchStrategy[int]:
    """A boot nonce as a board draws it: 32 random bits, not 0 (drawn as bytes: hypothesis'
    integers favour small values, and a nonce's every byte lands in frames and memory)."""
    return st.binary(min_size=4, max_size=4).map(lambda b: int.from_bytes(b, "little") or 1)


def cell_read_code(b: BoardConstants) -> st.SearchStrategy[int]:
    """A single-cell read code (write DAC) of every class: nominal, 0 V, below, at and above
    the read limit, the DAC's range and beyond it."""
    lim, full = b.max_cell_read_code, b.write_dac_full_scale_code
    return st.one_of(st.just(b.read_code), st.just(0), st.integers(1, lim),
                     st.just(lim + 1), st.integers(lim + 1, full), st.just(full + 1),
                     st.integers(0, 0xFFFF))


def row_code(b: BoardConstants) -> st.SearchStrategy[int]:
    """A driven row's code (row DAC): mostly 0 (not driven) or a read code."""
    lim, full = b.max_row_read_code, b.dac_full_scale_code
    return st.one_of(st.just(0), st.just(b.read_code), st.integers(1, lim),
                     st.sampled_from([lim + 1, full, full + 1]), st.integers(0, 0xFFFF))


def amplitude(b: BoardConstants) -> st.SearchStrategy[int]:
    lim, full = b.max_write_code, b.write_dac_full_scale_code
    return st.one_of(st.integers(1, 700), st.just(0), st.integers(701, lim),
                     st.sampled_from([lim + 1, full, full + 1]), st.integers(0, 0xFFFF))


def width_us() -> st.SearchStrategy[int]:
    return st.one_of(st.integers(1, 500), st.sampled_from([0, 1_000_000, 1_000_001]),
                     st.integers(0, 0xFFFF_FFFF))


# --------------------------------------------------------------------------- request kinds
def _read_cell(b: BoardConstants) -> st.SearchStrategy[Outgoing]:
    return st.builds(m.ReadCell, rows(b), cols(b), cell_read_code(b))


def _read_column(b: BoardConstants) -> st.SearchStrategy[Outgoing]:
    n = st.one_of(st.just(b.rows), st.integers(0, 40))
    return st.builds(m.ReadColumn, cols(b),
                     n.flatmap(lambda k: st.lists(row_code(b), min_size=k, max_size=k)
                               .map(tuple)))


def _write_pulse(b: BoardConstants) -> st.SearchStrategy[Outgoing]:
    return st.builds(m.WritePulse, rows(b), cols(b), st.sampled_from(list(m.Polarity)),
                     amplitude(b), width_us(), st.one_of(st.just(0), cell_read_code(b)))


@st.composite
def _spike_batch(draw, b: BoardConstants) -> Outgoing:
    n_bins = draw(st.one_of(st.integers(1, 24), st.sampled_from([0, 64, 255, 600])))
    bin_us = draw(st.one_of(st.just(1000), st.sampled_from([0, 1, 50, 65535])))
    paced = draw(st.booleans())
    columns = draw(st.one_of(
        st.lists(st.integers(0, b.cols - 1), unique=True, max_size=b.cols),
        st.lists(st.integers(0, 31), unique=True, max_size=4)))
    bins = (st.lists(st.integers(0, n_bins - 1), unique=True, max_size=min(n_bins, 12))
            if n_bins else st.just([]))
    dense = st.just(list(range(n_bins)))            # every bin: large replies
    group = st.builds(m.SpikeGroup,
                      st.lists(st.tuples(rows(b), row_code(b)), min_size=0, max_size=4)
                      .map(tuple),
                      st.one_of(bins, dense).map(lambda x: tuple(sorted(x))))
    groups = draw(st.lists(group, max_size=3))
    return m.SpikeBatch(tuple(groups), tuple(sorted(columns)), n_bins, bin_us,
                        draw(st.integers(0, 0xFFFF_FFFF)), paced)


def _program_cell(b: BoardConstants) -> st.SearchStrategy[Outgoing]:
    full = b.adc_full_scale_code
    return st.builds(
        m.ProgramCell, rows(b), cols(b),
        st.one_of(st.integers(0, full), st.just(full + 1)),
        st.one_of(st.integers(0, 400), st.integers(0, 0xFFFF)),
        st.one_of(st.integers(1, 20), st.sampled_from([0, 1000, 1001])),
        st.one_of(st.just(0), st.integers(1, b.max_write_code)),
        st.one_of(st.just(0), st.integers(1, b.max_write_code), st.just(b.max_write_code + 1)),
        st.one_of(st.just(0), st.integers(1, 200)),
        st.one_of(st.integers(1, 200), st.sampled_from([0, 1_000_001])),
        st.one_of(st.just(0), cell_read_code(b)),
        st.booleans())


def _window_block(b: BoardConstants, spike_p: float, conversions: int) -> m.DecisionParams:
    """A parameter block the board accepts: an LIF of tau 20 steps, threshold 2, a read chain
    whose code -> drive conversion fits the ADC's range."""
    alpha = tuple(min(int(math.exp(-k / 20) * 2.0 ** 64), (1 << 64) - 1)
                  for k in range(1, m.DW_ALPHA_TABLE + 1))
    block = m.DecisionParams(n_bins=200, bin_us=50, row_code=b.read_code, ref_steps=3,
                             num_shift=13, den_shift=16, q_shift=4,
                             spike_threshold=int(spike_p * (1 << 53)), alpha_pow=alpha,
                             thr=2 << 32, reset=0, inh=1 << 32, offset=12 << 32,
                             d=(b.adc_full_scale_code + 4000) << 32, k1=3 << 32, k0=1 << 30,
                             conversions=conversions)
    assert m.decision_conversion_fits(block, b.adc_full_scale_code)
    return block


@st.composite
def _decision_window(draw, b: BoardConstants) -> Outgoing:
    """DECISION_WINDOW: short windows (the ISA MCU runs every step), both read plans (the lean
    one with 1 .. adc_averages conversions, and one above: refused), motor spikes, traces, a
    paced window, the stored block, and refusals (5 rows, a row index beyond the rows)."""
    conversions = draw(st.one_of(st.just(0), st.integers(1, b.adc_averages),
                                 st.just(b.adc_averages + 1)))
    block = dataclasses.replace(
        _window_block(b, draw(st.sampled_from([0.05, 0.3, 1.0])), conversions),
        n_bins=draw(st.sampled_from([1, 20, 60, 200])),
        lif_flags=draw(st.sampled_from([0, int(m.DecisionLifFlag.INTEGRATE)])))
    n_bins = block.n_bins
    rows_ = draw(st.lists(st.integers(0, b.rows - 1), unique=True, min_size=0,
                          max_size=draw(st.sampled_from([3, 3, 5]))))
    cands = draw(st.lists(st.builds(
        m.DecisionCandidate, st.integers(0, b.cols - 1),
        st.integers(0, min(3, max(len(rows_) - 1, 0) + draw(st.sampled_from([0, 0, 0, 1])))),
        st.lists(st.integers(0, n_bins - 1), unique=True, max_size=4).map(
            lambda x: tuple(sorted(x)))), max_size=4))
    stride = draw(st.sampled_from([0, 0, 7, n_bins]))
    return m.DecisionWindow(draw(st.integers(0, (1 << 64) - 1)), tuple(rows_), tuple(cands),
                            block if draw(st.sampled_from([True, True, False])) else None,
                            draw(st.booleans()), stride,
                            draw(st.sampled_from([False, False, False, True])))


def _raw(b: BoardConstants) -> st.SearchStrategy[Outgoing]:
    """Any type code (requests, replies, unknown) with any payload bytes."""
    return st.builds(RawRequest, st.integers(0, 255), st.binary(max_size=40))


@st.composite
def _mutated(draw, b: BoardConstants) -> Outgoing:
    """A request of another kind whose payload was changed (CRC-valid: reaches the decoders)."""
    kind = draw(st.sampled_from(sorted(k for k in REQUEST_KINDS if k not in ("raw", "mutated"))))
    msg = draw(REQUEST_KINDS[kind](b))
    payload = bytearray(msg.encode())
    how = draw(st.sampled_from(["set", "cut", "add"]))
    if how == "set" and payload:
        payload[draw(st.integers(0, len(payload) - 1))] = draw(st.integers(0, 255))
    elif how == "cut" and payload:
        del payload[draw(st.integers(0, len(payload) - 1)):]
    else:
        payload += draw(st.binary(min_size=1, max_size=4))
    return RawRequest(_type_of(msg), bytes(payload))


_BIG_REPLIES = (m.SpikeBatch.TYPE, m.DecisionWindow.TYPE)
"""Requests whose reply the C firmware builds in its one large buffer (docs/firmware.md)."""


def _type_of(msg: Outgoing) -> int:
    return msg.type if isinstance(msg, RawRequest) else msg.TYPE


for _name, _strategy in (
        ("hello", lambda b: st.builds(m.Hello, st.one_of(st.just(1), st.integers(0, 255)))),
        ("read_cell", _read_cell), ("read_column", _read_column),
        ("write_pulse", _write_pulse), ("spike_batch", _spike_batch),
        ("program_cell", _program_cell), ("decision_window", _decision_window),
        ("status", lambda b: st.just(m.Status())),
        ("clock", lambda b: st.just(m.Clock())), ("reset", lambda b: st.just(m.Reset())),
        ("raw", _raw), ("mutated", _mutated)):
    register_request_kind(_name, _strategy)


# --------------------------------------------------------------------------- frames
def raw_frame(type_: int, seq: int, payload: bytes, nonce: int, *, flags: int = 0,
              version: int = 1, reserved: int = 0) -> bytes:
    """The raw bytes (before COBS) of a frame with any header values and a correct CRC."""
    head = struct.pack("<BBBBHHI", version, flags, type_, reserved, seq, len(payload), nonce)
    body = head + bytes(payload)
    return body + struct.pack("<H", crc16(body))


def wire(raw: bytes) -> bytes:
    return cobs_encode(raw) + b"\x00"


@dataclass
class Stats:
    """What the machine did, over all its runs (the bench prints it)."""

    sequences: int = 0
    steps: int = 0                  # writes to both boards (each compared)
    frames: int = 0                 # frames in them, intact or damaged (the requests)
    bytes_sent: int = 0
    restarts: int = 0
    kills: int = 0
    divergences: int = 0


STATS = Stats()

_FINDINGS: list[Path | None] = [None]


def findings_dir(path: str | Path | None) -> None:
    """Where a diverging sequence is written as a sequence-vector file (``last-finding.jsonl``,
    overwritten by every failing run, so after shrinking it holds the minimal one); None: not
    written."""
    _FINDINGS[0] = Path(path) if path is not None else None


@st.composite
def _frames(draw, machine: "DifferentialMachine") -> tuple[int, bytes]:
    """(type, raw frame) of a request as a host (or a broken host) sends it: mostly the board's
    nonce and the next seq, now and then nonce 0, a stale or random nonce, a seq used before,
    any flags, version or reserved byte."""
    kind = draw(st.sampled_from(sorted(REQUEST_KINDS)))
    msg = draw(REQUEST_KINDS[kind](machine.BOARD))
    type_ = _type_of(msg)
    which = draw(st.sampled_from(["board", "board", "board", "zero", "stale", "random"]))
    nonce = {"board": machine.nonce, "zero": 0, "stale": machine.old_nonces[-1]}.get(which)
    if nonce is None:
        nonce = draw(st.integers(0, 0xFFFF_FFFF))
    seq = machine._next_seq() if draw(st.integers(0, 9)) else draw(st.integers(0, 0xFFFF))
    flags = draw(st.one_of(st.just(0), st.integers(0, 255)))
    version = draw(st.one_of(st.just(1), st.integers(0, 255)))
    reserved = draw(st.one_of(st.just(0), st.integers(0, 255)))
    return type_, raw_frame(type_, seq, msg.encode(), nonce, flags=flags, version=version,
                            reserved=reserved)


# --------------------------------------------------------------------------- the machine
class DifferentialMachine(RuleBasedStateMachine):
    """Request sequences against both MCUs (see the module doc)."""

    BOARD: BoardConstants = BoardConfig()

    def __init__(self) -> None:
        super().__init__()
        self.twin: TwinBoards | None = None
        self.folder: Path | None = None
        self.nonce = 0                   # what the host believes the board's nonce is
        self.old_nonces: list[int] = [0x0BADF00D]
        self.seq = 0
        self.sent: list[tuple[int, bytes]] = []          # (type, raw frame) of recent requests
        self.last_spike: bytes | None = None

    # ------------------------------------------------------------------ set-up
    @initialize(nonces=st.lists(nonce32(), min_size=3, max_size=3),
                first_seq=st.integers(0, 0xFFFF), serial=st.sampled_from(
                    ["8B297CA46845", "A1", "0123456789ABCDEFGHIJKLMNOPQ", None]))
    def power_on(self, nonces, first_seq, serial) -> None:
        self.folder = scratch_folder("snan-diff-")
        self.twin = TwinBoards(self.folder, serial=serial, boot_nonces=tuple(nonces))
        STATS.sequences += 1
        self.seq = first_seq
        self._hello()

    def teardown(self) -> None:
        if self.twin is not None:
            self.twin.close()
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)

    # ------------------------------------------------------------------ helpers
    def _send(self, data: bytes, name: str) -> bytes:
        assert self.twin is not None
        STATS.steps += 1
        STATS.frames += len(frames_of(data))
        STATS.bytes_sent += len(data)
        try:
            out = self.twin.send(data, name)
        except Divergence:
            STATS.divergences += 1
            self._record()
            raise
        self._learn(out)
        return out

    def _record(self) -> None:
        folder = _FINDINGS[0]
        if folder is None or self.twin is None:
            return
        folder.mkdir(parents=True, exist_ok=True)
        seq = self.twin.as_sequence("finding", "a sequence on which the two MCUs differ")
        (folder / "last-finding.jsonl").write_text(dump_sequences("differential finding",
                                                                  [seq]), encoding="utf-8")

    def _learn(self, out: bytes) -> None:
        """What a host learns from the board's answer: its nonce (INFO, RESET)."""
        for f in frames_of(out):
            if not isinstance(f, Frame):
                continue
            if f.type == m.Info.TYPE:
                self._new_nonce(f.nonce)
            elif f.type == m.ResetReply.TYPE:
                self._new_nonce(f.nonce)

    def _new_nonce(self, nonce: int) -> None:
        if nonce != self.nonce:
            self.old_nonces.append(self.nonce)
            self.nonce = nonce

    def _next_seq(self) -> int:
        self.seq = (self.seq + 1) & 0xFFFF
        return self.seq

    def _hello(self) -> None:
        raw = raw_frame(m.Hello.TYPE, self._next_seq(), m.Hello().encode(), 0)
        self._remember(m.Hello.TYPE, raw)
        self._send(b"\x00" + wire(raw), "HELLO")

    def _remember(self, type_: int, raw: bytes) -> None:
        self.sent = (self.sent + [(type_, raw)])[-4:]
        if type_ in _BIG_REPLIES:
            self.last_spike = raw

    def _frame(self) -> st.SearchStrategy[tuple[int, bytes]]:
        return _frames(self)

    # ------------------------------------------------------------------ rules
    @rule(data=st.data(), lead=st.booleans())
    def request(self, data, lead) -> None:
        type_, raw = data.draw(self._frame())
        self._remember(type_, raw)
        self._send((b"\x00" if lead else b"") + wire(raw), f"request 0x{type_:02x}")

    @rule(data=st.data(), ops=st.lists(st.sampled_from(
        ["read", "read 0 V", "pulse", "program", "read column"]), min_size=2, max_size=5))
    def on_one_cell(self, data, ops) -> None:
        """Several requests on one cell, as the calibration does (an offset read at 0 V, a
        read, pulses, write-and-verify): what one leaves on the cell meets the next."""
        b = self.BOARD
        row, col = data.draw(st.integers(0, b.rows - 1)), data.draw(st.integers(0, b.cols - 1))
        for op in ops:
            if op == "read":
                msg: m.Request = m.ReadCell(row, col, data.draw(cell_read_code(b)))
            elif op == "read 0 V":
                msg = m.ReadCell(row, col, 0)
            elif op == "pulse":
                msg = m.WritePulse(row, col, data.draw(st.sampled_from(list(m.Polarity))),
                                   data.draw(st.integers(1, b.max_write_code)),
                                   data.draw(st.integers(1, 500)),
                                   data.draw(st.one_of(st.just(0), st.integers(1, b.read_code))))
            elif op == "program":
                msg = m.ProgramCell(row, col, data.draw(st.integers(0, b.adc_full_scale_code)),
                                    data.draw(st.integers(0, 400)), data.draw(st.integers(1, 12)))
            else:
                codes = [0] * b.rows
                codes[row] = data.draw(st.integers(0, b.max_row_read_code))
                msg = m.ReadColumn(col, tuple(codes))
            raw = raw_frame(msg.TYPE, self._next_seq(), msg.encode(), self.nonce)
            self._remember(msg.TYPE, raw)
            self._send(wire(raw), f"{op} ({row},{col})")

    @precondition(lambda self: bool(self.sent))
    @rule(back=st.integers(1, 4))
    def retransmit(self, back) -> None:
        type_, raw = self.sent[-min(back, len(self.sent))]
        if type_ in _BIG_REPLIES and raw is not self.last_spike:
            return          # docs/firmware.md: the C firmware keeps its latest large reply only
        again = bytearray(raw)
        again[1] |= FLAG_RETRANSMIT
        again[-2:] = struct.pack("<H", crc16(bytes(again[:-2])))
        self._send(b"\x00" + wire(bytes(again)), "retransmit")

    @rule(data=st.data(), how=st.sampled_from(
        ["flip", "drop", "insert", "cut", "zero", "overlong", "legacy", "junk", "cobs"]))
    def damaged(self, data, how) -> None:
        _, raw = data.draw(self._frame())
        enc = bytearray(cobs_encode(raw))
        pick = lambda: data.draw(st.integers(0, len(enc) - 1))  # noqa: E731
        if how == "flip":
            k = pick()
            enc[k] ^= 1 << data.draw(st.integers(0, 7))
            if enc[k] == 0:
                enc[k] = 0x80
            out = bytes(enc) + b"\x00"
        elif how == "drop":
            del enc[pick()]
            out = bytes(enc) + b"\x00"
        elif how == "insert":
            enc.insert(pick(), data.draw(st.integers(1, 255)))
            out = bytes(enc) + b"\x00"
        elif how == "cut":
            out = bytes(enc[:pick()]) + b"\x00"
        elif how == "zero":
            k = pick()
            out = bytes(enc[:k]) + b"\x00" + bytes(enc[k:]) + b"\x00"
        elif how == "overlong":
            out = bytes([data.draw(st.integers(1, 255))]) * data.draw(
                st.sampled_from([4127, 4128, 4200])) + b"\x00"
        elif how == "legacy":
            out = b"9,245,3,4,0\n\x00"
        elif how == "cobs":
            out = bytes([data.draw(st.integers(2, 255))]) + b"\x01" + b"\x00"
        else:
            out = data.draw(st.binary(min_size=1, max_size=30)) + b"\x00"
        self._send(out, f"damaged ({how})")

    @rule(data=st.data(), parts=st.integers(2, 3))
    def split(self, data, parts) -> None:
        type_, raw = data.draw(self._frame())
        self._remember(type_, raw)
        w = wire(raw)
        cuts = sorted(data.draw(st.lists(st.integers(1, len(w) - 1), min_size=parts - 1,
                                         max_size=parts - 1)))
        pieces = [w[a:b] for a, b in zip([0] + cuts, cuts + [len(w)])]
        for i, piece in enumerate(pieces):
            self._send(piece, f"split {i + 1}/{len(pieces)}")

    @rule(data=st.data())
    def two_in_one(self, data) -> None:
        (ta, a), (tb, b) = data.draw(self._frame()), data.draw(self._frame())
        self._remember(ta, a)
        self._remember(tb, b)
        self._send(wire(a) + wire(b), "two frames in one write")

    @rule(data=st.data(), first_seq=st.integers(0, 0xFFFF))
    def reconnect(self, data, first_seq) -> None:
        """A host dies in the middle of a frame; the next one starts a session."""
        _, raw = data.draw(self._frame())
        half = cobs_encode(raw)[:data.draw(st.integers(1, len(raw) - 1))]
        self._send(half, "a host dies mid-frame")
        self.seq = first_seq
        self.nonce = 0
        self._hello()

    @rule(kill=st.booleans(),
          nonces=st.lists(nonce32(), min_size=3, max_size=3),
          hello=st.booleans())
    def restart(self, kill, nonces, hello) -> None:
        assert self.twin is not None
        STATS.restarts += 1
        STATS.kills += int(kill)
        self.twin.restart(kill=kill, boot_nonces=nonces)
        self.sent, self.last_spike = [], None
        if hello:                        # the host notices (or keeps its old nonce: refused)
            self._hello()


def run_seeded(seed: int, *, examples: int, steps: int, database=None) -> None:
    """Run ``examples`` sequences of up to ``steps`` steps, seeded (the bench's entry)."""
    from hypothesis import HealthCheck, seed as hyp_seed, settings   # the test extra
    from hypothesis.stateful import run_state_machine_as_test

    machine = hyp_seed(seed)(type("DifferentialRun", (DifferentialMachine,), {}))
    run_state_machine_as_test(machine, settings=settings(
        max_examples=examples, stateful_step_count=steps, deadline=None, database=database,
        suppress_health_check=list(HealthCheck), print_blob=False))

