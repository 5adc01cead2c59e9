"""The firmware verification tools: the branch decoder and coverage hook (isa_coverage), the
seeded differential tester (differential_fast) and the mutant generator (firmware/mutate.py)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from snan_hil.firmware_emu.fw_image import FirmwareImage, default_elf_path

ROOT = Path(__file__).resolve().parents[2]
needs_elf = pytest.mark.skipif(not default_elf_path().is_file(),
                               reason="firmware ELF not built ('make firmware')")


def _mutate():
    spec = importlib.util.spec_from_file_location("_t_mutate", ROOT / "firmware" / "mutate.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["_t_mutate"] = mod
    spec.loader.exec_module(mod)
    return mod


@needs_elf
def test_decoded_branches_land_on_instructions_in_their_code():
    from snan_hil.firmware_emu.isa_coverage import decode
    image = FirmwareImage.load()
    branches, ends, calls = decode(image)
    base, text = image.text
    starts = set(ends.values()) | {base}
    assert len(branches) > 300 and calls
    for b in branches.values():
        assert b.target in starts and b.fall in starts | {base + len(text)}, hex(b.addr)


@needs_elf
def test_coverage_sees_both_outcomes_of_the_frame_checks(mcu):
    if mcu != "firmware":
        pytest.skip("coverage is of the C firmware")
    from snan_hil.firmware_emu.emulator import Emulator
    from snan_hil.firmware_emu.isa_coverage import BranchCoverage
    from snan_hil.firmware_emu.testing import default_array
    from snan_hil.protocol.conformance import load_session, run_session
    cov = BranchCoverage(FirmwareImage.load())
    session = load_session(ROOT / "conformance" / "v1" / "framed" / "cobs.jsonl")
    b = session.board
    emu = Emulator(None, b.chip_seed, array=default_array(b.chip_seed), mcu="firmware",
                   boot_nonces=b.boot_nonces)
    try:
        cov.attach(emu.backend.mcu)
        assert run_session(session, emu.feed) == []
    finally:
        emu.close()
    hit, total = cov.total()
    assert 0 < hit < total
    rx = next(f for f in cov.functions() if f.name == "proto_rx_byte")
    assert rx.outcomes > 0.3 * 2 * rx.branches
    ran, _ = cov.error_sites()
    assert ran                                  # the damaged frames were NAKed


def test_the_seeded_tester_agrees_on_both_mcus_and_catches_a_difference(mcu):
    if mcu != "firmware":
        pytest.skip("needs the firmware MCU")
    from snan_hil.firmware_emu import differential_fast as fast
    from snan_hil.firmware_emu.twin import Divergence
    stats = fast.run_stream(5, 400)
    assert stats.frames >= 400 and len(stats.kinds) >= 8
    twin = fast.FastTwin(1, (1, 2, 3))
    stream = fast.RequestStream(1)
    try:
        stream.learn(twin.send(stream.hello(), "HELLO"))
        state = twin.arrays["model"].state
        state[:] = np.asarray(state) * 0.5         # the model's chip drifts
        with pytest.raises(Divergence):
            for _ in range(50):
                data, kind = stream.next()
                stream.learn(twin.send(data, kind))
    finally:
        twin.close()


def test_every_error_path_of_the_sources_is_known_by_its_text():
    from snan_hil.firmware_emu.isa_coverage import error_lines
    paths = error_lines(ROOT / "firmware" / "src")
    assert len(paths) >= 40
    assert all(texts for _, _, texts in paths)
    assert {f for f, _, _ in paths} == {"ops.c", "proto.c", "window.c"}


def test_mutants_are_one_line_faults_of_four_kinds():
    mutate = _mutate()
    header = ROOT / "build" / "firmware" / "snan_constants.h"
    candidates = mutate.mutants(header=header if header.is_file() else None)
    chosen = mutate.pick(candidates, 16, 1)
    assert len(chosen) >= 60
    assert {m.kind for m in chosen} == set(mutate.KINDS)
    assert len({m.file for m in chosen}) >= 4
    assert chosen == mutate.pick(candidates, 16, 1)          # seeded
    for m in chosen[:20]:
        before = (ROOT / "firmware" / "src" / m.file).read_text().split("\n")
        after = mutate.apply(m).split("\n")
        assert len(before) == len(after)
        assert [i for i, (a, b) in enumerate(zip(before, after)) if a != b] == [m.line - 1]
