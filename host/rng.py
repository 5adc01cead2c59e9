"""Random streams shared bit-for-bit by the reference implementation and the numba kernels.

Per trial there are two sources of randomness:

* numpy ``Generator`` objects (PCG64) seeded from ``SeedSequence([seed, trial])`` (see
  :func:`trial_keys`) that draw the start/goal cells and, separately, the initial weights --
  always in Python, before the trial runs;
* a *window stream*: a splitmix64 counter that every decision window consumes in exactly
  the same way -- ``window_steps`` draws for the Bernoulli input spike train (one per time
  step, spike iff ``(z >> 11) < floor(p * 2**53)``) and then one draw for the tie-break
  (index ``((z >> 11) * n) >> 53`` among the ``n`` tied candidates). Pure integer
  arithmetic, so Python and numba give identical spike trains and choices.
"""

from __future__ import annotations

import numpy as np

MASK64 = (1 << 64) - 1
GOLDEN = 0x9E3779B97F4A7C15
MUL1 = 0xBF58476D1CE4E5B9
MUL2 = 0x94D049BB133111EB


def splitmix64_next(state: int) -> tuple[int, int]:
    """Advance a splitmix64 state; return (new_state, 64-bit output)."""
    state = (state + GOLDEN) & MASK64
    z = state
    z = ((z ^ (z >> 30)) * MUL1) & MASK64
    z = ((z ^ (z >> 27)) * MUL2) & MASK64
    return state, z ^ (z >> 31)


def spike_threshold(p: float) -> int:
    """Integer threshold on 53-bit draws: a spike iff draw53 < threshold."""
    return int(np.floor(p * float(1 << 53)))


def trial_seed_sequence(seed: int, trial: int) -> np.random.SeedSequence:
    return np.random.SeedSequence([int(seed) & MASK64, int(trial)])


def trial_keys(seed: int, trial: int) -> tuple[int, int, int]:
    """(window-stream key, task seed, weight seed) of trial ``trial`` of a run seeded ``seed``.

    The task seed draws start/goal cells, the weight seed the initial weights; keeping them
    apart means a trial with given start/goal sees the same weights and spikes as in a batch.
    """
    words = trial_seed_sequence(seed, trial).generate_state(3, dtype=np.uint64)
    return int(words[0]), int(words[1]), int(words[2])


class WindowStream:
    """Pure-Python splitmix64 window stream (used by the reference and by Python loops)."""

    def __init__(self, key: int) -> None:
        self.state = int(key) & MASK64

    def spikes(self, steps: int, p: float) -> np.ndarray:
        """Bernoulli spike train of ``steps`` time steps (bool array).

        splitmix64 is a counter generator (state t = key + t * GOLDEN mod 2^64), so the
        ``steps`` draws are computed at once in uint64 arithmetic (wrapping mod 2^64 like the
        masks of :func:`splitmix64_next`): the same integers, hence the same spikes and end
        state, as :meth:`spikes_stepwise`."""
        if steps <= 0:
            return np.zeros(0, dtype=bool)
        counter = np.arange(1, steps + 1, dtype=np.uint64)
        states = np.uint64(self.state) + counter * np.uint64(GOLDEN)
        z = states ^ (states >> np.uint64(30))
        z *= np.uint64(MUL1)
        z ^= z >> np.uint64(27)
        z *= np.uint64(MUL2)
        z ^= z >> np.uint64(31)
        self.state = int(states[-1])
        return (z >> np.uint64(11)) < np.uint64(spike_threshold(p))

    def spikes_stepwise(self, steps: int, p: float) -> np.ndarray:
        """Reference of :meth:`spikes`: one :func:`splitmix64_next` per time step."""
        thr = spike_threshold(p)
        out = np.zeros(steps, dtype=bool)
        s = self.state
        for t in range(steps):
            s, z = splitmix64_next(s)
            out[t] = (z >> 11) < thr
        self.state = s
        return out

    def choice(self, n: int) -> int:
        """Index in [0, n) (always consumes one draw, also for n == 1)."""
        self.state, z = splitmix64_next(self.state)
        return ((z >> 11) * n) >> 53
