"""``snan-hil transfer``: the weights a ``learn`` run's chip arm learnt on one chip, programmed
onto this board by write-and-verify and tested there on the run's last test trial
(:mod:`snan_hil.host.hil.transfer`; docs/learning.md section 12).

Examples::

    snan-hil learn --port emu://?state=a.npz --arms software,chip --sessions 30 --seed 11 \\
        --out run-a
    snan-hil transfer run-a --port emu://?state=b.npz -o a-on-b.json
    snan-hil equivalence run-a run-b run-c --transfer a-on-b.json ...

Writes ``-o`` (``snan-hil-transfer/1``: each session's test on this board beside the source
chip's own, the share of its success kept, the source run, seed, config and version).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from snan_hil.common.errors import UserError
from snan_hil.common.version import __version__
from snan_hil.files.atomicio import atomic_write_json
from snan_hil.files.outputs import json_kind
from snan_hil.host.hil.transfer import FORMAT, TransferJob
from snan_hil.tools.commands._board import add_result_options, file_use, plan_from_args
from snan_hil.tools.commands._job import run_on_board
from snan_hil.tools.console import console
from snan_hil.tools.ports import add_port_arguments

NAME = "transfer"
HELP = ("cross-chip transfer: program the weights a learn run's chip arm learnt onto this "
        "board and run the run's last test on it (docs/learning.md section 12)")
KIND = json_kind(FORMAT, "a 'snan-hil transfer' result")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", metavar="RUN",
                        help="a 'snan-hil learn' result: its --out folder or its learn.json "
                             "(the chip arm's learnt weights)")
    parser.add_argument("-o", "--output", default="transfer.json", metavar="FILE",
                        help="the result (JSON; default %(default)s)")
    parser.add_argument("--sessions", type=int, default=None, metavar="N",
                        help="the run's first N sessions only (default: all)")
    parser.add_argument("--layout", default=None,
                        help="layout file of this board's chip (default: the port's)")
    add_port_arguments(parser)
    add_result_options(parser)


def load_learn_run(text: str, option: str = "RUN") -> tuple[dict[str, Any], Path]:
    """The ``learn.json`` of ``text`` (a learn run's folder or the file itself) and its path;
    UserError (one line) when there is none or it is not one."""
    path = Path(text).expanduser()
    if path.is_dir():
        path = path / "learn.json"
    if not path.is_file():
        raise UserError(f"{option} {text}: no learn.json there; give the --out folder of a "
                        "'snan-hil learn' run (or its learn.json)")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise UserError(f"{option} {path}: not a 'snan-hil learn' result ({exc})") from None
    if not isinstance(doc, dict) or not str(doc.get("format", "")).startswith("snan-hil-learn/"):
        raise UserError(f"{option} {path}: not a 'snan-hil learn' result (format "
                        f"{doc.get('format') if isinstance(doc, dict) else None!r})")
    return doc, path


def run(args: argparse.Namespace) -> int:
    doc, source = load_learn_run(args.run)
    job = TransferJob(doc, str(source), first=args.sessions)
    plan = plan_from_args(args, use=file_use(args, updates_layout=True),
                          named={"RUN": str(source)})
    out = plan.outputs.file("-o", args.output, KIND)
    done = run_on_board(args, job, plan, seed=job.learn.lc.seed)
    result = dict(done.result)
    result.update(version=__version__, run=done.run_block(),
                  session=done.session.snapshot(), board_id=done.session.identity.board_id,
                  port=str(args.port))
    atomic_write_json(out, result, indent=1, allow_nan=False)
    s = result.get("summary") or {}
    if args.json:
        print(json.dumps({"output": str(out), "summary": s}))
        return 0
    kept = "-" if s.get("kept") is None else f"{100 * s['kept']:.0f} %"
    console.print(f"transfer of {source} onto {result['board_id']}: {s.get('sessions')} "
                  f"sessions, success {100 * s.get('target_success', 0):.0f} % here vs "
                  f"{100 * s.get('source_success', 0):.0f} % on the source chip (kept {kept}; "
                  f"target >= {100 * s.get('kept_target', 0.9):.0f} %: "
                  f"{'met' if s.get('met') else 'not met'}); written {out}",
                  highlight=False, soft_wrap=True)
    return 0
