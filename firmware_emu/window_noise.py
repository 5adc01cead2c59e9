"""A lean decision window's noise, keyed by the window (issue 33).

The emulated chip draws its read noise from one stream and the ADC its noise from another,
both running through every request. A decision window read with the lean plan (READ_PLAN,
conversions > 0) instead draws both from streams keyed by the chip (the array's seed, the ADC
stream's seed) and the window's own key (the host's spike-stream state of that window): its
reads then do not depend on what the board did before it, so launches whose windows the host
interleaves on the board (two requests outstanding, docs/hil.md) see the very reads they see
one after another, and a window sent again sees its reads again. The streams the other
requests use are left where they were; a window with the standard reads draws from them, as
SPIKE_BATCH does (so the on-board window with the standard reads and the batch mode read
alike). The statistics are those of the model (the same normal draws, another realisation);
both MCUs key alike (the Python MCU around the lean reads of DecisionWindowOp.run, the
instruction-level MCU around the firmware's ``run_lean``).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

MASK32 = (1 << 32) - 1


def stream_state(seed: int, other: int, key: int, salt: int) -> dict[str, Any]:
    """The PCG64 state of the stream keyed by ``(seed, other, key, salt)``."""
    material = [int(seed) & MASK32, int(seed) >> 32 & MASK32, int(other) & MASK32,
                int(other) >> 32 & MASK32, int(key) & MASK32, int(key) >> 32 & MASK32, salt]
    return dict(np.random.PCG64(np.random.SeedSequence(material)).state)


@contextmanager
def keyed(board: Any, key: int) -> Iterator[None]:
    """Inside: the chip's read noise and the ADC's noise of ``board`` (an emulated
    :class:`~snan_hil.firmware_emu.board.Board`) come from streams keyed by ``key``; after:
    both streams are where they were. A chip without a settable stream is left as it is.
    ``board.noise_salt`` (default 0) picks another realisation (the read-noise budget's
    floor: two boards reading the same windows with other noise, bench/bench_window.py)."""
    fe = board.front_end
    array = fe.array
    get = getattr(array, "rng_state", None)
    if get is None or getattr(array, "seed", None) is None:
        yield
        return
    saved = (get(), fe._rng.bit_generator.state)
    salt = 2 * int(getattr(board, "noise_salt", 0))
    array.set_rng_state(stream_state(array.seed, fe.seed, key, salt))
    fe._rng.bit_generator.state = stream_state(array.seed, fe.seed, key, salt + 1)
    try:
        yield
    finally:
        array.set_rng_state(saved[0])
        fe._rng.bit_generator.state = saved[1]


def other_realisation(board: Any, salt: int) -> None:
    """Give ``board`` (an emulated :class:`~snan_hil.firmware_emu.board.Board`) another
    realisation of its noise from here on: its running streams (the standard reads') restarted
    on streams keyed by ``salt``, and ``board.noise_salt`` = ``salt`` for the keyed windows.
    Two copies of one chip, one of them so changed, read the same requests with independent
    noise (the read-noise budget's floor, bench/bench_window.py). A chip without a settable
    stream is left as it is."""
    fe = board.front_end
    array = fe.array
    if getattr(array, "set_rng_state", None) is None or getattr(array, "seed", None) is None:
        return
    board.noise_salt = int(salt)
    array.set_rng_state(stream_state(array.seed, fe.seed, MASK32, 2 * int(salt)))
    fe._rng.bit_generator.state = stream_state(array.seed, fe.seed, MASK32, 2 * int(salt) + 1)
