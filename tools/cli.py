"""Entry point of the ``snan-hil`` command.

Sub-commands are discovered from :mod:`snan_hil.tools.commands`: every module there that
defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int`` becomes one
sub-command. User errors (:class:`snan_hil.errors.UserError`) are printed as one line on
stderr with exit code 2; Ctrl-C exits with 130.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import pkgutil
import sys
from types import ModuleType

from snan_hil import __version__
from snan_hil.errors import UserError
from snan_hil.tools import commands as commands_pkg

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130


def discover_commands() -> list[ModuleType]:
    """Import every sub-command module, sorted by command name."""
    found = []
    for info in pkgutil.iter_modules(commands_pkg.__path__):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{commands_pkg.__name__}.{info.name}")
        if all(hasattr(module, attr) for attr in ("NAME", "HELP", "add_arguments", "run")):
            found.append(module)
    return sorted(found, key=lambda m: m.NAME)


class HelpFormatter(argparse.HelpFormatter):
    """Appends "(default: X)" to an option's help once, and only where it says something: not
    when the help already states its default, nor for None (the help says in words what
    happens then), flags, required options, positionals or repeatable options."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if ("default" in text or not action.option_strings or action.required
                or default is None or default is argparse.SUPPRESS or default == []
                or isinstance(action, (argparse._StoreTrueAction, argparse._StoreFalseAction,
                                       argparse._CountAction))):
            return text
        return text + " (default: %(default)s)"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="snan-hil",
        description="Spiking neuron-astrocyte navigation agent on memristor hardware.",
    )
    parser.add_argument("--version", action="version", version=f"snan-hil {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="more log output (-v info, -vv debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", title="commands")
    for module in discover_commands():
        p = sub.add_parser(module.NAME, help=module.HELP, description=module.HELP,
                           formatter_class=HelpFormatter)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except UserError as exc:                 # an option of an earlier version (its new name)
        print(f"{getattr(exc, 'prog', parser.prog)}: error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    if not getattr(args, "_run", None):
        parser.print_help()
        return EXIT_USER_ERROR
    try:
        return int(args._run(args) or 0)
    except UserError as exc:
        print(f"snan-hil {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print(f"snan-hil {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
