"""SNAN configuration: presets, strict keys, overrides and validation errors."""

import pytest

from snan_hil.errors import UserError
from snan_hil.host.config import (ConfigError, apply_overrides, from_dict, load_config,
                                  preset_path)


def test_presets_hold_the_papers_astrocyte_parameters():
    c3 = load_config(preset="snan-3x3")
    c10 = load_config(preset="snan-10x10")
    assert (c3.grid.rows, c3.grid.cols, c3.grid.max_steps) == (3, 3, 100)
    assert (c10.grid.rows, c10.grid.cols, c10.grid.max_steps) == (10, 10, 1000)
    assert (c3.astro.tau_ca, c3.astro.a) == (1.2, 0.73)
    assert (c10.astro.tau_ca, c10.astro.a) == (22.0, 22.0)
    # shared Table tab_1 values
    for c in (c3, c10):
        assert c.input.p == 0.15 and c.neuron.tau_m_ms == 150 and c.neuron.t_ref_ms == 40
        assert c.neuron.i_bias == 0.02 and c.astro.eta == 5 and c.stdp.k == 1.5


def test_every_field_is_listed_in_the_presets():
    import yaml
    from dataclasses import fields, is_dataclass
    from snan_hil.host.config import SnanConfig
    data = yaml.safe_load(preset_path("snan-3x3").read_text())
    for f in fields(SnanConfig):
        if f.name == "name":
            continue
        section = getattr(SnanConfig(), f.name)
        assert is_dataclass(section)
        assert set(data[f.name]) == {g.name for g in fields(section)}, f.name


@pytest.mark.parametrize("override, fragment", [
    ("astro.tau=1", "unknown config key astro.tau"),
    ("nosuch.key=1", "unknown config key nosuch"),
    ("grid.rows=-3", "grid size must be positive"),
    ("grid.cols=0", "grid size must be positive"),
    ("grid.max_steps=0", "grid.max_steps must be >= 1"),
    ("input.p=1.5", "input.p must be in [0, 1]"),
    ("input.p=-0.1", "input.p must be in [0, 1]"),
    ("astro.tau_ca_unit=h", "astro.tau_ca_unit"),
    ("neuron.tau_m_ms=abc", "expected a number"),
    ("grid.rows=2.5", "expected an integer"),
    ("astro.enabled=maybe", "expected true or false"),
    ("astro.tau_ca=0", "astro.tau_ca must be > 0"),
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
    cfg = load_config(f, overrides=["astro.tau_ca=2.5", "synapse.w_inh=7"])
    assert (cfg.grid.rows, cfg.grid.cols) == (4, 5)
    assert cfg.stdp.mode == "off"          # YAML reads "off" as false; mapped back
    assert cfg.astro.tau_ca == 2.5 and cfg.synapse.w_inh == 7.0
    assert cfg.astro.tau_ca_ms == 2500.0
    assert apply_overrides(cfg, ["astro.tau_ca_unit=ms"]).astro.tau_ca_ms == 2.5


def test_from_dict_rejects_non_mappings_and_bad_sections():
    with pytest.raises(ConfigError):
        from_dict({"grid": 3})
    with pytest.raises(ConfigError):
        from_dict({"grid": {"rows": 1, "cols": 1}})   # a single cell: start != goal impossible
