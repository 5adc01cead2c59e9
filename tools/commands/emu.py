"""``snan-hil emu``: run the MemriCore board emulator on a pseudo-terminal or a TCP socket."""

from __future__ import annotations

import argparse
import os
import signal
import socket
import sys
import threading
import time
from pathlib import Path

from snan_hil.common.errors import UserError
from snan_hil.firmware_emu import durable, state
from snan_hil.firmware_emu.emulator import Emulator
from snan_hil.firmware_emu.faults import BoardFaults, parse_faults
from snan_hil.firmware_emu.journal import journal_path
from snan_hil.files.outputs import Outputs
from snan_hil.firmware_emu.server import (DEFAULT_IDLE_TIMEOUT_S, PtyServer, TcpServer,
                                          listening_socket, parse_host_port)
from snan_hil.lab.chips import forget_chip_layouts, register_served_chip
from snan_hil.tools.console import console, err_console
from snan_hil.tools.output_kinds import CHIP_STATE, add_force_option

NAME = "emu"
HELP = "run the MemriCore board emulator on a pseudo-terminal (or TCP) until Ctrl-C or SIGTERM"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    env = os.environ.get(state.STATE_ENV)
    now = f" (now {env})" if env else ""
    parser.add_argument("--socket", metavar="HOST:PORT", default=None,
                        help="serve TCP on HOST:PORT instead of a pty (pyserial: "
                             "socket://HOST:PORT); port 0 picks a free one (default: a pty)")
    parser.add_argument("--protocol", choices=("framed", "legacy"), default="framed",
                        help="framed (this project's protocol) or legacy (the old ASCII line "
                             "protocol, for the existing host software)")
    parser.add_argument("--state", metavar="CHIP.npz", default=None,
                        help="chip state file, loaded if it exists (with its journal, "
                             "CHIP.npz.journal) and kept durable; default: "
                             "the chip of '--port emu', i.e. "
                             f"${state.STATE_ENV}{now} if set, else "
                             f"{_home(state.user_state_path())}%(default).0s")
    parser.add_argument("--device", metavar="MODEL.json", default=None,
                        help="emulate the chip of a fitted device model ('snan-hil characterize "
                             "--model', or --from a lab's pulse CSV): the measured device made "
                             "physical, each measured cell at its place, the rest drawn from "
                             "the measured spread; kept in its own chip file (twins/ in the "
                             "user's data folder) unless --state names one "
                             "(docs/crossbar_model.md section 7; default: none, the packaged "
                             "YSZ chip)")
    parser.add_argument("--seed", type=int, default=None,
                        help="seed of a newly created chip and of the ADC noise "
                             "(default 0)%(default).0s")
    parser.add_argument("--baud", type=int, default=115200,
                        help="UART rate used for the virtual clock (a pty has no real rate)")
    parser.add_argument("--mcu", choices=("model", "firmware"), default="model",
                        help="MCU of the emulated board: the Python firmware model, or the C "
                             "firmware ELF (build/firmware/snan-fw.elf, 'make firmware') run "
                             "instruction by instruction on an emulated MIK32")
    parser.add_argument("--legacy-refusals", action="store_true",
                        help="with --protocol legacy: answer a request the board cannot execute "
                             "with -CODE,id (this project's extension; the existing firmware "
                             "sends nothing). Clients must opt in too (--legacy-refusals)")
    parser.add_argument("--wall-scale", type=float, default=None, metavar="S",
                        help="hold each reply until S x the board time of its request (virtual "
                             "time without the UART) has passed in wall time: 1 = real time, so "
                             "a mode-7 pulse is answered after the pulse; 0 = at once "
                             "(default: 1 for legacy, 0 for framed)")
    parser.add_argument("--idle-timeout", type=float, default=DEFAULT_IDLE_TIMEOUT_S,
                        metavar="SECONDS",
                        help="with --socket: disconnect the served client after this many "
                             "seconds without a request, so the next one can be served (0: "
                             "never; default %(default)g). Other clients meanwhile are told at "
                             "once that the board is busy")
    parser.add_argument("--reset-chip", action="store_true",
                        help="replace the chip state file (--state or the default) by a fresh "
                             "chip from --seed (a new chip id), forget the old chip's layouts "
                             "(its history database is kept, renamed after the old chip), then "
                             "exit")
    parser.add_argument("--spread", type=float, default=None, metavar="X",
                        help="with --reset-chip: the new chip's device-to-device spread, X "
                             "times the packaged sigmas (configs/device-ysz.yaml variability; "
                             "default 1): chips that differ, e.g. to test a result across "
                             "chips (docs/learning.md section 12)")
    parser.add_argument("--sync", choices=("interval", "request"), default="interval",
                        help="when the chip's journal is fsync'ed: at most once a second "
                             "(interval; a kill of the emulator loses nothing either way) or "
                             "before every reply that changed the chip (request: also safe "
                             "against power loss, ~4 ms per pulse)")
    parser.add_argument("--fault", action="append", default=None, metavar="SPEC",
                        help="make the emulated board faulty, for tests and demos (repeatable): "
                             "adc-stuck-bit[:BIT:VALUE], gain[:FACTOR], swap-col-lines[:A:B], "
                             "slow-dac[:DACk:TAU_US], uart-drop[:P], dead-cells[:R0-R1:C0-C1] "
                             "(docs/emulator.md, 'Faulty boards')")
    add_force_option(parser)


def _home(path) -> str:
    text = str(path)
    home = os.path.expanduser("~")
    return "~" + text[len(home):] if text.startswith(home + os.sep) else text


def run(args: argparse.Namespace) -> int:
    _check_options(args)
    faults = parse_faults(args.fault)
    address = parse_host_port(args.socket) if args.socket else None
    path, device = _chip_of(args)
    seed = 0 if args.seed is None else args.seed
    if args.reset_chip or not path.is_file() or CHIP_STATE.owns(path):
        # the chip is saved there (a file that is not a chip: the emulator refuses to load it)
        Outputs(force=args.force).file("--state", path, CHIP_STATE, updates=True,
                                       create_folder=state.made_by_us(path))
    if args.reset_chip:
        return _reset_chip(path, seed, device,
                           1.0 if args.spread is None else float(args.spread))

    # the address is taken before the chip file is made: a refused one leaves nothing behind
    listener = listening_socket(*address) if address is not None else None
    existed = path.exists()
    emu = Emulator(path, seed, protocol=args.protocol, baud=args.baud, mcu=args.mcu,
                   sync=args.sync, legacy_refusals=args.legacy_refusals,
                   wall_scale=args.wall_scale, faults=faults, device=device)
    server = _server(args, emu, address, listener)
    where = server.url if isinstance(server, TcpServer) else server.slave_path
    _print_serving(args, emu, faults, where)
    if emu.chip_serial:                  # hosts find this chip's layout and history beside it
        register_served_chip(emu.chip_serial, path, served_on=str(where))
    console.print(f"chip state: {_loaded(emu, existed, device)} {path}; chip "
                  f"{emu.chip_serial}, boot {emu.boot_number}", highlight=False, soft_wrap=True)
    console.print("press Ctrl-C to stop", style="dim")
    sys.stdout.flush()
    _serve_until_stopped(server)
    console.print(f"stopped after {server.connections} connection(s); chip state in {path}",
                  highlight=False, soft_wrap=True)
    return 0


def _check_options(args: argparse.Namespace) -> None:
    """UserError (one line) for an option no emulator could take, before any file or port."""
    if args.baud <= 0:
        raise UserError(f"--baud must be positive, got {args.baud}")
    if not args.idle_timeout >= 0:
        raise UserError(f"--idle-timeout must be >= 0 seconds (0: never), got "
                        f"{args.idle_timeout}")
    if args.legacy_refusals and args.protocol != "legacy":
        raise UserError("--legacy-refusals is an extension of the legacy line protocol; "
                        "give --protocol legacy")
    if args.wall_scale is not None and not 0 <= args.wall_scale < float("inf"):
        raise UserError(f"--wall-scale must be a number >= 0, got {args.wall_scale}")
    if args.seed is not None and args.seed < 0:
        raise UserError(f"--seed must be a whole number >= 0, got {args.seed}")
    if args.spread is not None:
        if not args.reset_chip:
            raise UserError("--spread sets the spread of a new chip: give it with --reset-chip")
        if not 0 <= args.spread <= 10:
            raise UserError(f"--spread must be 0..10 (times the packaged device-to-device "
                            f"sigmas), got {args.spread}")
        if args.device:
            raise UserError("--spread with --device: a twin's spread is its model's measured "
                            "one; leave --spread out")


def _event(text: str) -> None:
    """A server event (a client connected, refused, gone), one time-stamped line on stderr."""
    err_console.print(f"[dim]{time.strftime('%H:%M:%S')}[/dim] {text}", highlight=False,
                      soft_wrap=True)


def _server(args: argparse.Namespace, emu: Emulator, address: tuple[str, int] | None,
            listener: socket.socket | None) -> TcpServer | PtyServer:
    """The server of ``emu``: TCP on ``address`` (``--socket``; ``listener``: its listening
    socket, taken already), else a pseudo-terminal."""
    if address is not None:
        host, port = address
        return TcpServer(emu, host, port, on_event=_event, idle_timeout_s=args.idle_timeout,
                         sock=listener)
    return PtyServer(emu, on_event=_event)


def _loaded(emu: Emulator, existed: bool, device: state.TwinDevice | None) -> str:
    """How the chip state came to be: loaded (with a replayed journal), or a new chip (the
    twin of ``device`` when given)."""
    loaded = "loaded" if existed else "new chip, saved to"
    if device is not None:
        loaded = f"the twin of {device.path}: " + loaded
    if emu.store is not None and emu.store.replayed.records:
        loaded += (f" (+ {emu.store.replayed.records} journal record(s) of a run that was "
                   "not stopped cleanly)")
    return loaded


def _print_serving(args: argparse.Namespace, emu: Emulator, faults: BoardFaults,
                   where: str) -> None:
    """The line saying what is served where (MCU, protocol, baud, extras)."""
    extras = (", -CODE,id refusals" if args.legacy_refusals else "") + (
        f", replies paced at {emu.wall_scale:g} x board time" if emu.wall_scale else "") + (
        f", FAULTY: {', '.join(faults.specs)}" if faults.any else "")
    console.print(f"MemriCore emulator ({args.mcu} MCU, {args.protocol} protocol, "
                  f"{args.baud} baud virtual "
                  f"UART{extras}) serving on [bold]{where}[/bold]", highlight=False,
                  soft_wrap=True)


def _serve_until_stopped(server: TcpServer | PtyServer) -> None:
    """Serve until Ctrl-C, SIGTERM or SIGHUP (or the server ends), then stop the server (it
    saves the chip)."""
    stopping = threading.Event()
    restore = _stop_on_signals(stopping)
    server.start()
    thread = server._thread
    assert thread is not None                    # start() made it
    try:
        # no KeyboardInterrupt inside Thread.join: Python 3.11 then marks the serving thread
        # stopped while it still runs, server.stop() no longer waits for it, and the firmware
        # MCU's CPU could still run while the interpreter shuts down (a segfault at Ctrl-C)
        while thread.is_alive() and not stopping.wait(0.2):
            pass
    except KeyboardInterrupt:         # run off the main thread: Python's own SIGINT handler
        pass
    finally:
        server.stop()                 # saves the chip
        restore()


def _chip_of(args: argparse.Namespace) -> tuple[Path, state.TwinDevice | None]:
    """(chip state path, the twin's device model or None) of ``--state`` / ``--device``."""
    device = state.TwinDevice.load(args.device) if args.device else None
    if args.state is not None:
        return _state_path(args.state), device
    if device is not None:
        return state.twin_state_path(device.path), device
    return state.default_state_path(), device


def _reset_chip(path: Path, seed: int, device: state.TwinDevice | None = None,
                spread: float = 1.0) -> int:
    """Replace the chip by a fresh one (new serial; the twin of ``device`` when given; its
    device-to-device sigmas times ``spread``) and forget the old chip's layouts."""
    release = state.acquire(path)         # not while an emulator runs on this chip
    try:
        existed = path.exists() or journal_path(path).exists()
        try:
            old = durable.chip_serial(path)
        except UserError:
            old = None                     # unreadable: replaced anyway
        durable.create_chip(path, seed, device=device, spread=spread)   # atomic, with journal
    finally:
        release()
    # the history database beside the chip is a record, never deleted: the old chip's is
    # renamed after its serial, so the new chip starts its own
    removed, kept = forget_chip_layouts(path, old)
    what = f"the twin of {device.path}" if device is not None else "fresh chip" + (
        f", spread x{spread:g}" if spread != 1.0 else "")
    console.print(f"{'replaced' if existed else 'created'} chip state {path} "
                  f"({what}, seed {seed})", highlight=False, soft_wrap=True)
    if removed:
        console.print("forgot the old chip's layout: removed " + ", ".join(map(str, removed)),
                      highlight=False, soft_wrap=True)
    if kept is not None:
        console.print(f"the old chip's history database is kept as {kept}", highlight=False,
                      soft_wrap=True)
    return 0


def _stop_on_signals(stopping: "threading.Event"):
    """Make Ctrl-C (SIGINT), SIGTERM and SIGHUP set ``stopping`` (the server is then stopped
    and the chip saved); a SIGINT ignored at start (a background job) stays ignored. Returns
    a function that restores the previous handlers."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None

    def stop(signum, frame):  # noqa: ARG001
        stopping.set()

    previous = {}
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        sig = getattr(signal, name, None)
        if sig is None or (sig == signal.SIGINT and
                           signal.getsignal(sig) is signal.SIG_IGN):
            continue
        previous[sig] = signal.signal(sig, stop)

    def restore() -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return restore


def _state_path(text: str):
    path = Path(text).expanduser()
    if path.exists() and path.is_dir():
        raise UserError(f"--state {text}: is a directory; give a file name such as chip.npz")
    return path
