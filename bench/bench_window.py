"""On-board decision window benchmark (issues 23 and 33): the board's physical ceiling, the read
plan the decisions need, and how close the emulated board comes, measured vs the targets.

Usage: ``python bench/bench_window.py [--windows N] [--launches L] [--budget-sets K]
[--no-budget] [--medians] [--no-firmware] [--compare] [--sets K]`` (needs ``make firmware`` for
the firmware rows).

1. **Fixed point vs float** (target: equal spike counts on >= 99.9 % of windows): N random
   decision windows (default 100,000: half with the astrocyte model's inhibition pattern)
   through the board's fixed point and the host's float64 LIF on the same reads
   (``tools/window_agreement.py``).
2. **The read-noise budget** (target: the fewest conversions a read whose decisions stay
   >= 99 % identical to the standard ten-average reads): one weight set a chip (K sets, default
   10, trained with seed 1 and programmed on fresh default chips), ``hw_noastro`` and
   ``hw_astro`` x 10 launches (seed 1) with the standard read plan; every window also goes to
   copies of the chip read with the lean plan at N = 1..5 conversions, and to one read with the
   standard plan and another noise realisation (the floor: how often two ten-average reads
   disagree); per N the share of identical decisions (the host's rule on either board's
   counts, the same tie-break draw) with its Wilson 95 % interval. ``--medians``: also the
   route medians of full runs with each N against the standard run's intervals.
3. **The ceiling and the board time**, both MCUs: one weight set (20 cycles, seed 1) on a fresh
   default chip, ``hw_noastro`` + ``hw_astro`` x L launches (default 5) at 115200 baud, one
   launch after another; what a decision did (input spikes, reads, column selects, row-DAC
   words, the MCU's time: the firmware's executed instructions at 32 MHz, the Python MCU's
   modelled time; wire bytes each way) from the board's own counters, the ceiling from the
   datasheet figures (``host/hil/ceiling.py``: ADC 200 kS/s, DAC and front end settling 6 us,
   SPI 15 MHz, MCU 32 MHz, UART 115200 8N1) beside the measured board time (target: the
   ceiling's time >= 0.8 of the board time), and which part bounds it.
4. **Speed at 115200 baud**, both MCUs, the same launches: the standard plan one launch after
   another (as before issue 33), the lean plan one launch after another, and the lean plan with
   launches interleaved (two requests outstanding): decisions/s of board clock including the
   UART (target >= 40, stretch >= 55, the interleaved lean plan), wire bytes per decision,
   array energy per decision from CLOCK (target <= 1 uJ; the C firmware reports none), CPU
   per decision; the decisions interleaved equal those one after another.
5. **The two MCUs**: every conformance vector on both, and a short differential run (target:
   bit-identical).
6. **Firmware RAM** from the ELF's sections (target: .data + .bss + .noinit + stack <= 16 KB;
   the linker script asserts it too) and what is left.
7. ``--compare``: the full comparison (K sets x 10 launches x 4 scenarios, as ``snan-hil
   compare --port emu``) with the standard and the lean plan on a fresh chip each: medians per
   scenario and hw vs sw.

The machine is shared (2 cores): CPU figures are per CPU-second of this process; board times
are virtual (the emulator's clock), unaffected by the load.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

AGREEMENT_TARGET = 0.999
BUDGET_TARGET = 0.99
CEILING_TARGET = 0.8
RATE_TARGET, RATE_STRETCH = 40.0, 55.0
ENERGY_TARGET_J = 1e-6
RAM_LIMIT = 16 * 1024
BAUD = 115200
BUDGET_NS = (1, 2, 3, 4, 5)


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


def wilson(k: int, n: int) -> tuple[float, float]:
    """Wilson 95 % interval of k successes in n."""
    if not n:
        return 0.0, 1.0
    z, p = 1.959964, k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return c - h, c + h


def _weights(work: Path, sets: int) -> Path:
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.hil.train import save_weights, train_sets
    hil = load_hil_config()
    wpath = work / f"weights-{sets}.npz"
    if not wpath.exists():
        save_weights(train_sets(hil.train_config(), sets=sets, cycles=hil.task.cycles, seed=1,
                                start=hil.task.start, goal=hil.task.goal), wpath)
    return wpath


def _programmed(work: Path, wpath: Path, k: int, tag: str, mcu: str = "model"):
    """A fresh default chip (seed 0) with set k programmed: (state file, layout)."""
    from snan_hil.host.hil.testing import program_set
    from snan_hil.tools.ports import open_client
    state = work / f"chip-{tag}.npz"
    for f in work.glob(f"chip-{tag}.*"):
        f.unlink()
    client = open_client("emu", BAUD, state_file=str(state), seed=0, mcu=mcu)
    try:
        layout = program_set(client, wpath, k, work / f"chip-{tag}.layout.json")
    finally:
        client.close()
    return state, layout


def _copy(state: Path, tag: str) -> Path:
    dst = state.with_name(f"{state.stem}-{tag}.npz")
    shutil.copy(state, dst)
    return dst


def budget(work: Path, sets: int, launches: int) -> dict:
    """Part 2: per N (and "floor") [windows, identical decisions]."""
    import numpy as np

    from snan_hil.calibration.weights_io import load_weight_set
    from snan_hil.firmware_emu import window_noise
    from snan_hil.firmware_emu.inprocess import emulator_of
    from snan_hil.host import snan_kernel as K
    from snan_hil.host.agent import WindowTrial, environment, synapse_tables, trial_setup
    from snan_hil.host.hil.board_window import OnBoardMotorNeurons
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.hil.runner import TRIAL_STRIDE
    from snan_hil.tools.ports import open_client
    hil = load_hil_config()
    wpath = _weights(work, sets)
    tally: dict = {}
    for k in range(sets):
        w, _ = load_weight_set(wpath, k)
        state, layout = _programmed(work, wpath, k, f"budget{k}")
        clients = {}
        for tag in ("base", "floor", *BUDGET_NS):
            clients[tag] = open_client("emu", BAUD, state_file=str(_copy(state, str(tag))),
                                       seed=0)
        window_noise.other_realisation(emulator_of(clients["floor"].transport).board, 1)
        try:
            for scenario in ("hw_noastro", "hw_astro"):
                cfg = hil.launch_config(scenario == "hw_astro")
                env = environment(cfg)
                nbr, _ = synapse_tables(env, cfg)
                boards = {tag: OnBoardMotorNeurons(c, layout, nbr, cfg,
                                                   conversions=tag if isinstance(tag, int)
                                                   else 0)
                          for tag, c in clients.items()}
                tied = np.zeros(4, dtype=np.int64)
                for launch in range(launches):
                    nbr_, move, s0, goals, key = trial_setup(
                        env, cfg, hil.task.start, hil.task.goal, seed=1,
                        trial=k * TRIAL_STRIDE + launch)
                    run = WindowTrial(cfg, nbr_, move, s0, goals, key, boards["base"])
                    while not run.done:
                        window = run.open()
                        counts, spikes = boards["base"].motor_window(*window)
                        n = len(window.dirs)
                        ts = run.ts
                        _, z = K.splitmix_next(np.uint64(ts.key[0]))
                        z = np.uint64(z)

                        def choice(c, n=n, z=z, stay=run.p.no_spike_stay, tied=tied):
                            full = np.zeros(4, dtype=np.int64)
                            full[:n] = c
                            return K.choose_lane(full, n, z, stay, tied)
                        mine = choice(counts)
                        for tag, b in boards.items():
                            if tag == "base":
                                continue
                            other, _ = b.motor_window(*window)
                            t = tally.setdefault(tag, [0, 0])
                            t[0] += 1
                            t[1] += int(choice(other) == mine)
                        run.close(counts, spikes)
                        assert int(ts.iv[K.IV_CHOSEN]) == mine
        finally:
            for c in clients.values():
                c.close()
        del w
    return tally


def budget_medians(work: Path, sets: int, launches: int) -> dict:
    """``--medians``: per read plan the pooled hw medians [95 % CI] of full runs."""
    import numpy as np

    from snan_hil.calibration.weights_io import load_weight_set
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.hil.runner import run_scenario
    from snan_hil.host.intervals import interval_fields
    from snan_hil.tools.ports import open_client
    hil = load_hil_config()
    wpath = _weights(work, sets)
    out: dict = {}
    for k in range(sets):
        w, _ = load_weight_set(wpath, k)
        state, layout = _programmed(work, wpath, k, f"med{k}")
        for conv in (0, *BUDGET_NS[:3]):
            client = open_client("emu", BAUD, state_file=str(_copy(state, f"c{conv}")), seed=0)
            try:
                for s in ("hw_noastro", "hw_astro"):
                    r = run_scenario(s, w, hil, launches=launches, seed=1, client=client,
                                     layout=layout, mode="on_board", conversions=conv,
                                     interleave=False)
                    rows = out.setdefault((conv, s), [[], []])
                    rows[0] += r.path_lengths
                    rows[1] += [x.success for x in r.launches]
            finally:
                client.close()
    res = {}
    for key, (steps, ok) in out.items():
        won = [s for s, good in zip(steps, ok) if good]
        res[key] = {**interval_fields(steps, ok, seed=1),
                    "median_steps": float(np.median(won)) if won else None,
                    "success_rate": sum(ok) / len(ok)}
    return res


class _Meter:
    """The board's counters over a run: frames per chip, MCU time, link bytes."""

    def __init__(self, client, emu):
        self.client, self.emu = client, emu
        self.start = self._now()

    def _now(self) -> dict:
        bus = self.emu.board.bus
        out = {f"dev_{k}": d.frames for k, d in bus.devices.items()}
        c = self.client.counters_dict()
        out["out"], out["in"] = c["bytes_out"], c["bytes_in"]
        if self.emu.backend is not None:
            out["mcu_us"] = self.emu.backend.mcu.instructions / 32.0
        else:
            out["mcu_us"] = self.emu.clock.breakdown_us.get("mcu", 0.0)
        out["energy"] = self.emu.clock.energy_j
        return out

    def delta(self) -> dict:
        now = self._now()
        return {k: now[k] - self.start[k] for k in now}


def speed(mcu: str, launches: int, work: Path, wpath: Path) -> dict:
    """Parts 3 and 4 on one MCU: per plan (standard, lean, lean interleaved) the run's figures."""
    from snan_hil.calibration.weights_io import load_weight_set
    from snan_hil.firmware_emu.inprocess import emulator_of
    from snan_hil.host.hil.board_window import read_plan
    from snan_hil.host.hil.ceiling import WindowCounts, ceiling
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.hil.runner import run_scenario
    from snan_hil.tools.ports import open_client
    hil = load_hil_config()
    w, _ = load_weight_set(wpath, 0)
    state, layout = _programmed(work, wpath, 0, f"speed-{mcu}", mcu)
    out: dict = {}
    for plan, conv, inter in (("standard", 0, False), ("lean", None, False),
                              ("lean interleaved", None, True)):
        client = open_client("emu", BAUD, state_file=str(_copy(state, plan.replace(" ", "-"))),
                             seed=0, mcu=mcu)
        try:
            emu = emulator_of(client.transport)
            n_conv = read_plan(client, conv)
            meter = _Meter(client, emu)
            c0 = time.process_time()
            res = [run_scenario(s, w, hil, launches=launches, seed=1, client=client,
                                layout=layout, mode="on_board", baud=BAUD, conversions=conv,
                                interleave=inter) for s in ("hw_noastro", "hw_astro")]
            cpu = time.process_time() - c0
            d = meter.delta()
        finally:
            client.close()
        rows = [r for sr in res for r in sr.launches]
        n = sum(r.decisions for r in rows)
        windows = n                                        # one DECISION_WINDOW a decision
        dac_words = sum(d[f"dev_DAC{i}"] for i in range(4))
        frames = d["dev_ADC"]
        if n_conv:
            reads = (frames - windows) / n_conv
            selects = d["dev_SR_COL"] - windows
        else:
            reads = frames / (n_conv or (emu.board.config.adc_averages + 1))
            selects = reads
        counts = WindowCounts(spikes=sum(r.spikes for r in rows) / n, reads=reads / n,
                              selects=selects / n, row_words=dac_words / n,
                              conversions=n_conv or emu.board.config.adc_averages,
                              request_bytes=d["out"] / n, reply_bytes=d["in"] / n,
                              mcu_us=d["mcu_us"] / n, standard=not n_conv)
        total_us = sum(r.virtual_us for r in rows)
        out[plan] = {"decisions": n, "conversions": n_conv, "paths": [r.path for r in rows],
                     "ceiling": ceiling(counts, BAUD),
                     "board_ms": sum(r.virtual_us - r.wire_us for r in rows) / n / 1e3,
                     "total_ms": total_us / n / 1e3, "rate": 1e6 * n / total_us,
                     "bytes": (d["out"] + d["in"]) / n, "energy_j": d["energy"] / n,
                     "cpu_ms": cpu / n * 1e3, "spikes": counts.spikes,
                     "faults": dict(emu.backend.mcu.faults) if emu.backend else {}}
    return out


def mcus_identical(work: Path) -> tuple[int, int, str]:
    """Part 5: (conformance sessions the C firmware passes, sessions, differential finding)."""
    from snan_hil.firmware_emu import differential
    from snan_hil.firmware_emu.emulator import Emulator
    from snan_hil.firmware_emu.testing import default_array
    from snan_hil.protocol.conformance import load_session, run_session
    root = Path(__file__).resolve().parent.parent / "conformance" / "v1" / "framed"
    passed = total = 0
    for path in sorted(root.glob("*.jsonl")):
        if path.name in ("replies.jsonl", "sequences.jsonl"):
            continue
        session = load_session(path)
        b = session.board
        total += 1
        emu = Emulator(None, b.chip_seed, array=default_array(b.chip_seed), mcu="firmware",
                       baud=b.baud, boot_nonces=b.boot_nonces)
        try:
            passed += not run_session(session, emu.feed) and not emu.backend.mcu.faults
        finally:
            emu.close()
    differential.findings_dir(work / "findings")
    try:
        differential.run_seeded(7, examples=6, steps=20)
        finding = "none"
    except AssertionError as exc:
        finding = str(exc).splitlines()[0]
    return passed, total, finding


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
    from snan_hil.lab.opener import plan_board
    from snan_hil.lab.ports import BoardAddress
    from snan_hil.lab.runner import RunOptions, run_job
    hil = load_hil_config()
    wpath = _weights(work, sets)
    out = {}
    for plan, conv in (("standard", 0), ("lean", None)):
        state = work / f"cmp-{plan}.npz"
        state.unlink(missing_ok=True)
        t0 = time.perf_counter()
        request = CompareRequest(str(wpath), hil, launches=10, seed=1, mode="on_board",
                                 conversions=conv, report_dir=work / f"prog-{plan}")
        board = plan_board(BoardAddress("emu", baud=BAUD, state_file=str(state), seed=0))
        res = run_job(CompareJob(request), board, RunOptions(record="off")).result
        out[plan] = {"wall_s": time.perf_counter() - t0, "scenarios": res["scenarios"]}
    return out


def _print_budget(tally: dict) -> bool:
    print(f"   {'reads':<28}{'windows':>8}{'identical':>11}{'95 % interval':>20}")
    chosen = None
    for tag in ("floor", *BUDGET_NS):
        n, k = tally[tag]
        lo, hi = wilson(k, n)
        name = ("standard, another noise realisation" if tag == "floor"
                else f"lean, {tag} conversion{'s' if tag > 1 else ''}")
        print(f"   {name:<36}{n:>7}{k / n:>10.2%}   [{lo:.2%}, {hi:.2%}]")
        if tag != "floor" and chosen is None and k / n >= BUDGET_TARGET:
            chosen = tag
    from snan_hil.protocol.board import WINDOW_CONVERSIONS
    ok = chosen == WINDOW_CONVERSIONS
    print(f"   fewest conversions with >= {BUDGET_TARGET:.0%} identical: {chosen}; the board "
          f"setting WINDOW_CONVERSIONS = {WINDOW_CONVERSIONS}: "
          f"{'met' if ok else 'NOT MET (update it)'}")
    return ok


def _print_speed(mcu: str, sp: dict) -> list[bool]:
    verdicts = []
    for plan, r in sp.items():
        ce = r["ceiling"]
        parts = ", ".join(f"{k} {v / 1e3:.2f}" for k, v in ce.parts_us.items())
        print(f"   {mcu:<9}{plan:<17} ceiling {ce.time_us / 1e3:6.2f} ms ({ce.bound}-bound; "
              f"{parts} ms; chain {ce.chain_us / 1e3:.2f} ms)")
    print(f"   {'mcu':<9}{'plan':<17}{'dec':>5}{'spikes':>7}{'B/dec':>7}{'board ms':>9}"
          f"{'ceil/board':>11}{'+UART ms':>9}{'dec/s':>7}{'uJ/dec':>8}{'CPU ms':>8}")
    for plan, r in sp.items():
        ce = r["ceiling"]
        ratio = ce.time_us / 1e3 / r["board_ms"] if plan != "lean interleaved" else None
        print(f"   {mcu:<9}{plan:<17}{r['decisions']:5d}{r['spikes']:7.0f}{r['bytes']:7.1f}"
              + (f"{r['board_ms']:9.2f}{ratio:11.2f}" if ratio else f"{'(shared)':>9}{'':>11}")
              + f"{r['total_ms']:9.2f}{r['rate']:7.1f}{r['energy_j'] * 1e6:8.2f}"
              f"{r['cpu_ms']:8.1f}")
    lean, inter = sp["lean"], sp["lean interleaved"]
    ratio = lean["ceiling"].time_us / 1e3 / lean["board_ms"]
    ok = ratio >= CEILING_TARGET
    verdicts.append(ok)
    print(f"   {mcu}: lean board time {lean['board_ms']:.2f} ms against its ceiling "
          f"{lean['ceiling'].time_us / 1e3:.2f} ms ({lean['ceiling'].bound}): {ratio:.2f} "
          f"(target >= {CEILING_TARGET}): {'met' if ok else 'NOT MET'}; against the analog "
          f"chain alone {lean['ceiling'].chain_us / 1e3 / lean['board_ms']:.2f}")
    ok = inter["rate"] >= RATE_TARGET
    verdicts.append(ok)
    print(f"   {mcu}: {inter['rate']:.1f} decisions/s at {BAUD} baud, launches interleaved "
          f"(target >= {RATE_TARGET:.0f}, stretch >= {RATE_STRETCH:.0f}): "
          f"{'met' if ok else 'NOT MET'}{', stretch met' if inter['rate'] >= RATE_STRETCH else ''}"
          f"; standard plan {sp['standard']['rate']:.1f}/s, lean one after another "
          f"{lean['rate']:.1f}/s")
    same = inter["paths"] == lean["paths"]
    verdicts.append(same)
    print(f"   {mcu}: interleaved launches took {'the same' if same else 'DIFFERENT'} paths as "
          f"one after another ({len(lean['paths'])} launches)"
          + (f"; MCU faults {inter['faults']}" if inter["faults"] else ""))
    verdicts.append(not inter["faults"] and not lean["faults"])
    if mcu == "model":
        e = lean["energy_j"]
        ok = e <= ENERGY_TARGET_J
        verdicts.append(ok)
        print(f"   {mcu}: array energy {e * 1e6:.2f} uJ per decision (target <= "
              f"{ENERGY_TARGET_J * 1e6:.0f} uJ; standard plan "
              f"{sp['standard']['energy_j'] * 1e6:.2f}): {'met' if ok else 'NOT MET'}")
    return verdicts


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--windows", type=int, default=100_000)
    ap.add_argument("--launches", type=int, default=5)
    ap.add_argument("--budget-sets", type=int, default=10)
    ap.add_argument("--budget-launches", type=int, default=10)
    ap.add_argument("--no-budget", action="store_true", help="skip part 2")
    ap.add_argument("--medians", action="store_true", help="part 2: also full runs per N")
    ap.add_argument("--no-firmware", action="store_true", help="skip the --mcu firmware rows")
    ap.add_argument("--compare", action="store_true", help="also the full comparison per plan")
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

    if not args.no_budget:
        t0 = time.perf_counter()
        tally = budget(work, args.budget_sets, args.budget_launches)
        print(f"2. read-noise budget: {args.budget_sets} sets x {args.budget_launches} launches "
              f"x 2 hw scenarios, decisions against the standard ten-average reads "
              f"({time.perf_counter() - t0:.0f} s)")
        verdicts.append(_print_budget(tally))
    else:
        print("2. read-noise budget: skipped (--no-budget)")
    if args.medians:
        t0 = time.perf_counter()
        med = budget_medians(work, args.budget_sets, args.budget_launches)
        print(f"2b. route medians of full runs per read plan, {args.budget_sets} sets x "
              f"{args.budget_launches} launches, successful launches [95 % CI], success "
              f"({time.perf_counter() - t0:.0f} s)")
        inside_all = True
        for s in ("hw_noastro", "hw_astro"):
            std = med[(0, s)]
            ci = std["median_steps_ci"]
            for conv in (0, *BUDGET_NS[:3]):
                m = med[(conv, s)]
                inside = bool(m["median_steps"] is not None and ci is not None
                              and ci[0] <= m["median_steps"] <= ci[1])
                inside_all &= inside or not conv
                print(f"   {s:<11} {'standard' if not conv else f'{conv} conversions':<14} "
                      f"median {m['median_steps']} {m['median_steps_ci']}, success "
                      f"{m['success_rate']:.0%}"
                      + ("" if not conv else
                         f": {'inside' if inside else 'OUTSIDE'} the standard's interval"))
        ok = inside_all
        verdicts.append(ok)
        print(f"   every lean median inside the standard's interval: {'met' if ok else 'NOT MET'}")

    wpath = _weights(work, 1)
    mcus = ["model"] + ([] if args.no_firmware else ["firmware"])
    print(f"3-4. ceiling, board time and speed at {BAUD} baud, hw_noastro + hw_astro x "
          f"{args.launches} launches, 1 weight set (load {os.getloadavg()[0]:.1f})")
    for mcu in mcus:
        verdicts += _print_speed(mcu, speed(mcu, args.launches, work, wpath))
    if not args.no_firmware:
        passed, total, finding = mcus_identical(work)
        ok = passed == total and finding == "none"
        verdicts.append(ok)
        print(f"5. the two MCUs: {passed} of {total} conformance sessions bit-identical on the "
              f"C firmware; differential run (6 sequences x 20 steps): {finding}: "
              f"{'met' if ok else 'NOT MET'}")
    ram = firmware_ram()
    if ram is None:
        print("6. firmware RAM: no ELF (make firmware)")
    else:
        ok = ram["ram"] <= RAM_LIMIT
        verdicts.append(ok)
        print(f"6. firmware RAM {ram['ram']} of {RAM_LIMIT} B, {RAM_LIMIT - ram['ram']} B free "
              f"(.data {ram['data']}, .bss {ram['bss']}, .noinit {ram['noinit']}, stack "
              f"{ram['stack']}; flash {ram['text']} B): {'met' if ok else 'NOT MET'}")
    if args.compare:
        print(f"7. compare, {args.sets} sets x 10 launches x 4 scenarios, per read plan "
              "(median of successful launches [95 % CI] / of all launches, success)")
        for plan, r in compare_medians(args.sets, work).items():
            sc = r["scenarios"]
            parts = []
            for name in ("sw_noastro", "sw_astro", "hw_noastro", "hw_astro"):
                s = sc[name]
                ci = s.get("median_steps_ci") or [None, None]
                parts.append(f"{name} {s['median_steps']:g} [{ci[0]}, {ci[1]}] / "
                             f"{s.get('median_steps_all')} {s['success_rate']:.0%}")
            rel = [(sc[f"hw_{a}"]["median_steps"] - sc[f"sw_{a}"]["median_steps"])
                   / sc[f"sw_{a}"]["median_steps"] for a in ("noastro", "astro")]
            print(f"   {plan:<9} ({r['wall_s']:.0f} s): " + "; ".join(parts)
                  + f"; hw vs sw {rel[0]:+.0%}, {rel[1]:+.0%}")
    print("all targets met" if all(verdicts) else "SOME TARGETS NOT MET")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
