"""The kinds of file the CLI's commands write (:class:`snan_hil.files.outputs.OutputKind`), and the
``--force`` option: an existing output is replaced only when it is of its own kind. The kinds
of the board's own files (layout, program report, history database, chip state) are the
opener's (:mod:`snan_hil.lab.kinds`), re-exported here.

A new command that writes a file adds its kind here (or next to its format) and checks every
output with :class:`snan_hil.files.outputs.Outputs` before any long work; see docs/outputs.md.
"""

from __future__ import annotations

import argparse
import importlib
import json
from pathlib import Path
from typing import Any

from snan_hil.records.history import TABLE_COLUMNS
from snan_hil.lab.kinds import CHIP_STATE, HISTORY_DB, LAYOUT, PROGRAM_REPORT, check_history_output
from snan_hil.files.outputs import OutputKind, csv_kind, json_kind, png_kind

__all__ = ["LAYOUT", "PROGRAM_REPORT", "CHIP_STATE", "RETENTION_FORMAT", "RETENTION",
           "MAP_CSV_HEADER", "MAP_CSV", "MAP_PNG", "MAP_PNG_FORMAT", "experiment_figure",
           "add_force_option", "compare_files", "HISTORY_DB", "check_history_output",
           "MAC_CSV", "MAC_CSV_HEADER", "CELLS_FORMAT", "CELLS_JSON", "TICKET_FORMAT",
           "TICKET_JSON", "TICKET_CSV", "TICKET_CSV_HEADER", "history_csv_kind"]
# and, made on first use: WEIGHTS, COMPARE_JSON, COMPARE_FILES, SIM_PLOT, PROGRAM_TRACE,
# RETENTION_PNG, MAC_JSON, MAC_PNG, CELLS_PNG, TICKET_PNG, CELL_LIFE_PNG, PLAN_PNG
# (_kinds below)

RETENTION_FORMAT = "snan-hil-retention/1"
RETENTION = json_kind(RETENTION_FORMAT, "a 'snan-hil retention' result")
MAP_CSV_HEADER = "row,col,adc,resistance_ohm,conductance_s"
MAP_CSV = csv_kind(MAP_CSV_HEADER, "a 'snan-hil map' CSV")
MAP_PNG_FORMAT = "snan-hil-map/1"
MAP_PNG = png_kind(MAP_PNG_FORMAT, "a 'snan-hil map' image")
MAC_CSV_HEADER = ("vector,column,rows,measured_a,reference_a,readback_a,error_pct_fs,"
                  "error_pct_fs_readback,adc,scaled,saturated")
MAC_CSV = csv_kind(MAC_CSV_HEADER, "a 'snan-hil mac' CSV")
CELLS_FORMAT = "snan-hil-cells/1"
CELLS_JSON = json_kind(CELLS_FORMAT, "a 'snan-hil cells test' result")
TICKET_FORMAT = "snan-hil-pulse/1"
TICKET_JSON = json_kind(TICKET_FORMAT, "a 'snan-hil pulse' result")
TICKET_CSV_HEADER = "n,polarity,amplitude_v,width_us,g_before_s,g_after_s"
TICKET_CSV = csv_kind(TICKET_CSV_HEADER, "a 'snan-hil pulse' CSV")


def _format(module: str, name: str) -> Any:
    return getattr(importlib.import_module(f"snan_hil.{module}"), name)


def _compare_files() -> dict[str, OutputKind]:
    compare = importlib.import_module("snan_hil.host.hil.compare")
    return {
        "compare.json": _kinds["COMPARE_JSON"](),
        "launches.csv": csv_kind(",".join(compare.LAUNCH_COLUMNS),
                                 "a 'snan-hil compare' launches.csv"),
        "summary.csv": csv_kind(",".join(compare.SUMMARY_COLUMNS),
                                "a 'snan-hil compare' summary.csv",
                                earlier=(",".join(compare.SUMMARY_COLUMNS_V1),)),
        "speed_energy.csv": csv_kind(",".join(compare.SPEED_COLUMNS),
                                     "a 'snan-hil compare' speed_energy.csv",
                                     earlier=(",".join(compare.SPEED_COLUMNS_V1),)),
        "fig10c.png": png_kind(_format("host.hil.figure", "FIGURE_FORMAT"),
                               "a 'snan-hil compare' figure"),
    }


def _npz(module: str, name: str, what: str) -> Any:
    from snan_hil.files.outputs import npz_kind
    return npz_kind(_format(module, name), what)


_kinds: dict[str, Any] = {
    # the kinds whose format lives beside a heavy module (the compare, the kernels, matplotlib
    # figures): made on first use, so a command's start imports only what it writes
    "WEIGHTS": lambda: _npz("host.hil.train", "WEIGHTS_FORMAT",
                            "a weights file written by 'snan-hil train'"),
    "COMPARE_JSON": lambda: json_kind(_format("host.hil.compare", "RESULTS_FORMAT"),
                                      "a 'snan-hil compare' result"),
    "SIM_PLOT": lambda: png_kind(_format("host.plots", "SIM_PLOT_FORMAT"),
                                 "a 'snan-hil sim' plot"),
    "PROGRAM_TRACE": lambda: png_kind(_format("tools.bench_figures", "PROGRAM_TRACE_FORMAT"),
                                      "a 'program-weights --trace' figure"),
    "RETENTION_PNG": lambda: png_kind(_format("tools.bench_figures", "RETENTION_PNG_FORMAT"),
                                      "a 'retention --png' figure"),
    "MAC_JSON": lambda: json_kind(_format("calibration.mac", "MAC_FORMAT"),
                                  "a 'snan-hil mac' result"),
    "SELFTEST_JSON": lambda: json_kind(_format("calibration.selftest", "SELFTEST_FORMAT"),
                                       "a 'snan-hil selftest' report"),
    "MAC_PNG": lambda: png_kind(_format("tools.bench_figures", "MAC_PNG_FORMAT"),
                                "a 'snan-hil mac' figure"),
    "CELLS_PNG": lambda: png_kind(_format("tools.bench_figures", "CELLS_PNG_FORMAT"),
                                  "a 'snan-hil cells' map"),
    "TICKET_PNG": lambda: png_kind(_format("tools.bench_figures", "TICKET_PNG_FORMAT"),
                                   "a 'snan-hil pulse' figure"),
    "CELL_LIFE_PNG": lambda: png_kind(_format("tools.bench_figures", "CELL_LIFE_PNG_FORMAT"),
                                      "a 'snan-hil history --cell' figure"),
    "PLAN_PNG": lambda: png_kind(_format("tools.plan_figures", "PLAN_PNG_FORMAT"),
                                 "a 'snan-hil plan run --png' figure"),
    "COMPARE_FILES": _compare_files,
}


__all__ += list(_kinds)


def __getattr__(name: str) -> Any:
    """The kinds of :data:`_kinds`, made once on first use (PEP 562)."""
    make = _kinds.get(name)
    if make is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = make()
    globals()[name] = value
    return value


def history_csv_kind(table: str) -> OutputKind:
    """The CSV export of one history table (recognised by its header)."""
    return csv_kind(",".join(TABLE_COLUMNS[table]), f"a 'snan-hil history' {table} export")


def compare_files(sets: list[int] | None, *, programming: bool, figure: bool = True,
                  chips: int = 0) -> dict[str, OutputKind]:
    """The files ``compare`` / ``demo`` write into ``--out``: the result files, and one
    programming report per set (``programming/program-set<K>.json``; over a chip group of
    ``chips`` chips one per set and chip, ``program-set<K>-chip<k>.json``) when it programs
    (``sets`` None: not known yet, the folder alone is checked then)."""
    every: dict[str, OutputKind] = __getattr__("COMPARE_FILES")
    files = {k: v for k, v in every.items() if figure or k != "fig10c.png"}
    if programming and chips:
        files.update({f"programming/program-set{k}-chip{c}.json": PROGRAM_REPORT
                      for k in (sets or []) for c in range(chips)})
    elif programming:
        files.update({f"programming/program-set{k}.json": PROGRAM_REPORT
                      for k in (sets or [])})
    return files


def experiment_figure(name: str) -> OutputKind:
    """The folder ``<out>/<name>/`` of one experiment figure (replaced as a whole): ours when
    it is empty, or holds only the figure's four files and its JSON carries the experiment
    marker (or, from before the marker, the provenance every figure's JSON carried)."""
    allowed = {f"{name}.{ext}" for ext in ("json", "csv", "png", "md")}
    family = _format("host.experiments.common", "FIGURE_FORMAT").split("/")[0] + "/"

    def owns(folder: Path) -> bool:
        try:
            entries = {p.name for p in folder.iterdir()}
        except OSError:
            return False
        if not entries:
            return True
        if not entries <= allowed:
            return False
        try:
            data = json.loads((folder / f"{name}.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return False
        if not isinstance(data, dict):
            return False
        if "format" in data:
            return str(data["format"]).startswith(family)
        return "snan_hil_version" in data and "master_seed" in data
    return OutputKind(f"the output of 'snan-hil experiment {name}'", owns)


def add_force_option(parser: argparse.ArgumentParser) -> None:
    """``--force``: overwrite existing output files that are not of the command's own kind."""
    parser.add_argument("--force", action="store_true",
                        help="overwrite an existing output file even when it is not one this "
                             "command writes (default: refuse; inputs are never overwritten)")
