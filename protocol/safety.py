"""Host-side safety limits: no request leaves the host with a read above ``max_read_v`` or a
write above ``max_write_v`` (V), whatever the firmware would do with it.

The limits come from the board's INFO (or its defaults before HELLO). A DAC code is allowed
only if its voltage does not exceed the limit (floor, not nearest: 0.3 V at 12 bit / 5 V is
code 245 = 0.2991 V, not 246 = 0.3004 V). Compliance current depends on the cell's state and is
checked by the caller that knows it (calibration) and by the firmware.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

from snan_hil.protocol.errors import ProtocolError
from snan_hil.protocol.messages import Info

__all__ = ["HostSafetyError", "HostLimits", "floor_code"]


class HostSafetyError(ProtocolError):
    """A request would exceed a safety limit; it was not sent."""


def floor_code(volts: float, to_code: Callable[[float], int],
               to_volts: Callable[[int], float]) -> int:
    """Largest DAC code whose voltage does not exceed ``volts`` (V)."""
    code = max(0, to_code(volts))
    while code > 0 and to_volts(code) > volts:
        code -= 1
    return code


@dataclass(frozen=True, slots=True)
class HostLimits:
    """Largest row-DAC code of a read and write-DAC code of a pulse this host sends."""

    max_read_code: int
    max_write_code: int
    max_read_v: float
    max_write_v: float

    @classmethod
    def from_info(cls, info: Info) -> "HostLimits":
        read = min(floor_code(info.max_read_v, info.dac_code, info.dac_volts),
                   floor_code(info.max_read_v, info.write_dac_code, info.write_dac_volts))
        write = floor_code(info.max_write_v, info.write_dac_code, info.write_dac_volts)
        return cls(read, write, info.max_read_v, info.max_write_v)

    def check_reads(self, codes: Iterable[int], what: str) -> None:
        """Refuse any read DAC code above ``max_read_code``."""
        top = max((int(c) for c in codes), default=0)
        if top > self.max_read_code:
            raise HostSafetyError(
                f"{what}: read DAC code {top} exceeds the read limit {self.max_read_v} V "
                f"(largest allowed code {self.max_read_code}); not sent")

    def check_write(self, code: int, what: str) -> None:
        """Refuse a write-DAC amplitude code above ``max_write_code``."""
        if int(code) > self.max_write_code:
            raise HostSafetyError(
                f"{what}: write amplitude code {int(code)} exceeds the write limit "
                f"{self.max_write_v} V (largest allowed code {self.max_write_code}); not sent")
