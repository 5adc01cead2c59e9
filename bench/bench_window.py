"""On-board decision window benchmark (issue 23): DECISION_WINDOW against SPIKE_BATCH, measured
vs the targets.

Usage: ``python bench/bench_window.py [--windows N] [--launches L] [--repeat R] [--no-firmware]
[--compare] [--sets K]`` (needs ``make firmware`` for the firmware rows).

1. **Fixed point vs float** (target: equal spike counts on >= 99.9 % of windows): N random
   decision windows (default 100,000: half with the astrocyte model's inhibition pattern)
   through the board's fixed point and the host's float64 LIF on the same reads
   (``tools/window_agreement.py``).
2. **Speed at 115200 baud** on the emulated board, both MCUs: one weight set trained (20
   cycles, seed 1) and programmed on a fresh default chip per (MCU, mode), then ``hw_noastro``
   and ``hw_astro`` x L launches (default 5) in ``batch`` and ``on_board`` mode, the same
   launches on the same chip state. Per decision: the bytes of the decision requests and their
   replies on the wire (host link counters), the board time without the UART (board clock minus
   the UART time of the launch's bytes), the time including the UART; hardware decisions/s at
   115200 baud against the board's own limit (target: >= 0.8 of it; batch today ~0.26), wire
   bytes per decision (target: <= 100; batch ~1.5 kB), and whether both modes took the same
   paths (same reads on the same chip).
3. **Firmware MCU** cost: hardware decisions per CPU-second of this process with ``--mcu
   firmware``, on-board against batch, best of R (target: on-board >= batch).
4. **Firmware RAM** from the ELF's sections (target: .data + .bss + .noinit + stack <= 16 KB;
   the linker script asserts it too).
5. ``--compare``: the full comparison (K sets x 10 launches x 4 scenarios, as ``snan-hil
   compare --port emu``) in each mode on a fresh chip: the medians per scenario and hw vs sw.

The machine is shared (2 cores): CPU figures are per CPU-second of this process, wall figures
come with the load average.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

AGREEMENT_TARGET = 0.999
RATE_TARGET = 0.8
BYTES_TARGET = 100.0
RAM_LIMIT = 16 * 1024
MODES = ("batch", "on_board")


def agreement(windows: int) -> list[tuple[str, object]]:
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.tools.window_agreement import agreement_sample
    hil = load_hil_config()
    out = []
    for astro in (False, True):
        t0 = time.perf_counter()
        a = agreement_sample(hil.launch_config(astro), windows // 2, seed=1 + astro,
                             inh_share=0.5 if astro else 0.0)
        out.append((f"{'astro' if astro else 'no astro'} ({time.perf_counter() - t0:.0f} s)",
                    a))
    return out


class ByteMeter:
    """Counts the link bytes of one client method's calls (request + reply on the wire)."""

    def __init__(self, client, method: str):
        self.client, self.bytes, self.calls = client, 0, 0
        inner = getattr(client, method)

        def wrapped(*a, **k):
            c0 = client.counters_dict()
            try:
                return inner(*a, **k)
            finally:
                c1 = client.counters_dict()
                self.bytes += (c1["bytes_in"] + c1["bytes_out"] - c0["bytes_in"]
                               - c0["bytes_out"])
                self.calls += 1
        setattr(client, method, wrapped)


def speed(mcu: str, launches: int, work: Path, repeat: int) -> dict[str, dict]:
    """Per mode: decisions, bytes per decision, board / UART ms per decision, CPU per
    decision (best of ``repeat``), paths."""
    from snan_hil.calibration.weights_io import load_weight_set
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.hil.runner import run_scenario
    from snan_hil.host.hil.testing import program_set
    from snan_hil.host.hil.train import save_weights, train_sets
    from snan_hil.tools.ports import open_client
    hil = load_hil_config()
    wpath = work / "weights.npz"
    if not wpath.exists():
        trained = train_sets(hil.train_config(), sets=1, cycles=hil.task.cycles, seed=1,
                             start=hil.task.start, goal=hil.task.goal)
        save_weights(trained, wpath)
    w, _ = load_weight_set(wpath, 0)
    out: dict[str, dict] = {}
    for mode in MODES:
        state = work / f"chip-{mcu}-{mode}.npz"
        state.unlink(missing_ok=True)
        client = open_client("emu", 115200, state_file=str(state), seed=0, mcu=mcu)
        try:
            layout = program_set(client, wpath, 0, work / f"layout-{mcu}-{mode}.json")
            meter = ByteMeter(client, "decision_window" if mode == "on_board" else "spike_batch")
            best_cpu, rec = float("inf"), {}
            for _ in range(max(1, repeat)):
                meter.bytes = meter.calls = 0
                c0 = time.process_time()
                res = [run_scenario(s, w, hil, launches=launches, seed=1, client=client,
                                    layout=layout, mode=mode, baud=115200)
                       for s in ("hw_noastro", "hw_astro")]
                cpu = time.process_time() - c0
                rows = [r for sr in res for r in sr.launches]
                d = sum(r.decisions for r in rows)
                best_cpu = min(best_cpu, cpu / d)
                rec = {"decisions": d, "bytes": meter.bytes / meter.calls,
                       "board_ms": sum(r.virtual_us - r.wire_us for r in rows) / d / 1e3,
                       "total_ms": sum(r.virtual_us for r in rows) / d / 1e3,
                       "paths": [r.path for r in rows], "spikes": sum(r.spikes for r in rows)}
            rec["cpu_ms"] = best_cpu * 1e3
            out[mode] = rec
        finally:
            client.close()
    return out


def firmware_ram() -> dict[str, int] | None:
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "firmware"))
    from build import section_sizes  # firmware/build.py
    elf = Path(__file__).resolve().parent.parent / "build" / "firmware" / "snan-fw.elf"
    if not elf.is_file():
        return None
    s = section_sizes(elf)
    s["ram"] = s["data"] + s["bss"] + s["noinit"] + s["stack"]
    return s


def compare_medians(sets: int, work: Path) -> dict[str, dict]:
    from snan_hil.host.hil.compare import CompareJob, CompareRequest
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.hil.train import save_weights, train_sets
    from snan_hil.lab.opener import plan_board
    from snan_hil.lab.ports import BoardAddress
    from snan_hil.lab.runner import RunOptions, run_job
    hil = load_hil_config()
    wpath = work / f"weights-{sets}.npz"
    if not wpath.exists():
        trained = train_sets(hil.train_config(), sets=sets, cycles=hil.task.cycles, seed=1,
                             start=hil.task.start, goal=hil.task.goal)
        save_weights(trained, wpath)
    out = {}
    for mode in MODES:
        state = work / f"cmp-{mode}.npz"
        state.unlink(missing_ok=True)
        t0 = time.perf_counter()
        request = CompareRequest(str(wpath), hil, launches=10, seed=1, mode=mode,
                                 report_dir=work / f"prog-{mode}")
        board = plan_board(BoardAddress("emu", baud=115200, state_file=str(state), seed=0))
        res = run_job(CompareJob(request), board, RunOptions(record="off")).result
        out[mode] = {"wall_s": time.perf_counter() - t0, "scenarios": res["scenarios"],
                     "acceptance": res.get("acceptance", {})}
    return out


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--windows", type=int, default=100_000)
    ap.add_argument("--launches", type=int, default=5)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--no-firmware", action="store_true", help="skip the --mcu firmware rows")
    ap.add_argument("--compare", action="store_true", help="also the full comparison per mode")
    ap.add_argument("--sets", type=int, default=10)
    args = ap.parse_args(argv)
    tmp = tempfile.TemporaryDirectory(prefix="bench_window_")
    work = Path(tmp.name)
    os.environ["SNAN_HIL_EMU_STATE"] = str(work / "chip.npz")   # never the user's chip
    verdicts = []

    print(f"1. fixed point vs float64 LIF on the same reads ({args.windows:,} random windows)")
    total = mism = 0
    for label, a in agreement(args.windows):
        total += a.windows
        mism += a.count_mismatch
        print(f"   {label:<22} {a.windows:7,} windows, {a.lanes:7,} lanes, {a.motor_spikes:8,} "
              f"motor spikes: counts differ in {a.count_mismatch}, spike steps in "
              f"{a.time_mismatch} windows")
    rate = 1 - mism / total
    ok = rate >= AGREEMENT_TARGET
    verdicts.append(ok)
    print(f"   equal counts on {rate:.5%} of windows; target >= {AGREEMENT_TARGET:.1%}: "
          f"{'met' if ok else 'NOT MET'}")

    mcus = ["model"] + ([] if args.no_firmware else ["firmware"])
    print(f"2. speed at 115200 baud, hw_noastro + hw_astro x {args.launches} launches, 1 weight "
          "set (best CPU of "
          f"{args.repeat}; load {os.getloadavg()[0]:.1f})")
    print(f"   {'mcu':<9}{'mode':<10}{'dec':>5}{'B/dec':>8}{'board ms':>10}{'+UART ms':>10}"
          f"{'dec/s':>8}{'limit/s':>9}{'ratio':>7}{'CPU ms/dec':>12}")
    speeds = {}
    for mcu in mcus:
        speeds[mcu] = sp = speed(mcu, args.launches, work, args.repeat)
        for mode, r in sp.items():
            ratio = r["board_ms"] / r["total_ms"]
            print(f"   {mcu:<9}{mode:<10}{r['decisions']:5d}{r['bytes']:8.1f}{r['board_ms']:10.1f}"
                  f"{r['total_ms']:10.1f}{1e3 / r['total_ms']:8.2f}{1e3 / r['board_ms']:9.2f}"
                  f"{ratio:7.2f}{r['cpu_ms']:12.2f}")
        same = sp["batch"]["paths"] == sp["on_board"]["paths"]
        print(f"   {mcu}: on-board and batch took {'the same' if same else 'DIFFERENT'} paths "
              f"({len(sp['batch']['paths'])} launches, {sp['on_board']['spikes']} input spikes)")
        ob = sp["on_board"]
        ok_rate = ob["board_ms"] / ob["total_ms"] >= RATE_TARGET
        ok_bytes = ob["bytes"] <= BYTES_TARGET
        verdicts += [ok_rate, ok_bytes]
        print(f"   {mcu}: decisions/s at 115200 = {ob['board_ms'] / ob['total_ms']:.2f} of the "
              f"board's own limit (target >= {RATE_TARGET}; batch "
              f"{sp['batch']['board_ms'] / sp['batch']['total_ms']:.2f}): "
              f"{'met' if ok_rate else 'NOT MET'}; {ob['bytes']:.1f} wire bytes per decision "
              f"(target <= {BYTES_TARGET:.0f}; batch {sp['batch']['bytes']:.0f}): "
              f"{'met' if ok_bytes else 'NOT MET'}")
    if "firmware" in speeds:
        fw = speeds["firmware"]
        x = fw["batch"]["cpu_ms"] / fw["on_board"]["cpu_ms"]
        ok = x >= 1.0
        verdicts.append(ok)
        print(f"3. firmware MCU: {1e3 / fw['on_board']['cpu_ms']:.1f} on-board vs "
              f"{1e3 / fw['batch']['cpu_ms']:.1f} batch decisions per CPU-second ({x:.2f}x; "
              f"target >= 1): {'met' if ok else 'NOT MET'}")
    ram = firmware_ram()
    if ram is None:
        print("4. firmware RAM: no ELF (make firmware)")
    else:
        ok = ram["ram"] <= RAM_LIMIT
        verdicts.append(ok)
        print(f"4. firmware RAM {ram['ram']} of {RAM_LIMIT} B (.data {ram['data']}, .bss "
              f"{ram['bss']}, .noinit {ram['noinit']}, stack {ram['stack']}; flash {ram['text']} "
              f"B): {'met' if ok else 'NOT MET'}")
    if args.compare:
        print(f"5. compare, {args.sets} sets x 10 launches x 4 scenarios, per mode "
              "(median of successful launches [95 % CI] / of all launches, success)")
        for mode, r in compare_medians(args.sets, work).items():
            sc = r["scenarios"]
            parts = []
            for name in ("sw_noastro", "sw_astro", "hw_noastro", "hw_astro"):
                s = sc[name]
                ci = s.get("median_steps_ci") or [None, None]
                parts.append(f"{name} {s['median_steps']:g} [{ci[0]}, {ci[1]}] / "
                             f"{s.get('median_steps_all')} {s['success_rate']:.0%}")
            rel = [(sc[f"hw_{a}"]["median_steps"] - sc[f"sw_{a}"]["median_steps"])
                   / sc[f"sw_{a}"]["median_steps"] for a in ("noastro", "astro")]
            print(f"   {mode:<9} ({r['wall_s']:.0f} s): " + "; ".join(parts)
                  + f"; hw vs sw {rel[0]:+.0%}, {rel[1]:+.0%}")
    print("all targets met" if all(verdicts) else "SOME TARGETS NOT MET")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
