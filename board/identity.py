"""Who a board is: :class:`BoardIdentity`, built once from its INFO.

A board says who it is in INFO's ``board_id``: ``EMU-4D430001/<chip serial>`` for the Python
firmware model of the emulator, ``MC-4D430001/<chip serial>`` for the C firmware (which reads
the serial from the board's EEPROM), a MemriCore board's firmware id otherwise; old firmware
over the legacy line protocol says nothing (``""`` or ``"legacy"``). Everything a host keeps
about a board — its layout, program reports, history database, a run's resume key — is keyed
by this identity (docs/durability.md, "Layouts"), never by the port string, except for a board
that says nothing, which only its port can name. An emulated chip is one board whichever MCU
model runs it: ``EMU-`` and ``MC-`` ids with the same board number and chip serial are the same
board (:attr:`BoardIdentity.chip_key`), so its layout and history serve ``--mcu model`` and
``--mcu firmware`` alike.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from snan_hil.protocol.messages import Info

__all__ = ["BoardIdentity", "UNKNOWN_BOARD_IDS"]

UNKNOWN_BOARD_IDS = ("", "legacy")
"""Board ids of a board that does not say who it is (old firmware, legacy protocol)."""
_OWN_MCU_PREFIXES = ("EMU", "MC")
"""Board-id prefixes of this project's firmware: the Python MCU model, the C firmware."""


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

    @property
    def chip_key(self) -> str:
        """The board id without the MCU prefix of this project's firmware (``EMU-``: the
        emulator's Python MCU model, ``MC-``: the C firmware) when it names a chip: an
        emulated chip is the same board whichever MCU model runs it (``--mcu model`` reports
        ``EMU-4D430001/<serial>``, ``--mcu firmware`` ``MC-4D430001/<serial>``: the C firmware
        says what it would say on a real board); else the board id."""
        model, sep, rest = self.board_id.partition("-")
        if sep and model in _OWN_MCU_PREFIXES and self.chip_id:
            return rest
        return self.board_id

    def same_board(self, other: BoardIdentity) -> bool:
        """The same board id, or the same chip under the other MCU model (:attr:`chip_key`)."""
        return self.board_id == other.board_id or self.chip_key == other.chip_key

    def owns(self, recorded: BoardIdentity) -> bool:
        """Whether something recorded for the board ``recorded`` (a layout, a report) may be
        used with this one: the same board (:meth:`same_board`: an emulated chip recorded
        under either MCU model), or either side says nothing about who it is."""
        return not recorded.known or not self.known or self.same_board(recorded)

    def other_chip_note(self, recorded: BoardIdentity) -> str:
        """`` (another chip: ...)`` when ``recorded`` is the same board model with another
        chip (the emulator's chip was reset or replaced), else ""."""
        if recorded.board_model == self.board_model and not self.same_board(recorded):
            return " (another chip: the emulator's chip was reset or replaced)"
        return ""
