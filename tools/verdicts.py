"""The one printer of the paper's claims a command tested (:mod:`snan_hil.host.claims`): the
last lines of ``demo``, ``compare``, ``experiment`` and ``learn``, one line per claim: the
claim, the paper's numbers, ours with their 95 % intervals, and the verdict in colour
(reproduced / direction reproduced, not the size / not reproduced / undecided). With
``--json`` the lines go to stderr (stdout holds the one JSON object)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from rich.markup import escape

from snan_hil.host.claims import REPRODUCED, UNDECIDED, Verdict, verdicts
from snan_hil.tools.console import console, err_console

__all__ = ["print_verdicts", "verdict_lines"]

_STYLE = {REPRODUCED: "green", UNDECIDED: "yellow"}


def verdict_lines(command: str, result: Mapping[str, Any]) -> list[str]:
    """The lines :func:`print_verdicts` prints, as plain text."""
    return [v.line() for v in verdicts(command, result)]


def print_verdicts(command: str, result: Mapping[str, Any], *, json_mode: bool = False
                   ) -> list[Verdict]:
    """Print one line per paper claim ``command``'s ``result`` tests, under a one-line
    heading; returns the verdicts. Nothing is printed when it tests none."""
    found = verdicts(command, result)
    if not found:
        return found
    out = err_console if json_mode else console
    n_ok = sum(v.reproduced for v in found)
    out.print(f"the paper's claims this run tested: {n_ok} of {len(found)} reproduced "
              "(95 % intervals; the tests: docs/experiments.md, 'Verdicts')",
              highlight=False, soft_wrap=True)
    for v in found:
        style = _STYLE.get(v.verdict, "red" if v.verdict.startswith("not") else "yellow")
        note = f" ({v.note})" if v.note else ""
        out.print(f"{escape(v.head())}: [bold {style}]{v.verdict}[/]{escape(note)}",
                  highlight=False, soft_wrap=True)
    return found
