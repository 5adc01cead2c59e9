"""The conformance vectors (conformance/v1/framed) against every board implementation here.

* the committed vectors and docs/protocol.md's generated sections are what
  conformance/generate.py writes now (regenerate after a deliberate change);
* the Python board model (``--mcu model``) and the C firmware on the instruction-level MCU
  (``--mcu firmware``) answer every step of every session as the vectors say (byte for byte,
  except the fields docs/protocol.md leaves to the implementation: ERROR texts, INFO's
  strings, CLOCK's time and energy);
* the host client reacts to every reply vector as stated (resend, back off, raise, ignore);
* together the vectors cover every message, every ERROR code and the COBS edge cases.
"""

import subprocess
import sys
from pathlib import Path

import pytest

from snan_hil.firmware_emu.config import BoardConfig
from snan_hil.firmware_emu.emulator import Emulator
from snan_hil.firmware_emu.fw_image import default_elf_path
from snan_hil.firmware_emu.testing import default_array
from snan_hil.protocol import errors as E
from snan_hil.protocol import messages as m
from snan_hil.protocol.conformance import (Session, compare_replies, frames_of, load_replies,
                                           load_sequences, load_session, run_sequence,
                                           run_session)
from snan_hil.protocol.frames import Frame, cobs_decode
from snan_hil.protocol.link import LinkClient
from snan_hil.protocol.transport import CallbackTransport

ROOT = Path(__file__).resolve().parents[2]
VECTORS = ROOT / "conformance" / "v1" / "framed"
SESSIONS = sorted(p for p in VECTORS.glob("*.jsonl")
                  if p.name not in ("replies.jsonl", "sequences.jsonl"))
SEQUENCES = load_sequences(VECTORS / "sequences.jsonl")


def board(session: Session, mcu: str) -> Emulator:
    """A fresh emulated board in the session's start state."""
    b = session.board
    return Emulator(None, b.chip_seed, array=default_array(b.chip_seed), mcu=mcu, baud=b.baud,
                    boot_nonces=b.boot_nonces,
                    config=BoardConfig(on_board_learning="LEARN" in b.needs))


def test_vectors_and_doc_are_what_the_generator_writes():
    proc = subprocess.run([sys.executable, str(ROOT / "conformance" / "generate.py"), "--check"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr


@pytest.mark.parametrize("path", SESSIONS, ids=lambda p: p.stem)
def test_python_board_model_conforms(path):
    session = load_session(path)
    emu = board(session, "model")
    try:
        assert run_session(session, emu.feed) == []
    finally:
        emu.close()


@pytest.mark.skipif(not default_elf_path().is_file(), reason="firmware ELF not built")
@pytest.mark.parametrize("path", SESSIONS, ids=lambda p: p.stem)
def test_c_firmware_conforms(path):
    pytest.importorskip("unicorn")
    session = load_session(path)
    if "LEARN" in session.board.needs:
        pytest.skip("the C firmware has no on-board learning yet (issue 34 stage 1: the "
                    "Python MCU only)")
    emu = board(session, "firmware")
    try:
        assert run_session(session, emu.feed) == []
        mcu = emu.backend.mcu
        assert mcu.resets == 0 and mcu.faults == {}
    finally:
        emu.close()


def sequence_board(sequence, mcu, folder):
    """A durable emulated board in the sequence's start state (chip seed and serial, nonces)."""
    from snan_hil.firmware_emu.twin import EmulatedBoard
    b = sequence.board
    return EmulatedBoard(folder, mcu, chip_seed=b.chip_seed, serial=b.chip_serial,
                         boot_nonces=b.boot_nonces, baud=b.baud, trace=False)


@pytest.mark.parametrize("mcu", ["model", "firmware"])
@pytest.mark.parametrize("sequence", SEQUENCES, ids=lambda q: q.name)
def test_both_mcus_follow_the_sequence_vectors(sequence, mcu, tmp_path):
    """Vectors across restarts (kills with a journal replay, clean restarts) on a chip with a
    serial: the compliance basis of a 0 V read (issue 27.3), the first reads of a boot after
    an INFO that names the chip (27.4), programming that survives a kill."""
    if mcu == "firmware":
        pytest.importorskip("unicorn")
        if not default_elf_path().is_file():
            pytest.skip("firmware ELF not built")
    board = sequence_board(sequence, mcu, tmp_path)
    try:
        assert run_sequence(sequence, board) == []
        assert board.mcu_faults == {}
    finally:
        board.close()


def test_a_board_that_differs_is_caught():
    session = load_session(VECTORS / "read_cell.jsonl")
    emu = board(session, "model")
    try:
        emu.firmware.config = type(emu.firmware.config)(max_read_v=0.31)   # 246 now allowed
        problems = run_session(session, emu.feed)
    finally:
        emu.close()
    assert any("step 5" in p and "READ_CELL at 246" in p for p in problems)
    # free fields may differ, nothing else
    (step,) = [s for s in load_session(VECTORS / "hello.jsonl").steps[:1]]
    (info_frame,) = [f for f in frames_of(step.expect) if isinstance(f, Frame)]
    info = info_frame.message()
    import dataclasses
    from snan_hil.protocol.frames import encode_frame
    other = dataclasses.replace(info, firmware_version="lab-fw 2", board_id="LAB-7")
    wire = encode_frame(Frame.of(other, info_frame.seq, info_frame.nonce))
    assert compare_replies(step.expect, wire, step.free) is None
    assert compare_replies(step.expect, wire, ()) is not None
    worse = dataclasses.replace(other, max_write_v=1.5)
    assert "max_write_v" in compare_replies(step.expect, encode_frame(
        Frame.of(worse, info_frame.seq, info_frame.nonce)), step.free)


# --------------------------------------------------------------------------- host side
def _host_reaction(vector) -> str:
    """What LinkClient does when ``vector`` answers its READ_CELL (seq 0x0102, nonce N0)."""
    good = Frame.of(m.ReadCellReply(5123), 0x0102, 0x5EED1234)
    from snan_hil.protocol.frames import encode_frame
    sent: list[bytes] = []

    def board(data: bytes) -> bytes:
        sent.append(data)
        if len(sent) == 1:                 # HELLO
            return encode_frame(Frame.of(m.Info(boot_nonce=0x5EED1234), 0x0101, 0x5EED1234))
        if len(sent) == 2:                 # the READ_CELL: the vector (then, if it is one to
            return vector.wire + (encode_frame(good) if vector.host == "ignore" else b"")
        return encode_frame(good)          # a resend: the good reply

    client = LinkClient(CallbackTransport(board), first_seq=0x0101, timeout=0.05,
                        busy_backoff_s=0.0)
    client.hello()
    try:
        adc = client.read_cell(3, 4, 245)
    except E.ProtocolError as exc:
        return f"raise:{type(exc).__name__}"
    resends = len(sent) - 2
    if adc != 5123:
        return f"accepted {adc}"
    if resends == 0:
        return "ignore" if vector.host == "ignore" else "accept"
    return "resend_after_backoff" if client.counters.busy else "resend"


@pytest.mark.parametrize("vector", load_replies(VECTORS / "replies.jsonl"), ids=lambda v: v.name)
def test_host_reacts_to_each_reply_vector(vector):
    assert _host_reaction(vector) == vector.host


# --------------------------------------------------------------------------- coverage
def _all_frames():
    sent, received = [], []
    for path in SESSIONS:
        for step in load_session(path).steps:
            sent += frames_of(step.send)
            received += frames_of(step.expect)
    return sent, received


def test_vectors_cover_every_message_and_error_code():
    sent, received = _all_frames()
    replies = [f for v in load_replies(VECTORS / "replies.jsonl") for f in frames_of(v.wire)]
    types = {f.type for f in sent + received if isinstance(f, Frame)}
    assert set(m.MESSAGE_TYPES) <= types
    codes = {f.message().code for f in received + replies
             if isinstance(f, Frame) and f.type == m.ErrorReply.TYPE}
    assert codes == set(E.ErrorCode)
    board_codes = {f.message().code for f in received
                   if isinstance(f, Frame) and f.type == m.ErrorReply.TYPE}
    # what a board sends itself (BUSY comes from a server, UNSUPPORTED / INTERNAL from other
    # boards: reply vectors only)
    assert board_codes == set(E.ErrorCode) - {E.ErrorCode.BUSY, E.ErrorCode.UNSUPPORTED,
                                              E.ErrorCode.INTERNAL}
    naks = {f.message().detail for f in received
            if isinstance(f, Frame) and f.type == m.ErrorReply.TYPE
            and f.message().code == E.ErrorCode.BAD_FRAME}
    assert naks == set(E.NakReason)


def test_vectors_cover_the_cobs_edge_cases():
    wires = [s.send for p in SESSIONS for s in load_session(p).steps]
    bodies = [w.strip(b"\x00") for w in wires if b"\x00" not in w.strip(b"\x00")]
    # a 254-byte run at the end: canonical (FF + 254 bytes) and with an empty group after it
    assert any(len(b) > 255 and b[-255] == 0xFF for b in bodies)
    assert any(len(b) > 256 and b[-256] == 0xFF and b[-1] == 0x01 for b in bodies)
    # a 255-byte run (FF + 254, then 02 + 1) and a 254-byte run followed by a zero (FF, 01)
    def ff_then(code: int) -> bool:
        return any(b[i] == 0xFF and b[i + 255] == code
                   for b in bodies if len(b) < 400 for i in range(len(b) - 255))

    assert ff_then(0x02) and ff_then(0x01)
    raws = []
    for w in wires:
        for chunk in w.split(b"\x00"):
            try:
                raws.append(cobs_decode(chunk))
            except E.FrameError:
                pass
    assert any(len(r) == 14 for r in raws)                          # an empty payload
    assert any(len(r) == 14 + m.MAX_PAYLOAD for r in raws)          # the largest frame
    whole = [w for w in wires if len(frames_of(w)) == 1 and isinstance(frames_of(w)[0], Frame)]
    assert max(len(w) for w in whole) == 4128               # the longest frame on the wire
    assert any(len(w) > 4128 and b"\x00" not in w[:-1] for w in wires)   # over-long run
