"""Write-pulse polarity: the one type every layer uses for SET / RESET.

A base module like :mod:`snan_hil.common.errors`: every layer (protocol and crossbar_model included)
may import it. The numbering is the wire's (the legacy line protocol's ``sign`` field and the
framed WRITE_PULSE ``polarity`` byte, docs/protocol.md); :meth:`Polarity.parse` turns a
command-line word into it, and ``polarity.name`` is what reports and logs print.
"""

from __future__ import annotations

from enum import IntEnum

__all__ = ["Polarity"]


class Polarity(IntEnum):
    """Polarity of a write pulse on the MemriCore board (shared/reference/memricore-board.md).

    ``RESET`` (0): positive pulse on the bit line, conductance goes down (ADC code goes down);
    ``SET`` (1): negative pulse, conductance goes up (ADC code goes up). In the VTEAM model
    (crossbar_model.vteam) SET is the "on" switching direction and RESET the "off" one.
    """

    RESET = 0
    SET = 1

    @classmethod
    def parse(cls, text: str) -> Polarity:
        """``"set"`` / ``"SET"`` / ``"reset"`` ... -> Polarity; ValueError naming the choices."""
        try:
            return cls[text.strip().upper()]
        except KeyError:
            raise ValueError(f"polarity must be SET or RESET, got {text!r}") from None
