"""The board session: one board as one instrument (docs/architecture.md, "The board session").

A layer between the jobs (``calibration``, and ``host`` above it) and the wire (``protocol``):
:class:`~snan_hil.board.session.BoardSession` holds the connected client, the board's INFO, the
host limits, the identity (:class:`~snan_hil.board.identity.BoardIdentity`) and the board's
files (:class:`~snan_hil.board.files.BoardFiles`, pure path rules). It never opens a port and
never imports the emulator: :mod:`snan_hil.lab` builds sessions (the opener).
"""

from snan_hil.board.files import BoardFiles
from snan_hil.board.identity import BoardIdentity
from snan_hil.board.session import BoardSession, ChipSnapshots

__all__ = ["BoardFiles", "BoardIdentity", "BoardSession", "ChipSnapshots"]
