"""Where the CLI keeps a board's layout (tools layer: it may know the emulator).

A layout describes one chip — its bad cells, its read-chain calibration, what is programmed
where — so it is keyed by the board's identity from INFO, never by the port string:

* the in-process emulator (``--port emu``, ``emu://?state=FILE``): next to the chip's state
  file (``emu-chip.npz`` -> ``emu-chip.layout.json``), so it moves, and is reset, with the chip;
* any other board: ``layouts/<board id>.json`` in the user's data folder
  (:func:`snan_hil.files.userdata.user_data_dir`: ``$XDG_DATA_HOME/snan-hil``, default
  ``~/.local/share/snan-hil`` on Linux), the board id made file-safe. An emulator served by
  ``snan-hil emu`` reports ``EMU-4D430001/<chip serial>`` (a new serial after
  ``--reset-chip``), so its layout follows the chip whatever pty or socket serves it; a
  MemriCore board reports its firmware's board id (``MC-...``);
* old firmware that reports no identity (legacy protocol, board id "" or "legacy"): keyed by
  the port string as ``layouts/port-<port>.json``.

Every loaded layout is checked against the board it is used with (:func:`check_board`): a
layout recorded for another board or chip is refused with one line.

The last ``program-weights`` report goes next to the layout (``<stem>.program-report.json``)
unless ``--report`` names another file; when a failed run replaces a complete report, that one
is kept as ``<stem>.program-report.prev.json``. The board's history database goes next to
its default layout (``<stem>.history.sqlite``, :func:`default_history_path`), keyed the same
way: beside the emulator's chip for ``--port emu``, ``layouts/<board id>.history.sqlite`` for
any other board (known after HELLO).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from snan_hil.calibration.layout import Layout, LayoutError
from snan_hil.calibration.programmer import previous_report_path
from snan_hil.firmware_emu.protocol_emu import SCHEME, state_of_url
from snan_hil.protocol.messages import Info
from snan_hil.files.userdata import user_data_dir

__all__ = ["default_layout_path", "default_report_path", "layout_path_for", "layouts_dir",
           "emu_state_of_port", "emu_layout_path", "board_layout_path", "check_board",
           "load_board_layout", "layout_path_of_board", "forget_layouts", "known_layout_path",
           "default_history_path", "history_path_beside", "known_history_path"]

EMU_PORT = "emu"


def layouts_dir() -> Path:
    """The folder of the layouts of boards other than the in-process emulator."""
    return user_data_dir() / "layouts"


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("_") or "board"


def emu_state_of_port(port: str, state_file: str | os.PathLike | None = None) -> Path | None:
    """The chip state file of an in-process emulator port (``emu`` or an ``emu://`` URL;
    ``state_file`` overrides the default of ``emu``), else None."""
    if port == EMU_PORT:
        if state_file is not None:
            return Path(state_file).expanduser()
        from snan_hil.firmware_emu.state import default_state_path
        return default_state_path()
    if port.startswith(f"{SCHEME}://"):
        return state_of_url(port)
    return None


def emu_layout_path(state: str | os.PathLike) -> Path:
    """``<stem>.layout.json`` beside an emulated chip's state file."""
    state = Path(state)
    stem = state.name[:-len(state.suffix)] if state.suffix else state.name
    return state.with_name(f"{stem}.layout.json")


def layout_path_of_board(board_id: str) -> Path:
    """``layouts/<board id>.json`` in the user's data folder."""
    return layouts_dir() / f"{_safe(board_id)}.json"


def board_layout_path(info: Info, port: str) -> Path:
    """The layout file of the board that answered with ``info`` (not an in-process emulator)."""
    if info.known_identity:
        return layout_path_of_board(info.board_id)
    return layouts_dir() / f"port-{_safe(port)}.json"


def forget_layouts(*layouts: Path) -> list[Path]:
    """Remove layout files and their program reports; returns what was removed."""
    removed = []
    for layout in layouts:
        report = default_report_path(layout)
        for f in (layout, report, previous_report_path(report)):
            if f.is_file():
                f.unlink()
                removed.append(f)
    return removed


def default_layout_path(port: str, info: Info | None = None, *,
                        state_file: str | os.PathLike | None = None) -> Path:
    """Default layout file of the board on ``port`` (see the module docstring); ``info`` (the
    board's INFO) is needed for every port but the in-process emulator."""
    state = emu_state_of_port(port, state_file)
    if state is not None:
        return emu_layout_path(state)
    if info is None:
        raise ValueError(f"the layout of {port} is keyed by the board's identity: "
                         "open the board (HELLO) first")
    return board_layout_path(info, port)


def layout_path_for(port: str, layout: str | os.PathLike | None,
                    info: Info | None = None) -> Path:
    """``layout`` if given, else the port's default (:func:`default_layout_path`)."""
    return Path(layout).expanduser() if layout else default_layout_path(port, info)


def known_layout_path(port: str, layout: str | os.PathLike | None) -> Path | None:
    """The layout file when it is known without asking the board (``--layout``, or the
    in-process emulator's), else None: then it depends on the board's INFO."""
    if layout:
        return Path(layout).expanduser()
    state = emu_state_of_port(port)
    return emu_layout_path(state) if state is not None else None


def default_report_path(layout_path: str | os.PathLike) -> Path:
    """``<layout stem>.program-report.json`` next to the layout."""
    return _beside_layout(layout_path, ".program-report.json")


def check_board(layout: Layout, info: Info, path: str | os.PathLike, port: str) -> None:
    """LayoutError unless ``layout`` was made on the board (and chip) that sent ``info``.
    Layouts or boards without an identity (old legacy firmware) are not checked."""
    have = str(layout.board.get("board_id") or "")
    if not have or have == "legacy" or not info.known_identity or have == info.board_id:
        return
    raise LayoutError(f"layout {path} was made on board {have}, but {port} is board "
                      f"{info.board_id}"
                      + (" (another chip: the emulator's chip was reset or replaced)"
                         if have.partition("/")[0] == info.board_id.partition("/")[0] else "")
                      + "; program this board first (snan-hil program-weights ... "
                      f"--port {port}) or pass its own --layout")


def load_board_layout(port: str, layout: str | os.PathLike | None,
                      info: Info) -> tuple[Layout, Path]:
    """Load the layout of the board that sent ``info`` (``--layout`` or its default) and check
    that it belongs to that board (:func:`check_board`)."""
    path = layout_path_for(port, layout, info)
    loaded = Layout.load(path)
    check_board(loaded, info, path, port)
    return loaded, path


def history_path_beside(layout_path: str | os.PathLike) -> Path:
    """``<layout stem>.history.sqlite`` next to a board's default layout."""
    return _beside_layout(layout_path, ".history.sqlite")


def _beside_layout(layout_path: str | os.PathLike, suffix: str) -> Path:
    """``<layout stem><suffix>`` in the layout's folder; the stem drops ``.layout.json`` or
    ``.json``."""
    p = Path(layout_path)
    name = p.name
    for layout_suffix in (".layout.json", ".json"):
        if name.endswith(layout_suffix):
            name = name[:-len(layout_suffix)]
            break
    return p.with_name(name + suffix)


def default_history_path(port: str, info: Info | None = None, *,
                         state_file: str | os.PathLike | None = None) -> Path:
    """The board's history database, ``<stem>.history.sqlite`` beside its default layout
    (:func:`default_layout_path`, keyed the same way: beside the chip for the in-process
    emulator, by the board id from INFO for any other board, so ``info`` is needed for those;
    an explicit ``--layout`` does not move it: the history belongs to the board, not to one
    layout)."""
    return history_path_beside(default_layout_path(port, info, state_file=state_file))


def known_history_path(port: str) -> Path | None:
    """The default history database when it is known without asking the board (the
    in-process emulator's), else None: then it depends on the board's INFO."""
    state = emu_state_of_port(port)
    return history_path_beside(emu_layout_path(state)) if state is not None else None
