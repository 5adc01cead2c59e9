"""Branch coverage of the C firmware per function, on the instruction-level MCU (issue 37.4).

Usage: ``python bench/bench_fw_coverage.py [--frames N] [--seeds S,S] [--json FILE]
[--timing spin|collapsed]``

Runs, with :class:`snan_hil.firmware_emu.isa_coverage.BranchCoverage` hooked on the MCU: every
framed conformance session (``conformance/v1/framed``), a reset of the MCU (the boot path), and
the seeded differential streams (:mod:`snan_hil.firmware_emu.differential_fast`, ``--frames``
per seed, both MCUs compared on every write). Prints per function the conditional branches, the
outcomes reached (taken and not taken) and the percentage, the total, and which of the
firmware's ERROR call sites (calls of ``build_error``) ran, with the uncovered outcomes of the
functions below target.

Also the ERROR paths: every call of ``send_error``, ``send_nak`` and ``refuse`` in the C
sources, known by the text its ERROR reply carries (the compiler merges the calls' code, so
the binary alone cannot tell them apart), against the texts the firmware answered with.

Target: >= 95 % of the branch outcomes in every function, every ERROR path reached.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

from snan_hil.firmware_emu import differential_fast
from snan_hil.firmware_emu.config import BoardConfig
from snan_hil.firmware_emu.emulator import Emulator
from snan_hil.firmware_emu.fw_image import FirmwareImage
from snan_hil.firmware_emu.isa_coverage import BranchCoverage, error_lines
from snan_hil.firmware_emu.mcu_isa import TIMING_ENV, TIMINGS
from snan_hil.firmware_emu.testing import default_array
from snan_hil.protocol import messages as m
from snan_hil.protocol.errors import ErrorCode
from snan_hil.protocol.conformance import frames_of, load_session, run_session
from snan_hil.protocol.frames import Frame

ROOT = Path(__file__).resolve().parent.parent
VECTORS = ROOT / "conformance" / "v1" / "framed"
TARGET = 95.0


ERRORS: dict[tuple[str, str], int] = {}
MESSAGES: set[str] = set()


def tally(out: bytes) -> bytes:
    """Count the ERROR replies in a board's answer by (request type, code)."""
    for f in frames_of(out):
        if isinstance(f, Frame) and f.type == m.ErrorReply.TYPE:
            try:
                e = f.message()
            except Exception:                # noqa: BLE001 - a damaged reply counts nowhere
                continue
            assert isinstance(e, m.ErrorReply)
            MESSAGES.add(e.message)
            cls = m.MESSAGE_TYPES.get(e.request_type)
            key = (cls.__name__ if cls else "(other types)", e.code.name)
            ERRORS[key] = ERRORS.get(key, 0) + 1
    return out


def run_free(cov: BranchCoverage, folder: Path) -> None:
    """A board as a lab has it: a chip with a serial in the EEPROM, nonces from the MCU's own
    entropy (the conformance boards force both), reset a few times, a HELLO after each."""
    from snan_hil.firmware_emu.differential import raw_frame, wire
    emu = Emulator(folder / "chip.npz", 5, mcu="firmware")
    try:
        assert emu.backend is not None
        cov.attach(emu.backend.mcu)
        for seq in range(3):
            emu.backend.mcu.press_reset()
            tally(emu.feed(b"\x00" + wire(raw_frame(m.Hello.TYPE, seq, m.Hello().encode(), 0))))
    finally:
        emu.close()


def run_records(cov: BranchCoverage) -> int:
    """Every identity record of :func:`chip_identity.record_corpus` on the EEPROM, a reboot and
    a HELLO each; returns the records whose INFO named another serial than the record's."""
    from snan_hil.firmware_emu import chip_identity
    from snan_hil.firmware_emu.differential import raw_frame, wire
    emu = Emulator(None, 3, mcu="firmware")
    wrong = 0
    try:
        assert emu.backend is not None
        mcu = emu.backend.mcu
        cov.attach(mcu)
        for _, record, serial in chip_identity.record_corpus():
            mcu.write_identity_record(record)
            mcu.press_reset()
            out = tally(emu.feed(b"\x00" + wire(raw_frame(m.Hello.TYPE, 1, m.Hello().encode(),
                                                          0))))
            ids = [f.message().board_id for f in frames_of(out)
                   if isinstance(f, Frame) and f.type == m.Info.TYPE]
            want = chip_identity.firmware_board_id_text(BoardConfig().board_id, serial)
            wrong += ids != [want]
    finally:
        emu.close()
    return wrong


def run_corners(cov: BranchCoverage) -> int:
    """The requests of :mod:`corner_cases` (the timer's wrap, saturation near full scale,
    PROGRAM_CELL to the code just read) on
    both MCUs, compared, in the collapsed poll timing (the wrap is 134 s of waiting)."""
    from snan_hil.firmware_emu import corner_cases
    timing = os.environ.get(TIMING_ENV)
    os.environ[TIMING_ENV] = "collapsed"
    twin = differential_fast.FastTwin(1, (11, 12, 13), on_boot=cov.attach)
    try:
        replies = corner_cases.run(twin, differential_fast.RequestStream(1),
                                   corner_cases.timer_half() + corner_cases.timer_wrap() +
                                   corner_cases.saturation())
        replies += corner_cases.program_at_reading(twin, differential_fast.RequestStream(2))
    finally:
        twin.close()
        if timing is not None:
            os.environ[TIMING_ENV] = timing
    return sum(f.type == m.ErrorReply.TYPE for f in replies)


def run_conformance(cov: BranchCoverage) -> int:
    problems = 0
    for path in sorted(p for p in VECTORS.glob("*.jsonl")
                       if p.stem not in ("replies", "sequences")):
        session = load_session(path)
        b = session.board
        emu = Emulator(None, b.chip_seed, array=default_array(b.chip_seed), mcu="firmware",
                       baud=b.baud, boot_nonces=b.boot_nonces)
        try:
            assert emu.backend is not None
            cov.attach(emu.backend.mcu)
            problems += len(run_session(session, lambda data, e=emu: tally(e.feed(data))))
            emu.backend.mcu.press_reset()          # the boot path, under the hook
        finally:
            emu.close()
    return problems


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20000, help="compared frames per seed")
    ap.add_argument("--seeds", default="1,2", help="seeds of the differential streams")
    ap.add_argument("--json", type=Path, default=None, help="write the per-function figures")
    ap.add_argument("--timing", choices=TIMINGS, default="spin",
                    help="the MCU's poll loops: spin (they wait as on the MCU, default) or "
                         "collapsed (each ends at its first poll)")
    args = ap.parse_args(argv)
    os.environ[TIMING_ENV] = args.timing         # every MCU the workload boots
    image = FirmwareImage.load()
    cov = BranchCoverage(image)
    t0 = time.perf_counter()
    bad = run_conformance(cov)
    with tempfile.TemporaryDirectory(prefix="snan-cov-") as tmp:
        run_free(cov, Path(tmp))
    bad += run_records(cov)
    bad += run_corners(cov)
    stats = differential_fast.FastStats()
    for seed in (int(s) for s in args.seeds.split(",") if s.strip()):
        # (the boot path is covered by the conformance boards' resets: a reset here would
        # give the firmware a boot nonce the model does not draw)
        differential_fast.run_stream(seed, args.frames, stats=stats, on_boot=cov.attach,
                                     on_reply=tally)
    wall = time.perf_counter() - t0
    funcs = cov.functions()
    print(f"{'function':<22} {'branches':>8} {'outcomes':>9} {'coverage':>9}")
    below = []
    for f in sorted(funcs, key=lambda f: f.percent or 0.0):
        pct = f.percent or 0.0
        print(f"{f.name:<22} {f.branches:>8} {f.outcomes:>4}/{2 * f.branches:<4} {pct:>8.1f}%")
        if pct < TARGET:
            below.append(f)
    hit, total = cov.total()
    ran, missed = cov.error_sites()
    paths = error_lines(ROOT / "firmware" / "src")
    unhit = [(f, line, texts) for f, line, texts in paths if not MESSAGES & set(texts)]
    print(f"{'all':<22} {len(cov.branches):>8} {hit:>4}/{total:<4} {100 * hit / total:>8.1f}%")
    print(f"ERROR call sites in the binary (calls of build_error) reached: {len(ran)} of "
          f"{len(cov.error_calls)}" + (f"; not reached at {', '.join(hex(a) for a in missed)}"
                                       if missed else ""))
    print(f"ERROR paths of the sources (calls of send_error, send_nak, refuse; known by their "
          f"reply's text) answered by the firmware: {len(paths) - len(unhit)} of {len(paths)}")
    for f, line, texts in unhit:
        print(f"  not reached: {f}:{line} {' / '.join(texts)}")
    codes = sorted({code for _, code in ERRORS})
    print(f"ERROR replies seen, by request type and code ({sum(ERRORS.values())} in all):")
    for req in sorted({r for r, _ in ERRORS}):
        print(f"  {req:<16} " + ", ".join(f"{c} {ERRORS[(req, c)]}" for c in codes
                                          if (req, c) in ERRORS))
    import re
    source = " ".join(p.read_text() for p in (ROOT / "firmware" / "src").glob("*.c"))
    named = {n for n in re.findall(r"\bERR_([A-Z_]+)\b", source)} | {"BAD_FRAME"}
    never = sorted(c.name for c in ErrorCode if c.name in named and c.name not in codes)
    print("ERROR codes the firmware's sources name but never sent: " + (", ".join(never) or
                                                                       "none") +
          "; not named there (never sent): " + ", ".join(sorted(
              c.name for c in ErrorCode if c.name not in named and c.name != "BAD_CRC")))
    print(f"workload ({args.timing} poll timing): {len(list(VECTORS.glob('*.jsonl'))) - 2} "
          f"conformance sessions "
          f"({bad} mismatches), {stats.frames} differential frames ({stats.writes} writes, "
          f"{stats.restarts} power cycles), {wall:.0f} s")
    met = not below and not missed and not unhit
    print(f"target >= {TARGET:g} % branch outcomes in every function, every ERROR path: "
          + ("met" if met else f"NOT met: {len(below)} of {len(funcs)} functions below "
             f"{TARGET:g} %" + (f", {len(missed)} ERROR call sites not reached"
                                if missed else "")))
    for f in below[:12]:
        print(f"  {f.name}: uncovered {', '.join(f.uncovered[:8])}"
              + (" ..." if len(f.uncovered) > 8 else ""))
    if args.json is not None:
        args.json.write_text(json.dumps({
            "functions": [{"name": f.name, "branches": f.branches, "outcomes": f.outcomes,
                           "percent": f.percent, "uncovered": f.uncovered} for f in funcs],
            "total": [hit, total], "error_sites": {"ran": ran, "missed": missed},
            "errors": {f"{r} {c}": n for (r, c), n in sorted(ERRORS.items())},
            "stream": differential_fast.summary(stats)}, indent=1))
    return 0 if bad == 0 else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
