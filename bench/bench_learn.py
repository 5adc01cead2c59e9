"""Learning on the chip (issue 22, point 7): ``snan-hil learn`` on the emulated board, measured
against its targets.

Usage: ``python bench/bench_learn.py [--sessions N] [--cycles C] [--protocol framed|legacy]
[--out DIR] [--quick] [--no-batch]``

In a temporary folder (a fresh default chip, seed 0): ``snan-hil characterize`` of the 120
synapse cells of the 6x6 task's block (rows 0-14, 2 repeats), then ``snan-hil learn`` of the
6x6 task (18 -> 0) with the three arms on N paired sessions (default 10) of C cycles (default
20). Prints, measured against the target:

* the chip arm's median test route at cycle C within 25 % of the software arm's (with both
  95 % intervals and the success rates), or the measured reason why not;
* the pulses of the chip arm's ledger equal to the pulses the chip's history database holds
  for the learn run;
* one learning cycle (training + test) over the framed protocol in <= 10 s of wall time
  (median and largest over all cycles);
* the wire time of one learning cycle at 115200 baud on a real board (bytes on the line of the
  median cycle x 10 bits / 115200), no target: what a lab should expect as a floor;
* the chip arm's modes (framed only; issue 23 point 3): the run above takes the board's
  default, the on-board decision window (DECISION_WINDOW with the motor spike times in the
  training trials); the chip arm is run again with ``--mode batch`` (SPIKE_BATCH, the host runs
  the motor neurons) on a copy of the same characterised chip. Printed: the decisions' wire
  bytes per decision (requests and replies of the trials, pulses excluded) and the wall time
  per cycle of both, against issue 23's <= 100 B per decision, and whether the two modes gave
  the same routes, pulses and learnt weights (they read the same cells in the same order: the
  emulator's same noise draws). ``--no-batch`` skips the second run.

``--quick``: 2 sessions of 3 cycles, 24 characterised cells (the targets are for the full run).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

CHIP_VS_SOFTWARE = 0.25      #: chip median at the last cycle within 25 % of the software one
CYCLE_WALL_TARGET_S = 10.0   #: one learning cycle (train + test) over framed, emulator
WIRE_PER_DECISION_TARGET = 100  #: issue 23 point 4: wire bytes per decision, on-board mode


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=10)
    ap.add_argument("--cycles", type=int, default=20)
    ap.add_argument("--protocol", choices=("framed", "legacy"), default="framed")
    ap.add_argument("--out", default=None, help="keep the results here (default: a temp dir)")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--no-batch", action="store_true",
                    help="skip the chip arm's batch-mode run (the on-board vs batch figures)")
    a = ap.parse_args(argv)
    if a.quick:
        a.sessions, a.cycles = 2, 3
    from snan_hil.records.history import History
    from snan_hil.tools import cli

    work = Path(a.out) if a.out else Path(tempfile.mkdtemp(prefix="bench-learn-"))
    work.mkdir(parents=True, exist_ok=True)
    os.environ["SNAN_HIL_EMU_STATE"] = str(work / "chip.npz")
    os.environ["XDG_DATA_HOME"] = str(work / "data")
    cells = ";".join(f"{r},{c}" for r in range(15 if not a.quick else 3) for c in range(8))
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        rc = cli.main(["characterize", "--port", "emu", "--protocol", a.protocol, "--cells", cells,
                       "--model", str(work / "model.json"), "--png", str(work / "fit.png"),
                       "--json", "--force"])
    if rc:
        return rc
    t_char = time.perf_counter() - t0
    batch_dir = work / "batch-chip"
    if a.protocol == "framed" and not a.no_batch:
        # the same characterised chip for the batch-mode run of the chip arm
        batch_dir.mkdir(exist_ok=True)
        for f in work.glob("chip.*"):
            shutil.copy(f, batch_dir / f.name)
        if (work / "data").is_dir():
            shutil.copytree(work / "data", batch_dir / "data", dirs_exist_ok=True)
    out = work / "learn"
    t1 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        rc = cli.main(["learn", "--port", "emu", "--protocol", a.protocol, "--sessions",
                       str(a.sessions), "--cycles", str(a.cycles), "--out", str(out), "--json",
                       "--force"] + (["--resume"] if (out / "checkpoint").exists() else []))
    if rc:
        return rc
    t_learn = time.perf_counter() - t1
    doc = json.loads((out / "learn.json").read_text())
    sw = doc["arms"]["software"]["curves"]
    dv = doc["arms"]["device"]["curves"]
    ch = doc["arms"]["chip"]["curves"]
    last = a.cycles

    def fmt(c: dict, k: int) -> str:
        ci = c["median_ci"][k]
        m = c["median"][k]
        return (f"{'-' if m is None else f'{m:g}'} steps "
                f"[{'-' if ci is None else f'{ci[0]:g}, {ci[1]:g}'}], success "
                f"{100 * c['success'][k]:.0f} % "
                f"[{', '.join(f'{100 * v:.0f}' for v in c['success_ci'][k])}] %")
    print(f"\n6x6 route learning 18 -> 0, {a.sessions} paired sessions x {a.cycles} cycles, "
          f"{a.protocol} protocol (characterise {t_char:.0f} s, learn {t_learn:.0f} s wall)")
    for name, c in (("software", sw), ("device model", dv), ("chip", ch)):
        print(f"  {name:13s} cycle 0: {fmt(c, 0)}  |  cycle {last}: {fmt(c, last)}")
    ms, mc = sw["median"][last], ch["median"][last]
    if ms and mc:
        rel = mc / ms - 1.0
        ok = abs(rel) <= CHIP_VS_SOFTWARE
        print(f"1. chip arm median at cycle {last}: {mc:g} vs software {ms:g} = {100 * rel:+.0f} % "
              f"(target within +-{100 * CHIP_VS_SOFTWARE:.0f} %): {'MET' if ok else 'NOT MET'}")
        if not ok:
            print("   why: compare the device-model arm (the fitted steps without a board): "
                  f"cycle {last} median {dv['median'][last]}; the chip's success rate "
                  f"{100 * ch['success'][last]:.0f} % vs software "
                  f"{100 * sw['success'][last]:.0f} %")
    else:
        print(f"1. chip arm median at cycle {last}: no successful test in an arm "
              f"(software {ms}, chip {mc}): NOT MET")
    led = doc["ledger"]
    with History.open(doc["history"]["path"], create=False) as db:
        run = [r for r in db.runs("learn") if r.id == doc["history"]["run"]][0]
    print(f"2. ledger pulses {led['total']} (learning + programming; uncertain "
          f"{led['uncertain']}) vs the chip history's {run.pulses} for run {run.id}: "
          f"{'MET' if led['total'] == run.pulses else 'NOT MET'}")
    ls = doc["link_summary"]
    ok = ls["wall_s_max"] <= CYCLE_WALL_TARGET_S
    print(f"3. one learning cycle (train + test), wall: median {ls['wall_s_median']:.2f} s, "
          f"largest {ls['wall_s_max']:.2f} s (target <= {CYCLE_WALL_TARGET_S:g} s; "
          f"{ls['cycles']} cycles): {'MET' if ok else 'NOT MET'}")
    print(f"4. wire time of one learning cycle at 115200 baud: {ls['wire_s_at_115200']:.2f} s "
          f"({ls['wire_bytes_median']:.0f} bytes of the median cycle; {ls['decisions_median']:.0f} "
          f"decisions, {ls['pulses_median']:.0f} pulses)")
    per = {r["stage"]: 0 for r in led["rows"]}
    for r in led["rows"]:
        per[r["stage"]] += r["set"] + r["reset"]
    print(f"   pulses by stage: {per}; energy from CLOCK over the learning pulses: "
          f"{sum(r['energy_j'] or 0 for r in led['rows'] if r['stage'] != 'program'):.3g} J")
    if a.protocol == "framed" and not a.no_batch:
        rc = _modes(a, work, batch_dir, doc)
        if rc:
            return rc
    print(f"results in {work}")
    return 0


def _per_decision(doc: dict) -> tuple[float, float, float]:
    """(read bytes per decision, median wall per cycle s, read bytes per cycle) of a run."""
    link = doc["link"]
    dec = sum(c["read_decisions"] for c in link)
    rb = sum(c["read_bytes"] for c in link)
    return rb / max(dec, 1), statistics.median(c["wall_s"] for c in link), rb / max(len(link), 1)


def _modes(a: argparse.Namespace, work: Path, batch_dir: Path, doc: dict) -> int:
    """The chip arm in batch mode on the copy of the chip; on-board vs batch figures."""
    from snan_hil.tools import cli
    os.environ["SNAN_HIL_EMU_STATE"] = str(batch_dir / "chip.npz")
    os.environ["XDG_DATA_HOME"] = str(batch_dir / "data")
    out = work / "learn-batch"
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        rc = cli.main(["learn", "--port", "emu", "--sessions", str(a.sessions), "--cycles",
                       str(a.cycles), "--arms", "chip", "--mode", "batch", "--model",
                       str(work / "model.json"), "--out", str(out), "--json", "--force"]
                      + (["--resume"] if (out / "checkpoint").exists() else []))
    if rc:
        return rc
    t_batch = time.perf_counter() - t0
    bdoc = json.loads((out / "learn.json").read_text())
    ob, ow, oc = _per_decision(doc)
    bb, bw, bc = _per_decision(bdoc)
    ok = ob <= WIRE_PER_DECISION_TARGET
    print(f"5. chip arm, {doc['chip_mode']} vs {bdoc['chip_mode']} (batch run {t_batch:.0f} s "
          f"wall): decisions' wire bytes per decision {ob:.1f} vs {bb:.1f} B "
          f"({bb / ob:.1f}x fewer; target <= {WIRE_PER_DECISION_TARGET} B: "
          f"{'MET' if ok else 'NOT MET'}); at 115200 baud {oc * 10 / 115200:.2f} vs "
          f"{bc * 10 / 115200:.2f} s of reads per cycle; wall per cycle (emulator, median) "
          f"{ow:.2f} vs {bw:.2f} s")
    so = [s for s in doc["arms"]["chip"]["sessions"]]
    sb = [s for s in bdoc["arms"]["chip"]["sessions"]]
    same = sum(x == y for x, y in zip(so, sb))
    print(f"   same routes, pulses and learnt weights in {same} of {len(sb)} sessions "
          f"(ledger {doc['ledger']['total']} vs {bdoc['ledger']['total']} pulses)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
