"""Vectorised reads of the crossbar: n reads at once equal n single reads, value for value, and
leave the random stream where the single reads leave it; undriven cells draw no noise."""

import numpy as np
import pytest

from snan_hil.crossbar_model import ArrayConfig, CrossbarArray
from snan_hil.common.polarity import Polarity

SERIES = 3010.0


def pair(seed=4):
    return CrossbarArray.from_yaml(None, seed=seed), CrossbarArray.from_yaml(None, seed=seed)


def next_read(array):
    """One more noisy read (consumes the stream): equal for arrays whose streams agree."""
    return array.cell_current(0, 0, 0.2, SERIES)


def test_cell_currents_equal_single_reads_and_consume_the_same_draws():
    a, b = pair()
    many = a.cell_currents(7, 3, 0.2991, SERIES, 25)
    single = np.array([b.cell_current(7, 3, 0.2991, SERIES) for _ in range(25)])
    assert many.shape == (25,)
    assert np.array_equal(many, single)
    assert np.std(many) > 0                              # noisy chip: the reads differ
    assert next_read(a) == next_read(b)


@pytest.mark.parametrize("driven", [[5], list(range(15)), list(range(32)), []])
def test_column_currents_equal_single_reads(driven):
    a, b = pair()
    v = np.zeros(32)
    v[driven] = np.linspace(0.05, 0.2991, len(driven))
    many = a.column_currents(v, 6, 30)
    single = np.array([b.column_current(v, 6) for _ in range(30)])
    assert np.array_equal(many, single)
    assert next_read(a) == next_read(b)
    if driven:
        assert np.std(many) > 0
    else:
        assert not many.any()


def test_multi_column_currents_equal_column_by_column_reads():
    a, b = pair()
    v = np.zeros(32)
    v[[2, 9, 30]] = [0.1, 0.2, 0.2991]
    many = a.multi_column_currents(v, [4, 0, 7], 11)
    single = np.array([b.column_currents(v, c, 11) for c in (4, 0, 7)])
    assert many.shape == (3, 11)
    assert np.array_equal(many, single)
    assert next_read(a) == next_read(b)


def test_undriven_cells_draw_no_noise():
    seed = 9
    a = CrossbarArray.from_yaml(None, seed=seed)
    v = np.zeros(32)
    v[12] = 0.25
    got = a.column_current(v, 5)
    # The runtime stream is the second child of the seed's SeedSequence (see array.py); a read
    # with one driven cell uses exactly its next two normals (relative, absolute).
    stream = np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed).spawn(2)[1]))
    z = stream.standard_normal(2)
    rn = a.config.read_noise
    g = max(a.conductance()[12, 5] * (1 + rn.relative_sigma * z[0]) + rn.absolute_sigma_s * z[1], 0)
    r_mac = a.config.transistor.on_resistance_ohm + a.config.transistor.mac_row_series_ohm
    assert got == pytest.approx(0.25 * g / (1 + g * r_mac), rel=1e-12)
    assert a.cell_current(0, 0, 0.2, SERIES) != 0       # and the stream continues from there


def test_noise_free_reads_are_repeated_values():
    a = CrossbarArray(ArrayConfig.default().ideal(), seed=0)
    v = np.full(32, 0.1)
    assert np.array_equal(a.column_currents(v, 2, 4), np.full(4, a.column_current(v, 2)))
    assert np.array_equal(a.cell_currents(1, 1, 0.3, SERIES, 3),
                          np.full(3, a.cell_current(1, 1, 0.3, SERIES)))


def test_revision_counts_conductance_changes(tmp_path):
    a = CrossbarArray.from_yaml(None, seed=1)
    r0 = a.revision
    a.column_current(np.full(32, 0.1), 0)
    a.cell_current(0, 0, 0.3, SERIES)
    assert a.revision == r0                              # reads change nothing
    free = next(((r, c) for r in range(32) for c in range(8) if not a.stuck_mask[r, c]))
    a.set_conductance(*free, 5e-4)
    assert a.revision > r0
    r1 = a.revision
    a.apply_pulse(*free, 1.0, Polarity.SET, 1e-4)
    assert a.revision > r1
    a.save(str(tmp_path / "c.npz"))
    assert isinstance(CrossbarArray.load(str(tmp_path / "c.npz")).revision, int)


def test_vectorised_reads_check_their_arguments():
    a = CrossbarArray(seed=0)
    with pytest.raises(ValueError):
        a.column_currents(np.zeros(31), 0, 3)
    with pytest.raises(IndexError):
        a.multi_column_currents(np.zeros(32), [1, 8], 3)
    with pytest.raises(ValueError):
        a.column_currents(np.zeros(32), 0, -1)
    with pytest.raises(IndexError):
        a.cell_currents(32, 0, 0.3, SERIES, 2)
    with pytest.raises(ValueError):
        a.cell_currents(0, 0, float("nan"), SERIES, 2)
    assert a.column_currents(np.full(32, 0.1), 0, 0).shape == (0,)
