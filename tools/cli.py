"""Entry point of the ``snan-hil`` command.

Sub-commands are discovered from :mod:`snan_hil.tools.commands`: every module there that
defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int`` becomes one
sub-command (module ``read_cell`` is command ``read-cell``). Only the module of the command
given is imported (every one for ``--help`` or an unknown command), so a command's start
costs its own imports, not all of them. Exit statuses (README "Command line",
docs/outputs.md "Exit status"):

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

A signal that lands while Python runs an object's finalizer (``__del__``: numba and llvmlite
free compiler objects that way), where an exception would be printed and dropped, is
delivered again just after it; Ctrl-C while the command is still starting (importing) exits
with 130 too.

**An option given twice** is refused in one line (exit 2), on every command: argparse would
keep the last value silently (``--cells 20,0 --cells 20,1`` planned only 20,1). Options meant
to repeat say so by their action (``append``: ``--tag``, ``--vary``; ``--set``; counts:
``-v``) and are not affected; a flag given twice with the same meaning is harmless and taken.
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
from collections.abc import Callable, Sequence
from types import ModuleType
from typing import Any

from snan_hil.common.version import __version__
from snan_hil.common.errors import BoardLinkError, UserError
from snan_hil.host.checkpoint import discard_unstarted, forget_opened, unfinished_runs
from snan_hil.protocol.errors import BoardResetError, InternalBoardError
from snan_hil.tools import commands as commands_pkg

EXIT_USER_ERROR = 2
EXIT_BOARD_OR_LINK = 3
"""The board or the link to it failed (:class:`BoardLinkError`), not the command."""
EXIT_BROKEN_PIPE = 128 + 13
EXIT_INTERRUPTED = 128 + signal.SIGINT


def command_modules() -> list[str]:
    """The names of the sub-command modules (not imported)."""
    return sorted(info.name for info in pkgutil.iter_modules(commands_pkg.__path__)
                  if not info.name.startswith("_"))


def _command_module(name: str) -> ModuleType | None:
    module = importlib.import_module(f"{commands_pkg.__name__}.{name}")
    if all(hasattr(module, attr) for attr in ("NAME", "HELP", "add_arguments", "run")):
        return module
    return None


def discover_commands(only: str | None = None) -> list[ModuleType]:
    """Import the sub-command modules, sorted by command name: every one, or (``only``) the
    one of that command name when there is one."""
    names = command_modules()
    if only is not None and only.replace("-", "_") in names:
        module = _command_module(only.replace("-", "_"))
        if module is not None and module.NAME == only:
            return [module]
    found = [m for m in map(_command_module, names) if m is not None]
    return sorted(found, key=lambda m: m.NAME)


def _command_word(argv: Sequence[str] | None) -> str | None:
    """The sub-command named in ``argv`` (the first word that is not an option of the
    top-level parser), None when there is none."""
    for word in argv or ():
        if word == "--":
            return None
        if not word.startswith("-"):
            return word
    return None


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


_GIVEN: dict[int, dict[str, tuple[str, Any]]] = {}
"""Per namespace being parsed (by id): dest -> (option string, value) of the options given."""
_DEPTH = [0]


def _shown(value: Any) -> str:
    if isinstance(value, (list, tuple)):
        return " ".join(str(v) for v in value)
    return str(value)


def _given_once(base: type[argparse.Action]) -> type[argparse.Action]:
    """``base`` (store, store_const, store_true, store_false) refusing a second value for
    its destination in one command line (module docstring)."""
    class Once(base):  # type: ignore[valid-type, misc]
        def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                     values: Any, option_string: str | None = None) -> None:
            given = _GIVEN.setdefault(id(namespace), {})
            value = values if self.nargs != 0 else self.const
            now = option_string or "/".join(self.option_strings)
            before = given.get(self.dest)
            if before is not None and (self.nargs != 0 or before[1] != value):
                was, old = before
                what = (f"given twice ({was} {_shown(old)}, then {now} {_shown(value)})"
                        if self.nargs != 0 else f"conflicts with {was} given before it")
                raise argparse.ArgumentError(self, f"{what}; an option takes one value: "
                                                   "give it once")
            given[self.dest] = (now, value)
            super().__call__(parser, namespace, values, option_string)
    Once.__name__ = f"Once{base.__name__}"
    return Once


_ONCE = {name: _given_once(cls) for name, cls in (
    ("store", argparse._StoreAction), ("store_const", argparse._StoreConstAction),
    ("store_true", argparse._StoreTrueAction), ("store_false", argparse._StoreFalseAction))}


class Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line (the problem, and where the help
    is) instead of the whole usage block before it; exit code 2 as argparse's. An option
    that takes one value refuses a second one (module docstring). The sub-command parsers
    are of this class too (``add_subparsers`` takes the parent's)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        for name, cls in _ONCE.items():
            self.register("action", name, cls)
        self.register("action", None, _ONCE["store"])

    def error(self, message: str) -> typing.NoReturn:
        self.exit(EXIT_USER_ERROR, f"{self.prog}: error: {message}; see '{self.prog} --help'\n")

    def parse_known_args(self, args: Sequence[str] | None = None,  # type: ignore[override]
                         namespace: Any = None) -> tuple[argparse.Namespace, list[str]]:
        if _DEPTH[0] == 0:
            _GIVEN.clear()
        _DEPTH[0] += 1
        try:
            return super().parse_known_args(args, namespace)
        finally:
            _DEPTH[0] -= 1
            if _DEPTH[0] == 0:
                _GIVEN.clear()


class Terminated(KeyboardInterrupt):
    """SIGTERM / SIGHUP during a command: handled like Ctrl-C (``except KeyboardInterrupt``
    clean-up runs), exit code 128 + the signal number."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


REDELIVER_S = 0.05
"""A signal that landed in a finalizer is sent again every this long (s) until it lands
outside one."""


def _in_finalizer(frame: Any) -> bool:
    """Whether ``frame`` (where a signal handler interrupted Python) runs inside an object's
    ``__del__`` or a weakref finalizer: an exception raised there is printed as "Exception
    ignored in ..." and dropped, and the command would go on."""
    while frame is not None:
        code = frame.f_code
        if code.co_name == "__del__" or (code.co_name in ("__call__", "_exitfunc")
                                         and code.co_filename.endswith("weakref.py")):
            return True
        frame = frame.f_back
    return False


def _terminate_like_ctrl_c() -> Callable[[], None]:
    """Make SIGTERM and SIGHUP raise :class:`Terminated` (and SIGINT its KeyboardInterrupt)
    outside finalizers (:func:`_in_finalizer`: there the signal is sent again
    :data:`REDELIVER_S` later); returns the function restoring the previous handlers (a
    no-op outside the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None

    pending: set[int] = set()

    def again(signum: int) -> None:          # until the handler runs outside a finalizer
        while signum in pending:
            os.kill(os.getpid(), signum)
            threading.Event().wait(REDELIVER_S)

    def interrupt(signum: int, frame: Any) -> None:
        if _in_finalizer(frame):
            if signum not in pending:
                pending.add(signum)
                threading.Thread(target=again, args=(signum,), daemon=True).start()
            return
        pending.discard(signum)
        if signum == signal.SIGINT:
            raise KeyboardInterrupt
        raise Terminated(signum)

    previous = {}
    for name in ("SIGTERM", "SIGHUP", "SIGINT"):
        sig = getattr(signal, name, None)
        default = signal.default_int_handler if name == "SIGINT" else signal.SIG_DFL
        if sig is not None and signal.getsignal(sig) == default:
            previous[sig] = signal.signal(sig, interrupt)

    def restore() -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return restore


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The ``snan-hil`` parser: with ``argv``, of the command it names only (every command's
    when it names none or an unknown one)."""
    from snan_hil.tools.commands._run import SOFTWARE_COMMANDS, add_run_metadata_options
    parser = Parser(
        prog="snan-hil",
        description="Spiking neuron-astrocyte navigation agent on memristor hardware.",
    )
    parser.add_argument("--version", action="version", version=f"snan-hil {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="more log output (-v info, -vv debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", title="commands")
    word = _command_word(argv) if argv is not None else None
    if argv is not None and word is None and "--version" in argv:
        modules: list[ModuleType] = []          # the version needs no command
    else:
        modules = discover_commands(word if word not in (None, "help") else None)
    for module in modules:
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
    """Run ``snan-hil`` with ``argv`` (default: the process's arguments); the exit code."""
    restore = _terminate_like_ctrl_c()
    try:
        return _main(list(sys.argv[1:] if argv is None else argv))
    except KeyboardInterrupt as exc:        # while starting: before the command's own handler
        signum = getattr(exc, "signum", signal.SIGINT)
        what = "interrupted" if signum == signal.SIGINT else f"stopped by {exc}"
        print(f"snan-hil: {what} while starting; nothing was done", file=sys.stderr)
        return 128 + int(signum)
    finally:
        restore()


def _main(argv: list[str]) -> int:
    parser = build_parser(argv)
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
    args._argv = list(argv)                                       # recorded with a run
    seed = getattr(args, "seed", None)
    if isinstance(seed, int) and seed > MAX_SEED:    # the history stores it as SQLite INTEGER
        print(f"snan-hil {args.command}: error: --seed {seed}: at most {MAX_SEED} (2**63 - 1, "
              "what the run's record can hold); give a smaller seed", file=sys.stderr)
        return EXIT_USER_ERROR
    if isinstance(seed, int) and seed < 0:           # numpy's seeds are non-negative
        print(f"snan-hil {args.command}: error: --seed must be a whole number >= 0, got "
              f"{seed}", file=sys.stderr)
        return EXIT_USER_ERROR
    from snan_hil.tools.commands._run import SOFTWARE_COMMANDS, software_run
    from snan_hil.tools.ports import resolve_port, resolve_protocol
    forget_opened()                         # the runs of this command only
    try:
        if all(getattr(args, name, None) is None for name in ("boards", "dask", "group")):
            resolve_port(args, lambda line: print(f"snan-hil {args.command}: note: {line}",
                                                  file=sys.stderr))   # one board
        resolve_protocol(args)
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
        if isinstance(getattr(exc, "exit_code", None), int):   # records.control: unrecordable
            print(f"snan-hil {args.command}: error: {exc}", file=sys.stderr)
            return int(exc.exit_code)                           # type: ignore[attr-defined]
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


def _ended(args: argparse.Namespace, line: str, code: int) -> int:
    """Print ``line`` and, when the command left a run it can continue, how; ``code``."""
    print(line, file=sys.stderr)
    hint = resume_hint(args)
    if hint:
        print(f"snan-hil {args.command}: {hint}", file=sys.stderr)
    return code


def _interruption(exc: KeyboardInterrupt, signum: int) -> str:
    cause = getattr(exc, "cause", exc)                 # the job runner's JobInterrupted
    if type(cause).__name__ == "StopRequested":         # records.control: from snan-hil watch
        return f"{cause} before the next pulse; the run is recorded as interrupted"
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
