"""Who a board is: :class:`BoardIdentity`, built once from its INFO.

A board says who it is in INFO's ``board_id``: ``EMU-4D430001/<chip serial>`` for the Python
firmware model of the emulator, ``MC-4D430001/<chip serial>`` for the C firmware (which reads
the serial from the board's EEPROM), a MemriCore board's firmware id otherwise; old firmware
over the legacy line protocol says nothing (``""`` or ``"legacy"``). Everything a host keeps
about a board — its layout, program reports, history database, a run's resume key — is keyed
by this identity (docs/durability.md, "Layouts"), never by the port string, except for a board
that says nothing, which only its port can name.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from snan_hil.protocol.messages import Info

__all__ = ["BoardIdentity", "UNKNOWN_BOARD_IDS"]

UNKNOWN_BOARD_IDS = ("", "legacy")
"""Board ids of a board that does not say who it is (old firmware, legacy protocol)."""


@dataclass(frozen=True, slots=True)
class BoardIdentity:
    """The board id (with its chip part after ``/``) and firmware version a board reports."""

    board_id: str = ""
    firmware_version: str = ""

    @classmethod
    def from_info(cls, info: Info) -> BoardIdentity:
        """The identity in a board's INFO reply."""
        return cls(str(info.board_id), str(info.firmware_version))

    @classmethod
    def from_record(cls, record: dict[str, Any] | None) -> BoardIdentity:
        """The identity recorded in a file (a layout's ``board``, a report's ``board``)."""
        record = record or {}
        return cls(str(record.get("board_id") or ""), str(record.get("firmware_version") or ""))

    @property
    def known(self) -> bool:
        """Whether the board said who it is (see :data:`UNKNOWN_BOARD_IDS`)."""
        return self.board_id not in UNKNOWN_BOARD_IDS

    @property
    def chip_id(self) -> str:
        """The chip part of the board id (after ``/``; the chip serial of an emulated chip),
        "" for a board that names no chip."""
        return self.board_id.partition("/")[2]

    @property
    def board_model(self) -> str:
        """The board part of the board id (before ``/``)."""
        return self.board_id.partition("/")[0]

    def to_dict(self, **extra: Any) -> dict[str, Any]:
        """``{"board_id", "firmware_version"}`` and ``extra`` (e.g. ``port=``): the one shape
        in which results and layouts record the board."""
        return {"board_id": self.board_id, "firmware_version": self.firmware_version, **extra}

    def resume_key(self, port: str) -> dict[str, str | None]:
        """What identifies the board in a run's identity (``--resume`` refuses another one):
        the board id, not the port (the same board or served chip may come back on another
        port); a board that says nothing is keyed by its port as well."""
        if self.known:
            return {"board_id": self.board_id}
        return {"board_id": self.board_id, "port": port}

    def owns(self, recorded: BoardIdentity) -> bool:
        """Whether something recorded for the board ``recorded`` (a layout, a report) may be
        used with this one: the same board id, or either side says nothing about who it
        is."""
        return not recorded.known or not self.known or recorded.board_id == self.board_id

    def other_chip_note(self, recorded: BoardIdentity) -> str:
        """`` (another chip: ...)`` when ``recorded`` is the same board model with another
        chip (the emulator's chip was reset or replaced), else ""."""
        if recorded.board_model == self.board_model and recorded.board_id != self.board_id:
            return " (another chip: the emulator's chip was reset or replaced)"
        return ""
