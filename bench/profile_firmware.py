"""Where the C firmware spends its instructions during HIL decisions: per function (ELF symbols)
and, with ``llvm-objdump`` on the PATH, per source line — counted by the ISA-level MCU.

Usage: ``python bench/profile_firmware.py [--mode on_board|batch] [--launches L] [--top N]``
(needs ``make firmware``). One weight set is trained (20 cycles, seed 1) and programmed on a
fresh default chip, then ``hw_noastro`` and ``hw_astro`` x L launches run with ``--mcu
firmware`` at 115200 baud; a block hook counts every executed block (the translation cache is
flushed when it is added, so no block escapes it). Figures are per hardware decision: MCU
instructions (= cycles at one instruction a cycle, the collapsed poll loops included) and
blocks (what the emulator pays a hook call for). A profiling aid, not a target: the hook makes
the run several times slower.
"""

from __future__ import annotations

import argparse
import bisect
import collections
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path


def line_table(elf: Path) -> dict[int, str]:
    """Instruction address -> ``file:line`` from ``llvm-objdump -d -l`` ({} without it)."""
    tool = shutil.which("llvm-objdump")
    if tool is None:
        return {}
    dis = subprocess.run([tool, "-d", "-l", "--no-show-raw-insn", str(elf)],
                         capture_output=True, text=True, check=True).stdout
    out: dict[int, str] = {}
    cur = "?"
    for text in dis.splitlines():
        m = re.match(r"^; (/\S+):(\d+)", text)
        if m:
            cur = f"{os.path.basename(m.group(1))}:{m.group(2)}"
            continue
        m = re.match(r"^\s*([0-9a-f]{8}):", text)
        if m:
            out[int(m.group(1), 16)] = cur
    return out


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mode", default="on_board", choices=("on_board", "batch"))
    ap.add_argument("--launches", type=int, default=1)
    ap.add_argument("--top", type=int, default=25)
    args = ap.parse_args(argv)
    import unicorn

    from snan_hil.calibration.weights_io import load_weight_set
    from snan_hil.firmware_emu.emulator import Emulator
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.hil.runner import run_scenario
    from snan_hil.host.hil.testing import program_set
    from snan_hil.host.hil.train import save_weights, train_sets
    from snan_hil.protocol.link import LinkClient
    from snan_hil.protocol.transport import CallbackTransport

    tmp = tempfile.TemporaryDirectory(prefix="profile_firmware_")
    work = Path(tmp.name)
    os.environ["SNAN_HIL_EMU_STATE"] = str(work / "chip.npz")   # never the user's chip
    hil = load_hil_config()
    wpath = work / "weights.npz"
    save_weights(train_sets(hil.train_config(), sets=1, cycles=hil.task.cycles, seed=1,
                            start=hil.task.start, goal=hil.task.goal), wpath)
    w, _ = load_weight_set(wpath, 0)
    emu = Emulator(None, 0, mcu="firmware")
    client = LinkClient(CallbackTransport(emu.feed, name="profile"))
    client.hello()
    layout = program_set(client, wpath, 0, work / "layout.json")
    mcu = emu.backend.mcu
    img = mcu.image
    funcs = sorted((a, n) for n, (a, s) in img.symbols.items() if s > 0 and a >= 0x8000_0000)
    addrs = [a for a, _ in funcs]
    base, _ = img.text
    starts = list(mcu.core._istart)      # instruction index per half-word of .text
    blocks: collections.Counter[tuple[int, int]] = collections.Counter()

    def hook(_uc, addr, size, _data):
        blocks[(addr, size)] += 1

    mcu.cpu.hook_add(unicorn.UC_HOOK_BLOCK, hook)
    mcu.cpu.ctl_flush_tb()
    i0 = mcu.instructions
    res = [run_scenario(s, w, hil, launches=args.launches, seed=1, client=client, layout=layout,
                        mode=args.mode, baud=115200) for s in ("hw_noastro", "hw_astro")]
    d = sum(r.decisions for sr in res for r in sr.launches)
    total = (mcu.instructions - i0) / d
    ins: collections.Counter[str] = collections.Counter()
    blk: collections.Counter[str] = collections.Counter()
    lines = line_table(img.path)
    per_line: collections.Counter[str] = collections.Counter()
    for (addr, size), c in blocks.items():
        name = funcs[bisect.bisect_right(addrs, addr) - 1][1]
        o = addr - base
        ins[name] += c * (starts[(o + size) // 2] - starts[o // 2])
        blk[name] += c
        a = addr
        while lines and a < addr + size:
            per_line[lines.get(a, "?")] += c
            a += 4 if (mcu.cpu.mem_read(a, 1)[0] & 3) == 3 else 2
    print(f"{args.mode}: {d} decisions, {total:,.0f} MCU instructions and "
          f"{sum(blk.values()) / d:,.0f} blocks per decision (counted: "
          f"{sum(ins.values()) / d:,.0f})")
    print(f"  {'function':<28}{'instr/dec':>11}{'blocks/dec':>12}")
    for name, v in ins.most_common(args.top):
        print(f"  {name:<28}{v / d:11,.0f}{blk[name] / d:12,.0f}")
    if not lines:
        print("  (per source line: needs llvm-objdump on the PATH)")
    else:
        print(f"  {'source line':<28}{'instr/dec':>11}")
        for name, v in per_line.most_common(args.top):
            print(f"  {name:<28}{v / d:11,.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
