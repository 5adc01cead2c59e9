"""The paper's 10x10 field over a chip group (issue 35, point 6): ``compare --group``.

Usage: ``python bench/bench_group_10x10.py [--chips 3] [--sets 10] [--launches 10]
[--seed 1] [--out DIR]``

In a temporary folder (or ``--out``): 10x10 route weights (``snan-hil train --config
configs/hil-10x10.yaml``: --sets sets, 20 cycles, seed --seed), then ``snan-hil compare
--group`` over --chips fresh emulated chips (``emu://?state=chipK.npz&seed=K+1``: chips of
different seeds, so different device spreads), all four scenarios, --launches launches per set
and scenario — each a subprocess, timed with the wall clock.

Printed, each measured against its target:

* the comparison's wall time on this machine vs the target <= 15 min (the training's beside
  it, not part of the target);
* the real-board time at 115200 baud: the emulated boards' clocks, which count the UART at the
  link's baud (programming: each chip's report ``virtual_s``; launches: ``virtual_us`` of every
  hardware launch, the chips one window at a time, so an upper bound for chips that could
  work at once), plus the software scenarios' host time;
* per scenario the median path of the successful launches with its 95 % interval and the
  success rate, the paper's 10x10 figures beside them (Fig. 3/4: 362 without, 55 with
  astrocytes — software, fresh weights, random tasks: not this protocol);
* hardware vs software per astrocyte setting: the medians' difference vs the target +-20 %.

Exit status 0 when both targets are met, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SNAN = [sys.executable, "-m", "snan_hil.tools.cli"]
TARGET_WALL_S = 15 * 60.0
TARGET_HW_VS_SW = 0.20
PAPER = {"noastro": 362.0, "astro": 55.0}


CPU: dict[str, float] = {}
"""CPU time (user + system, s) of each command's subprocess, by command."""


def _cpu_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _run(args: list[str], cwd: Path) -> float:
    """Run ``snan-hil ARGS`` in ``cwd``; its wall time (s); its CPU time into :data:`CPU`."""
    t, c = time.perf_counter(), _cpu_children()
    env = dict(os.environ, XDG_DATA_HOME=str(cwd / "data"))
    env.pop("SNAN_HIL_PORT", None)
    proc = subprocess.run([*SNAN, *args], cwd=cwd, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        sys.stderr.write(proc.stdout[-3000:] + proc.stderr[-3000:])
        raise SystemExit(f"snan-hil {args[0]} failed with exit {proc.returncode}")
    CPU[args[0]] = _cpu_children() - c
    return time.perf_counter() - t


def _ci(v: dict) -> str:
    ci = v.get("median_steps_ci")
    med = v.get("median_steps")
    return "-" if med is None else f"{med:g} [{ci[0]:g}, {ci[1]:g}]" if ci else f"{med:g}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--chips", type=int, default=3)
    ap.add_argument("--sets", type=int, default=10)
    ap.add_argument("--launches", type=int, default=10)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default=None, help="keep the run here (default: a temp folder)")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="bench-group-") as tmp:
        work = Path(a.out).resolve() if a.out else Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        config = str(ROOT / "configs" / "hil-10x10.yaml")
        weights = work / "w10.npz"
        t_train = _run(["train", "--config", config, "--sets", str(a.sets), "--seed",
                        str(a.seed), "-o", str(weights), "--force"], work)
        ports = ",".join(f"emu://?state={work / f'chip{k}.npz'}&seed={k + 1}"
                         for k in range(a.chips))
        res = work / "res"
        t_cmp = _run(["compare", "--weights", str(weights), "--config", config, "--group",
                      ports, "--launches", str(a.launches), "--seed", str(a.seed), "--out",
                      str(res), "--no-figure", "--json", "--force"], work)
        data = json.loads((res / "compare.json").read_text())
    return report(data, a, t_train, t_cmp)


def report(data: dict, a: argparse.Namespace, t_train: float, t_cmp: float) -> int:
    rows = data["launch_rows"]
    hw = [r for r in rows if str(r["scenario"]).startswith("hw_")]
    sw = [r for r in rows if str(r["scenario"]).startswith("sw_")]
    prog_s = sum(float(p.get("virtual_s") or 0.0) for p in data["programming"].values())
    launch_s = sum(float(r.get("virtual_us") or 0.0) for r in hw) * 1e-6
    sw_s = sum(float(r.get("wall_s") or 0.0) for r in sw)
    board_s = prog_s + launch_s + sw_s
    plan = data["group"]["plan"]
    print(f"10x10 comparison over a group of {a.chips} emulated chips ({a.sets} sets x "
          f"{a.launches} launches x 4 scenarios; task {data['start']} -> {data['goal']}, step "
          f"limit {data['step_limit']})")
    for k, c in enumerate(plan["chips"]):
        print(f"  chip {k}: input neurons {c['pres'][0]}-{c['pres'][1]}, {c['synapses']} "
              f"synapses in {c['block_rows']} rows, {c['spare_cells']} spare cells")
    ok_wall = t_cmp <= TARGET_WALL_S
    load = os.getloadavg()[0]
    print(f"wall time of the comparison: {t_cmp:.0f} s (target <= {TARGET_WALL_S:.0f} s: "
          f"{'met' if ok_wall else 'NOT met'}; its CPU time {CPU.get('compare', 0.0):.0f} s, "
          f"load average {load:.1f} on {os.cpu_count()} cores at the end); training beside "
          f"it: {t_train:.0f} s wall, {CPU.get('train', 0.0):.0f} s CPU")
    print(f"real boards at {data['baud']} baud (the emulated clocks, UART included): "
          f"{board_s:.0f} s = programming {prog_s:.0f} s + hardware launches {launch_s:.0f} s "
          f"({len(hw)} launches, {sum(int(r['decisions']) for r in hw)} decisions) + software "
          f"{sw_s:.0f} s")
    pulses = sum(int(p.get("pulses_total") or 0) for p in data["programming"].values())
    all_ok = all(p.get("all_ok") for p in data["programming"].values())
    print(f"programming: {pulses} pulses over {len(data['programming'])} sets; every cell "
          f"inside its window: {all_ok}")
    sc = data["scenarios"]
    ok_match = True
    for astro in ("noastro", "astro"):
        s, h = sc[f"sw_{astro}"], sc[f"hw_{astro}"]
        print(f"  {astro:8s} software {_ci(s)} ({s['success_rate']:.0%} success), chip group "
              f"{_ci(h)} ({h['success_rate']:.0%}); paper (Fig. 3/4) {PAPER[astro]:g}")
        if s.get("median_steps") and h.get("median_steps") is not None:
            diff = h["median_steps"] / s["median_steps"] - 1.0
            within = abs(diff) <= TARGET_HW_VS_SW
            ok_match = ok_match and within
            print(f"           hardware vs software {diff:+.0%} (target within "
                  f"+-{TARGET_HW_VS_SW:.0%}: {'met' if within else 'NOT met'})")
        else:
            ok_match = False
    return 0 if ok_wall and ok_match else 1


if __name__ == "__main__":
    raise SystemExit(main())
