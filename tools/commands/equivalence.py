"""``snan-hil equivalence``: is learning on the chip equivalent to learning in software? The
TOST of the chip arm against software at one cycle, per chip and pooled, the success-rate
difference, the power the data give, and the cross-chip transfers
(:mod:`snan_hil.host.hil.equivalence`; docs/learning.md section 12). No board: it reads the
results of ``snan-hil learn`` (one run per chip) and ``snan-hil transfer``.

Examples::

    snan-hil equivalence pilot-run                        # the power a pilot gives
    snan-hil equivalence chip-a chip-b chip-c --transfer a-on-b.json b-on-a.json ... \\
        -o equivalence.json

Writes ``-o`` (``snan-hil-equivalence/1``: the analysis, the runs' seeds and configs, the
version). Ends with one verdict line per claim it tests.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

from snan_hil.common.errors import UserError
from snan_hil.common.version import __version__
from snan_hil.files.atomicio import atomic_write_json
from snan_hil.files.outputs import Outputs, json_kind
from snan_hil.host.hil.equivalence import (ALPHA, MARGIN, POWER, TRANSFER_TARGET, analyse,
                                           paired_at)
from snan_hil.host.hil.transfer import FORMAT as TRANSFER_FORMAT
from snan_hil.tools.commands.transfer import load_learn_run
from snan_hil.tools.console import console
from snan_hil.tools.output_kinds import add_force_option

NAME = "equivalence"
HELP = ("is learning on the chip equivalent to software? TOST at a cycle per chip and pooled, "
        "success difference, power, cross-chip transfer (from learn / transfer results)")
FORMAT = "snan-hil-equivalence/1"
KIND = json_kind(FORMAT, "a 'snan-hil equivalence' result")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("runs", nargs="+", metavar="RUN",
                        help="'snan-hil learn' results with the software and chip arms, one "
                             "per chip (their --out folders or learn.json), each with its own "
                             "--seed")
    parser.add_argument("--transfer", nargs="+", default=[], metavar="FILE",
                        help="'snan-hil transfer' results, one per ordered pair of chips "
                             "(default: none, no transfer in the analysis)")
    parser.add_argument("--cycle", type=int, default=None,
                        help="the cycle compared (default: the runs' last, 20)")
    parser.add_argument("--sessions", type=int, default=None, metavar="N",
                        help="the first N paired sessions of each run only (a pilot: the "
                             "sessions a run of N gives; default: all)")
    parser.add_argument("--margin", type=float, default=MARGIN,
                        help="equivalence margin of the route, relative: the chip's within "
                             "[1/(1+M), 1+M] x software's (default %(default)g)")
    parser.add_argument("--alpha", type=float, default=ALPHA,
                        help="level of each one-sided test (default %(default)g: 90 %% "
                             "intervals)")
    parser.add_argument("--power", type=float, default=POWER,
                        help="power the session count is planned for (default %(default)g)")
    parser.add_argument("-o", "--output", default=None, metavar="FILE",
                        help="write the analysis as JSON (default: not written)")
    parser.add_argument("--json", action="store_true", help="print the analysis as JSON")
    add_force_option(parser)


def _check(args: argparse.Namespace) -> None:
    if not 0 < args.margin < 1:
        raise UserError(f"--margin must be between 0 and 1 (0.15: 15 %), got {args.margin}")
    if not 0 < args.alpha < 0.5:
        raise UserError(f"--alpha must be between 0 and 0.5, got {args.alpha}")
    if not 0.5 <= args.power < 1:
        raise UserError(f"--power must be 0.5 .. below 1, got {args.power}")
    if args.cycle is not None and args.cycle < 0:
        raise UserError(f"--cycle must be >= 0, got {args.cycle}")


def _label(path: Path) -> str:
    return path.parent.name or str(path)


def _load_transfer(text: str) -> dict[str, Any]:
    path = Path(text).expanduser()
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UserError(f"--transfer {text}: no such file; write it with 'snan-hil transfer "
                        "RUN --port P -o FILE'") from None
    except (OSError, ValueError) as exc:
        raise UserError(f"--transfer {text}: not a 'snan-hil transfer' result ({exc})") \
            from None
    if not isinstance(doc, dict) or doc.get("format") != TRANSFER_FORMAT \
            or "summary" not in doc:
        raise UserError(f"--transfer {text}: not a finished 'snan-hil transfer' result "
                        f"({TRANSFER_FORMAT}); run 'snan-hil transfer' to the end")
    doc["path"] = str(path)
    return doc


def _history_of(doc: dict[str, Any]) -> str | None:
    h = (doc.get("history") or {}).get("path")
    return str(Path(h).resolve()) if h else None


def transfers(runs: dict[str, dict[str, Any]], paths: dict[str, Path],
              docs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each transfer's row: source chip (the run it came from), target chip (the run learnt on
    the board it ran on, by the board's history database; else its board id), summary."""
    by_path = {str(p.resolve()): name for name, p in paths.items()}
    by_history = {h: name for name, d in runs.items() if (h := _history_of(d)) is not None}
    rows: list[dict[str, Any]] = []
    seen: dict[tuple[Any, Any], str] = {}
    for t in docs:
        source = by_path.get(str(Path(t["source"]).resolve()), t["source"])
        hist = ((t.get("session") or {}).get("files") or {}).get("history")
        target = by_history.get(str(Path(hist).resolve())) if hist else None
        if target is not None and target == source:       # the claim is about another chip
            raise UserError(f"--transfer {t['path']}: the weights of {source} tested on the "
                            f"chip {source} learnt on, not on another chip; give transfers "
                            "onto another chip's board ('snan-hil transfer RUN --port' of "
                            "another chip)")
        pair = (source, target or t.get("board_id"))
        if pair in seen:                            # one transfer per ordered pair of chips
            raise UserError(f"--transfer {t['path']}: {pair[0]} -> {pair[1]} is also "
                            f"--transfer {seen[pair]}; give one transfer per ordered pair "
                            "of chips")
        seen[pair] = t["path"]
        rows.append({**t["summary"], "source": source,
                     "target": pair[1], "file": t["path"],
                     "seed": t.get("seed")})
    return rows


def run(args: argparse.Namespace) -> int:
    _check(args)
    runs: dict[str, dict[str, Any]] = {}
    paths: dict[str, Path] = {}
    for text in args.runs:
        doc, path = load_learn_run(text)
        name = _label(path)
        if name in runs or path.resolve() in {p.resolve() for p in paths.values()}:
            raise UserError(f"RUN {text}: given twice (or two runs in folders named {name!r}); "
                            "give each chip's run once, in folders of their own names")
        runs[name], paths[name] = doc, path
    reads = {f"RUN {p}": p for p in paths.values()}
    reads.update({f"--transfer {text}": text for text in args.transfer})
    out = Outputs(reads, force=args.force).file("-o", args.output, KIND) \
        if args.output else None
    pairs = [paired_at(doc, args.cycle, name, args.sessions) for name, doc in runs.items()]
    if len({p.cycle for p in pairs}) != 1:
        raise UserError("the runs end at different cycles; give --cycle")
    result = analyse(pairs, args.margin, args.alpha, args.power)
    result["transfer"] = transfers(runs, paths, [_load_transfer(t) for t in args.transfer])
    result.update(format=FORMAT, version=__version__, power_target=args.power,
                  first_sessions=args.sessions,
                  runs={n: {"path": str(paths[n]), "seed": d["config"]["seed"],
                            "sessions": d["config"]["sessions"], "config": d["config"],
                            "version": d.get("version"),
                            "history": (d.get("history") or {}).get("path")}
                        for n, d in runs.items()})
    if out is not None:
        atomic_write_json(out, result, indent=1, allow_nan=False)
    if args.json:
        print(json.dumps(result))
    else:
        for line in report_lines(result):
            console.print(line, highlight=False, soft_wrap=True)
    return 0


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.0f} %"


def route_line(name: str, row: dict[str, Any], margin: float) -> str:
    """One line per chip: the route ratio with its interval, the TOST verdict, the power."""
    r = row.get("route")
    if r is None:
        return f"{name}: no route TOST ({row.get('route_note')})"
    lo, hi = r["ratio_ci"]
    pw = row["power"]
    verdict = "equivalent" if r["equivalent"] else "equivalence not shown"
    return (f"{name}: route chip/software {r['ratio']:.3f} [{100 * (1 - 2 * r['alpha']):.0f} "
            f"% CI {lo:.3f}, {hi:.3f}] over {r['n']} route pairs vs +-{100 * margin:.0f} % "
            f"[{r['bounds'][0]:.3f}, {r['bounds'][1]:.3f}]: {verdict} (TOST p = {r['p']:.3g}); "
            f"sd of ln ratio {pw['sd_log']:.3f}: {pw['route_pairs_needed']} route pairs "
            f"(~{pw['sessions_needed']} sessions) for {100 * pw['power']:.0f} % power at "
            f"+-{100 * margin:.0f} %; these {r['n']} allow +-{100 * pw['margin_allowed']:.0f} %")


def success_line(name: str, row: dict[str, Any]) -> str:
    s = row["success"]
    return (f"{name}: success chip {_pct(s['chip'])} vs software {_pct(s['software'])} "
            f"({s['sessions']} sessions): difference {100 * s['difference']:+.1f} points "
            f"[{100 * s['confidence']:.0f} % CI {100 * s['ci'][0]:+.1f}, "
            f"{100 * s['ci'][1]:+.1f}]; {s['chip_only']} sessions only the chip solved, "
            f"{s['software_only']} only software (McNemar exact p = {s['mcnemar_p']:.2f})")


def report_lines(result: dict[str, Any]) -> list[str]:
    """The printed report: per chip and pooled the route and success lines, the transfers,
    then the verdicts."""
    margin = result["margin"]
    lines = [f"chip vs software at cycle {result['cycle']} (paired sessions; route on the "
             f"log scale, TOST at alpha {result['alpha']:g}):"]
    for name, row in result["chips"].items():
        lines += [route_line(name, row, margin), success_line(name, row)]
    for t in result["transfer"]:
        lines.append(f"transfer {t['source']} -> {t['target']}: success {_pct(t['target_success'])}"
                     f" vs {_pct(t['source_success'])} on {t['source']} (kept "
                     f"{_pct(t['kept'])}; difference {100 * t['difference']:+.1f} points "
                     f"[90 % CI {100 * t['ci'][0]:+.1f}, {100 * t['ci'][1]:+.1f}]; "
                     f"{t['lost']} lost, {t['gained']} gained)")
    return lines + verdict_lines(result)


def verdict_lines(result: dict[str, Any]) -> list[str]:
    """One line per claim: the chip keeps the software route (pooled TOST, else the one
    chip's), within the margin; the weights transfer (every pair keeps >= 90 %)."""
    chips = result["chips"]
    name = "pooled" if "pooled" in chips else next(iter(chips))
    row, margin = chips[name], result["margin"]
    r = row.get("route")
    out = []
    if r is not None:
        lo, hi = r["ratio_ci"]
        verdict = "reproduced (equivalent)" if r["equivalent"] else (
            "not reproduced (a difference beyond the margin)" if hi < r["bounds"][0]
            or lo > r["bounds"][1] else "undecided (the interval crosses the margin)")
        out.append(f"learning on the chip keeps the software route at cycle {result['cycle']} "
                   f"(Conclusions, 'equivalent task performance'): {name} ratio "
                   f"{r['ratio']:.3f} [{lo:.3f}, {hi:.3f}] within +-{100 * margin:.0f} %: "
                   f"{verdict}; margin this run can show: "
                   f"+-{100 * row['power']['margin_allowed']:.0f} %")
    ts = result.get("transfer") or []
    if ts:
        kept = [t["kept"] for t in ts if t["kept"] is not None]
        worst = min(kept) if kept else math.nan
        met = all(t["met"] for t in ts)
        out.append(f"weights learnt on one chip keep >= {100 * TRANSFER_TARGET:.0f} % of its "
                   f"success on another: {len(ts)} ordered pairs, least kept "
                   f"{_pct(worst if kept else None)}: {'met' if met else 'not met'}")
    return out
