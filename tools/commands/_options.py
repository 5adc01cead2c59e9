"""Command-line options shared by several commands, one name per meaning.

* ``--set KEY=VALUE``: a config override, on every command that has a model config
  (repeatable; each VALUE is read for its field's type, :mod:`snan_hil.config.loader`).
* ``--weight-set K``: the index of a weight set in a weights file.
* ``--workers N`` / ``--dask ADDR``: where the trials of a sweep run (experiment, readings).

Spellings of earlier versions (``--override``; ``--set K`` for a weight set; ``--only``) give
one line naming the new option instead of being taken for something else.
"""

from __future__ import annotations

import argparse
import re
from collections.abc import Mapping, Sequence
from typing import Any

from snan_hil.common.errors import UserError
from snan_hil.config.loader import parse_assignments
from snan_hil.host.config import RENAMED, SnanConfig
from snan_hil.protocol.board import MEMRICORE

__all__ = ["OptionError", "accept_negative_cells", "add_conversions_option",
           "add_executor_options", "add_mode_option",
           "add_set_option",
           "add_weight_set_option", "add_renamed_option", "check_executor_options",
           "check_set_conflicts", "parse_cell", "set_values", "value_text"]


class OptionError(UserError):
    """A command-line option given in an earlier version's spelling; ``prog`` names the
    command (``snan-hil run``)."""

    def __init__(self, prog: str, message: str) -> None:
        super().__init__(message)
        self.prog = prog


class _SetAction(argparse._AppendAction):
    """``--set KEY=VALUE`` (appended); a bare integer is the old weight-set spelling."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        text = str(values)
        if ("=" not in text and text.strip().lstrip("+-").isdigit()
                and "--weight-set" in parser._option_string_actions):
            raise OptionError(parser.prog,
                              f"--set {text}: a weight set is chosen with --weight-set "
                              f"{text.strip()} now; --set takes config overrides KEY=VALUE")
        super().__call__(parser, namespace, values, option_string)


class _RenamedAction(argparse.Action):
    """A hidden option of an earlier version: one line naming its new spelling."""

    def __init__(self, option_strings: Sequence[str], dest: str, *, new: str,
                 **kwargs: Any) -> None:
        self.new = new
        super().__init__(option_strings, dest, nargs="?", help=argparse.SUPPRESS,
                         default=argparse.SUPPRESS)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        given = f"{option_string} {values}" if values is not None else str(option_string)
        raise OptionError(parser.prog, f"{given}: {option_string} is now {self.new}")


class _OldSetAction(_RenamedAction):
    """``--set`` on a command with a weight set and no config overrides: ``--set K`` is the
    old weight-set spelling; any other value is refused with the same hint."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        text = "" if values is None else str(values)
        if text.strip().lstrip("+-").isdigit() or not text:
            super().__call__(parser, namespace, values, option_string)
        raise OptionError(parser.prog, f"--set {text}: {parser.prog} takes no config overrides "
                                       "(--set KEY=VALUE); a weight set is chosen with "
                                       "--weight-set K")


def add_set_option(parser: argparse.ArgumentParser, *, example: str = "astro.tau_ca_s=1.2",
                   what: str = "override a config value") -> None:
    """``--set KEY=VALUE`` into ``args.overrides`` (a list), plus the old ``--override``."""
    parser.add_argument("--set", dest="overrides", action=_SetAction, default=[],
                        metavar="KEY=VALUE",
                        help=f"{what}, e.g. --set {example} (repeatable; numbers as YAML 1.2 "
                             "reads them)")
    parser.add_argument("--override", action=_RenamedAction, new="--set KEY=VALUE")


def add_weight_set_option(parser: argparse.ArgumentParser, *, help: str,
                          default: int | None = 0, old_set: bool = True) -> None:
    """``--weight-set K`` into ``args.set_index``; ``old_set`` adds a hidden ``--set`` that
    names ``--weight-set`` (for commands without config overrides; a command with them has
    the ``--set`` of :func:`add_set_option`, which gives the same hint for ``--set K``)."""
    parser.add_argument("--weight-set", dest="set_index", type=int, default=default,
                        metavar="K", help=help)
    if old_set:
        parser.add_argument("--set", action=_OldSetAction, new="--weight-set K")


def add_executor_options(parser: argparse.ArgumentParser, *, dask_note: str) -> None:
    """``--workers N`` (default None: all cores) and ``--dask ADDR`` (default None: local
    processes); ``dask_note`` ends the ``--dask`` help, in parentheses."""
    parser.add_argument("--workers", type=int, default=None,
                        help="local worker processes (default: all cores; 1 = serial)")
    parser.add_argument("--dask", metavar="ADDR", default=None,
                        help="run on a Dask distributed scheduler, e.g. tcp://host:8786 "
                             f"({dask_note})")


def check_executor_options(args: argparse.Namespace) -> None:
    """UserError (one line) for ``--workers`` below 1 or given together with ``--dask``."""
    if args.workers is not None and args.workers < 1:
        raise UserError(f"--workers must be >= 1, got {args.workers}")
    if args.dask and args.workers is not None:
        raise UserError("--dask and --workers exclude each other (Dask has its own workers)")


#: help of ``--mode`` (how the hardware scenarios read the synapses)
MODE_HELP = ("how hw scenarios read the synapses: on-board = one DECISION_WINDOW per decision, "
             "the board reads the synapses and runs the motor neurons (current framed "
             "firmware); batch = one SPIKE_BATCH per decision, the host runs the motor neurons; "
             "per-window = each synapse cell read once per decision window (legacy mode 9 / "
             "READ_CELL); per-spike = a fresh read per input spike and synapse (READ_COLUMN, or "
             "mode 9 over legacy; slow); default: on-board on a board with DECISION_WINDOW, "
             "batch on one with SPIKE_BATCH, per-window otherwise (docs/hil.md)")


def add_mode_option(parser: argparse.ArgumentParser, modes: Sequence[str],
                    help: str = MODE_HELP) -> None:
    """``--mode`` of the hardware scenarios: ``modes`` (``HW_MODES``) spelled with dashes,
    default None (chosen from the board's protocol)."""
    parser.add_argument("--mode", choices=[m.replace("_", "-") for m in modes], default=None,
                        help=help)


CONVERSIONS_HELP = (
    "ADC conversions a read of the on-board window (mode on-board): N = the lean read plan, "
    "each read N conversions of the ADC pipeline; 0 = the board's standard reads (ten "
    "averages); default: the board's read plan (WINDOW_CONVERSIONS on a board with the "
    "READ_PLAN capability, the standard reads otherwise; docs/hil.md)")


def add_conversions_option(parser: argparse.ArgumentParser, help: str = CONVERSIONS_HELP) -> None:
    """``--conversions N`` of the on-board window (default None: the board's read plan)."""
    parser.add_argument("--conversions", type=int, default=None, metavar="N", help=help)


def check_conversions(args: argparse.Namespace) -> None:
    """``--conversions N`` checked before any board is opened (UserError, one line): N in
    0..``adc_averages`` of MemriCore (0: the standard ten-average reads, 1..10: the lean
    read plan; a board declaring fewer refuses the rest when opened), and only where the
    on-board decision window runs: not over the legacy line protocol (no window), not with
    another ``--mode``."""
    n = getattr(args, "conversions", None)
    if n is None:
        return
    top = MEMRICORE.adc_averages
    if not 0 <= n <= top:
        raise UserError(f"--conversions {n}: give 0 (the board's standard ten-average reads) "
                        f"or 1..{top} (the lean read plan), or leave it out (the board's "
                        "default plan)")
    if getattr(args, "protocol", None) == "legacy":
        raise UserError("--conversions sets the on-board decision window's reads; the legacy "
                        "line protocol has no such window: leave --conversions out")
    mode = getattr(args, "mode", None)
    if mode is not None and mode.replace("-", "_") != "on_board":
        raise UserError(f"--conversions sets the on-board decision window's reads; --mode "
                        f"{mode} reads the synapses from the host: leave --conversions out, "
                        "or use --mode on-board")


def add_renamed_option(parser: argparse.ArgumentParser, old: str, new: str) -> None:
    """A hidden ``old`` option that fails with one line naming ``new``."""
    parser.add_argument(old, action=_RenamedAction, new=new)


def accept_negative_cells(parser: argparse.ArgumentParser) -> None:
    """Let ``parser`` take a negative-looking cell such as ``-1,0`` as an option's value (then
    :func:`parse_cell` says it is outside the array) instead of argparse's "expected one
    argument" / "unrecognized arguments": argparse takes words that look like negative
    numbers as values when the parser has no option looking like one."""
    parser._negative_number_matcher = re.compile(
        r"^-\d+(,-?\d+)?$|^-\d*\.\d+$")


def parse_cell(text: str, option: str = "--cell", rows: int | None = None,
               cols: int | None = None) -> tuple[int, int]:
    """``"R,C"`` -> (row, col); with ``rows``/``cols`` also inside the array (UserError, one
    line, naming the array's ranges)."""
    parts = str(text).replace(" ", "").split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        row, col = int(parts[0]), int(parts[1])
    except ValueError:
        raise UserError(f"{option} {text!r}: give a cell as ROW,COL (bit line, word line), "
                        "e.g. 3,5") from None
    if rows is not None and cols is not None and not (0 <= row < rows and 0 <= col < cols):
        raise UserError(f"{option} {text}: cell ({row},{col}) is outside the {rows}x{cols} "
                        f"array (rows 0..{rows - 1}, columns 0..{cols - 1})")
    return row, col


def set_values(overrides: Sequence[str]) -> dict[str, Any]:
    """The ``--set`` texts as ``{dotted key: typed value}`` for the SNAN model config, a section
    given as a mapping (``--set grid={rows: 4}``) spread into its dotted keys. Raises
    :class:`~snan_hil.config.loader.ConfigError` for a bad item (the same line the config's
    loading would give)."""
    def spread(key: str, value: Any) -> dict[str, Any]:
        if isinstance(value, dict):
            out: dict[str, Any] = {}
            for k, v in value.items():
                out.update(spread(f"{key}.{k}", v))
            return out
        return {key: value}

    flat: dict[str, Any] = {}
    for key, value in parse_assignments(SnanConfig, overrides, renamed=RENAMED).items():
        flat.update(spread(key, value))
    return flat


def value_text(value: Any) -> str:
    return ("true" if value else "false") if isinstance(value, bool) else str(value)


def check_set_conflicts(overrides: Sequence[str],
                        named: Mapping[str, tuple[str, Any]]) -> None:
    """Refuse an explicit option and a ``--set`` that name the same config key with different
    values (neither silently wins): ``named`` maps a dotted config key to (the option as the
    user gave it, e.g. ``"--max-steps 7"``, the value it gives that key). Equal values are
    fine. Raises :class:`~snan_hil.common.errors.UserError` (one line naming both) before any work.
    """
    if not named or not overrides:
        return
    sets = set_values(overrides)
    for key, (option, value) in named.items():
        if key in sets and not _same(sets[key], value):
            given = value_text(sets[key])
            raise UserError(f"{option} and --set {key}={given} give {key} different values "
                            f"({value_text(value)} vs {given}); give one of them")


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, bool) or isinstance(b, bool):
        return isinstance(a, bool) and isinstance(b, bool) and a == b
    return bool(a == b)
