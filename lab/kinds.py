"""The kinds of the board's own files (:class:`snan_hil.files.outputs.OutputKind`): layout,
program report, history database, emulated chip state. The opener checks them like any other
output before the board is opened (docs/outputs.md); ``tools/output_kinds.py`` re-exports them
with the kinds of the commands' other files."""

from __future__ import annotations

from pathlib import Path

from snan_hil.calibration.layout import LAYOUT_FORMAT
from snan_hil.calibration.programmer import REPORT_FORMAT
from snan_hil.common.errors import UserError
from snan_hil.crossbar_model.array import CHIP_STATE_FORMAT
from snan_hil.files.outputs import OutputKind, Outputs, json_kind, npz_kind
from snan_hil.records.history import check_history_file, check_history_intact

__all__ = ["LAYOUT", "PROGRAM_REPORT", "CHIP_STATE", "HISTORY_DB", "check_history_output"]

LAYOUT = json_kind(LAYOUT_FORMAT, "a snan-hil layout")
PROGRAM_REPORT = json_kind(REPORT_FORMAT, "a snan-hil programming report")
CHIP_STATE = npz_kind(CHIP_STATE_FORMAT, "an emulated chip's state")


def _owns_history(path: Path) -> bool:
    try:
        check_history_file(path)
    except UserError:
        return False
    return True


HISTORY_DB = OutputKind("a snan-hil history database", _owns_history)


def check_history_output(outs: Outputs, option: str, path: str | Path, *,
                         default: bool) -> Path:
    """The history database a command adds to: refused (exit 2, also with ``--force``: it is
    never replaced) when the file is not a snan-hil history database or is damaged (SQLite's
    quick check; the line says how to save what it holds), then checked like an output the
    command updates (its folder writable, not one of the inputs)."""
    p = check_history_intact(path, option)
    return outs.file(option, p, HISTORY_DB, updates=True, create_folder=default)
