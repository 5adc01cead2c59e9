"""Where the CLI keeps layouts and reports by default (tools layer: it may know the emulator).

* ``--port emu``: next to the emulator's chip state file (``$SNAN_HIL_EMU_STATE`` or
  ``~/.local/share/snan-hil/emu-chip.npz``): ``emu-chip.layout.json``, so a layout always goes
  with the chip it describes;
* any other port: ``layouts/<port>.json`` in the user's data folder
  (:func:`snan_hil.userdata.user_data_dir`: ``$XDG_DATA_HOME/snan-hil``, default
  ``~/.local/share/snan-hil`` on Linux), the port name made file-safe
  (``/dev/ttyUSB0`` -> ``dev_ttyUSB0.json``, ``socket://host:5000`` -> ``socket_host_5000.json``).

The last ``program-weights`` report goes next to the layout (``<stem>.program-report.json``)
unless ``--report`` names another file. The board's history database goes next to its default
layout (``<stem>.history.sqlite``, :func:`default_history_path`): one per board, beside the
emulator's chip for ``--port emu``, in the user's data folder for real boards.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from snan_hil.userdata import user_data_dir

__all__ = ["default_layout_path", "default_report_path", "layout_path_for",
           "default_history_path"]


def default_layout_path(port: str) -> Path:
    """Default layout file of a board port (see the module docstring)."""
    if port == "emu":
        # A layout always goes with the emulated chip it describes.
        from snan_hil.firmware_emu.state import default_state_path
        state = default_state_path()
        stem = state.name[:-len(state.suffix)] if state.suffix else state.name
        return state.with_name(f"{stem}.layout.json")
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", port).strip("_") or "port"
    return user_data_dir() / "layouts" / f"{safe}.json"


def layout_path_for(port: str, layout: str | os.PathLike | None) -> Path:
    """``layout`` if given, else the port's default."""
    return Path(layout).expanduser() if layout else default_layout_path(port)


def default_report_path(layout_path: str | os.PathLike) -> Path:
    """``<layout stem>.program-report.json`` next to the layout."""
    p = Path(layout_path)
    name = p.name
    for suffix in (".layout.json", ".json"):
        if name.endswith(suffix):
            name = name[:-len(suffix)]
            break
    return p.with_name(f"{name}.program-report.json")


def default_history_path(port: str) -> Path:
    """The board's history database, ``<stem>.history.sqlite`` beside its default layout
    (:func:`default_layout_path`; an explicit ``--layout`` does not move it: the history
    belongs to the board, not to one layout)."""
    p = default_layout_path(port)
    name = p.name
    for suffix in (".layout.json", ".json"):
        if name.endswith(suffix):
            name = name[:-len(suffix)]
            break
    return p.with_name(f"{name}.history.sqlite")
