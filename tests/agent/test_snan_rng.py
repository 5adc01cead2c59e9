"""The window stream's vectorised spike train against the per-step splitmix64 reference."""

import numpy as np
import pytest

from snan_hil.host.rng import MASK64, WindowStream


@pytest.mark.parametrize("key", [0, 1, MASK64, MASK64 - 5, 0x9E3779B97F4A7C15, 123456789])
@pytest.mark.parametrize("p", [0.0, 0.15, 0.5, 1.0])
def test_vectorised_spikes_equal_the_stepwise_stream(key, p):
    fast, ref = WindowStream(key), WindowStream(key)
    for steps in (1000, 1, 0, 37, 1000):
        got, want = fast.spikes(steps, p), ref.spikes_stepwise(steps, p)
        assert got.dtype == want.dtype == np.bool_
        assert np.array_equal(got, want)
        assert fast.state == ref.state                  # the stream continues alike
        assert fast.choice(3) == ref.choice(3)
    if 0.0 < p < 1.0:
        assert 0 < got.sum() < got.size


def test_spike_rate_follows_p():
    stream = WindowStream(7)
    rate = np.mean([stream.spikes(1000, 0.15).mean() for _ in range(200)])
    assert abs(rate - 0.15) < 4 * np.sqrt(0.15 * 0.85 / 200_000)
