"""Entry point of the ``snan-hil`` command.

Sub-commands are discovered from :mod:`snan_hil.tools.commands`: every module there that
defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int`` becomes one
sub-command. Exit statuses (README "Command line", docs/outputs.md "Exit status"):

* 0: done; 1: the job finished, with failures it reports (cells not programmed, ...);
* 2: a user mistake (:class:`snan_hil.common.errors.UserError`: bad option, bad file, a port
  that cannot be opened) or a file-system error naming a file (a full disk, say): one line;
* 3: the board or its link failed (:class:`snan_hil.common.errors.BoardLinkError`: no answer,
  a garbled line, a reset, the port gone mid-command): one line naming the port and what to
  check, and how to continue a resumable run;
* 130: Ctrl-C; SIGTERM and SIGHUP interrupt a command like Ctrl-C does (its clean-up runs:
  temporary files are removed, an interrupted programming run writes its report), 128 +
  signal;
* 141: a reader closed stdout early (``... --json | head``): the command ends quietly, as
  SIGPIPE would.
"""

from __future__ import annotations

import argparse
import importlib
import io
import logging
import os
import pkgutil
import shlex
import signal
import sys
import threading
import typing
from collections.abc import Callable
from types import ModuleType

from snan_hil.common.version import __version__
from snan_hil.common.errors import BoardLinkError, UserError
from snan_hil.host.checkpoint import discard_unstarted, forget_opened, unfinished_runs
from snan_hil.protocol.errors import BoardResetError, InternalBoardError
from snan_hil.tools import commands as commands_pkg
from snan_hil.tools.commands._run import (SOFTWARE_COMMANDS, add_run_metadata_options,
                                          software_run)
from snan_hil.tools.ports import resolve_port

EXIT_USER_ERROR = 2
EXIT_BOARD_OR_LINK = 3
"""The board or the link to it failed (:class:`BoardLinkError`), not the command."""
EXIT_BROKEN_PIPE = 128 + 13


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


class Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line (the problem, and where the help
    is) instead of the whole usage block before it; exit code 2 as argparse's. The
    sub-command parsers are of this class too (``add_subparsers`` takes the parent's)."""

    def error(self, message: str) -> typing.NoReturn:
        self.exit(EXIT_USER_ERROR, f"{self.prog}: error: {message}; see '{self.prog} --help'\n")


class Terminated(KeyboardInterrupt):
    """SIGTERM / SIGHUP during a command: handled like Ctrl-C (``except KeyboardInterrupt``
    clean-up runs), exit code 128 + the signal number."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def _terminate_like_ctrl_c() -> Callable[[], None]:
    """Make SIGTERM and SIGHUP raise :class:`Terminated`; returns the function restoring the
    previous handlers (a no-op outside the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None

    def interrupt(signum: int, frame: object) -> None:
        raise Terminated(signum)

    previous = {}
    for name in ("SIGTERM", "SIGHUP"):
        sig = getattr(signal, name, None)
        if sig is not None and signal.getsignal(sig) == signal.SIG_DFL:
            previous[sig] = signal.signal(sig, interrupt)

    def restore() -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return restore


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
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
        if module.NAME in SOFTWARE_COMMANDS:
            add_run_metadata_options(p)
        p.set_defaults(_run=module.run)
    return parser


MAX_SEED = 2**63 - 1
"""Largest ``--seed`` of any command: SQLite's INTEGER (the history's run record) holds 64-bit
signed values; larger seeds were accepted, pulsed the chip, then failed to be recorded."""


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args, extra = parser.parse_known_args(argv)
        if extra:            # named by the sub-command they were given to, not the top level
            prog = f"{parser.prog} {args.command}" if getattr(args, "command", None) \
                else parser.prog
            parser.exit(EXIT_USER_ERROR, f"{prog}: error: unrecognized arguments: "
                                         f"{' '.join(extra)}; see '{prog} --help'\n")
    except UserError as exc:                 # an option of an earlier version (its new name)
        print(f"{getattr(exc, 'prog', parser.prog)}: error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    if not getattr(args, "_run", None):
        parser.print_help()
        return EXIT_USER_ERROR
    args._argv = list(sys.argv[1:] if argv is None else argv)   # recorded with a run
    seed = getattr(args, "seed", None)
    if isinstance(seed, int) and seed > MAX_SEED:    # the history stores it as SQLite INTEGER
        print(f"snan-hil {args.command}: error: --seed {seed}: at most {MAX_SEED} (2**63 - 1, "
              "what the run's record can hold); give a smaller seed", file=sys.stderr)
        return EXIT_USER_ERROR
    restore = _terminate_like_ctrl_c()
    forget_opened()                         # the runs of this command only
    try:
        if getattr(args, "boards", None) is None and getattr(args, "dask", None) is None:
            resolve_port(args, lambda line: print(f"snan-hil {args.command}: note: {line}",
                                                  file=sys.stderr))   # one board
        if args.command in SOFTWARE_COMMANDS:
            with software_run(args):
                return int(args._run(args) or 0)
        return int(args._run(args) or 0)
    except BoardLinkError as exc:
        discard_unstarted()         # a new run's checkpoint with nothing done: as before
        return _ended(args, board_or_link_line(args, exc), EXIT_BOARD_OR_LINK)
    except UserError as exc:
        discard_unstarted()         # a new run's checkpoint with nothing done: as before
        print(f"snan-hil {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except BrokenPipeError:
        return _reader_went_away()
    except KeyboardInterrupt as exc:
        signum = getattr(exc, "signum", signal.SIGINT)
        return _ended(args, f"snan-hil {args.command}: {_interruption(exc, signum)}",
                      128 + int(signum))
    except OSError as exc:
        if exc.filename is None:          # not a file: a bug or an unexpected failure
            raise
        logging.getLogger(__name__).debug("file error", exc_info=True)
        where = f"{exc.filename}" + (f" -> {exc.filename2}" if exc.filename2 else "")
        print(f"snan-hil {args.command}: error: {exc.strerror or exc}: {where}",
              file=sys.stderr)
        return EXIT_USER_ERROR
    finally:
        restore()


def _ended(args: argparse.Namespace, line: str, code: int) -> int:
    """Print ``line`` and, when the command left a run it can continue, how; ``code``."""
    print(line, file=sys.stderr)
    hint = resume_hint(args)
    if hint:
        print(f"snan-hil {args.command}: {hint}", file=sys.stderr)
    return code


def _interruption(exc: KeyboardInterrupt, signum: int) -> str:
    if type(exc).__name__ == "StopRequested":           # records.control: from snan-hil watch
        return f"{exc} before the next pulse; the run is recorded as interrupted"
    return "interrupted" if signum == signal.SIGINT else f"stopped by {exc}"


def board_or_link_line(args: argparse.Namespace, exc: BoardLinkError) -> str:
    """The one line of a board or link failure: the port (unless the message names it) and
    what to check (unless the message says it)."""
    text = str(exc)
    port = getattr(args, "port", None)
    where = f" (--port {port})" if port and str(port) not in text else ""
    advice = next((a for kind, a in _BOARD_ADVICE if isinstance(exc, kind)), None)
    if advice is None and not any(word in text for word in ("check", "update", "wait")):
        advice = "check the board's power, cable and port"
    return (f"snan-hil {args.command}: board or link failed{where}: {text}"
            + (f"; {advice}" if advice else ""))


_BOARD_ADVICE = (
    (BoardResetError, "the board restarted during the command: check its power supply, then "
                      "run the command again"),
    (InternalBoardError, "the board's firmware failed: power the board off and on, then run "
                         "the command again"),
)
"""What to check after a failure whose message speaks to a program, not to the user."""


def resume_hint(args: argparse.Namespace) -> str | None:
    """After an interrupt: how to continue the run the command left in its ``--out`` (its
    checkpoint, :func:`snan_hil.host.checkpoint.unfinished_runs`), None when it opened none."""
    if not unfinished_runs():
        return None
    argv = list(getattr(args, "_argv", []))
    if "--resume" not in argv:
        argv.append("--resume")
    return "to continue where it stopped: snan-hil " + shlex.join(argv)


def _reader_went_away() -> int:
    """The reader of stdout closed it (``snan-hil ... --json | head``): exit quietly like a
    program killed by SIGPIPE (128 + 13), pointing stdout at /dev/null so the interpreter's
    final flush does not complain."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, io.UnsupportedOperation):  # stdout is no file (tests)
        pass
    return EXIT_BROKEN_PIPE


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
