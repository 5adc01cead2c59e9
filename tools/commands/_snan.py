"""Shared CLI options of the SNAN commands (``sim``, ``demo``): preset / config file,
grid size, astrocytes on/off, step limit and ``--set`` overrides."""

from __future__ import annotations

import argparse
import re

from snan_hil.common.errors import UserError
from snan_hil.host.config import SnanConfig, apply_overrides, load_config
from snan_hil.host.reading_presets import DEFAULT_READING, load_reading, names
from snan_hil.tools.commands._options import add_set_option, check_set_conflicts


def add_model_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--grid", metavar="N|MxK", default=None,
                        help="grid size; 3 and 10 select the paper's presets "
                             "(configs/snan-3x3.yaml, snan-10x10.yaml), other sizes use the "
                             "10x10 parameters (default: from --config, else 3)")
    parser.add_argument("--astro", action=argparse.BooleanOptionalAction, default=None,
                        help="with / without astrocytes (default: from the config: with)")
    parser.add_argument("--max-steps", type=int, default=None,
                        help="trial step limit (default: from the config; 100 for 3x3, "
                             "1000 for 10x10)")
    parser.add_argument("--config", metavar="FILE", default=None,
                        help="YAML configuration file (see configs/; default: the preset of "
                             "--grid)")
    add_reading_option(parser)
    add_set_option(parser)


def add_reading_option(parser: argparse.ArgumentParser) -> None:
    """``--reading NAME``: a named reading of the paper's open points (configs/readings/)."""
    parser.add_argument("--reading", default=DEFAULT_READING, metavar="NAME",
                        help=f"named reading of the paper's open points: {', '.join(names())} "
                             f"(default {DEFAULT_READING}: the readings sweep's choice; "
                             "paper-literal: state carried across windows, STDP in the trial "
                             "on every candidate; docs/model.md). Applied before --set")


def reading_overrides(args: argparse.Namespace) -> list[str]:
    """The ``--set`` texts of ``--reading`` (refused, one line, when a --set or an option gives
    one of its keys another value)."""
    preset = load_reading(getattr(args, "reading", "scored"))
    check_set_conflicts(args.overrides, {k: (f"--reading {preset.name}", v)
                                         for k, v in preset.overrides.items()})
    return preset.assignments()


def parse_grid(text: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(-?\d+)\s*(?:[xX]\s*(-?\d+)\s*)?", text)
    if not m:
        raise UserError(f"--grid {text!r}: expected N or MxK, e.g. 3 or 10x10")
    rows = int(m.group(1))
    cols = int(m.group(2)) if m.group(2) is not None else rows
    if rows < 1 or cols < 1:
        raise UserError(f"--grid {text!r}: sizes must be positive")
    return rows, cols


def model_options(args: argparse.Namespace) -> dict[str, tuple[str, object]]:
    """The config keys that --grid / --astro / --max-steps name, as given: ``{dotted key:
    (option text, value)}`` (for :func:`check_set_conflicts`)."""
    named: dict[str, tuple[str, object]] = {}
    if args.grid is not None:
        rows, cols = parse_grid(args.grid)
        named["grid.rows"] = (f"--grid {args.grid}", rows)
        named["grid.cols"] = (f"--grid {args.grid}", cols)
    if getattr(args, "astro", None) is not None:
        named["astro.enabled"] = ("--astro" if args.astro else "--no-astro", bool(args.astro))
    if getattr(args, "max_steps", None) is not None:
        named["grid.max_steps"] = (f"--max-steps {args.max_steps}", args.max_steps)
    return named


def config_from_args(args: argparse.Namespace) -> SnanConfig:
    """Preset or file, then --grid / --astro / --max-steps, then --set overrides; an option
    and a --set naming the same key with different values are refused (UserError)."""
    size = parse_grid(args.grid) if args.grid is not None else None
    check_set_conflicts(args.overrides, model_options(args))
    if args.config is not None:
        cfg = load_config(args.config)
    elif size is None or size == (3, 3):
        cfg = load_config(preset="snan-3x3")
    else:
        cfg = load_config(preset="snan-10x10")
    extra: list[str] = []
    if size is not None:
        extra += [f"grid.rows={size[0]}", f"grid.cols={size[1]}"]
        if args.config is None and size not in ((3, 3), (10, 10)):
            cfg = apply_overrides(cfg, [f"name=snan-{size[0]}x{size[1]}"])
    if args.astro is not None:
        extra.append(f"astro.enabled={'true' if args.astro else 'false'}")
    if args.max_steps is not None:
        extra.append(f"grid.max_steps={args.max_steps}")
    return apply_overrides(cfg, reading_overrides(args) + extra + list(args.overrides))
