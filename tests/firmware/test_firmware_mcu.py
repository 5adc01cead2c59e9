"""The C firmware on the instruction-level MCU against the Python firmware model.

Same chip seed, same request bytes -> the same replies (INFO's version strings, boot nonces,
CLOCK and ERROR message texts excepted: docs/firmware.md), the same pulse counts; every kind of
bad frame answered as docs/protocol.md says; retransmissions never pulse twice; mutated frames
never crash or hang the firmware; the generated C header matches the Python definitions.
"""

import dataclasses
import os
import random
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("unicorn")

from snan_hil.firmware_emu.emulator import Emulator                       # noqa: E402
from snan_hil.firmware_emu.fw_image import default_elf_path               # noqa: E402
from snan_hil.firmware_emu.testing import default_array                    # noqa: E402
from snan_hil.protocol import messages as m                                # noqa: E402
from snan_hil.protocol.crc import crc16                                    # noqa: E402
from snan_hil.protocol.errors import ErrorCode, NakReason                  # noqa: E402
from snan_hil.protocol.frames import (Frame, FrameDecoder, cobs_encode, encode_frame,  # noqa: E402
                                      pack_frame)

ROOT = Path(__file__).resolve().parents[2]
if not default_elf_path().is_file():
    pytest.skip("firmware ELF not built ('make firmware')", allow_module_level=True)


def make(mcu, seed=0):
    return Emulator(None, seed, array=default_array(seed), mcu=mcu)


class Board:
    """One emulated board fed raw bytes; replies decoded; the nonce learnt from HELLO/RESET."""

    def __init__(self, mcu, seed=0):
        self.emu = make(mcu, seed)
        self.dec = FrameDecoder()
        self.nonce = 0

    def send(self, raw_wire: bytes) -> list[Frame]:
        frames = self.dec.feed(self.emu.feed(raw_wire))
        for f in frames:
            if f.type == m.Info.TYPE:
                self.nonce = m.Info.decode(f.payload).boot_nonce
            elif f.type == m.ResetReply.TYPE:
                self.nonce = m.ResetReply.decode(f.payload).new_nonce
        return frames

    def request(self, msg, seq, nonce=None, flags=0) -> list[Frame]:
        n = self.nonce if nonce is None else nonce
        return self.send(encode_frame(Frame(msg.TYPE, seq, msg.encode(), n, flags)))

    @property
    def pulses(self):
        return self.emu.board.front_end.pulses_applied


def normalise(f: Frame):
    """What must be identical between the two MCUs."""
    msg = f.message()
    if isinstance(msg, m.Info):
        msg = dataclasses.replace(msg, firmware_version="", board_id="", boot_nonce=0)
    elif isinstance(msg, m.ErrorReply):
        # NONCE_MISMATCH's detail is the request's (board-specific) nonce
        msg = (msg.code, msg.request_type,
               None if msg.code == ErrorCode.NONCE_MISMATCH else msg.detail)
    elif isinstance(msg, (m.ClockReply, m.ResetReply)):
        msg = type(msg).__name__
    return (f.type, f.seq, f.flags, msg)


def raw_frame(type_, seq, payload, nonce, *, version=1, length=None, crc_ok=True):
    head = struct.pack("<BBBBHHI", version, 0, type_, 0, seq,
                       len(payload) if length is None else length, nonce)
    body = head + payload
    crc = crc16(body) ^ (0 if crc_ok else 0x5A5A)
    return cobs_encode(body + struct.pack("<H", crc)) + b"\x00"


def scripted(board: Board) -> list:
    """A request script covering every message, refusal and bad-frame kind; returns replies."""
    out = []
    r = lambda msg, seq, **kw: out.extend(board.request(msg, seq, **kw))  # noqa: E731
    raw = lambda *a, **kw: out.extend(board.send(raw_frame(*a, **kw)))   # noqa: E731
    r(m.Hello(), 100, nonce=0)
    r(m.ReadCell(3, 2, 245), 101)
    r(m.ReadCell(3, 2, 246), 102)                           # SAFETY_LIMIT (read > 0.3 V)
    r(m.ReadCell(3, 2, 5000), 103)                          # OUT_OF_RANGE code
    r(m.ReadCell(40, 2, 100), 104)                          # OUT_OF_RANGE row
    r(m.ReadCell(3, 9, 100), 105)                           # OUT_OF_RANGE col
    r(m.WritePulse(5, 1, m.Polarity.SET, 800, 100), 106)    # first pulse: pre-read + pulse
    r(m.WritePulse(5, 1, m.Polarity.SET, 800, 100), 106, flags=1)   # retransmit: from cache
    r(m.WritePulse(5, 1, m.Polarity.RESET, 1000, 250, 200), 107)
    r(m.WritePulse(5, 1, m.Polarity.SET, 1147, 100), 108)   # SAFETY_LIMIT write amplitude
    r(m.WritePulse(5, 1, m.Polarity.SET, 900, 0), 109)      # OUT_OF_RANGE width
    r(m.WritePulse(5, 1, m.Polarity.SET, 0, 0), 110)        # amplitude 0: read only
    r(m.ReadColumn(1, tuple([245] * 15 + [0] * 17)), 111)
    r(m.ReadColumn(1, tuple([245] * 3)), 112)               # OUT_OF_RANGE n
    r(m.ReadColumn(1, tuple([245] * 31 + [300])), 113)      # SAFETY_LIMIT
    groups = (m.SpikeGroup(tuple((i, 82) for i in range(15)), (0, 3, 9)),
              m.SpikeGroup(((20, 245), (21, 100), (22, 30)), (3, 15)))
    r(m.SpikeBatch(groups, (0, 2, 5, 7), n_bins=16, bin_us=1000, first_bin=7), 114)
    r(m.SpikeBatch(groups, (0, 2), n_bins=16, bin_us=50, paced=True), 115)
    r(m.SpikeBatch((m.SpikeGroup(((0, 245),), tuple(range(300))),), tuple(range(8)),
                   n_bins=300), 116)                        # reply too large: OUT_OF_RANGE
    # SPIKE_BATCH edge cases (docs/protocol.md): each refused before anything is driven
    r(m.SpikeBatch((m.SpikeGroup(((1, 100),), ()),), (0,), n_bins=0), 140)   # n_bins 0
    r(m.SpikeBatch(groups, (0,), n_bins=16, bin_us=0, paced=True), 141)
    r(m.SpikeBatch(groups, (0,), n_bins=16, bin_us=0), 142)          # not paced: accepted
    r(m.SpikeBatch((groups[0], m.SpikeGroup((), (1,))), (0,), n_bins=16), 143)   # no rows
    r(m.SpikeBatch((m.SpikeGroup(((20, 245), (21, 100), (20, 30)), (3,)),), (0,),
                   n_bins=16), 144)                                  # repeated row
    r(m.ProgramCell(6, 3, 6000, 120, 60), 117)
    r(m.ProgramCell(6, 4, 2500, 50, 80, 300, 900, 20, 50, 0, True), 118)
    r(m.ProgramCell(6, 4, 2500, 50, 0), 119)                # OUT_OF_RANGE max_pulses
    r(m.ProgramCell(6, 4, 2500, 50, 10, 500, 1200, 8), 120)  # SAFETY_LIMIT ramp end
    r(m.Status(), 121)
    raw(0x33, 122, b"", board.nonce)                        # UNKNOWN_TYPE
    raw(m.ReadCell.TYPE, 123, b"\x01\x02\x03", board.nonce)  # MALFORMED (truncated payload)
    raw(m.WritePulse.TYPE, 124, bytes([1, 1, 2, 0, 1, 100, 0, 0, 0, 0, 0]), board.nonce)
    raw(m.ProgramCell.TYPE, 145, m.ProgramCell(6, 4, 2500, 50, 5).encode()[:-1] + b"\x02",
        board.nonce)                                                 # bool 2: MALFORMED
    raw(m.ReadCell.TYPE, 125, bytes(4), board.nonce, crc_ok=False)   # BAD_CRC
    raw(m.ReadCell.TYPE, 126, bytes(4), board.nonce, version=2)      # BAD_VERSION
    raw(m.ReadCell.TYPE, 127, bytes(4), board.nonce, length=9)       # length: dropped
    raw(m.ReadCell.TYPE, 128, bytes([1, 1, 100, 0]), board.nonce ^ 0xFFFF)  # NONCE_MISMATCH
    out.extend(board.send(b"\x05\x01\x02\x03\x00"))          # COBS/short: dropped
    out.extend(board.send(b"\x11" * 5000 + b"\x00"))         # over-long run: dropped
    r(m.SpikeBatch((), (), n_bins=8, bin_us=1), 129)
    raw(m.SpikeBatch.TYPE, 130, bytes(14) + b"\x00", board.nonce)    # trailing byte
    r(m.Hello(2), 131, nonce=0)                              # HELLO with version 2
    r(m.Status(), 132)
    r(m.Reset(), 133)
    r(m.ReadCell(5, 1, 245), 134)
    r(m.ReadCell(5, 1, 245), 134, nonce=0)                   # another key: executed again
    r(m.Status(), 135)
    return out


def test_same_replies_and_pulses_on_both_mcus():
    model, fw = Board("model"), Board("firmware")
    a, b = scripted(model), scripted(fw)
    assert [normalise(f) for f in b] == [normalise(f) for f in a]
    assert len(a) > 30
    status = [f.message() for f in a if f.type == m.StatusReply.TYPE]
    assert status[0].pulses_applied > 10                 # WRITE_PULSE and PROGRAM_CELL pulses
    # the pulses were the same pulses: the two chips end in the same state
    np.testing.assert_allclose(fw.emu.array.conductance(), model.emu.array.conductance(),
                               rtol=1e-12, atol=0)
    mcu = fw.emu.backend.mcu
    assert mcu.resets == 0 and mcu.faults == {} and mcu.adc_early_frames == 0


def test_every_bad_frame_gets_the_documented_answer():
    fw = Board("firmware")
    fw.request(m.Hello(), 1, nonce=0)
    codes = {}
    for name, wire in {
        "crc": raw_frame(2, 2, bytes(4), fw.nonce, crc_ok=False),
        "version": raw_frame(2, 3, bytes(4), fw.nonce, version=9),
        "unknown": raw_frame(0x7E, 4, b"", fw.nonce),
        "truncated": raw_frame(4, 5, bytes(10), fw.nonce),
        "oversized": raw_frame(7, 6, b"\x00", fw.nonce),
        "nonce": raw_frame(7, 7, b"", fw.nonce + 1),
    }.items():
        (reply,) = fw.send(wire)
        codes[name] = reply.message().code
    assert codes == {"crc": ErrorCode.BAD_CRC, "version": ErrorCode.BAD_VERSION,
                     "unknown": ErrorCode.UNKNOWN_TYPE, "truncated": ErrorCode.MALFORMED,
                     "oversized": ErrorCode.MALFORMED, "nonce": ErrorCode.NONCE_MISMATCH}
    # NAK (BAD_FRAME, seq 0) with the reason: bad COBS, wrong length field, too short,
    # over-long run
    for wire, reason in ((b"\x09\x01\x00", NakReason.COBS),
                         (raw_frame(2, 8, bytes(4), fw.nonce, length=3), NakReason.LENGTH),
                         (cobs_encode(bytes(6)) + b"\x00", NakReason.LENGTH),
                         (b"\x22" * 4200 + b"\x00", NakReason.LENGTH)):
        (nak,) = fw.send(wire)
        assert nak.seq == 0 and (nak.message().code, nak.message().detail) == \
            (ErrorCode.BAD_FRAME, reason)
    assert codes["crc"] == ErrorCode.BAD_FRAME
    (status,) = fw.request(m.Status(), 9)
    s = status.message()
    assert s.framing_errors == 4 and s.crc_errors == 1 and s.malformed == 2
    assert s.unknown_types == 1 and s.nonce_mismatches == 1 and s.refusals == 10


def test_retransmitted_pulse_is_answered_from_the_cache_and_not_applied_twice():
    fw = Board("firmware")
    fw.request(m.Hello(), 1, nonce=0)
    pulse = m.WritePulse(4, 4, m.Polarity.SET, 700, 100)
    (first,) = fw.request(pulse, 2)
    assert fw.pulses == 1
    for _ in range(3):
        (again,) = fw.request(pulse, 2, flags=1)
        assert again.flags & 2 and again.payload == first.payload
    fw.request(m.SpikeBatch((m.SpikeGroup(((0, 100),), (0,)),), (0,), n_bins=8), 3)
    (again,) = fw.request(pulse, 2, flags=1)          # still cached after other requests
    assert again.payload == first.payload and fw.pulses == 1
    (st,) = fw.request(m.Status(), 4)
    assert st.message().duplicates == 4 and st.message().pulses_applied == 1


def test_fuzzed_frames_never_crash_hang_or_double_pulse():
    """30,000 mutated frames (~4 s of CPU); ``SNAN_HIL_FUZZ_FRAMES=1000000`` for a longer
    campaign (what is checked does not depend on the number)."""
    n = int(os.environ.get("SNAN_HIL_FUZZ_FRAMES", "30000"))
    rng = random.Random(12)
    fw = Board("firmware")
    fw.request(m.Hello(), 1, nonce=0)
    pulses_at_reset = 0
    seeds = [m.ReadCell(1, 1, 200), m.WritePulse(2, 2, m.Polarity.SET, 600, 20),
             m.ReadColumn(0, tuple([100] * 32)), m.Status(), m.Clock(),
             m.SpikeBatch((m.SpikeGroup(((3, 100), (4, 90)), (0, 5)),), (1, 2), n_bins=8),
             m.ProgramCell(7, 7, 3000, 100, 5)]
    for _ in range(n):
        msg = rng.choice(seeds)
        raw = bytearray(pack_frame(Frame(msg.TYPE, rng.randrange(65536), msg.encode(),
                                         rng.choice((fw.nonce, 0, 1)))))
        for _ in range(rng.randrange(1, 4)):
            kind = rng.randrange(4)
            if kind == 0:
                raw[rng.randrange(len(raw))] ^= 1 << rng.randrange(8)
            elif kind == 1 and len(raw) > 1:
                del raw[max(1, rng.randrange(len(raw))):]
            elif kind == 2:
                raw.insert(rng.randrange(len(raw) + 1), rng.randrange(256))
            else:
                raw[rng.randrange(len(raw))] = rng.randrange(256)
        if rng.random() < 0.5:                        # keep the CRC right: reach the parsers
            raw[-2:] = struct.pack("<H", crc16(bytes(raw[:-2])))
        replies = fw.send(cobs_encode(bytes(raw)) + b"\x00")
        if any(f.type == m.ResetReply.TYPE for f in replies):   # a mutated type can be RESET
            pulses_at_reset = fw.pulses
    mcu = fw.emu.backend.mcu
    assert mcu.resets == 0 and mcu.faults == {}      # no trap, no watchdog, no bad access
    assert mcu.s.wdt_kicks > n                       # the watchdog was armed all along
    (info,) = fw.request(m.Hello(), 2, nonce=0)      # still serving
    (st,) = fw.request(m.Status(), 3)
    # every pulse the chip saw was applied by an executed request and counted once
    assert st.message().pulses_applied == fw.pulses - pulses_at_reset


def test_generated_header_matches_the_python_definitions():
    header = default_elf_path().parent / "snan_constants.h"
    code = subprocess.run([sys.executable, str(ROOT / "firmware" / "gen_constants.py"),
                           "--check", str(header)]).returncode
    assert code == 0, "build/firmware/snan_constants.h is stale: run 'make firmware'"
    text = header.read_text()
    assert f"#define MSG_SPIKE_BATCH                    0x{m.SpikeBatch.TYPE:02X}" in text
    assert f"#define ERR_NONCE_MISMATCH                 {int(ErrorCode.NONCE_MISMATCH)}" in text
    assert f"#define PROTO_MAX_PAYLOAD                  {m.MAX_PAYLOAD}" in text


def test_missing_elf_is_one_clear_line(tmp_path, monkeypatch):
    from snan_hil.common.errors import UserError
    monkeypatch.setenv("SNAN_HIL_FIRMWARE_ELF", str(tmp_path / "none.elf"))
    with pytest.raises(UserError, match="make firmware"):
        make("firmware")


# identical behaviour on longer runs: the same requests, so the same replies all the way
TIMING = ("wall_s", "virtual_s")


def test_program_weights_is_the_same_on_both_mcus(tmp_path):
    from snan_hil.calibration.programmer import program_weights
    from snan_hil.calibration.testing import session_of
    from snan_hil.calibration.testing import grid_weights
    from snan_hil.firmware_emu.inprocess import emulator_of, open_inprocess_transport
    from snan_hil.protocol.link import LinkClient
    w = grid_weights(6, 6, seed=11)
    runs = {}
    for mcu in ("model", "firmware"):
        transport = open_inprocess_transport(state_file=str(tmp_path / f"{mcu}.npz"), seed=0,
                                             mcu=mcu)
        emu = emulator_of(transport)
        client = LinkClient(transport)
        client.hello()
        try:
            result = program_weights(session_of(client, tmp_path / f"{mcu}.json"), w,
                                     {"grid": [6, 6]})
        finally:
            client.close()
        runs[mcu] = (result.report, emu.board.front_end.pulses_applied, emu.array.conductance())
    (ra, pa, ga), (rb, pb, gb) = runs["model"], runs["firmware"]
    assert ra["cells"] == rb["cells"] and len(ra["cells"]) == 120      # every pulse count too
    summary = lambda r: {k: v for k, v in r["summary"].items() if k not in TIMING}  # noqa: E731
    assert summary(ra) == summary(rb) and ra["ledger"] == rb["ledger"]
    assert summary(rb)["ok"] == 120 and summary(rb)["median_abs_rel_error"] <= 0.03
    assert pa == pb == summary(rb)["host_pulses"] > 500
    np.testing.assert_allclose(gb, ga, rtol=1e-12, atol=0)


def test_a_hil_launch_is_the_same_on_both_mcus(tmp_path):
    from snan_hil.calibration.weights_io import load_weight_set
    from snan_hil.host.hil.runner import run_scenario
    from snan_hil.host.hil.testing import make_weights, program_set, small_hil_config
    from snan_hil.tools.ports import open_client
    hil = small_hil_config(max_steps=15)
    wpath = make_weights(tmp_path / "w.npz", sets=1, cycles=2, hil=hil)
    w, _ = load_weight_set(wpath, 0)
    runs = {}
    for mcu in ("model", "firmware"):
        client = open_client("emu", state_file=str(tmp_path / f"{mcu}.npz"), seed=0, mcu=mcu)
        try:
            layout = program_set(client, wpath, 0, tmp_path / f"{mcu}.json")
            res = run_scenario("hw_astro", w, hil, launches=2, seed=3, client=client,
                               layout=layout)
        finally:
            client.close()
        runs[mcu] = res
    a, b = runs["model"], runs["firmware"]
    assert [r.path for r in a.launches] == [r.path for r in b.launches]
    stats = lambda r: {k: v for k, v in r.read_stats.items() if k != "wall_s"}  # noqa: E731
    assert stats(a) == stats(b) and sum(r.spikes for r in b.launches) > 500
