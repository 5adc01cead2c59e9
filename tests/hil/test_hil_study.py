"""HIL training readings: what the normalize reading keeps, and the software study."""

import numpy as np

from snan_hil.host.hil.config import load_hil_config
from snan_hil.host.hil.study import study_reading
from snan_hil.host.intervals import paper_inside, wilson
from snan_hil.host.hil.train import train_sets


def test_default_training_normalizes_each_cells_outgoing_weights():
    hil = load_hil_config(overrides=["grid.max_steps=40"])
    assert hil.train_overrides["stdp.target"] == "normalize"
    tr = train_sets(hil.train_config(), sets=2, cycles=3, seed=5, start=18, goal=0)
    for k in range(2):
        w, w0 = tr.weights[k], tr.initial[k]
        assert not np.allclose(w, w0)                       # it did learn
        np.testing.assert_allclose(w.sum(axis=1), w0.sum(axis=1), rtol=1e-9)
        assert np.all(w[w > 0] < hil.model.stdp.w_max)      # nothing saturates


def test_chosen_training_saturates_weights_normalize_does_not():
    hil = load_hil_config(overrides=["grid.max_steps=40"])
    kw = dict(base_seeds=[3], sets=2, launches=2)
    chosen = study_reading(hil, "chosen", ["stdp.target=chosen"], **kw)
    norm = study_reading(hil, "normalize", [], **kw)
    assert chosen.frac_at_wmax > 0.1
    assert norm.frac_at_wmax == 0.0
    s = norm.summary()
    for sc in ("sw_noastro", "sw_astro"):
        assert s[sc]["launches"] == 4
        assert all(1 <= n <= 40 for n in norm.steps[sc])
        assert len(s[sc]["per_seed_median_all"]) == 1
        n_ok = sum(norm.success[sc])
        assert s[sc]["success_rate_ci"] == list(wilson(n_ok, 4))
        assert s[sc]["paper_median_steps"] == (7.0 if sc == "sw_astro" else 14.0)
        assert s[sc]["paper_inside"] == paper_inside(s[sc]["paper_median_steps"],
                                                     s[sc]["median_steps_ci"])
        lo, hi = s[sc]["median_steps_all_ci"]
        assert lo <= s[sc]["median_steps_all"] <= hi
    assert norm.summary() == s                   # the bootstrap is seeded (base seed)
