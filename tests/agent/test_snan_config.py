"""SNAN configuration: presets, strict keys, overrides and validation errors."""

import pytest

from snan_hil.common.errors import UserError
from snan_hil.host.config import (ConfigError, apply_overrides, from_dict, load_config,
                                  preset_path)


def test_presets_hold_the_papers_astrocyte_parameters():
    c3 = load_config(preset="snan-3x3")
    c10 = load_config(preset="snan-10x10")
    assert (c3.grid.rows, c3.grid.cols, c3.grid.max_steps) == (3, 3, 100)
    assert (c10.grid.rows, c10.grid.cols, c10.grid.max_steps) == (10, 10, 1000)
    assert (c3.astro.tau_ca_s, c3.astro.a) == (1.2, 0.73)
    assert (c10.astro.tau_ca_s, c10.astro.a) == (22.0, 22.0)
    # shared Table tab_1 values
    for c in (c3, c10):
        assert c.input.p == 0.15 and c.neuron.tau_m_ms == 150 and c.neuron.t_ref_ms == 40
        assert c.neuron.i_bias == 0.02 and c.astro.eta == 5 and c.stdp.k == 1.5


def test_every_field_is_listed_in_the_presets():
    from dataclasses import fields, is_dataclass
    from snan_hil.config.loader import read_yaml
    from snan_hil.host.config import SnanConfig
    data = read_yaml(preset_path("snan-3x3"))
    for f in fields(SnanConfig):
        if f.name == "name":
            continue
        section = getattr(SnanConfig(), f.name)
        assert is_dataclass(section)
        assert set(data[f.name]) == {g.name for g in fields(section)}, f.name


@pytest.mark.parametrize("override, fragment", [
    ("astro.tau=1", "unknown config key astro.tau"),
    ("nosuch.key=1", "unknown config key nosuch"),
    ("grid.rows=-3", "grid.rows: must be >= 1, got -3"),
    ("grid.cols=0", "grid.cols: must be >= 1, got 0"),
    ("grid.max_steps=0", "grid.max_steps: must be >= 1, got 0"),
    ("input.p=1.5", "input.p: must be <= 1.0, got 1.5"),
    ("input.p=-0.1", "input.p: must be >= 0.0, got -0.1"),
    ("stdp.mode=sometimes", "stdp.mode: expected one of 'off', 'window' or 'trial_end'"),
    ("neuron.tau_m_ms=abc", "expected a number"),
    ("grid.rows=2.5", "expected an integer"),
    ("astro.enabled=maybe", "expected true or false"),
    ("astro.tau_ca_s=0", "astro.tau_ca_s: must be > 0.0, got 0"),
    ("stdp.tau_minus_ms=0", "stdp.tau_minus_ms: must be > 0.0, got 0"),
    ("stdp.a_minus=-0.1", "stdp.a_minus: must be >= 0.0, got -0.1"),
    ("synapse.w_lo=0.9", "synapse.w_lo must be <= synapse.w_hi, got 0.9 > 0.8"),
    ("neuron.v_reset=2", "neuron.v_reset must be below every (astrocyte-lowered) threshold, "
                         "got 2.0 >= 1.16667"),
    ("astro.tau_ca_s=1e-4", "got 0.0001 s < 1.0 ms"),
])
def test_bad_values_raise_one_line_user_errors(override, fragment):
    with pytest.raises(UserError) as exc:
        load_config(preset="snan-3x3", overrides=[override])
    msg = str(exc.value)
    assert fragment in msg
    assert "\n" not in msg


def test_unknown_key_in_a_file_is_rejected(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("grid:\n  rows: 3\n  colz: 3\n")
    with pytest.raises(ConfigError, match="unknown config key grid.colz"):
        load_config(f)


def test_file_overrides_and_defaults(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("grid: {rows: 4, cols: 5}\nstdp: {mode: off}\n")
    cfg = load_config(f, overrides=["astro.tau_ca_s=2.5", "synapse.w_inh=7"])
    assert (cfg.grid.rows, cfg.grid.cols) == (4, 5)
    assert cfg.stdp.mode == "off"          # YAML reads "off" as false; mapped back
    assert cfg.astro.tau_ca_s == 2.5 and cfg.synapse.w_inh == 7.0
    assert cfg.astro.tau_ca_ms == 2500.0
    assert apply_overrides(cfg, ["astro.tau_ca_s=0.0025"]).astro.tau_ca_ms == 2.5


def test_from_dict_rejects_non_mappings_and_bad_sections():
    with pytest.raises(ConfigError):
        from_dict({"grid": 3})
    with pytest.raises(ConfigError):
        from_dict({"grid": {"rows": 1, "cols": 1}})   # a single cell: start != goal impossible


# ---- issue 14: numbers as YAML 1.2 reads them, in files and in --set ------------------------
def test_exponent_numbers_are_floats_in_overrides_and_files(tmp_path):
    cfg = load_config(preset="snan-3x3", overrides=["astro.alpha_n_per_ms=1e-3"])
    assert cfg.astro.alpha_n_per_ms == 0.001
    assert load_config(preset="snan-3x3", overrides=["astro.alpha_n_per_ms=1.0e-5"]
                       ).astro.alpha_n_per_ms == 1e-5
    assert load_config(preset="snan-3x3", overrides=["input.t_stim_ms=1e3"]
                       ).input.t_stim_ms == 1000.0
    f = tmp_path / "c.yaml"
    f.write_text("astro:\n  alpha_n_per_ms: 1e-3\ninput:\n  t_stim_ms: 1e3\n")
    cfg = load_config(f)
    assert cfg.astro.alpha_n_per_ms == 0.001 and cfg.input.t_stim_ms == 1000.0


def test_leading_zero_is_decimal_and_sexagesimal_is_refused(tmp_path):
    assert load_config(preset="snan-3x3", overrides=["grid.max_steps=010"]).grid.max_steps == 10
    f = tmp_path / "c.yaml"
    f.write_text("grid:\n  max_steps: 010\n")
    assert load_config(f).grid.max_steps == 10
    with pytest.raises(ConfigError, match="grid.max_steps: expected an integer, got '1:40'"):
        load_config(preset="snan-3x3", overrides=["grid.max_steps=1:40"])
    f.write_text("grid:\n  max_steps: 1:40\n")
    with pytest.raises(ConfigError, match="grid.max_steps: expected an integer, got '1:40'"):
        load_config(f)


def test_mapping_overrides_are_typed_and_old_keys_say_their_new_name():
    cfg = load_config(preset="snan-3x3")
    assert apply_overrides(cfg, {"astro.alpha_n_per_ms": 1e-5}).astro.alpha_n_per_ms == 1e-5
    with pytest.raises(ConfigError, match="astro.enabled: expected true or false, got 'false'"):
        apply_overrides(cfg, {"astro.enabled": "false"})          # no text round trip
    with pytest.raises(ConfigError, match="astro.tau_ca is gone: give astro.tau_ca_s"):
        apply_overrides(cfg, ["astro.tau_ca=1.2"])


def test_stored_configs_of_earlier_versions_are_read():
    from snan_hil.host.config import from_stored
    old = load_config(preset="snan-10x10").to_dict()
    old["astro"].pop("tau_ca_s")
    old["astro"].update(tau_ca=22.0, tau_ca_unit="s")
    assert from_stored(old) == load_config(preset="snan-10x10")
    old["astro"].update(tau_ca=22.0, tau_ca_unit="ms")
    assert from_stored(old).astro.tau_ca_ms == 22.0
