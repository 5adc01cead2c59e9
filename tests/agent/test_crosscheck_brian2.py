"""The SNAN in Brian2, driven with the kernel's recorded input spike trains, gives the
kernel's spike counts per window and its decisions, and the reference's interneuron spikes
(snan_hil.host.crosscheck_brian2; docs/model.md "Cross-check with Brian2")."""

from __future__ import annotations

import pytest

from snan_hil.host.config import load_config

pytest.importorskip("brian2")


@pytest.mark.parametrize("sets", [
    [],                                                      # the score-chosen defaults
    ["neuron.reset_each_window=false", "stdp.mode=window", "stdp.target=all",
     "stdp.pairing=nearest"],                                # carried state, in-trial STDP
])
def test_brian2_gives_the_kernels_counts_and_decisions(sets):
    from snan_hil.host.crosscheck_brian2 import compare_trial
    cfg = load_config(preset="snan-3x3", overrides=[*sets, "grid.max_steps=3"])
    c = compare_trial(cfg, start=0, goal=8, seed=1, trial=0, interneurons=True)
    assert c.windows == 3 and c.kernel.path == c.brian2.path
    assert c.count_mismatches == [] and c.kernel.counts == c.brian2.counts
    assert sum(map(sum, c.kernel.counts)) > 10                  # the motor neurons did fire
    # interneurons per cell: beside the occupied cell's (driven by its input), those of
    # visited cells fire once their astrocyte has lowered the threshold
    assert c.reference_inter == c.brian2.inter_spikes
    switched = [n for w, cells in enumerate(c.brian2.inter_spikes)
                for cell, n in enumerate(cells) if cell != c.kernel.path[w]]
    assert sum(switched) > 0
    assert c.agree
