"""Two MCUs, one chip: the Python firmware model and the C firmware driven alike and compared.

:class:`EmulatedBoard` is one emulated board on a chip file of its own that can be power-cycled
the way a lab's board is: cleanly (the emulator stops, snapshots, starts again) or by a kill
(what ``kill -9`` leaves on disk - the snapshot and the journal - is started again, so the
journal is replayed). It is also the board :func:`snan_hil.protocol.conformance.run_sequence`
drives through the sequence vectors (``conformance/v1/framed/sequences.jsonl``).

:class:`TwinBoards` holds two of them on copies of one chip file - ``--mcu model`` and ``--mcu
firmware`` (the C firmware ELF on the instruction-level MCU) - with the same chip seed, chip
serial and forced boot nonces, feeds both the same bytes and after every step requires

* the same reply bytes (:func:`~snan_hil.protocol.conformance.compare_replies`: byte for byte
  except the fields docs/protocol.md leaves to the implementation: ERROR texts, INFO's version
  and board id strings, CLOCK's time and energy);
* the same SPI traffic: every frame to every chip (row DACs, write DAC, ADC, the two 74HC595s)
  in the same order with the same bytes (times differ: the firmware's own timing);
* the same chip: conductance states, breakdown flags, programming times, the chip's clock and
  its noise stream, the board's ADC noise stream.

A difference raises :class:`Divergence` naming the step and what differs. Every step is
recorded (:attr:`TwinBoards.steps`), so a failing sequence can be written as a sequence vector
(:meth:`TwinBoards.as_sequence`). The generator of sequences is
:mod:`snan_hil.firmware_emu.differential` (hypothesis); this module has no test-framework
dependency.
"""

from __future__ import annotations

import atexit
import json
import os
import shutil
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from snan_hil.firmware_emu import durable
from snan_hil.firmware_emu.emulator import Emulator
from snan_hil.protocol.conformance import (FREE_FIELDS, Sequence as VectorSequence,
                                           SequenceBoardSetup, SequenceStep, compare_replies,
                                           frames_of)
from snan_hil.protocol.frames import Frame
from snan_hil.protocol.messages import MESSAGE_TYPES

__all__ = ["DEFAULT_SERIAL", "ALL_FREE", "Divergence", "EmulatedBoard", "TwinBoards",
           "analog_reply", "fresh_chip_file", "scratch_folder"]

DEFAULT_SERIAL = "8B297CA46845"
"""The chip serial of the boards here (12 hex digits, as ``snan-hil emu`` draws them): the C
firmware reads it from the EEPROM identity record and reports it in INFO."""

ALL_FREE = tuple(f"{name}.{f}" for name, fs in FREE_FIELDS.items() for f in fs)
"""Every reply field an implementation chooses itself (docs/protocol.md, section 7)."""

_ANALOG_TYPES = frozenset(t for t, cls in MESSAGE_TYPES.items() if cls.__name__ in (
    "ReadCellReply", "ReadColumnReply", "WritePulseReply", "SpikeBatchReply",
    "ProgramCellReply", "StatusReply"))


class Divergence(AssertionError):
    """The two MCUs answered or left the board differently (the message says where)."""


def analog_reply(wire: bytes) -> bool:
    """Whether a board's answer carries chip measurements (ADC codes, counters after them)."""
    return any(isinstance(f, Frame) and f.type in _ANALOG_TYPES for f in frames_of(wire))


_TEMPLATES: dict[tuple[int, str | None], Path] = {}


def scratch_folder(prefix: str) -> Path:
    """A new temporary folder for chip files, on a RAM disk (``/dev/shm``) where there is one:
    the emulator fsyncs its journal and snapshots, which costs milliseconds on a disk and
    nothing there (the files' contents are the same)."""
    shm = Path("/dev/shm")
    root = shm if shm.is_dir() and os.access(shm, os.W_OK) else None
    return Path(tempfile.mkdtemp(prefix=prefix, dir=root))


def fresh_chip_file(chip_seed: int, serial: str | None) -> Path:
    """A chip file as :func:`durable.create_chip` makes it from ``chip_seed`` with ``serial``,
    made once per process (a new chip parses the device configuration: ~0.3 s) and copied by
    the callers; it lives in a temporary folder removed at exit."""
    key = (int(chip_seed), serial)
    path = _TEMPLATES.get(key)
    if path is None or not path.exists():
        folder = scratch_folder("snan-chip-")
        atexit.register(shutil.rmtree, folder, True)
        path = folder / "chip.npz"
        durable.create_chip(path, chip_seed, serial)
        _TEMPLATES[key] = path
    return path


class EmulatedBoard:
    """One emulated board (``mcu`` "model" or "firmware") on the chip file ``folder/chip.npz``
    (created from ``chip_seed`` with serial ``serial`` when missing), booted with the forced
    ``boot_nonces`` (power-on, then one per RESET). ``trace``: record the SPI traffic.

    :meth:`feed` is the UART; :meth:`restart` power-cycles it: ``kill=False`` stops the
    emulator cleanly (snapshot) and starts it again; ``kill=True`` stops it as a SIGKILL would
    (:meth:`Emulator.kill`: every answered request is in the journal, nothing else is written)
    and starts a new one on the files, which replays the journal.
    """

    def __init__(self, folder: str | Path, mcu: str, *, chip_seed: int = 0,
                 serial: str | None = DEFAULT_SERIAL, boot_nonces: Sequence[int] = (1,),
                 baud: int = 115200, trace: bool = True):
        self.root = Path(folder)
        self.root.mkdir(parents=True, exist_ok=True)
        self.mcu, self.chip_seed, self.baud, self.trace = mcu, int(chip_seed), int(baud), trace
        self.path = self.root / "chip.npz"
        if not self.path.exists():
            shutil.copy2(fresh_chip_file(self.chip_seed, serial), self.path)
        self.starts = 0
        self.emu = self._start(boot_nonces)

    def _start(self, boot_nonces: Sequence[int]) -> Emulator:
        self.starts += 1
        emu = Emulator(self.path, self.chip_seed, mcu=self.mcu, baud=self.baud,
                       boot_nonces=list(boot_nonces))
        if self.trace:
            emu.board.bus.trace = []
        return emu

    def feed(self, data: bytes) -> bytes:
        """Bytes from the host -> the board's answer."""
        return self.emu.feed(data)

    def restart(self, *, kill: bool, boot_nonces: Sequence[int]) -> None:
        """Power-cycle the board (see the class doc); the next boot draws ``boot_nonces``."""
        if kill:
            self.emu.kill()          # the files as a SIGKILL leaves them
        else:
            self.emu.close()
        self.emu = self._start(boot_nonces)

    def take_trace(self) -> list[tuple[str, bytes]]:
        """The SPI frames (chip select, bytes sent) since the last call."""
        trace = self.emu.board.bus.trace
        if trace is None:
            return []
        out = [(t.cs, bytes(t.mosi)) for t in trace]
        trace.clear()
        return out

    def chip(self) -> dict[str, Any]:
        """What must be equal between two boards on equal chips: the array (states, breakdown,
        programming times, clock, noise stream: every pulse draws from it) and the board's ADC
        noise stream. (Not the front end's pulse counter: the model zeroes it at a RESET as
        its STATUS counter, the C firmware keeps its own; STATUS compares those.)"""
        a = self.emu.array
        fe = self.emu.board.front_end
        return {"state": a.state.tobytes(), "broken": a.broken.tobytes(),
                "t_prog": a.t_prog.tobytes(), "time_s": float(a.time_s),
                "chip_noise": json.dumps(a.noise_state, sort_keys=True, default=str),
                "adc_noise": json.dumps(fe._rng.bit_generator.state, sort_keys=True,
                                        default=str)}

    @property
    def mcu_faults(self) -> dict[str, int]:
        """Resets and bad register accesses of the firmware MCU (empty for the model)."""
        backend = self.emu.backend
        if backend is None:
            return {}
        mcu = backend.mcu
        out = dict(mcu.faults)
        if mcu.resets:
            out.update({f"reset: {k}": v for k, v in mcu.reset_causes.items()})
        return out

    def close(self) -> None:
        self.emu.close()


@dataclass
class TwinBoards:
    """The two MCUs on copies of one chip (see the module doc). ``folder``: where their chip
    files live (a scratch folder)."""

    folder: Path
    chip_seed: int = 0
    serial: str | None = DEFAULT_SERIAL
    boot_nonces: tuple[int, ...] = (0x5EED1234, 0x5EED5678, 0x5EED9ABC)
    baud: int = 115200
    steps: list[SequenceStep] = field(default_factory=list)
    boards: dict[str, EmulatedBoard] = field(default_factory=dict)

    MCUS = ("model", "firmware")

    def __post_init__(self) -> None:
        self.folder = Path(self.folder)
        template = fresh_chip_file(self.chip_seed, self.serial)
        for mcu in self.MCUS:
            (self.folder / mcu).mkdir(parents=True, exist_ok=True)
            shutil.copy2(template, self.folder / mcu / "chip.npz")
        for mcu in self.MCUS:
            self.boards[mcu] = EmulatedBoard(self.folder / mcu, mcu, chip_seed=self.chip_seed,
                                             serial=self.serial, boot_nonces=self.boot_nonces,
                                             baud=self.baud)
        self._check("power-on")

    # ------------------------------------------------------------------ steps
    def send(self, data: bytes, name: str = "send", note: str = "") -> bytes:
        """Feed ``data`` to both boards; the model's answer. Divergence if they differ."""
        outs = {mcu: b.feed(data) for mcu, b in self.boards.items()}
        expect = outs["model"]
        self.steps.append(SequenceStep(name, "send", data, expect, note=note, free=ALL_FREE,
                                       analog=analog_reply(expect)))
        why = compare_replies(expect, outs["firmware"], ALL_FREE)
        if why:
            raise Divergence(self._where(f"replies differ: {why}"))
        self._check(name)
        return expect

    def restart(self, *, kill: bool, boot_nonces: Sequence[int], name: str = "",
                note: str = "") -> None:
        """Power-cycle both boards alike (cleanly or by a kill, then journal replay)."""
        nonces = tuple(int(n) for n in boot_nonces)
        for b in self.boards.values():
            b.restart(kill=kill, boot_nonces=nonces)
        self.steps.append(SequenceStep(name or ("kill and restart" if kill else "restart"),
                                       "restart", kill=kill, boot_nonces=nonces, note=note))
        self._check(self.steps[-1].name)

    def _check(self, name: str) -> None:
        model, fw = self.boards["model"], self.boards["firmware"]
        faults = fw.mcu_faults
        if faults:
            raise Divergence(self._where(f"the firmware MCU faulted: {faults}"))
        ta, tb = model.take_trace(), fw.take_trace()
        if ta != tb:
            k = next((i for i, (x, y) in enumerate(zip(ta, tb)) if x != y), min(len(ta), len(tb)))
            show = lambda t: f"{t[k][0]} {t[k][1].hex()}" if k < len(t) else "nothing"  # noqa: E731
            raise Divergence(self._where(
                f"SPI traffic differs at frame {k} of {len(ta)} (model) / {len(tb)} "
                f"(firmware): model {show(ta)}, firmware {show(tb)}"))
        ca, cb = model.chip(), fw.chip()
        diff = [k for k in ca if ca[k] != cb[k]]
        if diff:
            raise Divergence(self._where("the chips differ after the step: " + ", ".join(diff)))

    def _where(self, what: str) -> str:
        return f"step {len(self.steps)} ({self.steps[-1].name if self.steps else 'start'}): {what}"

    # ------------------------------------------------------------------ results
    def as_sequence(self, name: str, title: str) -> VectorSequence:
        """The steps so far as a sequence vector (the model's answers as ``expect``)."""
        board = SequenceBoardSetup(chip_seed=self.chip_seed, chip_serial=self.serial,
                                   baud=self.baud, boot_nonces=self.boot_nonces)
        return VectorSequence(name, title, board, tuple(self.steps))

    def close(self) -> None:
        for b in self.boards.values():
            b.close()

    def __enter__(self) -> "TwinBoards":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
