"""The equivalence run of issue 35 point 3, as the commands a lab types (docs/learning.md
section 12; ``bench/bench_equivalence.py``, ``docs/tables/make_tables.py --run equivalence``).

Three emulated chips that differ by their seed and their device-to-device spread
(:data:`CHIPS`: ``snan-hil emu --reset-chip --seed S --spread X``), each characterised
(``snan-hil characterize --model``) and learnt on with the software and chip arms on paired
seeds (``snan-hil learn --arms software,chip --sessions 30 --seed L``: each chip its own master
seed, so that the pooled software sessions are all different sessions); the power a pilot gives
(``snan-hil equivalence learn-B --sessions 10``: the first 10 sessions of chip B's run, the
sessions a 10-session run gives, looked at before the other results); the cross-chip transfers
(``snan-hil transfer``: each chip's learnt weights onto another chip); the analysis
(``snan-hil equivalence learn-A learn-B learn-C --transfer ...``).

:func:`run_study` runs the steps whose outputs are not in its folder yet (a step's output is
written only when the step finished), so a study that stopped continues where it was.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from snan_hil.common.version import __version__

__all__ = ["ChipSpec", "CHIPS", "PAIRS", "SESSIONS", "CYCLES", "PILOT_SESSIONS",
           "PILOT_CHIP", "run_study", "commands"]


@dataclass(frozen=True)
class ChipSpec:
    """An emulated chip of the study: ``name``, the chip's ``seed``, its device-to-device
    ``spread`` (times the packaged sigmas), the master ``learn_seed`` of its sessions."""

    name: str
    seed: int
    spread: float
    learn_seed: int


CHIPS = (ChipSpec("A", 101, 1.0, 11), ChipSpec("B", 102, 0.5, 12), ChipSpec("C", 103, 2.0, 13))
"""The chips: the packaged spread, half of it, twice it."""
PAIRS = (("A", "B"), ("B", "C"), ("C", "A"), ("B", "A"), ("C", "B"), ("A", "C"))
"""The transfers (source chip, target chip): every ordered pair, the cycle first."""
SESSIONS = 30
CYCLES = 20
PILOT_SESSIONS = 10
PILOT_CHIP = "B"


def _state(d: Path, chip: str) -> Path:
    return d / chip / "chip.npz"


def commands(d: Path, sessions: int = SESSIONS, cycles: int = CYCLES,
             pairs: Sequence[tuple[str, str]] = PAIRS, chips: Sequence[ChipSpec] = CHIPS
             ) -> list[tuple[str, list[str], dict[str, str], Path]]:
    """The study's steps in order: (what, ``snan-hil`` arguments, environment, the output that
    says the step is done)."""
    steps: list[tuple[str, list[str], dict[str, str], Path]] = []
    for c in chips:
        env = {"SNAN_HIL_EMU_STATE": str(_state(d, c.name))}
        steps += [
            (f"chip {c.name}: a fresh emulated chip, seed {c.seed}, spread x{c.spread:g}",
             ["emu", "--state", str(_state(d, c.name)), "--reset-chip", "--seed", str(c.seed),
              "--spread", str(c.spread)], {}, _state(d, c.name)),
            (f"chip {c.name}: characterise its synapse cells",
             ["characterize", "--port", "emu", "--model", str(d / c.name / "model.json"),
              "--json"], env, d / c.name / "model.json"),
            (f"chip {c.name}: {sessions} paired sessions x {cycles} cycles, software and chip",
             ["learn", "--port", "emu", "--arms", "software,chip", "--sessions", str(sessions),
              "--cycles", str(cycles), "--seed", str(c.learn_seed), "--out",
              str(d / f"learn-{c.name}"), "--json", "--no-figure"], env,
             d / f"learn-{c.name}" / "learn.json")]
    for src, dst in pairs:
        out = d / f"transfer-{src}-{dst}.json"
        steps.append((f"transfer: chip {src}'s learnt weights onto chip {dst}",
                      ["transfer", str(d / f"learn-{src}"), "--port", "emu", "-o", str(out),
                       "--json"], {"SNAN_HIL_EMU_STATE": str(_state(d, dst))}, out))
    return steps


def _cli(args: Sequence[str], env: dict[str, str]) -> str:
    from snan_hil.tools.subprocess_cli import run_cli
    return run_cli(args, env)


def _shown(args: Sequence[str], env: dict[str, str], d: Path) -> str:
    import shlex
    text = " ".join(f"{k}={v}" for k, v in env.items()) + (" " if env else "")
    return (text + "snan-hil " + shlex.join(args)).replace(str(d) + "/", "")


def _compact(sessions: int, cycles: int, chips: Sequence[ChipSpec], pilot: int) -> list[str]:
    """The study's commands as a reader types them (one line per kind of step; ``steps`` of
    the data: every one)."""
    each = ", ".join(f"({c.name}, {c.seed}, {c.spread:g}, {c.learn_seed})" for c in chips)
    return [f"snan-hil emu --state X/chip.npz --reset-chip --seed S --spread F; "
            f"SNAN_HIL_EMU_STATE=X/chip.npz snan-hil characterize --port emu --model "
            f"X/model.json; SNAN_HIL_EMU_STATE=X/chip.npz snan-hil learn --port emu --arms "
            f"software,chip --sessions {sessions} --cycles {cycles} --seed L --out learn-X "
            f"for (X, S, F, L) in {each}",
            "SNAN_HIL_EMU_STATE=Y/chip.npz snan-hil transfer learn-X --port emu -o "
            "transfer-X-Y.json for every ordered pair (X, Y)",
            f"snan-hil equivalence learn-{PILOT_CHIP} --sessions {pilot}",
            "snan-hil equivalence learn-A learn-B learn-C --transfer transfer-*.json"]


def run_study(d: Path, *, sessions: int = SESSIONS, cycles: int = CYCLES,
              pilot: int = PILOT_SESSIONS, pairs: Sequence[tuple[str, str]] = PAIRS,
              chips: Sequence[ChipSpec] = CHIPS, say: Callable[[str], None] = print
              ) -> dict[str, Any]:
    """Run the study in folder ``d`` (module doc; the steps already done are kept) and return
    its data: the pilot's and the final analysis (``snan-hil equivalence --json``), the chips,
    the commands, the version, the steps found done (``steps_reused``) and the wall time when
    every step ran now (else None)."""
    d.mkdir(parents=True, exist_ok=True)
    t0, load0 = time.perf_counter(), os.getloadavg()[0]
    shown = []
    reused = 0
    for what, args, env, done in commands(d, sessions, cycles, pairs, chips):
        shown.append(_shown(args, env, d))
        if done.exists():
            reused += 1
            continue
        say(what)
        _cli(args, env)
    learn = [str(d / f"learn-{c.name}") for c in chips]
    pilot_args = ["equivalence", str(d / f"learn-{PILOT_CHIP}"), "--sessions", str(pilot),
                  "--json"]
    final_args = ["equivalence", *learn, "--transfer",
                  *[str(d / f"transfer-{s}-{t}.json") for s, t in pairs],
                  "-o", str(d / "equivalence.json"), "--force", "--json"]
    pilot_doc = json.loads(_cli(pilot_args, {}))
    final = json.loads(_cli(final_args, {}))
    from snan_hil.host.hil.equivalence import margin_allowed
    p = pilot_doc["chips"][f"learn-{PILOT_CHIP}"]
    sd = p["route"]["sd_log"] if p.get("route") else None
    share = p["power"]["route_pair_share"] if p.get("power") else None
    plan = {}
    if sd is not None and share:
        for n_sessions in (sessions, sessions * len(chips)):
            pairs_n = int(n_sessions * share)
            plan[str(n_sessions)] = {"route_pairs": pairs_n,
                                     "margin_allowed": margin_allowed(sd, pairs_n)}
    return {"command": _compact(sessions, cycles, chips, pilot),
            "steps": [*shown, _shown(pilot_args, {}, d),
                      _shown(final_args[:final_args.index("-o")], {}, d)],
            "chips": [{"name": c.name, "seed": c.seed, "spread": c.spread,
                       "learn_seed": c.learn_seed} for c in chips],
            "sessions": sessions, "cycles": cycles, "pilot_sessions": pilot,
            "pilot_chip": PILOT_CHIP, "pilot": pilot_doc, "pilot_plan": plan,
            "result": final, "version": __version__, "steps_reused": reused,
            # the wall time of the whole study only when every step ran now
            "wall_s": None if reused else time.perf_counter() - t0,
            "load": (load0 + os.getloadavg()[0]) / 2}


def plot(data: dict[str, Any], path: Path) -> Path:
    """The run in one figure (docs/figures/equivalence.png): A, each chip's and the pooled
    route ratio chip/software with its 90 % interval against the +-margin band; B, the
    success difference with its 90 % interval; C, each transfer's kept share against 90 %."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from snan_hil.files.atomicio import atomic_path
    from snan_hil.host.hil.equivalence import TRANSFER_TARGET
    res = data["result"]
    names = list(res["chips"])
    labels = [n.removeprefix("learn-") for n in names]
    fig, ax = plt.subplots(1, 3, figsize=(13, 3.8))
    lo_b, hi_b = 1 / (1 + res["margin"]), 1 + res["margin"]
    ax[0].axvspan(lo_b, hi_b, color="tab:green", alpha=0.15,
                  label=f"±{100 * res['margin']:.0f} %")
    ax[0].axvline(1.0, color="grey", lw=0.8)
    for i, n in enumerate(names):
        r = res["chips"][n].get("route")
        if r is None:
            continue
        lo, hi = r["ratio_ci"]
        ax[0].errorbar(r["ratio"], i, xerr=[[r["ratio"] - lo], [hi - r["ratio"]]], fmt="o",
                       color="k" if n == "pooled" else "tab:blue", capsize=3)
    ax[0].set_xscale("log")
    ax[0].set_yticks(range(len(names)), labels)
    ax[0].set_xlabel("route ratio chip / software at cycle %d (90 %% CI)" % res["cycle"])
    ax[0].set_title("A  route: TOST")
    ax[0].legend(loc="lower right", fontsize=8)
    ax[1].axvline(0.0, color="grey", lw=0.8)
    for i, n in enumerate(names):
        s = res["chips"][n]["success"]
        ax[1].errorbar(100 * s["difference"], i,
                       xerr=[[100 * (s["difference"] - s["ci"][0])],
                             [100 * (s["ci"][1] - s["difference"])]],
                       fmt="o", color="k" if n == "pooled" else "tab:blue", capsize=3)
    ax[1].set_yticks(range(len(names)), labels)
    ax[1].set_xlabel("success chip − software, points (90 % CI)")
    ax[1].set_title("B  success")
    ts = res.get("transfer") or []
    kept = [100 * (t["kept"] or 0) for t in ts]
    ax[2].bar(range(len(ts)), kept, color=["tab:blue" if t["met"] else "tab:red" for t in ts])
    ax[2].axhline(100 * TRANSFER_TARGET, color="tab:green", ls="--", label="target 90 %")
    ax[2].set_xticks(range(len(ts)), [f"{str(t['source']).removeprefix('learn-')}→"
                                      f"{str(t['target']).removeprefix('learn-')}" for t in ts])
    ax[2].set_ylabel("success kept on the other chip, %")
    ax[2].set_title("C  cross-chip transfer")
    ax[2].legend(loc="lower right", fontsize=8)
    fig.suptitle(f"chip arm vs software, {len(data['chips'])} emulated chips x "
                 f"{data['sessions']} paired sessions (6x6, 18 -> 0)", fontsize=10)
    fig.tight_layout()
    with atomic_path(path, suffix=".tmp.png") as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
    return path
