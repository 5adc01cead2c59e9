"""On-board learning's messages (issue 34 stage 1; docs/protocol.md, "On-board learning"):
LEARN_SETUP (0x0B), LEARN_APPLY (0x0C), LEARN_STATE (0x0D) and LEARN_WINDOW (0x0E: a
DECISION_WINDOW of a training trial, with the trial, the window's index and the host's
decision on the window before it). Capability bit 8 (:data:`LEARN_CAPABILITY`).

Formats: weights, changes and predicted steps are int32 Q1.30; decay and amplitude factors
u64 Q0.64; a synapse's cell is one byte ``row << 3 | col``. The board's arithmetic is
:mod:`snan_hil.firmware_emu.learn_fixed`; the host builds the block in
:mod:`snan_hil.host.hil.board_learning`. Registered in the message tables of
:mod:`snan_hil.protocol.messages` on import (the package ``snan_hil.protocol`` imports it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from snan_hil.protocol.errors import FieldRangeError, MalformedPayloadError
from snan_hil.protocol.messages import (DW_ALPHA_TABLE, MESSAGE_TYPES, REQUEST_TYPES,
                                        Capability, DecisionWindow, DecisionWindowReply, Reply,
                                        Request, _pack, _Reader)

__all__ = ["LEARN_CAPABILITY", "LEARN_MAX_SYNAPSES", "LEARN_W_ONE", "LEARN_TABLE_BITS",
           "LEARN_NO_LANE", "LearnSynapse", "LearnSetup", "LearnSetupReply", "LearnApply",
           "LearnApplyReply", "LearnOrder",
           "LearnTouched", "LearnState", "LearnStateReply", "LearnSynapseState", "LearnWindow",
           "LearnWindowReply", "cell_byte", "cell_of"]

LEARN_CAPABILITY = Capability.LEARN
"""INFO capability bit 8: the board learns (these messages)."""
LEARN_MAX_SYNAPSES = 128
LEARN_W_ONE = 1 << 30
"""1.0 in the Q1.30 weights, changes and steps."""
LEARN_TABLE_BITS = (4, 5, 6, 7)
"""Allowed ``table_bits`` b of the step tables (2^b intervals over the weight window 0..1)."""
LEARN_NO_LANE = 7
"""``decided``: no lane chosen (or no window before this one)."""
_HEAD = "<BBBHHHHQQii"
_SYN = "<Bii"


def cell_byte(row: int, col: int) -> int:
    """A synapse's cell on the wire: ``row << 3 | col`` (rows 0..31, columns 0..7)."""
    if not (0 <= row < 32 and 0 <= col < 8):
        raise FieldRangeError(f"cell ({row},{col}) does not fit the learning's cell byte")
    return row << 3 | col


def cell_of(byte: int) -> tuple[int, int]:
    return byte >> 3, byte & 7


@dataclass(frozen=True, slots=True)
class LearnSynapse:
    """One synapse of the learning table: its cell byte, intended weight, estimate (Q1.30)."""

    cell: int
    w_int: int
    w_est: int


@dataclass(frozen=True, slots=True)
class LearnSetupReply(Reply):
    TYPE: ClassVar[int] = 0x8B
    FMT: ClassVar[str] = "<BI"
    n_syn: int = 0
    pulses_applied: int = 0


@dataclass(frozen=True, slots=True)
class LearnSetup(Request[LearnSetupReply]):
    """The learning block and the session's synapses (docs/protocol.md "0x0B LEARN_SETUP").
    The board replaces its learning state with this one."""

    TYPE: ClassVar[int] = 0x0B
    flags: int = 0
    table_bits: int = 6
    max_pulses: int = 127
    set_code: int = 0
    reset_code: int = 0
    width_us: int = 100
    last_trial: int = 0
    k_a_plus: int = 0
    k_a_minus: int = 0
    w_min: int = 0
    w_max: int = 1 << 30
    dec_plus_pow: tuple[int, ...] = (0,) * DW_ALPHA_TABLE
    dec_minus_pow: tuple[int, ...] = (0,) * DW_ALPHA_TABLE
    set_steps: tuple[int, ...] = ()
    reset_steps: tuple[int, ...] = ()
    synapses: tuple[LearnSynapse, ...] = ()

    @property
    def nearest(self) -> bool:
        return bool(self.flags & 1)

    def encode(self) -> bytes:
        n_pts = (1 << self.table_bits) + 1 if 0 <= self.table_bits <= 8 else -1
        if len(self.set_steps) != n_pts or len(self.reset_steps) != n_pts:
            raise FieldRangeError(f"LearnSetup: step tables need 2^{self.table_bits} + 1 "
                                  "points each")
        if len(self.dec_plus_pow) != DW_ALPHA_TABLE or len(self.dec_minus_pow) != DW_ALPHA_TABLE:
            raise FieldRangeError(f"LearnSetup: decay tables need {DW_ALPHA_TABLE} values")
        if len(self.synapses) > 255:
            raise FieldRangeError("LearnSetup: more than 255 synapses")
        out = [_pack(_HEAD, self.flags, self.table_bits, self.max_pulses, self.set_code,
                     self.reset_code, self.width_us, self.last_trial, self.k_a_plus,
                     self.k_a_minus, self.w_min, self.w_max),
               _pack(f"<{DW_ALPHA_TABLE}Q{DW_ALPHA_TABLE}Q", *self.dec_plus_pow,
                     *self.dec_minus_pow),
               _pack(f"<{n_pts}i{n_pts}i", *self.set_steps, *self.reset_steps),
               _pack("<B", len(self.synapses))]
        out += [_pack(_SYN, s.cell, s.w_int, s.w_est) for s in self.synapses]
        return b"".join(out)

    @classmethod
    def decode(cls, payload: bytes) -> "LearnSetup":
        r = _Reader(cls, payload)
        head = r.take(_HEAD)
        if head[0] & ~1:
            raise MalformedPayloadError(f"LearnSetup: unknown flag bits 0x{head[0]:02x}")
        if head[1] > 8:
            raise MalformedPayloadError(f"LearnSetup: table_bits {head[1]} cannot be framed")
        n = DW_ALPHA_TABLE
        dec = r.take(f"<{n}Q{n}Q")
        n_pts = (1 << head[1]) + 1
        steps = r.take(f"<{n_pts}i{n_pts}i")
        (n_syn,) = r.take("<B")
        syn = tuple(LearnSynapse(*r.take(_SYN)) for _ in range(n_syn))
        r.end()
        names = ("flags", "table_bits", "max_pulses", "set_code", "reset_code", "width_us",
                 "last_trial", "k_a_plus", "k_a_minus", "w_min", "w_max")
        return cls(**dict(zip(names, head)), dec_plus_pow=tuple(dec[:n]),
                   dec_minus_pow=tuple(dec[n:]), set_steps=tuple(steps[:n_pts]),
                   reset_steps=tuple(steps[n_pts:]), synapses=syn)


@dataclass(frozen=True, slots=True)
class LearnWindowReply(DecisionWindowReply):
    """A learning window's reply: DECISION_WINDOW's (:class:`DecisionWindowReply`)."""

    TYPE: ClassVar[int] = 0x8E


@dataclass(frozen=True, slots=True)
class LearnWindow(Request[LearnWindowReply]):
    """A decision window of a training trial (docs/protocol.md "0x0E LEARN_WINDOW"):
    ``u16 trial, u16 window, u8 decided`` then the DECISION_WINDOW payload of ``window_req``.
    ``decided``: the lane the host chose in window ``window - 1`` (:data:`LEARN_NO_LANE`:
    none)."""

    TYPE: ClassVar[int] = 0x0E
    trial: int = 1
    window: int = 0
    decided: int = LEARN_NO_LANE
    window_req: DecisionWindow = DecisionWindow()

    def encode(self) -> bytes:
        return _pack("<HHB", self.trial, self.window, self.decided) + self.window_req.encode()

    @classmethod
    def decode(cls, payload: bytes) -> "LearnWindow":
        r = _Reader(cls, payload)
        trial, window, decided = r.take("<HHB")
        if decided & ~0x07:
            raise MalformedPayloadError(f"LearnWindow: decided byte 0x{decided:02x}")
        return cls(trial, window, decided, DecisionWindow.decode(payload[5:]))


@dataclass(frozen=True, slots=True)
class LearnOrder:
    """Pulses applied to one synapse at a trial's end: ``polarity`` 0 SET, 1 RESET."""

    synapse: int
    polarity: int
    count: int


@dataclass(frozen=True, slots=True)
class LearnTouched:
    """A synapse a trial touched, its new state (Q1.30)."""

    synapse: int
    w_int: int
    w_est: int


@dataclass(frozen=True, slots=True)
class LearnApplyReply(Reply):
    """The trial's pulse orders and the synapses it touched (docs/protocol.md "0x0C")."""

    TYPE: ClassVar[int] = 0x8C
    already: bool = False
    trial: int = 0
    pulses_applied: int = 0
    orders: tuple[LearnOrder, ...] = ()
    touched: tuple[LearnTouched, ...] = ()

    def encode(self) -> bytes:
        out = [_pack("<BHIB", int(self.already), self.trial, self.pulses_applied,
                     len(self.orders))]
        for o in self.orders:
            if not (0 < o.count < 128 and o.polarity in (0, 1)):
                raise FieldRangeError(f"LearnApplyReply: order {o}")
            out.append(_pack("<BB", o.synapse, o.polarity << 7 | o.count))
        out.append(_pack("<B", len(self.touched)))
        out += [_pack(_SYN, t.synapse, t.w_int, t.w_est) for t in self.touched]
        return b"".join(out)

    @classmethod
    def decode(cls, payload: bytes) -> "LearnApplyReply":
        r = _Reader(cls, payload)
        flags, trial, pulses, n = r.take("<BHIB")
        if flags & ~1:
            raise MalformedPayloadError(f"LearnApplyReply: flags 0x{flags:02x}")
        orders = []
        for _ in range(n):
            j, pc = r.take("<BB")
            if not pc & 0x7F:
                raise MalformedPayloadError("LearnApplyReply: an order of 0 pulses")
            orders.append(LearnOrder(j, pc >> 7, pc & 0x7F))
        (nt,) = r.take("<B")
        touched = tuple(LearnTouched(*r.take(_SYN)) for _ in range(nt))
        r.end()
        return cls(bool(flags & 1), trial, pulses, tuple(orders), touched)

    @property
    def pulses(self) -> int:
        return sum(o.count for o in self.orders)


@dataclass(frozen=True, slots=True)
class LearnApply(Request[LearnApplyReply]):
    """A training trial's end: the decision on its last window, then the plan applied."""

    TYPE: ClassVar[int] = 0x0C
    FMT: ClassVar[str] = "<HHB"
    trial: int = 1
    window: int = 0
    decided: int = LEARN_NO_LANE


@dataclass(frozen=True, slots=True)
class LearnSynapseState:
    """One synapse in LEARN_STATE's reply: cell byte, weights (Q1.30), the ledger."""

    cell: int
    w_int: int
    w_est: int
    n_set: int
    n_reset: int


@dataclass(frozen=True, slots=True)
class LearnStateReply(Reply):
    TYPE: ClassVar[int] = 0x8D
    last_trial: int = 0
    pulses_applied: int = 0
    n_syn: int = 0
    first: int = 0
    synapses: tuple[LearnSynapseState, ...] = ()

    def encode(self) -> bytes:
        out = [_pack("<HIBBB", self.last_trial, self.pulses_applied, self.n_syn, self.first,
                     len(self.synapses))]
        out += [_pack("<BiiHH", s.cell, s.w_int, s.w_est, s.n_set, s.n_reset)
                for s in self.synapses]
        return b"".join(out)

    @classmethod
    def decode(cls, payload: bytes) -> "LearnStateReply":
        r = _Reader(cls, payload)
        last, pulses, n_syn, first, count = r.take("<HIBBB")
        syn = tuple(LearnSynapseState(*r.take("<BiiHH")) for _ in range(count))
        r.end()
        return cls(last, pulses, n_syn, first, syn)


@dataclass(frozen=True, slots=True)
class LearnState(Request[LearnStateReply]):
    """Read the learning state and the ledger of synapses ``first .. first + count - 1``."""

    TYPE: ClassVar[int] = 0x0D
    FMT: ClassVar[str] = "<BB"
    first: int = 0
    count: int = 255


def _register(*classes: Any) -> None:
    for cls in classes:
        MESSAGE_TYPES[cls.TYPE] = cls
        if issubclass(cls, Request):
            REQUEST_TYPES[cls.TYPE] = cls
            assert cls.REPLY.TYPE == cls.TYPE | 0x80, cls


_register(LearnSetup, LearnSetupReply, LearnApply, LearnApplyReply, LearnState,
          LearnStateReply, LearnWindow, LearnWindowReply)
