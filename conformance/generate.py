"""Generate the framed-protocol conformance vectors from the Python board model, and the
examples and size table of docs/protocol.md from the vectors.

Usage::

    python conformance/generate.py            # write conformance/v1/framed/*.jsonl and the doc
    python conformance/generate.py --check    # exit 1 if either is not what would be written

Each session below is a list of exchanges (what the host sends: messages or deliberately
broken bytes); the answers are what the reference board model (``firmware_emu``, ``--mcu
model``) sends back on a fresh emulated board with the stated chip seed and boot nonces. The
layout of the files is in ``conformance/README.md``; ``protocol/conformance.py`` reads and
checks them; ``tests/protocol/test_conformance.py`` runs them against both board implementations.
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import struct
import sys
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from snan_hil.firmware_emu.config import BoardConfig
from snan_hil.firmware_emu.emulator import Emulator
from snan_hil.firmware_emu.testing import default_array
from snan_hil.protocol import messages as m
from snan_hil.protocol.conformance import (FREE_FIELDS, BoardSetup, ReplyVector, Sequence,
                                           SequenceBoardSetup, SequenceStep, Session, Step,
                                           describe_frame, dump_replies, dump_sequences,
                                           dump_session, frames_of, message_fields)
from snan_hil.protocol.crc import crc16
from snan_hil.protocol.errors import ErrorCode, NakReason
from snan_hil.protocol.frames import (FLAG_FROM_CACHE, FLAG_RETRANSMIT, Frame, cobs_encode,
                                      encode_frame, pack_frame)
from snan_hil.protocol.transport import wire_seconds

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "conformance" / "v1" / "framed"
DOC = ROOT / "docs" / "protocol.md"

N0, N1, N2 = 0x5EED1234, 0x5EED5678, 0x5EED9ABC
"""The boot nonces every session's board draws: at power-on, at the first and second RESET."""

SET, RESET = m.Polarity.SET, m.Polarity.RESET
ANALOG_TYPES = {m.ReadCellReply.TYPE, m.ReadColumnReply.TYPE, m.WritePulseReply.TYPE,
                m.SpikeBatchReply.TYPE, m.ProgramCellReply.TYPE, m.DecisionWindowReply.TYPE}


# --------------------------------------------------------------------------- building sessions
@dataclass
class Script:
    """The exchanges of one session, before the board's answers are known."""

    name: str
    title: str
    seed: int = 0
    nonce: int = 0                      # what requests carry (the script tracks the board's)
    items: list[tuple[str, bytes, str, str]] = field(default_factory=list)
    needs: tuple[str, ...] = ()         # optional capabilities the board must have

    def send(self, name: str, wire: bytes, note: str = "", doc: str = "") -> None:
        self.items.append((name, bytes(wire), note, doc))

    def req(self, name: str, msg: m.Message, seq: int, *, nonce: int | None = None,
            flags: int = 0, lead: bytes = b"", note: str = "", doc: str = "") -> None:
        n = self.nonce if nonce is None else nonce
        self.send(name, lead + encode_frame(Frame(msg.TYPE, seq, msg.encode(), n, flags)), note,
                  doc)

    def raw(self, name: str, type_: int, seq: int, payload: bytes, *, nonce: int | None = None,
            version: int = 1, flags: int = 0, length: int | None = None, crc_xor: int = 0,
            reserved: int = 0, note: str = "", doc: str = "") -> None:
        self.send(name, raw_frame(type_, seq, payload, self.nonce if nonce is None else nonce,
                                  version=version, flags=flags, length=length, crc_xor=crc_xor,
                                  reserved=reserved), note, doc)

    def hello(self, seq: int = 1, doc: str = "") -> None:
        self.req("HELLO", m.Hello(), seq, nonce=0, lead=b"\x00", doc=doc,
                 note="the first request of a session, with a leading 0x00 (host rule 2)")
        self.nonce = N0


def raw_frame(type_: int, seq: int, payload: bytes, nonce: int, *, version: int = 1,
              flags: int = 0, length: int | None = None, crc_xor: int = 0,
              reserved: int = 0) -> bytes:
    """A frame with any header values, a wrong length field or a damaged CRC."""
    head = struct.pack("<BBBBHHI", version, flags, type_, reserved, seq,
                       len(payload) if length is None else length, nonce)
    body = head + payload
    crc = crc16(body) ^ crc_xor
    return cobs_encode(body + struct.pack("<H", crc)) + b"\x00"


def spike_payload(first_bin: int, n_bins: int, bin_us: int, mask: int, flags: int,
                  groups: Iterable[tuple[list[tuple[int, int]], bytes]]) -> bytes:
    """A SPIKE_BATCH payload with any values (bitmaps given as bytes)."""
    groups = list(groups)
    out = struct.pack("<IHHIBB", first_bin, n_bins, bin_us, mask, flags, len(groups))
    for rows, bitmap in groups:
        out += bytes([len(rows)]) + b"".join(struct.pack("<BH", r, c) for r, c in rows) + bitmap
    return out


def no_zero_crc(make, seqs: Iterable[int]) -> tuple[int, bytes]:
    """The first seq whose frame ``make(seq)`` (raw bytes) has a CRC without a zero byte."""
    for seq in seqs:
        raw = make(seq)
        if raw[-1] and raw[-2]:
            return seq, raw
    raise RuntimeError("no seq gives a CRC without zero bytes")


# --------------------------------------------------------------------------- the sessions
def s_hello() -> Script:
    s = Script("hello", "HELLO and INFO: the version checks, any nonce, the reply cache")
    s.hello(doc="hello")
    s.req("HELLO retransmitted", m.Hello(), 1, nonce=0, flags=FLAG_RETRANSMIT, lead=b"\x00",
          note="same seq and bytes: the cached INFO again, flag FROM_CACHE")
    s.req("HELLO with a nonce", m.Hello(), 2, nonce=0x12345678,
          note="HELLO is exempt from the nonce check")
    s.req("HELLO version 2", m.Hello(2), 3, nonce=0, doc="bad_version",
          note="BAD_VERSION, detail = the version the board speaks (1)")
    s.req("HELLO version 0", m.Hello(0), 4, nonce=0)
    s.raw("HELLO with 2 payload bytes", m.Hello.TYPE, 5, b"\x01\x01", nonce=0,
          note="MALFORMED, detail = the payload length")
    s.raw("HELLO without payload", m.Hello.TYPE, 6, b"", nonce=0)
    s.send("HELLO after a legacy host's line", b"7,0,0,0,0,0,0,0\n\x00"
           + encode_frame(Frame.of(m.Hello(), 7, 0)),
           note="the line is a damaged frame (NAK COBS), then INFO")
    return s


def s_read_cell() -> Script:
    s = Script("read_cell", "READ_CELL: write-DAC codes, the read limit, code 0 = 0 V")
    s.hello()
    s.req("READ_CELL (3,4) at 245", m.ReadCell(3, 4, 245), 2, doc="read_cell",
          note="the nominal read code (0.2991 V)")
    s.req("READ_CELL retransmitted", m.ReadCell(3, 4, 245), 2, flags=FLAG_RETRANSMIT,
          lead=b"\x00", doc="read_cell_again", note="answered from the cache, not read again")
    s.req("READ_CELL at code 0", m.ReadCell(3, 4, 0), 3,
          note="0 V: the ADC offset of the cell path (code 0 is literal in READ_CELL)")
    s.req("READ_CELL at 246", m.ReadCell(3, 4, 246), 4, doc="safety",
          note="0.3004 V > max_read_v: SAFETY_LIMIT, detail = the code")
    s.req("READ_CELL at 4096", m.ReadCell(3, 4, 4096), 5,
          note="beyond the 12-bit write DAC: OUT_OF_RANGE, detail = the code")
    s.req("READ_CELL row 32", m.ReadCell(32, 0, 245), 6, note="OUT_OF_RANGE, detail = row")
    s.req("READ_CELL col 8", m.ReadCell(0, 8, 245), 7, note="OUT_OF_RANGE, detail = column")
    s.req("READ_CELL with nonce 0", m.ReadCell(1, 1, 245), 8, nonce=0,
          note="0 = any board: executed")
    s.raw("READ_CELL with 3 payload bytes", m.ReadCell.TYPE, 9, b"\x01\x01\xf5")
    s.raw("READ_CELL with 5 payload bytes", m.ReadCell.TYPE, 10, b"\x01\x01\xf5\x00\x00")
    s.req("READ_CELL seq 2 with another payload", m.ReadCell(5, 4, 245), 2,
          note="same seq, different payload: a new request, executed")
    return s


def s_read_column() -> Script:
    s = Script("read_column", "READ_COLUMN: row-DAC codes, one per row")
    s.hello()
    codes = tuple([245] * 15 + [0] * 17)
    s.req("READ_COLUMN 1, rows 0-14 at 245", m.ReadColumn(1, codes), 2, doc="read_column")
    s.req("READ_COLUMN, every row at 0", m.ReadColumn(1, (0,) * 32), 3,
          note="the ADC offset of the column path")
    s.req("READ_COLUMN with 3 codes", m.ReadColumn(1, (245,) * 3), 4,
          note="n != rows: OUT_OF_RANGE, detail = n")
    s.req("READ_COLUMN with 33 codes", m.ReadColumn(1, (0,) * 33), 5)
    s.req("READ_COLUMN code 246", m.ReadColumn(1, (0,) * 31 + (246,)), 6,
          note="SAFETY_LIMIT, detail = the code")
    s.req("READ_COLUMN code 4096", m.ReadColumn(1, (0,) * 31 + (4096,)), 7,
          note="beyond the 12-bit row DAC: OUT_OF_RANGE")
    s.req("READ_COLUMN col 8", m.ReadColumn(8, (0,) * 32), 8)
    s.raw("READ_COLUMN odd length", m.ReadColumn.TYPE, 9, bytes([1, 32]) + bytes(65),
          note="MALFORMED")
    return s


def s_write_pulse() -> Script:
    s = Script("write_pulse", "WRITE_PULSE: polarity, limits, compliance, no pulse twice")
    s.hello()
    s.req("WRITE_PULSE SET 410 100 us", m.WritePulse(3, 4, SET, 410, 100, 0), 3,
          doc="write_pulse", note="read_code 0 = INFO's read_code (245)")
    s.req("WRITE_PULSE retransmitted", m.WritePulse(3, 4, SET, 410, 100, 0), 3,
          flags=FLAG_RETRANSMIT, lead=b"\x00", note="from the cache: no second pulse")
    s.req("WRITE_PULSE RESET 600 200 us read at 200", m.WritePulse(3, 4, RESET, 600, 200, 200),
          4)
    s.req("WRITE_PULSE amplitude 0", m.WritePulse(3, 4, SET, 0, 0, 0), 5,
          note="no pulse, only the read (width ignored)")
    s.req("WRITE_PULSE width 0", m.WritePulse(3, 4, SET, 410, 0, 0), 6,
          note="OUT_OF_RANGE, detail = the width")
    s.req("WRITE_PULSE width 1000001", m.WritePulse(3, 4, SET, 410, 1_000_001, 0), 7)
    s.req("WRITE_PULSE amplitude 1147", m.WritePulse(3, 4, SET, 1147, 100, 0), 8,
          note="1.4005 V > max_write_v: SAFETY_LIMIT")
    s.req("WRITE_PULSE amplitude 4096", m.WritePulse(3, 4, SET, 4096, 100, 0), 9,
          note="beyond the write DAC: OUT_OF_RANGE")
    s.raw("WRITE_PULSE polarity 2", m.WritePulse.TYPE, 10,
          struct.pack("<BBBHIH", 3, 4, 2, 410, 100, 0), note="MALFORMED")
    s.req("WRITE_PULSE read code 246", m.WritePulse(3, 4, SET, 410, 100, 246), 11,
          note="SAFETY_LIMIT on the read after")
    s.req("WRITE_PULSE on a shorted cell", m.WritePulse(12, 4, SET, 1146, 100, 0), 12,
          note="(12,4) is stuck high on this chip: the predicted current exceeds the "
               "compliance: SAFETY_LIMIT, detail = the current in uA (it reads the cell first)")
    s.req("STATUS", m.Status(), 13, doc="status",
          note="pulses_applied 2, duplicates 1: the retransmission did not pulse")
    return s


def s_spike_batch() -> Script:
    s = Script("spike_batch", "SPIKE_BATCH: windows, pacing, the edge cases, reply limits")
    s.hello()
    doc_req = m.SpikeBatch((m.SpikeGroup(((0, 245), (1, 123)), (0, 9)),), (0, 1), 16, 1000)
    s.req("SPIKE_BATCH 2 spikes x 2 columns", doc_req, 4, doc="spike_batch")
    groups = (m.SpikeGroup(tuple((i, 82) for i in range(15)), (0, 3, 9)),
              m.SpikeGroup(((20, 245), (21, 100), (22, 30)), (3, 15)))
    s.req("SPIKE_BATCH two groups, 4 columns, first_bin 7",
          m.SpikeBatch(groups, (0, 2, 5, 7), 16, 1000, 7), 5,
          note="spikes by bin, then group; first_bin echoed")
    s.req("SPIKE_BATCH paced, 50 us bins", m.SpikeBatch(groups, (0, 2), 16, 50, 0, True), 6)
    s.req("SPIKE_BATCH without groups", m.SpikeBatch((), (0, 1), 8, 1000), 7,
          note="an empty window: 0 spikes")
    s.req("SPIKE_BATCH, a group without spikes", m.SpikeBatch(
        (m.SpikeGroup(((4, 200),), ()), m.SpikeGroup(((5, 200),), (1,))), (3,), 8, 1000), 8)
    s.req("SPIKE_BATCH without columns", m.SpikeBatch(
        (m.SpikeGroup(((4, 200),), (0, 2)),), (), 8, 1000), 9,
          note="spikes applied, nothing read: 2 spikes x 0 columns")
    s.raw("SPIKE_BATCH n_bins 0", m.SpikeBatch.TYPE, 10,
          spike_payload(0, 0, 1000, 1, 0, [([(1, 100)], b"")]),
          note="OUT_OF_RANGE, detail 0")
    s.req("SPIKE_BATCH paced with bin_us 0",
          m.SpikeBatch((m.SpikeGroup(((1, 100),), (2,)),), (0,), 8, 0, 0, True), 11,
          note="OUT_OF_RANGE, detail 0")
    s.req("SPIKE_BATCH bin_us 0 not paced",
          m.SpikeBatch((m.SpikeGroup(((1, 100),), (2,)),), (0,), 8, 0), 12,
          note="accepted: bin_us matters only when paced")
    s.req("SPIKE_BATCH a group without rows", m.SpikeBatch(
        (m.SpikeGroup(((1, 100),), (2,)), m.SpikeGroup((), (3,))), (0,), 8, 1000), 13,
          note="OUT_OF_RANGE, detail = the group's index")
    s.req("SPIKE_BATCH a row twice in a group", m.SpikeBatch(
        (m.SpikeGroup(((4, 100), (5, 90), (4, 80)), (2,)),), (0,), 8, 1000), 14,
          note="OUT_OF_RANGE, detail = the row")
    s.raw("SPIKE_BATCH bitmap bit beyond n_bins", m.SpikeBatch.TYPE, 15,
          spike_payload(0, 4, 1000, 1, 0, [([(1, 100)], b"\x10")]), note="MALFORMED")
    s.raw("SPIKE_BATCH unknown flag bit", m.SpikeBatch.TYPE, 16,
          spike_payload(0, 8, 1000, 1, 2, [([(1, 100)], b"\x01")]), note="MALFORMED")
    s.raw("SPIKE_BATCH trailing byte", m.SpikeBatch.TYPE, 17,
          spike_payload(0, 8, 1000, 1, 0, [([(1, 100)], b"\x01")]) + b"\x00",
          note="MALFORMED")
    s.req("SPIKE_BATCH column 8", m.SpikeBatch((m.SpikeGroup(((1, 100),), (2,)),), (0, 8), 8),
          18, note="OUT_OF_RANGE, detail = the column")
    s.req("SPIKE_BATCH row code 246", m.SpikeBatch(
        (m.SpikeGroup(((1, 246),), (2,)),), (0,), 8), 19, note="SAFETY_LIMIT")
    s.req("SPIKE_BATCH reply too large", m.SpikeBatch(
        (m.SpikeGroup(((0, 245),), tuple(range(300))),), tuple(range(8)), 300), 20,
          note="300 spikes x 8 columns: OUT_OF_RANGE, detail = the reply size, nothing run")
    s.req("SPIKE_BATCH largest reply: 511 spikes x 4 columns", m.SpikeBatch(
        (m.SpikeGroup(((5, 245),), tuple(range(511))),), (0, 1, 2, 3), 512, 1000), 21,
          note="a 4095-byte reply payload")
    import random
    rng = random.Random(160)
    bins = tuple(sorted(rng.sample(range(1000), 160)))
    window = m.SpikeBatch((m.SpikeGroup(tuple((r, 245) for r in range(15)), bins),),
                          tuple(range(8)), 1000, 1000)
    s.req("SPIKE_BATCH a 1 s window: 160 spikes x 8 columns", window, 22, doc="window",
          note="15 rows driven per spike, as a HIL decision window")
    many = (m.SpikeGroup(((0, 245),), tuple(range(300))),)
    s.req("SPIKE_BATCH too large, with column 31", m.SpikeBatch(
        many, tuple(range(8)) + (31,), 300), 23,
          note="the reply size (board rule 6) is checked before the columns and counts every "
               "mask bit: OUT_OF_RANGE, detail = 7 + 2 x 300 x 9 (issue 27, item 6)")
    s.req("SPIKE_BATCH with column 31, small", m.SpikeBatch(
        (m.SpikeGroup(((0, 245),), (1, 3)),), (0, 31), 8), 24,
          note="within the payload: the column check answers, detail 31")
    s.req("SPIKE_BATCH too large, paced with bin_us 0", m.SpikeBatch(
        many, tuple(range(8)), 300, 0, 0, True), 25,
          note="the reply size first: detail 4807, not the bin_us check's 0")
    return s


def s_program_cell() -> Script:
    s = Script("program_cell", "PROGRAM_CELL: the default ramp, explicit ramps, bool, limits")
    s.hello()
    s.req("PROGRAM_CELL default ramp", m.ProgramCell(3, 4, 6000, 60, 100, 0, 0, 0, 100, 0, True),
          7, doc="program_cell", note="amplitude codes 0: the old host's ramp 246..983 by 8")
    s.req("PROGRAM_CELL explicit ramp",
          m.ProgramCell(6, 4, 2500, 50, 80, 300, 900, 20, 50, 0, True), 8)
    s.req("PROGRAM_CELL without fine tuning",
          m.ProgramCell(7, 2, 4000, 80, 60, 0, 0, 0, 100, 0, False), 9)
    s.raw("PROGRAM_CELL fine_tune 2", m.ProgramCell.TYPE, 10,
          m.ProgramCell(7, 2, 4000, 80, 60).encode()[:-1] + b"\x02",
          note="a bool is 0 or 1: MALFORMED")
    s.req("PROGRAM_CELL max_pulses 0", m.ProgramCell(7, 2, 4000, 80, 0), 11,
          note="OUT_OF_RANGE, detail 0")
    s.req("PROGRAM_CELL max_pulses 1001", m.ProgramCell(7, 2, 4000, 80, 1001), 12)
    s.req("PROGRAM_CELL ramp end 1147", m.ProgramCell(7, 2, 4000, 80, 10, 500, 1147, 8), 13,
          note="SAFETY_LIMIT before any pulse")
    s.req("PROGRAM_CELL start above stop", m.ProgramCell(7, 2, 4000, 80, 10, 900, 300, 8), 14,
          note="OUT_OF_RANGE, detail = start")
    s.req("PROGRAM_CELL target 16384", m.ProgramCell(7, 2, 16384, 80, 10), 15)
    s.req("PROGRAM_CELL width 0", m.ProgramCell(7, 2, 4000, 80, 10, 0, 0, 0, 0), 16)
    s.req("PROGRAM_CELL read code 246", m.ProgramCell(7, 2, 4000, 80, 10, 0, 0, 0, 100, 246),
          17, note="SAFETY_LIMIT")
    s.req("STATUS", m.Status(), 18)
    return s


def s_status_clock_reset() -> Script:
    s = Script("status_clock_reset", "STATUS, CLOCK, RESET and the boot nonce")
    s.hello()
    s.req("STATUS", m.Status(), 2, doc="status_request")
    s.req("CLOCK", m.Clock(), 3, doc="clock", note="time and energy: free (docs/protocol.md)")
    s.req("RESET", m.Reset(), 4, doc="reset", note="a new boot nonce, sent in the reply header")
    old = s.nonce
    s.nonce = N1
    s.req("READ_CELL with the old nonce", m.ReadCell(2, 2, 245), 5, nonce=old,
          doc="nonce_mismatch", note="NONCE_MISMATCH, detail = the request's nonce")
    s.req("READ_CELL with nonce 0", m.ReadCell(2, 2, 245), 6, nonce=0)
    s.req("READ_CELL with the new nonce", m.ReadCell(2, 2, 245), 7)
    s.req("RESET retransmitted", m.Reset(), 4, nonce=old, flags=FLAG_RETRANSMIT,
          lead=b"\x00", note="the cached RESET reply (not a second reset: the nonce stays)")
    s.req("STATUS after the reset", m.Status(), 8, note="counters since the reset")
    s.raw("STATUS with a payload byte", m.Status.TYPE, 9, b"\x00", note="MALFORMED")
    s.raw("CLOCK with a payload byte", m.Clock.TYPE, 10, b"\x00")
    s.raw("RESET with a payload byte", m.Reset.TYPE, 11, b"\x00",
          note="MALFORMED: not executed, the nonce stays")
    s.req("HELLO", m.Hello(), 12, nonce=0, note="INFO's boot_nonce is the new nonce")
    s.req("RESET again", m.Reset(), 13, note="the next nonce")
    s.nonce = N2
    s.req("STATUS", m.Status(), 14)
    s.req("READ_CELL with the nonce of before the last RESET", m.ReadCell(2, 2, 245), 15,
          nonce=N1, note="NONCE_MISMATCH")
    s.req("the same retransmitted", m.ReadCell(2, 2, 245), 15, nonce=N1, flags=FLAG_RETRANSMIT,
          lead=b"\x00", note="NONCE_MISMATCH is not cached: checked and answered again, "
                             "flags 0, counted again (issue 27, item 6)")
    s.req("STATUS", m.Status(), 16, note="nonce_mismatches 2, duplicates 0")
    return s


def s_errors() -> Script:
    s = Script("errors", "ERROR replies to whole frames and NAKs of damaged ones")
    s.hello()
    for seq, t in ((2, 0x00), (3, 0x0B), (4, 0x7F), (5, 0x81), (6, 0xFF)):
        s.raw(f"type 0x{t:02x}", t, seq, b"", note="UNKNOWN_TYPE, detail = the type")
    s.raw("frame version 2", m.ReadCell.TYPE, 7, m.ReadCell(1, 1, 245).encode(), version=2,
          note="BAD_VERSION, detail = the board's version (1)")
    s.raw("frame version 0", m.ReadCell.TYPE, 8, m.ReadCell(1, 1, 245).encode(), version=0)
    s.raw("CRC damaged", m.ReadCell.TYPE, 9, m.ReadCell(3, 4, 245).encode(), crc_xor=0x0100,
          doc="nak", note="NAK: BAD_FRAME, seq 0, detail 1 (CRC)")
    s.send("COBS group past the end", b"\x09\x01\x02\x00", note="NAK, detail 2 (COBS)")
    s.raw("length field 9, 4 payload bytes", m.ReadCell.TYPE, 10,
          m.ReadCell(3, 4, 245).encode(), length=9, note="NAK, detail 3 (length)")
    good = encode_frame(Frame.of(m.ReadCell(3, 4, 245), 11, N0))
    s.send("a byte dropped", good[:6] + good[7:],
           note="NAK; which check fails first (here COBS) depends on the byte")
    s.send("a 0x00 inserted", good[:8] + b"\x00" + good[8:],
           note="two damaged frames: two NAKs")
    s.send("shorter than a header", cobs_encode(bytes(6)) + b"\x00", note="NAK, detail 3")
    s.raw("payload of 4097 bytes", m.SpikeBatch.TYPE, 12, bytes(4097),
          note="above the maximum payload: NAK, detail 3")
    s.send("4200 bytes without a delimiter", b"\x22" * 4200 + b"\x00",
           note="more than the largest frame: one NAK, dropped up to the next 0x00")
    s.send("a legacy host's line", b"9,245,3,4,0\n\x00", note="NAK")
    s.req("READ_CELL after all that", m.ReadCell(3, 4, 245), 13)
    s.req("STATUS", m.Status(), 14, note="crc_errors, framing_errors, refusals counted")
    return s


def s_cache() -> Script:
    s = Script("cache", "The reply cache: what is replayed, what is executed again")
    s.hello()
    pulse = m.WritePulse(5, 1, SET, 500, 50, 0)
    s.req("WRITE_PULSE seq 10", pulse, 10)
    s.req("retransmitted (RETRANSMIT)", pulse, 10, flags=FLAG_RETRANSMIT, lead=b"\x00",
          note="FROM_CACHE, no pulse")
    s.req("the same bytes without the flag", pulse, 10,
          note="the flag is not part of the key: FROM_CACHE, no pulse")
    s.req("seq 10 with another payload", m.WritePulse(5, 1, SET, 510, 50, 0), 10,
          note="a different request: executed (a pulse); seq 10 now holds its reply")
    s.req("the first WRITE_PULSE again", pulse, 10, flags=FLAG_RETRANSMIT,
          note="no longer cached under seq 10: executed again. A host never reuses a seq "
               "for other content")
    s.req("a refusal", m.ReadCell(5, 1, 246), 11)
    s.req("the refusal retransmitted", m.ReadCell(5, 1, 246), 11, flags=FLAG_RETRANSMIT,
          note="ERROR replies are cached too")
    s.req("seq 11 with nonce 0", m.ReadCell(5, 1, 246), 11, nonce=0,
          note="another nonce is another key: executed")
    s.req("HELLO", m.Hello(), 12, nonce=0, note="a new session: the cache is cleared")
    s.req("the first WRITE_PULSE after HELLO", pulse, 10, flags=FLAG_RETRANSMIT,
          note="executed: never resend a request across a HELLO")
    s.req("STATUS", m.Status(), 13, note="pulses_applied 4, duplicates 3")
    read = m.ReadCell(5, 1, 245)
    s.req("READ_CELL with unknown flag bits 0xFC", read, 14, flags=0xFC,
          note="flags a board does not act on are ignored: executed, reply flags 0 "
               "(issue 27, item 6)")
    s.req("the same with flags 0x05 (RETRANSMIT and an unknown bit)", read, 14, flags=0x05,
          note="the flags are no part of the cache key: FROM_CACHE")
    s.req("READ_CELL with FROM_CACHE set", m.ReadCell(5, 2, 245), 15, flags=FLAG_FROM_CACHE,
          note="a reply's flag in a request means nothing: executed, reply flags 0")
    s.raw("STATUS with reserved byte 0x5A", m.Status.TYPE, 16, b"", reserved=0x5A,
          note="the reserved byte is ignored: executed")
    return s


def s_cobs() -> Script:
    s = Script("cobs", "COBS edge cases: empty payloads, 254-byte runs, the largest frames")
    s.hello()
    s.req("STATUS (empty payload)", m.Status(), 2)

    def run_end(seq: int) -> bytes:             # 254 non-zero bytes at the end of the frame
        p = spike_payload(0x01010101, 252 * 8, 0x0101, 0, 0, [([(1, 245)], b"\x01" * 252)])
        return pack_frame(Frame(m.SpikeBatch.TYPE, seq, p, N0))

    seq, raw = no_zero_crc(run_end, range(3, 200))
    assert b"\x00" not in raw[-254:] and raw[-255] == 0
    s.send("a 254-byte run at the frame's end", cobs_encode(raw) + b"\x00",
           note="canonical: FF + 254 bytes, no trailing group; executed (252 spikes, no "
                "columns)")
    body = cobs_encode(raw)
    assert body[-255] == 0xFF
    s.send("the same frame, non-canonical", body + b"\x01\x00",
           note="FF + 254 bytes + an empty group 01: decoders accept both forms (FROM_CACHE)")

    def run255(seq: int) -> bytes:
        p = spike_payload(0x01010101, 253 * 8, 0x0101, 0, 0, [([(1, 245)], b"\x02" * 253)])
        return pack_frame(Frame(m.SpikeBatch.TYPE, seq, p, N0))

    seq255, raw255 = no_zero_crc(run255, range(seq + 1, 400))
    s.send("a 255-byte run", cobs_encode(raw255) + b"\x00", note="FF + 254 bytes, then 02 + 1")

    def run_zero(seq: int) -> bytes:            # 254 non-zero bytes, then a 0x00 inside
        p = spike_payload(0, 256 * 8, 1000, 0, 0,
                          [([(1, 245)], b"\x01" * 254 + b"\x00\x01")])
        return pack_frame(Frame(m.SpikeBatch.TYPE, seq, p, N0))

    seqz = seq255 + 1
    s.send("a 254-byte run followed by 0x00", cobs_encode(run_zero(seqz)) + b"\x00",
           note="FF + 254 bytes, then 01 for the zero")
    big = spike_payload(0, 4078 * 8, 1000, 0, 0, [([(1, 245)], bytes(4078))])
    assert len(big) == m.MAX_PAYLOAD
    s.raw("the largest payload (4096 bytes)", m.SpikeBatch.TYPE, seqz + 1, big,
          note="32624 bins without a spike: executed, 0 spikes")
    dense = spike_payload(0x01010101, 4078 * 8, 0x0101, 0, 0, [([(1, 0x0101)], b"\x01" * 4078)])
    wire = raw_frame(m.SpikeBatch.TYPE, seqz + 2, dense, N0)
    s.send(f"the longest encoded frame ({len(wire)} bytes on the wire)", wire,
           note="a 4096-byte payload without zero bytes: refused (row code 257, SAFETY_LIMIT) "
                "after a complete decode")
    st = encode_frame(Frame.of(m.Status(), seqz + 3, N0))
    s.send("extra delimiters around a frame", b"\x00\x00" + st + b"\x00\x00",
           note="empty frames are ignored: one reply")
    a = encode_frame(Frame.of(m.ReadCell(1, 1, 245), seqz + 4, N0))
    b = encode_frame(Frame.of(m.Clock(), seqz + 5, N0))
    s.send("two requests in one write", a + b, note="two replies, in order")
    tail = encode_frame(Frame.of(m.ReadCell(1, 1, 245), seqz + 6, N0))
    s.send("a request split: first part", tail[:7], note="nothing yet")
    s.send("a request split: the rest", tail[7:], note="the reply")
    return s


def window_params() -> m.DecisionParams:
    """The parameter block the host sends for the 6x6 HIL model (configs/hil-6x6.yaml: tau_m
    150 ms, threshold 7, reset 0, R 1, w_inh 50, refractory 40 ms, p = 0.15, 1000 bins of 1 ms)
    on MemriCore's nominal read chain at code 245 and the default weight map."""
    from snan_hil.calibration.mapping import WeightMap
    from snan_hil.calibration.readchain import ReadChain
    from snan_hil.host.hil.board_window import window_params as params
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.kernel_params import kernel_params
    from snan_hil.protocol.board import MEMRICORE
    kp = kernel_params(load_hil_config().launch_config(True))
    return params(kp, ReadChain.nominal(MEMRICORE), WeightMap(), MEMRICORE.read_code)


def s_decision_window() -> Script:
    s = Script("decision_window", "DECISION_WINDOW: one decision window on the board, its "
               "parameter block, the refusals")
    s.hello()
    P = window_params()
    dw = m.DecisionWindow
    C = m.DecisionCandidate
    key = 0x0123456789ABCDEF
    # cells of the fresh emulated chip: (0, 2) and (1, 0) read ~550-620 uS (w ~0.55), (0, 3)
    # ~240 uS (w ~0.2, silent)
    cands = (C(2, 0, (35, 150, 265, 380, 495, 610, 725, 840, 955)), C(0, 1), C(3, 0))
    s.req("DECISION_WINDOW without a stored parameter block", dw(key, (0, 1), cands), 2,
          note="OUT_OF_RANGE, detail 0: send the block with the window (flag PARAMS)")
    s.req("DECISION_WINDOW with its parameter block, motor spikes",
          dw(key, (0, 1), cands, P, motor_spikes=True), 3, doc="decision_window",
          note="rows 0 and 1 driven alone per input spike, columns 0, 2, 3 read for each; "
               "lane 0 inhibited every 115 ms; the counts and every motor spike")
    s.req("retransmitted", dw(key, (0, 1), cands, P, motor_spikes=True), 3,
          flags=FLAG_RETRANSMIT, lead=b"\x00", note="from the cache: not run again")
    s.req("the next window: the stored block", dw(key + 1, (2,), (C(0, 0), C(2, 0))), 4,
          doc="decision_window_next", note="no parameter block: 29 bytes on the wire")
    s.req("a window with a membrane trace every 100 steps", dw(key + 2, (2,), (C(2, 0),),
                                                              trace_stride=100), 5,
          note="10 points of 1 lane, Q16.16")
    small = dataclasses.replace(P, n_bins=40, bin_us=200)
    s.req("a paced window of 40 bins of 200 us (a new block)",
          dw(key + 3, (0,), (C(2, 0, (5, 30)),), small, paced=True), 6)
    s.req("no rows, no candidates: the spikes are only drawn", dw(key + 4, (), ()), 7,
          note="n_input_spikes only")
    integ = dataclasses.replace(P, lif_flags=int(m.DecisionLifFlag.INTEGRATE))
    s.req("refractory neurons integrate (lif_flags bit 0)",
          dw(key + 5, (2,), (C(6, 0, (20, 140)), C(0, 0)), integ, motor_spikes=True), 8)
    lean = dataclasses.replace(P, conversions=2)
    s.req("the lean read plan: 2 conversions a read (flag READ_PLAN, one byte after the block)",
          dw(key, (0, 1), cands, lean, motor_spikes=True), 9, doc="decision_window_lean",
          note="row 0: columns 2, 3; row 1: column 0 - each row's own candidates; no dummy "
               "conversion, the ADC's pipeline carries each read's last conversion")
    s.req("the next lean window: the stored block keeps its plan",
          dw(key + 1, (2,), (C(0, 0), C(2, 0))), 10)
    s.req("a lean window, 1 conversion a read, one column shared by two candidates",
          dw(key + 6, (4,), (C(5, 0, (100, 101)), C(5, 0), C(1, 0)),
             dataclasses.replace(P, conversions=1), motor_spikes=True), 11)
    s.req("a lean window of 10 conversions a read, with a trace",
          dw(key + 7, (3, 9), (C(1, 1), C(6, 0)), dataclasses.replace(P, conversions=10),
             trace_stride=250), 12)
    s.req("a paced lean window of 40 bins of 200 us",
          dw(key + 3, (0,), (C(2, 0, (5, 30)), C(4, 0)),
             dataclasses.replace(small, conversions=3), paced=True), 13)
    s.req("a lean window without candidates: the spikes are only drawn",
          dw(key + 4, (1,), (), lean), 14)
    seq = 15
    for name, key_, value, note in (
            ("n_bins 0", "n_bins", 0, "detail = n_bins"),
            ("n_bins 16385", "n_bins", 16385, ""),
            ("row code 0", "row_code", 0, "detail 0"),
            ("row code 246", "row_code", 246, "SAFETY_LIMIT, detail = the code"),
            ("row code 4096", "row_code", 4096, "OUT_OF_RANGE, detail = the code"),
            ("num_shift 18", "num_shift", 18, "detail = the field's offset in the block, 9"),
            ("den_shift 63", "den_shift", 63, "detail 10"),
            ("q_shift 32", "q_shift", 32, "detail 11"),
            ("spike threshold 2^53 + 1", "spike_threshold", (1 << 53) + 1, "detail 12"),
            ("threshold 0 (at rest)", "thr", 0, "detail 148"),
            ("threshold 2^56 + 1", "thr", (1 << 56) + 1, "detail 148"),
            ("reset at the threshold", "reset", P.thr, "detail 156"),
            ("negative inhibition", "inh", -1, "detail 164"),
            ("negative offset", "offset", -1, "detail 172"),
            ("d 0", "d", 0, "detail 180"),
            ("d too small for the ADC's full scale", "d", 16383 << 33, "detail 180"),
            ("negative k1", "k1", -1, "detail 188"),
            ("k0 beyond 2^56", "k0", (1 << 56) + 1, "detail 196"),
            ("11 conversions a read", "conversions", 11, "detail 204, the read plan byte")):
        s.req(f"parameter block: {name}", dw(key, (0,), (C(0, 0),),
                                              dataclasses.replace(P, **{key_: value})), seq,
              note=note)
        seq += 1
    s.req("after the refusals: the stored block is still the integrate one",
          dw(key + 5, (2,), (C(6, 0, (20, 140)), C(0, 0)), motor_spikes=True), seq,
          note="a refused request changes nothing: the same reply as step 9, read again")
    seq += 1
    for name, req, note in (
            ("PACED with bin_us 0", dw(key, (0,), (C(0, 0),), dataclasses.replace(P, bin_us=0),
                                      paced=True), "detail 2"),
            ("5 rows", dw(key, (0, 1, 2, 3, 4), (C(0, 0),)), "detail 5"),
            ("row 32", dw(key, (32,), (C(0, 0),)), "detail 32"),
            ("a row twice", dw(key, (3, 5, 3), (C(0, 0),)), "detail 3"),
            ("5 candidates", dw(key, (0,), tuple(C(k, 0) for k in range(5))), "detail 5"),
            ("column 8", dw(key, (0,), (C(8, 0),)), "detail 8"),
            ("row index 2 of 2 rows", dw(key, (0, 1), (C(0, 2),)), "detail 2"),
            ("an interneuron spike at step 1000", dw(key, (0,), (C(0, 0, (3, 1000)),)),
             "detail 1000"),
            ("a reply that could exceed the payload", dw(key, (0,), tuple(C(k, 0) for k in
                                                                         range(4)),
                                                       trace_stride=1),
             "4 lanes x 1000 points: detail = the size")):
        s.req(f"DECISION_WINDOW {name}", req, seq, note=note)
        seq += 1
    good = dw(key, (0,), (C(0, 0, (3, 9)),)).encode()
    s.raw("DECISION_WINDOW with a read plan of 0 conversions", m.DecisionWindow.TYPE, seq,
          bytes([0x11]) + P.encode() + b"\x00" + good[1:],
          note="MALFORMED: a plan byte is 1..255 (above the board's averages: OUT_OF_RANGE)")
    seq += 1
    for name, payload, note in (
            ("an unknown flag bit", bytes([0x20]) + good[1:], "MALFORMED"),
            ("READ_PLAN without a parameter block", bytes([0x10]) + good[1:], "MALFORMED"),
            ("TRACE with stride 0", bytes([0x04]) + good[1:9] + b"\x00\x00" + good[9:],
             "MALFORMED"),
            ("a reserved layout bit", good[:9] + bytes([good[9] | 0x08]) + good[10:],
             "MALFORMED"),
            ("an interneuron list of 0 spikes", good[:12] + b"\x00", "MALFORMED"),
            ("a spike gap of 4 bytes", good[:12] + b"\x01\x83\x80\x80\x00", "MALFORMED"),
            ("a truncated payload", good[:-1], "MALFORMED"),
            ("a trailing byte", good + b"\x00", "MALFORMED"),
            ("a parameter block with lif_flags bit 1",
             bytes([0x01]) + dataclasses.replace(P, lif_flags=0).encode()[:8] + b"\x02"
             + P.encode()[9:] + good[1:], "MALFORMED")):
        s.raw(f"DECISION_WINDOW {name}", m.DecisionWindow.TYPE, seq, payload, note=note)
        seq += 1
    s.req("HELLO", m.Hello(), seq, nonce=0, note="a new session: the block is forgotten")
    seq += 1
    s.req("DECISION_WINDOW after HELLO without a block", dw(key, (0,), (C(0, 0),)), seq,
          note="OUT_OF_RANGE, detail 0")
    seq += 1
    s.req("with the block again", dw(key, (0,), (C(0, 0),), P), seq)
    seq += 1
    s.req("RESET", m.Reset(), seq, note="forgets the block too")
    s.nonce = N1
    seq += 1
    s.req("DECISION_WINDOW after RESET without a block", dw(key, (0,), (C(0, 0),)), seq,
          note="OUT_OF_RANGE, detail 0")
    seq += 1
    s.req("STATUS", m.Status(), seq, note="spikes_applied and column_reads count the "
          "windows' spikes (per row) and reads")
    return s


# --------------------------------------------------------------------------- sequences
@dataclass
class SeqScript(Script):
    """A sequence: a session's exchanges plus restarts of the board (a kill or a clean stop),
    on a chip with a serial (``serial``), first booted with ``nonces``."""

    serial: str = "8B297CA46845"
    nonces: tuple[int, ...] = (N0, N1, N2)

    def restart(self, name: str, *, kill: bool, nonces: Iterable[int], note: str = "") -> None:
        self.items.append((name, (kill, tuple(nonces)), note, ""))   # type: ignore[arg-type]
        self.nonce = 0


def q_offset_read_then_pulse() -> SeqScript:
    s = SeqScript("offset_read_then_pulse", "A 0 V read is no compliance basis (issue 27.3)")
    s.hello()
    s.req("READ_CELL (3,4) at 0 V", m.ReadCell(3, 4, 0), 2,
          note="the calibration's offset read, on a cell not read since boot")
    s.req("WRITE_PULSE (3,4) SET 410", m.WritePulse(3, 4, SET, 410, 100, 0), 3,
          note="applied: the 0 V read is no basis, so the cell is read at the read code first "
               "(it was refused before: a 0 V reading predicts an unbounded current)")
    s.req("READ_CELL (5,1) at 245", m.ReadCell(5, 1, 245), 4, note="a basis for (5,1)")
    s.req("READ_CELL (5,1) at 0 V", m.ReadCell(5, 1, 0), 5,
          note="leaves the basis of (5,1) as it was")
    s.req("WRITE_PULSE (5,1) RESET 600", m.WritePulse(5, 1, RESET, 600, 100, 0), 6,
          note="predicted from the read at 245: applied without a read first")
    s.req("STATUS", m.Status(), 7,
          note="cell_reads 6 (two 0 V reads, one at 245, the read first on (3,4), the two "
               "reads after the pulses), pulses_applied 2")
    return s


def q_info_with_a_serial() -> SeqScript:
    s = SeqScript("info_with_a_chip_serial", "INFO with a chip serial, then the first reads of "
                  "a boot (issue 27.4)", nonces=(0x08AC378A, N1, N2))
    s.hello()
    s.nonce = 0x08AC378A
    s.req("READ_CELL (0,0) at 245", m.ReadCell(0, 0, 245), 2,
          note="the first read of the boot: a real reading (the C firmware's INFO with a 12-"
               "character serial was 160 bytes for a 152-byte buffer; the nonce's top byte "
               "0x08 landed on its copy of the column register, so this read read 0)")
    s.req("HELLO retransmitted", m.Hello(), 1, nonce=0, flags=FLAG_RETRANSMIT, lead=b"\x00",
          note="the cached INFO, whole")
    s.req("READ_CELL (0,1) at 245", m.ReadCell(0, 1, 245), 3)
    s.restart("kill and restart (the journal is replayed)", kill=True,
              nonces=(0x0BAD5EED, N1, N2))
    s.hello(seq=20)
    s.nonce = 0x0BAD5EED
    s.req("READ_CELL (7,3) at 245", m.ReadCell(7, 3, 245), 21,
          note="the first read after the restart, on the column 0x0B selects")
    s.restart("clean restart", kill=False, nonces=(0x0F00D00F, N1, N2))
    s.hello(seq=30)
    s.nonce = 0x0F00D00F
    s.req("WRITE_PULSE (2,7) read only", m.WritePulse(2, 7, SET, 0, 0, 0), 31,
          note="amplitude 0: the read, on the column 0x0F selects")
    s.req("STATUS", m.Status(), 32)
    return s


def q_longest_serial() -> SeqScript:
    s = SeqScript("longest_chip_serial", "INFO with the longest serial the identity record "
                  "holds (27 characters)", serial="0123456789ABCDEFGHIJKLMNOPQ",
                  nonces=(0x08AC378A, N1, N2))
    s.hello()
    s.nonce = 0x08AC378A
    s.req("READ_CELL (1,0) at 245", m.ReadCell(1, 0, 245), 2)
    s.req("HELLO retransmitted", m.Hello(), 1, nonce=0, flags=FLAG_RETRANSMIT, lead=b"\x00")
    s.req("READ_COLUMN 2", m.ReadColumn(2, tuple([245] * 4 + [0] * 28)), 3)
    s.req("STATUS", m.Status(), 4)
    return s


def q_kill_and_replay() -> SeqScript:
    s = SeqScript("kill_and_replay", "Programming survives a kill: the journal is replayed, "
                  "the board boots afresh")
    s.hello()
    s.req("PROGRAM_CELL (6,3) to 6000", m.ProgramCell(6, 3, 6000, 120, 60), 2)
    s.req("READ_CELL (6,3)", m.ReadCell(6, 3, 245), 3)
    s.restart("kill and restart", kill=True, nonces=(0x2BAD5EED, N1, N2),
              note="a SIGKILL: no snapshot; the next start replays the journal")
    s.req("READ_CELL with the nonce of before", m.ReadCell(6, 3, 245), 4, nonce=N0,
          note="NONCE_MISMATCH: the board was restarted")
    s.hello(seq=5)
    s.nonce = 0x2BAD5EED
    s.req("READ_CELL (6,3)", m.ReadCell(6, 3, 245), 6, note="the programmed cell, replayed")
    s.req("WRITE_PULSE (6,3) RESET 500", m.WritePulse(6, 3, RESET, 500, 100, 0), 7,
          note="its basis is the read of this boot")
    s.req("STATUS", m.Status(), 8, note="counters of this boot only")
    s.restart("clean restart", kill=False, nonces=(0x3BAD5EED, N1, N2))
    s.hello(seq=9)
    s.nonce = 0x3BAD5EED
    s.req("READ_CELL (6,3)", m.ReadCell(6, 3, 245), 10)
    return s


SEQUENCES = (q_offset_read_then_pulse, q_info_with_a_serial, q_longest_serial,
             q_kill_and_replay)


def run_sequence_script(script: SeqScript) -> Sequence:
    """Answer a sequence script with the reference board model on a durable chip."""
    import shutil
    import tempfile
    from snan_hil.firmware_emu.twin import EmulatedBoard, analog_reply
    setup = SequenceBoardSetup(chip_seed=script.seed, chip_serial=script.serial,
                               boot_nonces=script.nonces)
    folder = Path(tempfile.mkdtemp(prefix="snan-vectors-"))
    board = EmulatedBoard(folder, "model", chip_seed=script.seed, serial=script.serial,
                          boot_nonces=script.nonces, trace=False)
    steps: list[SequenceStep] = []
    try:
        for name, wire, note, _doc in script.items:
            if isinstance(wire, tuple):                     # a restart (SeqScript.restart)
                kill, nonces = wire
                board.restart(kill=kill, boot_nonces=nonces)
                steps.append(SequenceStep(name, "restart", note=note, kill=kill,
                                          boot_nonces=nonces))
                continue
            out = board.feed(wire)
            free = [f"{cls.__name__}.{x}" for f in frames_of(out) if isinstance(f, Frame)
                    for cls in [m.MESSAGE_TYPES.get(f.type)] if cls is not None
                    for x in FREE_FIELDS.get(cls.__name__, ())]
            steps.append(SequenceStep(name, "send", wire, out, note,
                                      tuple(dict.fromkeys(free)), analog_reply(out)))
    finally:
        board.close()
        shutil.rmtree(folder, ignore_errors=True)
    return Sequence(script.name, script.title, setup, tuple(steps))


def s_learn() -> Script:
    """On-board learning (issue 34 stage 1) on the Python MCU with the capability; the C
    firmware skips it until it implements LEARN (docs/protocol.md "On-board learning")."""
    from snan_hil.calibration.mapping import WeightMap
    from snan_hil.host.hil.board_learning import learn_block, with_synapses
    from snan_hil.protocol import learn_messages as lm
    from snan_hil.tools.learn_agreement import fitted_chip_model, train_config
    s = Script("learn", "On-board learning: LEARN_SETUP, LEARN_WINDOW, LEARN_APPLY, "
               "LEARN_STATE (capability bit 8)", needs=("LEARN",))
    s.hello()
    s.req("LEARN_STATE before any setup", lm.LearnState(0, 8), 2, note="n_syn 0")
    block = learn_block(train_config(), fitted_chip_model(), WeightMap(), set_code=983,
                        reset_code=491, width_us=100, table_bits=4)
    cells = {(0, 0): (0, 2), (0, 1): (1, 0), (0, 2): (0, 3)}
    w = {(0, 0): 0.55, (0, 1): 0.5, (0, 2): 0.2}
    setup = with_synapses(block, cells, w, w)
    s.req("LEARN_SETUP: 3 synapses, tables of 2^4 + 1 points, SET 1.2 V / RESET 0.6 V, 100 us",
          setup, 3)
    s.req("LEARN_SETUP with max_pulses 0", dataclasses.replace(setup, max_pulses=0), 4,
          note="OUT_OF_RANGE, detail 2; the state is kept")
    P = window_params()
    C = m.DecisionCandidate
    key = 0x0123456789ABCDEF
    win = m.DecisionWindow(key, (0, 1), (C(2, 0), C(0, 1), C(3, 0)), P)
    s.req("LEARN_WINDOW 0 of trial 1 (with the parameter block)", lm.LearnWindow(1, 0, 7, win),
          5, note="the board pairs its motor spikes with the input spikes it drew")
    s.req("LEARN_WINDOW 1 of trial 1: lane 1 was chosen in window 0",
          lm.LearnWindow(1, 1, 1, m.DecisionWindow(key + 1, (0, 1), (C(2, 0), C(0, 1)))), 6)
    s.req("LEARN_APPLY of trial 1: lane 0 chosen in window 1", lm.LearnApply(1, 1, 0), 7,
          note="the plan applied: its orders, the synapses touched, STATUS's pulse counter")
    s.req("LEARN_APPLY of trial 1 again (a new request: a host that crashed)",
          lm.LearnApply(1, 1, 0), 8, note="ALREADY: nothing applied")
    s.req("LEARN_WINDOW of trial 1 again", lm.LearnWindow(1, 2, 7, m.DecisionWindow(
        key + 2, (0,), (C(2, 0),))), 9, note="OUT_OF_RANGE, detail 1: trial 1 is applied")
    s.req("LEARN_STATE", lm.LearnState(0, 8), 10, note="the ledger: SET/RESET per synapse")
    s.req("STATUS", m.Status(), 11, note="pulses_applied = the ledger's total")
    s.req("RESET", m.Reset(), 12, note="the learning state is RAM: lost")
    s.nonce = N1
    s.req("LEARN_STATE after the RESET", lm.LearnState(0, 8), 13, note="n_syn 0")
    s.req("LEARN_APPLY after the RESET", lm.LearnApply(2, 0, 7), 14,
          note="OUT_OF_RANGE, detail 0: no learning state")
    return s


SESSIONS = (s_hello, s_read_cell, s_read_column, s_write_pulse, s_spike_batch, s_program_cell,
            s_status_clock_reset, s_errors, s_cache, s_cobs, s_decision_window, s_learn)


def run(script: Script) -> Session:
    """Answer a script with the reference board model."""
    board = BoardSetup(chip_seed=script.seed, boot_nonces=(N0, N1, N2), needs=script.needs)
    emu = Emulator(None, script.seed, array=default_array(script.seed), mcu="model",
                   baud=board.baud, boot_nonces=board.boot_nonces,
                   config=BoardConfig(on_board_learning="LEARN" in script.needs))
    steps, analog_state = [], False
    try:
        for name, wire, note, doc in script.items:
            out = emu.feed(wire)
            frames = [f for f in frames_of(out) if isinstance(f, Frame)]
            free: list[str] = []
            analog = False
            for f in frames:
                cls = m.MESSAGE_TYPES.get(f.type)
                if cls is not None:
                    free += [f"{cls.__name__}.{x}" for x in FREE_FIELDS.get(cls.__name__, ())]
                if f.type in ANALOG_TYPES:
                    analog = analog_state = True
                elif f.type == m.StatusReply.TYPE and analog_state:
                    analog = True      # counters that follow the chip's readings
            steps.append(Step(name, wire, out, note, doc, tuple(dict.fromkeys(free)), analog))
    finally:
        emu.close()
    return Session(script.name, script.title, board, tuple(steps))


# --------------------------------------------------------------------------- reply vectors
def reply_vectors() -> list[ReplyVector]:
    """Frames a host receives while its READ_CELL (3,4,245), seq 0x0102, is outstanding
    (after a HELLO that learnt nonce N0), and what it must do."""
    seq = 0x0102

    def err(code: ErrorCode, detail: int, text: str, *, s: int = seq, nonce: int = N0,
            req: int = m.ReadCell.TYPE) -> bytes:
        return encode_frame(Frame.of(m.ErrorReply(code, req, detail, text), s, nonce))

    return [
        ReplyVector("the reply", encode_frame(Frame.of(m.ReadCellReply(5123), seq, N0)),
                    "accept"),
        ReplyVector("the reply from the cache", encode_frame(Frame.of(
            m.ReadCellReply(5123), seq, N0, FLAG_FROM_CACHE)), "accept"),
        ReplyVector("NAK", err(ErrorCode.BAD_FRAME, NakReason.CRC,
                               "damaged frame: CRC mismatch", s=0, req=0), "resend",
                    "resend the outstanding request at once, same seq"),
        ReplyVector("NAK with another seq", err(ErrorCode.BAD_FRAME, NakReason.LENGTH,
                                                "damaged frame: wrong length", s=0x7777,
                                                req=0), "resend",
                    "a NAK's seq means nothing"),
        ReplyVector("NAK from a server in front of the board", err(
            ErrorCode.BAD_FRAME, NakReason.CRC, "damaged frame: CRC mismatch", s=0, nonce=0,
            req=0), "resend",
                    "nonce 0: a server that serves another client answers a damaged frame of a "
                    "waiting one (issue 27, item 6); resent at once, then BUSY"),
        ReplyVector("BUSY from a server", encode_frame(Frame.of(m.ErrorReply(
            ErrorCode.BUSY, m.ReadCell.TYPE, 42, "serving 127.0.0.1:40000 since 12:00:00"),
            seq, 0)), "resend_after_backoff",
                    "nonce 0: a server in front of the board answers, the board never saw it; "
                    "after the retries: BoardBusyError with the message"),
        *(ReplyVector(code.name, err(code, detail, text), f"raise:{error}")
          for code, detail, text, error in (
              (ErrorCode.UNSUPPORTED, 0, "not implemented", "UnsupportedRequestError"),
              (ErrorCode.INTERNAL, 0, "firmware fault", "InternalBoardError"),
              (ErrorCode.UNKNOWN_TYPE, 2, "unknown request type", "UnsupportedRequestError"),
              (ErrorCode.MALFORMED, 4, "payload does not decode", "MalformedRequestError"),
              (ErrorCode.OUT_OF_RANGE, 32, "row outside the array", "OutOfRangeError"),
              (ErrorCode.SAFETY_LIMIT, 246, "read above the limit", "SafetyLimitError"),
              (ErrorCode.BAD_VERSION, 1, "version not supported", "VersionMismatchError"))),
        ReplyVector("NONCE_MISMATCH", err(ErrorCode.NONCE_MISMATCH, N0, "earlier boot",
                                          nonce=N1), "raise:BoardResetError"),
        ReplyVector("a reply with a new nonce", encode_frame(Frame.of(m.ReadCellReply(5123), seq,
                                                                      N1)),
                    "raise:BoardResetError", "the board was reset"),
        ReplyVector("a reply to another seq", encode_frame(Frame.of(m.ReadCellReply(77), seq - 1,
                                                                    N0)),
                    "ignore", "late or duplicated: discarded, keep waiting"),
        ReplyVector("a reply of the wrong type", encode_frame(Frame.of(m.ClockReply(1, 0.0),
                                                                       seq, N0)),
                    "ignore", "counted as unexpected"),
        ReplyVector("PROGRAM_CELL reply with ok = 2", encode_frame(Frame(
            m.ProgramCellReply.TYPE, seq, struct.pack("<HHHB", 100, 1, 0, 2), N0)),
                    "ignore", "a bool is 0 or 1: malformed, discarded"),
    ]


# --------------------------------------------------------------------------- the doc
DOC_EXAMPLES = (
    # (session, doc id, request title, reply title)
    ("hello", "hello", "HELLO (with the leading 0x00 of a new session)",
     "INFO (the emulated MemriCore board, boot nonce 0x5EED1234)"),
    ("read_cell", "read_cell", "READ_CELL row 3, col 4, at the nominal read code 245 (0.2991 V)",
     "READ_CELL reply"),
    ("read_cell", "read_cell_again", "the same READ_CELL retransmitted (flag RETRANSMIT, "
     "leading 0x00)", "the cached reply (flag FROM_CACHE)"),
    ("read_cell", "safety", "READ_CELL at code 246 (0.3004 V)", "ERROR SAFETY_LIMIT"),
    ("read_column", "read_column", "READ_COLUMN column 1, rows 0-14 at code 245",
     "READ_COLUMN reply"),
    ("write_pulse", "write_pulse", "WRITE_PULSE row 3, col 4, SET, write code 410 (0.50 V), "
     "100 us, read_code 0", "WRITE_PULSE reply"),
    ("spike_batch", "spike_batch", "SPIKE_BATCH, rows 0 and 1 (codes 245 and 123), 16 bins of "
     "1 ms, spikes in bins 0 and 9, columns 0 and 1", "SPIKE_BATCH reply, 2 spikes x 2 columns"),
    ("program_cell", "program_cell", "PROGRAM_CELL row 3, col 4, target 6000 +- 60, amplitude "
     "codes 0 (the old host's ramp), 100 pulses of 100 us, fine tune", "PROGRAM_CELL reply"),
    ("status_clock_reset", "status_request", "STATUS", "STATUS reply"),
    ("status_clock_reset", "clock", "CLOCK", "CLOCK reply"),
    ("status_clock_reset", "reset", "RESET", "RESET reply (the new nonce in its header)"),
    ("status_clock_reset", "nonce_mismatch", "READ_CELL with the nonce of before the RESET",
     "ERROR NONCE_MISMATCH"),
    ("hello", "bad_version", "HELLO asking for protocol version 2", "ERROR BAD_VERSION"),
    ("errors", "nak", "READ_CELL whose CRC was damaged on the line",
     "NAK: ERROR BAD_FRAME, seq 0"),
    ("decision_window", "decision_window", "DECISION_WINDOW with its parameter block (the 6x6 "
     "HIL model), rows 0 and 1, three candidates (lane 0 with 9 interneuron spikes), motor "
     "spikes", "DECISION_WINDOW reply: 166 input spikes, counts 0 / 7 / 0, the 7 motor spikes"),
    ("decision_window", "decision_window_next", "DECISION_WINDOW, the next window (the stored "
     "block), row 2, two candidates", "DECISION_WINDOW reply, counts 4 / 6"),
    ("decision_window", "decision_window_lean", "DECISION_WINDOW with its parameter block and "
     "the lean read plan (flag READ_PLAN, 2 conversions a read), the same window as above",
     "DECISION_WINDOW reply of the lean plan"),
)
BEGIN = "<!-- generated:{} begin (conformance/generate.py; do not edit) -->"
END = "<!-- generated:{} end -->"


def _hex_lines(data: bytes) -> str:
    return "\n".join(" ".join(f"{b:02x}" for b in data[i:i + 16]) for i in range(0, len(data), 16))


def _doc_frame(direction: str, title: str, wire: bytes, session: str, step: int) -> str:
    events = frames_of(wire)
    assert len(events) == 1, (session, step, title)
    f = events[0]
    if not isinstance(f, Frame):            # a damaged frame: the bytes and why
        return "\n".join([f"#### {direction}: {title}", "",
                          f"Damaged (vector `{session}` step {step}): {f}.", "", "```",
                          _hex_lines(wire), "```", ""])
    raw = pack_frame(f)
    d = describe_frame(f)
    meta = {"message": d["message"], "type": d["type"], "seq": f.seq, "nonce": d["nonce"],
            "crc": d["crc"], "flags": f.flags, "fields": message_fields(f.message())}
    import json
    return "\n".join([
        f"#### {direction}: {title}",
        "",
        f"`{d['message']}` (vector `{session}` step {step}): header "
        f"`{' '.join(f'{b:02x}' for b in raw[:12])}` · payload ({len(f.payload)} B) "
        f"`{' '.join(f'{b:02x}' for b in f.payload)}` · CRC "
        f"`{' '.join(f'{b:02x}' for b in raw[-2:])}` ({d['crc']})",
        "",
        f"<!-- vector {json.dumps(meta)} -->",
        "```",
        _hex_lines(wire),
        "```",
        "",
    ])


def doc_examples(sessions: dict[str, Session]) -> str:
    parts = []
    for session, doc_id, req_title, reply_title in DOC_EXAMPLES:
        steps = sessions[session].steps
        (k, step), = [(i, s) for i, s in enumerate(steps, 1) if s.doc == doc_id]
        parts.append(_doc_frame("host -> board", req_title, step.send, session, k))
        parts.append(_doc_frame("board -> host", reply_title, step.expect, session, k))
    return "\n".join(parts).rstrip() + "\n"


def doc_sizes(sessions: dict[str, Session]) -> str:
    rows = [("READ_CELL", "read_cell", "read_cell"),
            ("WRITE_PULSE", "write_pulse", "write_pulse"),
            ("SPIKE_BATCH, a 1 s window: 160 spikes x 8 columns", "spike_batch", "window"),
            ("DECISION_WINDOW, a 1 s window, 2 candidates (stored parameters)",
             "decision_window", "decision_window_next")]
    out = ["| exchange | request on wire | reply on wire | wire time at 115200 | at 921600 |",
           "|---|---|---|---|---|"]
    for label, session, doc_id in rows:
        step = next(s for s in sessions[session].steps if s.doc == doc_id)
        req, rep = len(step.send), len(step.expect)
        t1, t2 = (wire_seconds(req + rep, b) * 1e3 for b in (115200, 921600))
        out.append(f"| {label} | {req} B | {rep} B | {t1:.1f} ms | {t2:.2f} ms |")
    window = next(s for s in sessions["spike_batch"].steps if s.doc == "window")
    (reply,) = [f for f in frames_of(window.expect) if isinstance(f, Frame)]
    r = len(pack_frame(reply))
    on_wire = len(window.expect)
    out += ["", f"The sizes are those of the vectors (`read_cell`, `write_pulse`, `spike_batch` "
            f"step \"a 1 s window\"), measured, not estimated. On the wire a frame of *r* raw "
            f"bytes (14 + payload) takes *r* + 2 bytes when a zero byte occurs at least every 254 "
            f"bytes and up to *r* + ⌊*r*/254⌋ + 2 without any zero byte. A 160 × 8 reply is {r} "
            f"raw bytes: between {r + 2} and {r + r // 254 + 2} B on the wire ({on_wire} B in "
            f"the vector; real ADC codes rarely contain a zero byte: codes of 256 and above, low "
            f"bytes seldom 0)."]
    return "\n".join(out) + "\n"


def render_doc(text: str, sessions: dict[str, Session]) -> str:
    for name, body in (("examples", doc_examples(sessions)), ("sizes", doc_sizes(sessions))):
        begin, end = BEGIN.format(name), END.format(name)
        pattern = re.compile(re.escape(begin) + r".*?" + re.escape(end), re.S)
        if not pattern.search(text):
            raise SystemExit(f"{DOC}: the marked section '{name}' is missing")
        replacement = f"{begin}\n\n{body}\n{end}"
        text = pattern.sub(lambda _m, r=replacement: r, text)
    return text


# --------------------------------------------------------------------------- main
def generate() -> tuple[dict[Path, str], dict[str, Session]]:
    files: dict[Path, str] = {}
    sessions: dict[str, Session] = {}
    for make in SESSIONS:
        session = run(make())
        sessions[session.name] = session
        files[OUT / f"{session.name}.jsonl"] = dump_session(session)
    files[OUT / "sequences.jsonl"] = dump_sequences(
        "Sequences across restarts: what a request or a boot leaves behind",
        [run_sequence_script(make()) for make in SEQUENCES])
    files[OUT / "replies.jsonl"] = dump_replies(
        "replies", "Frames a host receives and what it must do", reply_vectors())
    return files, sessions


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true",
                    help="exit 1 if the vectors or the doc differ from what would be written")
    args = ap.parse_args(argv)
    files, sessions = generate()
    files[DOC] = render_doc(DOC.read_text(encoding="utf-8"), sessions)
    stale = [p for p, text in files.items()
             if not p.is_file() or p.read_text(encoding="utf-8") != text]
    known = set(files)
    extra = [p for p in OUT.glob("*.jsonl") if p not in known]
    if args.check:
        for p in stale + extra:
            print(f"{p.relative_to(ROOT)} is not what conformance/generate.py writes; run it",
                  file=sys.stderr)
        return 1 if stale or extra else 0
    OUT.mkdir(parents=True, exist_ok=True)
    for p in stale:
        p.write_text(files[p], encoding="utf-8")
        print(f"wrote {p.relative_to(ROOT)}")
    for p in extra:
        p.unlink()
        print(f"removed {p.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
