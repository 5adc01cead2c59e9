"""Figure titles that name what is shown, the board, the port and the date (docs/bench.md)."""

from __future__ import annotations

import datetime as _dt

from snan_hil.protocol.messages import Info

__all__ = ["figure_title", "board_text"]


def board_text(info: Info | None, port: str | None, board_id: str | None = None) -> str:
    """``board EMU-4D430001, port emu`` (what is known of it; ``board_id`` when there is no
    INFO, e.g. from the history; ``port`` may list several, "a, b": then "ports")."""
    parts = []
    board = info.board_id if info is not None and info.board_id else board_id
    if board:
        parts.append(f"board {board}")
    if port:
        parts.append(f"{'ports' if ', ' in port else 'port'} {port}")
    return ", ".join(parts)


def figure_title(what: str, info: Info | None, port: str | None,
                 when: _dt.datetime | None = None, *, board_id: str | None = None) -> str:
    """``<what> — board <id>, port <port>, <YYYY-MM-DD HH:MM> UTC``."""
    when = when or _dt.datetime.now(_dt.timezone.utc)
    stamp = when.astimezone(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    where = board_text(info, port, board_id)
    return f"{what} — {where + ', ' if where else ''}{stamp}"
