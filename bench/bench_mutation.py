"""Mutation testing of the C firmware: do the conformance vectors and the differential tester
catch seeded faults? (issue 37.4)

Usage: ``python bench/bench_mutation.py [--per-kind N] [--seed S] [--frames K] [--json FILE]
[--only FILE:LINE,...]``

Takes ``--per-kind`` faults of each of four kinds from the firmware sources as they are now
(``firmware/mutate.py``: off-by-one, wrong register bit, dropped check, swapped operands),
builds each mutant (the mutated file compiled with the build's flags, linked with the other
objects of ``build/firmware``: run ``make firmware`` first) and runs it on the instruction-level
MCU against

1. every framed conformance session (``conformance/v1/framed``), then
2. the seeded differential tester (``firmware_emu/differential_fast.py``, ``--frames`` frames
   in all over five streams, one per chip serial kind: every write compared with the Python
   model - replies, the chip serial INFO names, SPI traffic, chip), then
3. every identity record of ``chip_identity.record_corpus`` (INFO names the serial of a valid
   one only), the corner requests (``firmware_emu/corner_cases.py``: a paced batch past the timer's
   wrap, column readings climbing to full scale, PROGRAM_CELL to the code just read), then
4. the sequence vectors (``sequences.jsonl``: restarts, kills with a journal replay).

A mutant is **killed** when a vector's reply differs, the firmware does not boot, faults or
resets, or the two MCUs diverge; **stillborn** when it does not compile (``-Werror``), not
counted. Prints each mutant's fate, the score (killed / compiled) and the survivors.

Target: >= 50 compiled mutants, >= 90 % killed.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FW = ROOT / "firmware"
OUT = ROOT / "build" / "firmware"
VECTORS = ROOT / "conformance" / "v1" / "framed"


def _module(name: str, path: Path):  # noqa: ANN202 - a module
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def build_mutant(build, mutate, mutant, tmp: Path) -> tuple[Path | None, str]:  # noqa: ANN001
    """(ELF, "") or (None, the compiler's first error line)."""
    src = tmp / mutant.file
    src.write_text(mutate.apply(mutant))
    obj = tmp / (Path(mutant.file).stem + ".o")
    cc = build.ZIG_CC
    proc = subprocess.run(cc + build.CFLAGS + ["-I", str(OUT), "-I", str(FW / "src"), "-c",
                                              str(src), "-o", str(obj)],
                          capture_output=True, text=True)
    if proc.returncode:
        err = next((ln for ln in proc.stderr.splitlines() if "error" in ln), proc.stderr[:200])
        return None, err.strip()
    objs = [str(obj) if Path(s).stem == obj.stem else str(OUT / (Path(s).stem + ".o"))
            for s in build.SOURCES]
    elf = tmp / "snan-fw.elf"
    proc = subprocess.run(cc + build.CFLAGS + ["-T", str(FW / "link.ld"), "-Wl,--gc-sections",
                                              "-o", str(elf)] + objs,
                          capture_output=True, text=True)
    if proc.returncode:
        return None, (proc.stderr.strip().splitlines() or ["link failed"])[-1]
    return elf, ""


def _records(image) -> str:  # noqa: ANN001 - a FirmwareImage
    """Each identity record of ``chip_identity.record_corpus`` on the EEPROM, a reboot, a
    HELLO: "" if INFO names each record's serial (none for an invalid one)."""
    from snan_hil.firmware_emu import chip_identity
    from snan_hil.firmware_emu.config import BoardConfig
    from snan_hil.firmware_emu.differential import raw_frame, wire
    from snan_hil.firmware_emu.emulator import Emulator
    from snan_hil.protocol import messages as m
    from snan_hil.protocol.conformance import frames_of
    from snan_hil.protocol.frames import Frame
    emu = Emulator(None, 3, mcu="firmware", elf=image)
    try:
        assert emu.backend is not None
        mcu = emu.backend.mcu
        for what, record, serial in chip_identity.record_corpus():
            mcu.write_identity_record(record)
            mcu.press_reset()
            out = emu.feed(b"\x00" + wire(raw_frame(m.Hello.TYPE, 1, m.Hello().encode(), 0)))
            ids = [f.message().board_id for f in frames_of(out)
                   if isinstance(f, Frame) and f.type == m.Info.TYPE]
            if ids != [chip_identity.firmware_board_id_text(BoardConfig().board_id, serial)]:
                return f"records: {what}: INFO {ids}"
    finally:
        emu.close()
    return ""


def judge(elf: Path, frames: int, seed: int) -> str:
    """Why the mutant is killed ("" if it survives)."""
    from snan_hil.common.errors import UserError
    from snan_hil.firmware_emu import corner_cases, differential_fast
    from snan_hil.firmware_emu.emulator import Emulator
    from snan_hil.firmware_emu.fw_image import FirmwareImage
    from snan_hil.firmware_emu.testing import default_array
    from snan_hil.firmware_emu.twin import EmulatedBoard
    from snan_hil.protocol.conformance import (load_sequences, load_session, run_sequence,
                                               run_session)
    try:
        image = FirmwareImage.load(elf)
        for path in sorted(p for p in VECTORS.glob("*.jsonl")
                           if p.stem not in ("replies", "sequences")):
            session = load_session(path)
            b = session.board
            emu = Emulator(None, b.chip_seed, array=default_array(b.chip_seed),
                           mcu="firmware", baud=b.baud, boot_nonces=b.boot_nonces, elf=image)
            try:
                problems = run_session(session, emu.feed)
                mcu = emu.backend.mcu if emu.backend is not None else None
                if problems:
                    return f"conformance: {problems[0][:120]}"
                if mcu is not None and (mcu.faults or mcu.resets):
                    return f"conformance: MCU fault/reset in {session.name}"
            finally:
                emu.close()
        for k in range(len(differential_fast.SERIALS)):       # each serial kind once
            differential_fast.run_stream(seed * 8 + k, max(1, frames // 5), elf=image)
        why = _records(image)
        if why:
            return why
        twin = differential_fast.FastTwin(1, (11, 12, 13), elf=image)
        try:                                                  # the timer wrap, full scale
            corner_cases.run(twin, differential_fast.RequestStream(seed),
                             corner_cases.timer_half() + corner_cases.timer_wrap() +
                             corner_cases.saturation())
            corner_cases.program_at_reading(twin, differential_fast.RequestStream(seed))
        finally:
            twin.close()
        with tempfile.TemporaryDirectory(prefix="snan-mutant-seq-") as tmp:
            for k, sequence in enumerate(load_sequences(VECTORS / "sequences.jsonl")):
                sb = sequence.board
                board = EmulatedBoard(Path(tmp) / str(k), "firmware", chip_seed=sb.chip_seed,
                                      serial=sb.chip_serial, boot_nonces=sb.boot_nonces,
                                      baud=sb.baud, trace=False)
                try:
                    problems = run_sequence(sequence, board)
                    if problems or board.mcu_faults:
                        return f"sequences: {(problems or [str(board.mcu_faults)])[0][:120]}"
                finally:
                    board.close()
    except UserError as exc:
        return f"refused: {str(exc)[:120]}"
    except AssertionError as exc:
        return f"differential: {str(exc).splitlines()[0][:120]}"
    except Exception as exc:                      # noqa: BLE001 - any crash kills the mutant
        return f"crash: {type(exc).__name__}: {str(exc)[:100]}"
    return ""


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-kind", type=int, default=16, help="mutants of each kind")
    ap.add_argument("--seed", type=int, default=1, help="seed of the choice of mutants")
    ap.add_argument("--frames", type=int, default=2000,
                    help="compared frames of the differential tester per mutant")
    ap.add_argument("--json", type=Path, default=None, help="write every mutant's fate")
    ap.add_argument("--only", default="",
                    help="comma-separated FILE:LINE: only the chosen mutants at those lines")
    args = ap.parse_args(argv)
    if not (OUT / "snan-fw.elf").is_file():
        print("bench_mutation: build the firmware first (make firmware)", file=sys.stderr)
        return 2
    build = _module("_snan_fw_build", FW / "build.py")
    mutate = _module("_snan_fw_mutate", FW / "mutate.py")
    chosen = mutate.pick(mutate.mutants(header=OUT / "snan_constants.h"), args.per_kind,
                         args.seed)
    if args.only:
        where = {w.strip() for w in args.only.split(",") if w.strip()}
        chosen = [mu for mu in chosen if f"{mu.file}:{mu.line}" in where]
    rows = []
    t0 = time.perf_counter()
    import os

    from snan_hil.firmware_emu.fw_image import ELF_ENV
    for k, mutant in enumerate(chosen, 1):
        with tempfile.TemporaryDirectory(prefix="snan-mutant-") as tmp:
            elf, err = build_mutant(build, mutate, mutant, Path(tmp))
            fate = "stillborn" if elf is None else "killed"
            if elf is not None:
                os.environ[ELF_ENV] = str(elf)        # the boards the vectors open
            try:
                why = err if elf is None else judge(elf, args.frames, args.seed + k)
            finally:
                os.environ.pop(ELF_ENV, None)
            if elf is not None and not why:
                fate = "SURVIVED"
        rows.append({"mutant": mutant.name, "kind": mutant.kind, "after": mutant.after.strip(),
                     "fate": fate, "why": why})
        print(f"{k:>3} {fate:<9} {mutant.name:<34} {mutant.after.strip()[:60]:<60} "
              f"{why[:90]}", flush=True)
    compiled = [r for r in rows if r["fate"] != "stillborn"]
    killed = [r for r in compiled if r["fate"] == "killed"]
    score = 100.0 * len(killed) / len(compiled) if compiled else 0.0
    print(f"mutants: {len(rows)} chosen, {len(rows) - len(compiled)} stillborn (do not "
          f"compile), {len(compiled)} compiled, {len(killed)} killed: score {score:.1f} % "
          f"({time.perf_counter() - t0:.0f} s)")
    for kind in mutate.KINDS:
        ks = [r for r in compiled if r["kind"] == kind]
        print(f"  {kind:<17} {sum(r['fate'] == 'killed' for r in ks)}/{len(ks)} killed")
    survivors = [r for r in compiled if r["fate"] == "SURVIVED"]
    for r in survivors:
        print(f"  survivor: {r['mutant']}: {r['after']}")
    met = len(compiled) >= 50 and score >= 90.0
    print(f"target >= 50 compiled mutants, >= 90 % killed: {'met' if met else 'NOT met'}")
    if args.json is not None:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
