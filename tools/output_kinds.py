"""The kinds of file the CLI's commands write (:class:`snan_hil.files.outputs.OutputKind`), and the
``--force`` option: an existing output is replaced only when it is of its own kind. The kinds
of the board's own files (layout, program report, history database, chip state) are the
opener's (:mod:`snan_hil.lab.kinds`), re-exported here.

A new command that writes a file adds its kind here (or next to its format) and checks every
output with :class:`snan_hil.files.outputs.Outputs` before any long work; see docs/outputs.md.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from snan_hil.calibration.mac import MAC_FORMAT
from snan_hil.calibration.selftest import SELFTEST_FORMAT
from snan_hil.host.experiments.common import FIGURE_FORMAT
from snan_hil.host.hil.compare import (LAUNCH_COLUMNS, RESULTS_FORMAT, SPEED_COLUMNS,
                                       SPEED_COLUMNS_V1, SUMMARY_COLUMNS, SUMMARY_COLUMNS_V1)
from snan_hil.host.hil.figure import FIGURE_FORMAT as COMPARE_FIGURE_FORMAT
from snan_hil.host.hil.train import WEIGHTS_FORMAT
from snan_hil.records.history import TABLE_COLUMNS
from snan_hil.host.plots import SIM_PLOT_FORMAT
from snan_hil.lab.kinds import CHIP_STATE, HISTORY_DB, LAYOUT, PROGRAM_REPORT, check_history_output
from snan_hil.tools.bench_figures import (CELL_LIFE_PNG_FORMAT, CELLS_PNG_FORMAT,
                                          MAC_PNG_FORMAT, PROGRAM_TRACE_FORMAT,
                                          RETENTION_PNG_FORMAT, TICKET_PNG_FORMAT)
from snan_hil.files.outputs import OutputKind, csv_kind, json_kind, npz_kind, png_kind

__all__ = ["LAYOUT", "PROGRAM_REPORT", "WEIGHTS", "CHIP_STATE", "COMPARE_JSON", "COMPARE_FILES",
           "RETENTION_FORMAT", "RETENTION", "SIM_PLOT", "MAP_CSV_HEADER", "MAP_CSV", "MAP_PNG",
           "MAP_PNG_FORMAT", "experiment_figure", "add_force_option", "compare_files",
           "HISTORY_DB", "check_history_output", "PROGRAM_TRACE",
           "RETENTION_PNG", "MAC_JSON", "MAC_CSV", "MAC_CSV_HEADER", "MAC_PNG", "CELLS_FORMAT",
           "CELLS_JSON", "CELLS_PNG", "TICKET_FORMAT", "TICKET_JSON", "TICKET_CSV",
           "TICKET_CSV_HEADER", "TICKET_PNG", "CELL_LIFE_PNG", "history_csv_kind"]

WEIGHTS = npz_kind(WEIGHTS_FORMAT, "a weights file written by 'snan-hil train'")
COMPARE_JSON = json_kind(RESULTS_FORMAT, "a 'snan-hil compare' result")
RETENTION_FORMAT = "snan-hil-retention/1"
RETENTION = json_kind(RETENTION_FORMAT, "a 'snan-hil retention' result")
SIM_PLOT = png_kind(SIM_PLOT_FORMAT, "a 'snan-hil sim' plot")
MAP_CSV_HEADER = "row,col,adc,resistance_ohm,conductance_s"
MAP_CSV = csv_kind(MAP_CSV_HEADER, "a 'snan-hil map' CSV")
MAP_PNG_FORMAT = "snan-hil-map/1"
MAP_PNG = png_kind(MAP_PNG_FORMAT, "a 'snan-hil map' image")

PROGRAM_TRACE = png_kind(PROGRAM_TRACE_FORMAT, "a 'program-weights --trace' figure")
RETENTION_PNG = png_kind(RETENTION_PNG_FORMAT, "a 'retention --png' figure")
MAC_JSON = json_kind(MAC_FORMAT, "a 'snan-hil mac' result")
SELFTEST_JSON = json_kind(SELFTEST_FORMAT, "a 'snan-hil selftest' report")
MAC_CSV_HEADER = ("vector,column,rows,measured_a,reference_a,readback_a,error_pct_fs,"
                  "error_pct_fs_readback,adc,scaled,saturated")
MAC_CSV = csv_kind(MAC_CSV_HEADER, "a 'snan-hil mac' CSV")
MAC_PNG = png_kind(MAC_PNG_FORMAT, "a 'snan-hil mac' figure")
CELLS_FORMAT = "snan-hil-cells/1"
CELLS_JSON = json_kind(CELLS_FORMAT, "a 'snan-hil cells test' result")
CELLS_PNG = png_kind(CELLS_PNG_FORMAT, "a 'snan-hil cells' map")
TICKET_FORMAT = "snan-hil-pulse/1"
TICKET_JSON = json_kind(TICKET_FORMAT, "a 'snan-hil pulse' result")
TICKET_CSV_HEADER = "n,polarity,amplitude_v,width_us,g_before_s,g_after_s"
TICKET_CSV = csv_kind(TICKET_CSV_HEADER, "a 'snan-hil pulse' CSV")
TICKET_PNG = png_kind(TICKET_PNG_FORMAT, "a 'snan-hil pulse' figure")
CELL_LIFE_PNG = png_kind(CELL_LIFE_PNG_FORMAT, "a 'snan-hil history --cell' figure")


def history_csv_kind(table: str) -> OutputKind:
    """The CSV export of one history table (recognised by its header)."""
    return csv_kind(",".join(TABLE_COLUMNS[table]), f"a 'snan-hil history' {table} export")


COMPARE_FILES: dict[str, OutputKind] = {
    "compare.json": COMPARE_JSON,
    "launches.csv": csv_kind(",".join(LAUNCH_COLUMNS), "a 'snan-hil compare' launches.csv"),
    "summary.csv": csv_kind(",".join(SUMMARY_COLUMNS), "a 'snan-hil compare' summary.csv",
                            earlier=(",".join(SUMMARY_COLUMNS_V1),)),
    "speed_energy.csv": csv_kind(",".join(SPEED_COLUMNS),
                                 "a 'snan-hil compare' speed_energy.csv",
                                 earlier=(",".join(SPEED_COLUMNS_V1),)),
    "fig10c.png": png_kind(COMPARE_FIGURE_FORMAT, "a 'snan-hil compare' figure"),
}


def compare_files(sets: list[int] | None, *, programming: bool, figure: bool = True
                  ) -> dict[str, OutputKind]:
    """The files ``compare`` / ``demo`` write into ``--out``: the result files, and one
    programming report per set (``programming/program-set<K>.json``) when it programs
    (``sets`` None: not known yet, the folder alone is checked then)."""
    files = {k: v for k, v in COMPARE_FILES.items() if figure or k != "fig10c.png"}
    if programming:
        files.update({f"programming/program-set{k}.json": PROGRAM_REPORT
                      for k in (sets or [])})
    return files


def experiment_figure(name: str) -> OutputKind:
    """The folder ``<out>/<name>/`` of one experiment figure (replaced as a whole): ours when
    it is empty, or holds only the figure's four files and its JSON carries the experiment
    marker (or, from before the marker, the provenance every figure's JSON carried)."""
    allowed = {f"{name}.{ext}" for ext in ("json", "csv", "png", "md")}
    family = FIGURE_FORMAT.split("/")[0] + "/"

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
