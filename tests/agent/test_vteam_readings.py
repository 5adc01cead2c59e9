"""Memristive STDP readings (docs/learning.md §5): the VTEAM mapping as config keys that the
readings machinery can vary, its targets file, and the reading the search found learning."""

from pathlib import Path

import numpy as np
import pytest

from snan_hil.host.config import ConfigError, load_config
from snan_hil.host.experiments.route import route_batch
from snan_hil.host.experiments.trials import prepare
from snan_hil.host.plasticity import vteam_rule
from snan_hil.host.readings import load_targets, plan_sweep

TARGETS = Path(__file__).resolve().parents[2] / "configs" / "vteam-targets.yaml"


def test_the_reading_keys_are_checked():
    for bad, text in (("vteam.spike_a_pos_v=0.7", "below the 0.6 V"),
                      ("vteam.mapping=resistance", "vteam.mapping"),
                      ("vteam.spike_t_neg_peak_ms=9", "spike_t_neg_peak_ms"),
                      ("vteam.balance=-1", "vteam.balance")):
        with pytest.raises(ConfigError, match=text):
            load_config(preset="snan-3x3", overrides=[bad])


def test_the_rule_follows_the_config():
    cfg = load_config(preset="snan-3x3", overrides=["stdp.rule=vteam"])
    assert prepare(cfg).params.vteam and not prepare(cfg.replace(
        **{"stdp.rule": "additive"})).params.vteam
    rule, (g_pot, g_dep) = vteam_rule(cfg)
    w = 50                                            # row of w = 0.5 (1 % steps)
    dt = rule.dt0_ms + rule.dtstep_ms * np.arange(rule.lut.shape[1])
    peak, low = rule.lut[w].max(), rule.lut[w].min()
    assert peak == pytest.approx(cfg.stdp.a_plus)     # vteam.peak 0: stdp.a_plus
    assert low == pytest.approx(-cfg.vteam.balance * cfg.stdp.a_plus)
    assert dt[rule.lut[w].argmax()] > 0 > dt[rule.lut[w].argmin()]
    # an 8 ms lobe: nothing beyond ~10 ms; the device's 30 ms lobe reaches further
    assert np.all(rule.lut[:, np.abs(dt) > 10.0] == 0.0)
    wide, _ = vteam_rule(cfg.replace(**{"vteam.spike_t_neg_ms": 30.0}))
    dt_wide = wide.dt0_ms + wide.dtstep_ms * np.arange(wide.lut.shape[1])
    assert np.any(wide.lut[:, np.abs(dt_wide) > 15.0] != 0.0)
    # the mappings differ: in the conductance reading steps grow with w, in the state one not
    cond, _ = vteam_rule(cfg.replace(**{"vteam.mapping": "conductance"}))
    assert cond.lut[90].max() > 3 * cond.lut[10].max()
    assert rule.lut[90].max() < 1.5 * rule.lut[10].max()
    # mirrored: potentiation for pre after post
    mirror, _ = vteam_rule(cfg.replace(**{"vteam.orientation": -1}))
    assert dt[mirror.lut[w].argmax()] < 0


def test_the_targets_file_scores_fig7_with_the_readings_machinery():
    targets = load_targets(TARGETS)
    assert {t.condition for t in targets} == {"route3/cycle0", "route3/cycle20",
                                              "route10/cycle0", "route10/cycle20"}
    plan = plan_sweep({"vteam.balance": [0.25, 0.0]}, targets, 20, 1, base=["stdp.rule=vteam"])
    assert [u.name for u in plan.units] == ["route10", "route3"]
    keys = {key for (_i, _u), (_cfg, key) in plan.jobs.items()}
    assert len(keys) == 4                             # the balance reaches every unit's config


def test_the_found_reading_learns_where_the_devices_own_does_not():
    base = load_config(preset="snan-3x3", overrides=["stdp.rule=vteam"])
    own = base.replace(**{"vteam.mapping": "conductance", "vteam.balance": 0.0,
                          "vteam.spike_t_neg_ms": 30.0})
    params = {"sessions": [0, 40], "protocol": {"cycles": 20}, "plasticity": {}}
    found = np.array(route_batch(base, params, 3)["test_success"])[:, -1].mean()
    device = np.array(route_batch(own, params, 3)["test_success"])[:, -1].mean()
    assert found >= 0.9 and device <= found - 0.2, (found, device)
