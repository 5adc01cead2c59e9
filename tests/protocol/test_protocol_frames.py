"""Frames: COBS, header/CRC checks, the streaming decoder under garbage and damage."""

import pathlib
import random
import re
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from snan_hil.protocol.errors import CobsError, CrcError, FrameLengthError
from snan_hil.protocol.frames import (HEADER_SIZE, OVERHEAD, Frame, FrameDecoder, cobs_decode,
                                      cobs_encode, decode_frame, encode_frame, max_encoded_size,
                                      pack_frame, unpack_frame)

SETTINGS = settings(max_examples=150, deadline=None, derandomize=True)
DOC = pathlib.Path(__file__).resolve().parents[2] / "docs" / "protocol.md"


def ref_cobs_encode(data: bytes) -> bytes:
    """Textbook byte-at-a-time COBS, independent of the implementation under test."""
    out, code_pos, code = bytearray([0]), 0, 1
    for i, byte in enumerate(data):
        if byte == 0:
            out[code_pos] = code
            code_pos, code = len(out), 1
            out.append(0)
        else:
            out.append(byte)
            code += 1
            if code == 0xFF:
                out[code_pos] = code
                if i + 1 == len(data):
                    return bytes(out)
                code_pos, code = len(out), 1
                out.append(0)
    out[code_pos] = code
    return bytes(out)


@pytest.mark.parametrize("data,encoded", [
    # the examples of the COBS article (Wikipedia, "Consistent Overhead Byte Stuffing")
    ("00", "0101"),
    ("0000", "010101"),
    ("001100", "01021101"),
    ("11220033", "03112202 33"),
    ("11223344", "0511223344"),
    ("11000000", "0211010101"),
])
def test_cobs_known_vectors(data, encoded):
    raw, enc = bytes.fromhex(data), bytes.fromhex(encoded.replace(" ", ""))
    assert cobs_encode(raw) == enc
    assert cobs_decode(enc) == raw


def test_cobs_254_and_255_byte_runs():
    # examples 7-11 of the same article
    run254 = bytes(range(1, 255))
    assert cobs_encode(run254) == b"\xff" + run254
    assert cobs_encode(b"\x00" + run254) == b"\x01\xff" + run254
    run255 = bytes(range(1, 256))
    assert cobs_encode(run255) == b"\xff" + run255[:254] + b"\x02\xff"
    assert cobs_encode(bytes(range(2, 256)) + b"\x00") == \
        b"\xff" + bytes(range(2, 256)) + b"\x01\x01"
    assert cobs_encode(bytes(range(3, 256)) + b"\x00\x01") == \
        b"\xfe" + bytes(range(3, 256)) + b"\x02\x01"
    assert cobs_decode(cobs_encode(run254 + b"\x00")) == run254 + b"\x00"


@SETTINGS
@given(st.binary(max_size=1200))
def test_cobs_round_trip_and_reference(data):
    enc = cobs_encode(data)
    assert b"\x00" not in enc
    assert cobs_decode(enc) == data
    assert enc == ref_cobs_encode(data)
    assert len(enc) <= len(data) + len(data) // 254 + 1


def test_cobs_rejects_invalid():
    with pytest.raises(CobsError):
        cobs_decode(b"\x05\x01")       # group runs past the end
    with pytest.raises(CobsError):
        cobs_decode(b"\x02\x00")       # contains the delimiter


def test_frame_layout_little_endian():
    frame = Frame(type=0x02, seq=0x1234, payload=b"\xaa\xbb", nonce=0xDEADBEEF, flags=1)
    raw = pack_frame(frame)
    assert raw[:HEADER_SIZE] == bytes([1, 1, 0x02, 0, 0x34, 0x12, 0x02, 0x00,
                                       0xEF, 0xBE, 0xAD, 0xDE])
    assert raw[HEADER_SIZE:-2] == b"\xaa\xbb"
    assert len(raw) == OVERHEAD + 2
    assert unpack_frame(raw) == frame
    assert decode_frame(encode_frame(frame)) == frame


def test_frame_checks():
    raw = bytearray(pack_frame(Frame(0x02, 5, b"\x01\x02\x03\x04")))
    with pytest.raises(FrameLengthError):
        unpack_frame(bytes(raw[:OVERHEAD - 1]))
    bad_len = bytearray(raw)
    bad_len[6] = 9
    with pytest.raises(FrameLengthError):
        unpack_frame(bytes(bad_len))
    bad_crc = bytearray(raw)
    bad_crc[HEADER_SIZE] ^= 0x40
    with pytest.raises(CrcError) as info:
        unpack_frame(bytes(bad_crc))
    assert info.value.header == (1, 0, 0x02, 5, 0)   # header kept for a BAD_CRC reply
    with pytest.raises(FrameLengthError):
        unpack_frame(pack_frame(Frame(0x05, 1, bytes(100))), max_payload=99)


def _random_frame(rng: random.Random) -> Frame:
    size = rng.choice([0, 1, 4, 30, 253, 254, 255, 600, 2500])
    payload = bytes(rng.choice([0, 0, rng.randrange(256)]) for _ in range(size))
    return Frame(rng.randrange(256), rng.randrange(65536), payload, rng.randrange(2**32),
                 rng.randrange(4))


def _build_stream(rng: random.Random, n: int):
    """A stream of intact, duplicated, reordered, truncated, bit-flipped frames and garbage.

    Returns (stream bytes, the intact frames the decoder must yield, in order).
    """
    pool = [_random_frame(rng) for _ in range(n)]
    stream, expected = bytearray(), []
    clean = True  # the previous segment ended with a delimiter
    for _ in range(3 * n):
        kind = rng.choice(["frame", "frame", "dup", "garbage", "trunc", "flip", "flip2"])
        frame = rng.choice(pool)  # picking from a pool duplicates and reorders
        enc = encode_frame(frame)
        if kind in ("frame", "dup"):
            stream += enc
            if clean:
                expected.append(frame)
            if kind == "dup":
                stream += enc
                expected.append(frame)
            clean = True
        elif kind == "garbage":
            stream += bytes(rng.randrange(256) for _ in range(rng.randrange(1, 80)))
            clean = stream.endswith(b"\x00")
        elif kind == "trunc":
            stream += enc[:rng.randrange(1, len(enc) - 1)]
            if rng.random() < 0.5:
                stream += b"\x00"
            clean = stream.endswith(b"\x00")
        else:
            body = bytearray(enc[:-1])
            for _ in range(1 if kind == "flip" else rng.randrange(2, 6)):
                pos = rng.randrange(len(body))
                body[pos] ^= 1 << rng.randrange(8)
            stream += bytes(body) + b"\x00"
            clean = True
    return bytes(stream), expected


@pytest.mark.parametrize("seed", range(6))
def test_decoder_fuzz_yields_exactly_the_intact_frames(seed):
    rng = random.Random(seed)
    stream, expected = _build_stream(rng, 40)
    whole = FrameDecoder(max_payload=3000)
    got = whole.feed(stream)
    assert got == expected
    assert whole.counters.frames == len(expected)
    assert whole.counters.errors > 0
    # any chunking gives the same result
    chunked = FrameDecoder(max_payload=3000)
    out, pos = [], 0
    while pos < len(stream):
        step = rng.choice([1, 2, 3, 17, 255, 4000])
        out += chunked.feed(stream[pos:pos + step])
        pos += step
    assert out == expected
    assert chunked.counters == whole.counters


@SETTINGS
@given(st.lists(st.binary(max_size=300), max_size=20))
def test_decoder_never_raises_on_garbage(chunks):
    dec = FrameDecoder(max_payload=64)
    for chunk in chunks:
        for frame in dec.feed(chunk):
            # anything yielded re-encodes to a frame that passes every check
            assert decode_frame(encode_frame(frame), 64) == frame


@SETTINGS
@given(st.binary(min_size=1, max_size=200), st.integers(0, 10_000))
def test_single_and_double_bit_flips_are_detected(payload, where):
    frame = Frame(0x04, 3, payload, 77)
    raw = bytearray(pack_frame(frame))
    bit = where % (8 * len(raw))
    raw[bit // 8] ^= 1 << (bit % 8)
    bit2 = (where * 7919 + 13) % (8 * len(raw))
    if bit2 != bit and where % 2:
        raw[bit2 // 8] ^= 1 << (bit2 % 8)
    with pytest.raises((CrcError, FrameLengthError)):
        unpack_frame(bytes(raw))


def test_overlong_garbage_is_dropped_and_decoder_recovers():
    dec = FrameDecoder(max_payload=32)
    good = Frame(0x02, 1, b"\x01\x02\x03\x04")
    assert dec.feed(b"\x07" * (max_encoded_size(32) + 50)) == []
    assert dec.pending == 0
    assert dec.counters.length_errors == 1
    # the tail of the overlong run (up to its delimiter) is skipped, then frames flow again
    assert dec.feed(b"\x07" * 10 + b"\x00" + encode_frame(good)) == [good]


def test_empty_frames_between_delimiters_are_ignored():
    good = Frame(0x07, 9)
    dec = FrameDecoder()
    assert dec.feed(b"\x00\x00\x00" + encode_frame(good) + b"\x00\x00") == [good]
    assert dec.counters.errors == 0


def _bitwise_crc(data: bytes) -> int:
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = (((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1) & 0xFFFF
    return crc


def _doc_vectors():
    text = DOC.read_text(encoding="utf-8")
    return re.findall(r"<!-- vector (\{.*?\}) -->\s*```\s*\n(.*?)```", text, re.S)


def test_documented_test_vectors_decode_to_their_stated_fields():
    import json

    from snan_hil.protocol.conformance import message_fields

    vectors = _doc_vectors()
    assert len(vectors) >= 20
    for meta_text, dump in vectors:
        meta = json.loads(meta_text)
        wire = bytes.fromhex("".join(line.split("|")[0] for line in dump.strip().splitlines()))
        frames = FrameDecoder().feed(wire)
        assert len(frames) == 1, meta
        frame = frames[0]
        assert (frame.type, frame.seq, frame.nonce, frame.flags) == \
            (int(meta["type"], 16), meta["seq"], int(meta["nonce"], 16), meta.get("flags", 0))
        # the CRC stated in the doc is the CCITT-FALSE of header+payload (bitwise reference)
        raw = pack_frame(frame)
        assert struct.unpack("<H", raw[-2:])[0] == int(meta["crc"], 16) == \
            _bitwise_crc(raw[:-2])
        msg = frame.message()
        assert type(msg).__name__ == meta["message"]
        fields = message_fields(msg)               # JSON-ready (nested dataclasses as dicts)
        for key, value in meta.get("fields", {}).items():
            assert fields[key] == value, (meta["message"], key)
