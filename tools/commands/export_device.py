"""``snan-hil export-device``: a fitted device model out to the tools labs know — an IBM aihwkit
device configuration, a CrossSim-style ΔG lookup table — and the physical chip the emulator
makes of it (:mod:`snan_hil.crossbar_model.export`, :mod:`snan_hil.crossbar_model.device_twin`;
docs/crossbar_model.md §7).

Examples::

    snan-hil export-device model.json --aihwkit model-aihwkit.json --crosssim lut/
    snan-hil export-device model.json --twin twin.json

In aihwkit (the configuration names the classes and their keyword arguments)::

    import json
    from aihwkit.simulator.configs import SingleRPUConfig, devices
    d = json.load(open("model-aihwkit.json"))["device"]
    config = SingleRPUConfig(device=getattr(devices, d["class"])(**d["parameters"]))
"""

from __future__ import annotations

import argparse
import json

from snan_hil.common.errors import UserError
from snan_hil.crossbar_model.device_twin import load_device_model, twin_spec
from snan_hil.crossbar_model.export import (AIHWKIT_FORMAT, CROSSSIM_FILES, CROSSSIM_FORMAT,
                                            aihwkit_export, write_crosssim)
from snan_hil.files.atomicio import atomic_write_json
from pathlib import Path

from snan_hil.files.outputs import OutputKind, Outputs, json_kind
from snan_hil.tools.console import console
from snan_hil.tools.output_kinds import add_force_option

NAME = "export-device"
HELP = ("export a fitted device model as an aihwkit device configuration, a CrossSim-style "
        "lookup table, or the emulator's physical twin of it")

TWIN_FORMAT_KIND = json_kind("snan-hil-twin/1", "a snan-hil twin description")
AIHWKIT_KIND = json_kind(AIHWKIT_FORMAT, "a snan-hil aihwkit export")
LOOKUP_KIND = json_kind(CROSSSIM_FORMAT, "a snan-hil CrossSim export")


def _own_table(path: Path) -> bool:
    try:
        with open(path, encoding="utf-8") as fh:
            return fh.readline().startswith("snan-hil device model")
    except (OSError, UnicodeDecodeError):
        return False


TABLE_KIND = OutputKind("a CrossSim table written by snan-hil", _own_table)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", metavar="MODEL.json",
                        help="a fitted device model ('snan-hil characterize --model', or "
                             "--from a pulse CSV)")
    parser.add_argument("--aihwkit", metavar="FILE", default=None,
                        help="write the aihwkit device configuration (PiecewiseStepDevice and "
                             "SoftBoundsDevice keyword arguments, forward noise, drift) as JSON "
                             "(default: none)")
    parser.add_argument("--crosssim", metavar="DIR", default=None,
                        help="write CrossSim's dG_increasing.txt / dG_decreasing.txt lookup "
                             "tables (and lookup.json) into DIR (default: none)")
    parser.add_argument("--twin", metavar="FILE", default=None,
                        help="write the physical chip the emulator makes of the model (every "
                             "measured cell's device, the population, the source of each value; "
                             "default: none)")
    parser.add_argument("--json", action="store_true",
                        help="print the aihwkit configuration (or the twin with --twin only) as "
                             "JSON")
    add_force_option(parser)


def run(args: argparse.Namespace) -> int:
    if not (args.aihwkit or args.crosssim or args.twin or args.json):
        raise UserError("export-device: give --aihwkit FILE, --crosssim DIR, --twin FILE or "
                        "--json")
    outs = Outputs({"model": args.model}, force=args.force)
    aihwkit_path = outs.file("--aihwkit", args.aihwkit, AIHWKIT_KIND) if args.aihwkit else None
    lut = outs.folder("--crosssim", args.crosssim,
                      files={**{name: TABLE_KIND for name in CROSSSIM_FILES.values()},
                             "lookup.json": LOOKUP_KIND}) if args.crosssim else None
    twin_path = outs.file("--twin", args.twin, TWIN_FORMAT_KIND) if args.twin else None
    model = load_device_model(args.model)
    doc = aihwkit_export(model)
    if aihwkit_path is not None:
        atomic_write_json(aihwkit_path, doc, indent=1, allow_nan=False)
    written = write_crosssim(model, lut) if lut is not None else []
    twin = None
    if twin_path is not None:
        from snan_hil.firmware_emu.config import BoardConfig
        twin = twin_spec(model, read_draws=BoardConfig().adc_averages)
        atomic_write_json(twin_path, twin.to_dict(), indent=1, allow_nan=False)
    if args.json:
        shown = twin.to_dict() if twin is not None and not args.aihwkit else doc
        print(json.dumps(shown, indent=1, allow_nan=False))
        return 0
    p = doc["device"]["parameters"]
    console.print(f"aihwkit PiecewiseStepDevice: dw_min {p['dw_min']:.4g}, up_down "
                  f"{p['up_down']:+.3f}, dw_min_std {p['dw_min_std']:.3f}, w in [-1, 1] = ln G "
                  f"over [{model.g_min_s * 1e6:.1f}, {model.g_max_s * 1e6:.1f}] uS",
                  highlight=False)
    for opt, path in (("--aihwkit", aihwkit_path), ("--twin", twin_path)):
        if path is not None:
            console.print(f"wrote {opt} {path}", highlight=False)
    if written:
        console.print(f"wrote --crosssim {lut}: " + ", ".join(p.name for p in written),
                      highlight=False)
    return 0
