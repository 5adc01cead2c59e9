"""Where a board's files live: :class:`BoardFiles`, resolved once per session (pure path rules).

A layout describes one chip — its bad cells, its read-chain calibration, what is programmed
where — so it is keyed by the chip, never by the port string:

* an emulated chip (its state file known: the in-process emulator ``--port emu`` /
  ``emu://?state=FILE``, or a chip served by ``snan-hil emu --state FILE`` on this machine):
  beside the chip's state file, ``emu-chip.npz`` -> ``emu-chip.layout.json``, so it moves, and
  is reset, with the chip (:meth:`BoardFiles.beside_chip`);
* any other board: ``layouts/<board id>.json`` in the user's data folder
  (:func:`snan_hil.files.userdata.user_data_dir`), the board id made file-safe
  (:meth:`BoardFiles.of_board`);
* old firmware that reports no identity (legacy protocol, board id "" or "legacy"): keyed by the
  port string as ``layouts/port-<port>.json``.

The last ``program-weights`` report goes beside the layout it programmed
(``<stem>.program-report.json``); when a failed run replaces a complete report, that one is
kept as ``<stem>.program-report.prev.json`` (:func:`previous_report_path`). The history
database goes beside the board's *default* layout (``<stem>.history.sqlite``): an explicit
``--layout`` does not move it, the history belongs to the board, not to one layout.
"""

from __future__ import annotations

import dataclasses
import os
import re
from dataclasses import dataclass
from pathlib import Path

from snan_hil.board.identity import BoardIdentity
from snan_hil.files.userdata import user_data_dir

__all__ = ["BoardFiles", "layouts_dir", "layout_path_of_board", "layout_beside_chip",
           "report_beside", "history_beside", "previous_report_path", "safe_name"]

_LAYOUT_SUFFIXES = (".layout.json", ".json")


def layouts_dir() -> Path:
    """The folder of the layouts of boards whose chip file is not known here."""
    return user_data_dir() / "layouts"


def safe_name(text: str) -> str:
    """``text`` made a file name (runs of other characters become ``_``)."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("_") or "board"


def layout_path_of_board(board_id: str) -> Path:
    """``layouts/<board id>.json`` in the user's data folder."""
    return layouts_dir() / f"{safe_name(board_id)}.json"


def layout_beside_chip(state: str | os.PathLike[str]) -> Path:
    """``<stem>.layout.json`` beside an emulated chip's state file."""
    path = Path(state)
    stem = path.name[:-len(path.suffix)] if path.suffix else path.name
    return path.with_name(f"{stem}.layout.json")


def _beside_layout(layout: str | os.PathLike[str], suffix: str) -> Path:
    """``<layout stem><suffix>`` in the layout's folder; the stem drops ``.layout.json`` or
    ``.json``."""
    path = Path(layout)
    name = path.name
    for ending in _LAYOUT_SUFFIXES:
        if name.endswith(ending):
            name = name[:-len(ending)]
            break
    return path.with_name(name + suffix)


def report_beside(layout: str | os.PathLike[str]) -> Path:
    """``<layout stem>.program-report.json`` beside a layout."""
    return _beside_layout(layout, ".program-report.json")


def history_beside(layout: str | os.PathLike[str]) -> Path:
    """``<layout stem>.history.sqlite`` beside a board's default layout."""
    return _beside_layout(layout, ".history.sqlite")


def previous_report_path(report: str | os.PathLike[str]) -> Path:
    """Where a failed run keeps the last complete report it replaces: ``<name>.prev.json``
    beside ``<name>.json`` (``chip.program-report.json`` -> ``chip.program-report.prev.json``)."""
    path = Path(report)
    stem = path.name[:-len(".json")] if path.name.endswith(".json") else path.name
    return path.with_name(f"{stem}.prev.json")


@dataclass(frozen=True)
class BoardFiles:
    """The files of one board (None: none / not known). ``layout``: its layout (JSON);
    ``report``: the program report beside it and ``previous_report`` where a failed run keeps
    the last complete one; ``history``: the board's history database (SQLite); ``chip_state``:
    the emulated chip's state file (None for a real chip)."""

    layout: Path | None = None
    report: Path | None = None
    previous_report: Path | None = None
    history: Path | None = None
    chip_state: Path | None = None

    @classmethod
    def of_layout(cls, layout: str | os.PathLike[str], *, history: Path | None = None,
                  chip_state: Path | None = None) -> BoardFiles:
        """The files of a board whose layout is ``layout``: report and previous report beside
        it, ``history`` and ``chip_state`` as given."""
        layout = Path(layout)
        report = report_beside(layout)
        return cls(layout, report, previous_report_path(report), history, chip_state)

    @classmethod
    def beside_chip(cls, state: str | os.PathLike[str]) -> BoardFiles:
        """The default files of an emulated chip: beside its state file."""
        state = Path(state)
        layout = layout_beside_chip(state)
        return cls.of_layout(layout, history=history_beside(layout), chip_state=state)

    @classmethod
    def of_board(cls, identity: BoardIdentity, port: str) -> BoardFiles:
        """The default files of a board whose chip file is not known here: keyed by its board
        id in the user's data folder (by ``port`` when it says nothing about who it is)."""
        if identity.known:
            layout = layout_path_of_board(identity.board_id)
        else:
            layout = layouts_dir() / f"port-{safe_name(port)}.json"
        return cls.of_layout(layout, history=history_beside(layout))

    def overridden(self, *, layout: str | os.PathLike[str] | None = None,
                   report: str | os.PathLike[str] | None = None,
                   history: str | os.PathLike[str] | None = None) -> BoardFiles:
        """These files with the ones the user named: ``layout`` (its report moves beside it),
        ``report`` (its previous report beside it), ``history``; ``~`` expanded."""
        files = self
        if layout is not None:
            path = Path(layout).expanduser()
            report_path = report_beside(path)
            files = dataclasses.replace(files, layout=path, report=report_path,
                                        previous_report=previous_report_path(report_path))
        if report is not None:
            path = Path(report).expanduser()
            files = dataclasses.replace(files, report=path,
                                        previous_report=previous_report_path(path))
        if history is not None:
            files = dataclasses.replace(files, history=Path(history).expanduser())
        return files

    def to_dict(self) -> dict[str, str | None]:
        """The paths as text (None where not known), for provenance records."""
        return {f.name: None if getattr(self, f.name) is None else str(getattr(self, f.name))
                for f in dataclasses.fields(self)}
