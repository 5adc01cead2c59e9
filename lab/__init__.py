"""The lab layer: opening boards (the opener) and the notebook API.

* :func:`~snan_hil.lab.opener.plan_board` / :class:`~snan_hil.lab.opener.BoardPlan` — the one
  place a :class:`~snan_hil.board.session.BoardSession` is built (outputs checked, history,
  emulator state, client, HELLO, in that order), from a port string or URL
  (:class:`~snan_hil.lab.ports.BoardAddress`);
* :func:`open_board` — ``with snan_hil.open_board("emu://?state=chip.npz&seed=3") as board:``
  read a cell, map, pulse, program weights, run a scenario (:mod:`snan_hil.lab.notebook`,
  docs/notebook.md).

Above ``host`` in the layers (tools > lab > host > calibration | firmware_emu > board >
protocol | crossbar_model): it may use the emulator (its ``emu://`` transport, chip files).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__all__ = ["open_board", "BoardAddress", "FileUse", "plan_board", "open_session"]

if TYPE_CHECKING:
    from snan_hil.lab.notebook import open_board
    from snan_hil.lab.opener import FileUse, open_session, plan_board
    from snan_hil.lab.ports import BoardAddress

_WHERE = {"open_board": "snan_hil.lab.notebook", "BoardAddress": "snan_hil.lab.ports",
          "FileUse": "snan_hil.lab.opener", "plan_board": "snan_hil.lab.opener",
          "open_session": "snan_hil.lab.opener"}


def __getattr__(name: str) -> Any:
    """Import on first use (``import snan_hil.lab`` stays cheap)."""
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(_WHERE[name]), name)
