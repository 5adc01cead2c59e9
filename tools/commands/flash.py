"""``snan-hil flash``: put this project's firmware on a real board's MIK32, safely.

Checks the ELF before anything is written (:func:`snan_hil.lab.flashing.check_image`), writes
its flash image as Intel HEX, drives the MIK32 vendor's uploader (OpenOCD over JTAG; refused in
one line when it is not installed), then opens the board's serial port and checks its INFO.
``--check-only`` stops after the image checks. Never tried on real hardware (docs/firmware.md).
"""

from __future__ import annotations

import argparse
import json
import tempfile
from typing import Any
from pathlib import Path

from rich.table import Table

from snan_hil.common.errors import UserError
from snan_hil.lab.ports import EMU_PORT
from snan_hil.lab.flashing import (UPLOADER_ENV, UploaderOptions, check_boot, check_image,
                                   find_uploader, intel_hex, run_uploader, uploader_command)
from snan_hil.tools.console import console
from snan_hil.tools.ports import add_port_arguments, client_from_args

NAME = "flash"
HELP = ("check the firmware ELF, write it to a real board's MIK32 with the vendor's uploader "
        "(OpenOCD, JTAG), then check the board's INFO")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_port_arguments(parser)
    parser.add_argument("--elf", default=None,
                        help="the firmware ELF (default build/firmware/snan-fw.elf, 'make "
                             "firmware')")
    parser.add_argument("--uploader", default=None, metavar="PATH",
                        help="the vendor's mik32_upload.py (or its packaged mik32_upload); "
                             f"default ${UPLOADER_ENV}, else found on the PATH")
    parser.add_argument("--openocd", default=None, metavar="PATH",
                        help="OpenOCD's executable (the uploader's --openocd-exec; default: the "
                             "uploader's)")
    parser.add_argument("--openocd-scripts", default=None, metavar="DIR",
                        help="OpenOCD's scripts folder (the uploader's --openocd-scripts; default: "
                             "the uploader's)")
    parser.add_argument("--openocd-interface", default=None, metavar="CFG",
                        help="the JTAG adapter's config, e.g. the uploader's "
                             "openocd-scripts/interface/ftdi/mikron-link.cfg (default: the "
                             "uploader's)")
    parser.add_argument("--openocd-target", default=None, metavar="CFG",
                        help="the MCU's config, e.g. the uploader's "
                             "openocd-scripts/target/mik32.cfg (default: the uploader's)")
    parser.add_argument("--adapter-speed", type=int, default=None, metavar="KHZ",
                        help="JTAG clock in kHz (the uploader's default when omitted)")
    parser.add_argument("--check-only", action="store_true",
                        help="check the image and print the uploader's command; write nothing")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")


def run(args: argparse.Namespace) -> int:
    report = _checked_image(args)
    prefix = find_uploader(args.uploader)
    result: dict[str, object] = {"image": report.to_dict()}
    if prefix is None:
        where = args.uploader or f"${UPLOADER_ENV} or mik32_upload(.py) on the PATH"
        if args.check_only:
            result["uploader"] = None
            _finish(args, result, "image checked; no uploader installed "
                    f"({where}): nothing would be written")
            return 0
        raise UserError(f"the MIK32 uploader is not installed ({where}): nothing was written; "
                        "install MikronMIK32/mik32-uploader with OpenOCD and give --uploader "
                        "PATH/mik32_upload.py (docs/firmware.md)")
    if not _upload(args, report, prefix, result):        # --check-only: said what it would run
        return 0
    info = _booted(args, result)
    _finish(args, result, f"flashed and booted: {info.firmware_version}, board "
            f"{info.board_id} on {args.port}")
    return 0


def _checked_image(args: argparse.Namespace) -> Any:
    """The ELF's image report (printed unless --json); UserError (one line, nothing written)
    for a bad option, a bad image, or a flash without a board port."""
    if args.adapter_speed is not None and args.adapter_speed <= 0:
        raise UserError(f"--adapter-speed must be a positive number of kHz, got "
                        f"{args.adapter_speed}")
    report = check_image(args.elf)
    if not args.json:
        _print_checks(report)
    if not report.ok:
        raise UserError(f"firmware ELF {report.path} not flashed: {report.first_problem()}; "
                        "nothing was written (make firmware builds a good one)")
    if not args.check_only and args.port == EMU_PORT:
        raise UserError("give --port (the flashed board's serial port, e.g. /dev/ttyUSB0; "
                        "not the emulator): after flashing, its INFO is checked")
    return report


def _upload(args: argparse.Namespace, report: Any, prefix: list[str],
            result: dict[str, object]) -> bool:
    """Write the image with the vendor's uploader (its command into ``result``); False with
    --check-only (the command said, nothing run)."""
    assert report.image is not None
    opts = UploaderOptions(args.openocd, args.openocd_scripts, args.openocd_interface,
                           args.openocd_target, args.adapter_speed)
    with tempfile.TemporaryDirectory(prefix="snan-fw-") as tmp:
        hex_path = Path(tmp) / "snan-fw.hex"
        hex_path.write_text(intel_hex(report.image))
        cmd = uploader_command(prefix, hex_path, opts, report.boot_mode)
        result["uploader"] = cmd
        if args.check_only:
            _finish(args, result, "image checked; would run: " + " ".join(cmd))
            return False
        if not args.json:
            console.print("writing: " + " ".join(cmd), highlight=False, soft_wrap=True)
        run_uploader(cmd)
    return True


def _booted(args: argparse.Namespace, result: dict[str, object]) -> Any:
    """The INFO of the board restarted from its new firmware (into ``result``); UserError
    when it does not answer as this firmware."""
    client = client_from_args(args)
    try:
        info = client.info or client.hello()
    finally:
        client.close()
    problems = check_boot(info)
    result["info"] = info.to_dict()
    result["boot_problems"] = problems
    if problems:
        raise UserError(f"flashed, but the board on {args.port} does not answer as this "
                        f"firmware: {problems[0]}; check the boot pins (SPIFI) and "
                        "docs/firmware.md")
    return info


def _finish(args: argparse.Namespace, result: dict[str, object], line: str) -> None:
    if args.json:
        print(json.dumps({**result, "result": line}, indent=1))
    else:
        console.print(line, highlight=False, soft_wrap=True)


def _print_checks(report) -> None:  # noqa: ANN001 - an ImageReport
    t = Table(title=f"firmware image {report.path} (boot mode: {report.boot_mode})")
    for name in ("check", "result", "found", "needed"):
        t.add_column(name, overflow="fold")
    for c in report.checks:
        t.add_row(c.name, "[green]ok[/]" if c.ok else "[bold red]FAIL[/]", c.measured,
                  c.expected)
    console.print(t)
