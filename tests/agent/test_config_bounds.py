"""Issue 21 point 5: configuration fields declare their bounds beside the field, the loader
(files and ``--set``) and objects built in code check them with one line naming the field and
the bound, and the CLI's defaults are the config classes' defaults."""

from __future__ import annotations

import argparse
import dataclasses
import typing

import pytest

from snan_hil.config import loader as configio
from snan_hil.config.loader import ConfigError
from snan_hil.host.config import InputConfig, SnanConfig, StdpConfig, load_config


def _one_line(exc: pytest.ExceptionInfo) -> str:
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


# ---- SnanConfig: --set, files, objects built in code -------------------------------------------
@pytest.mark.parametrize("item, needle", [
    ("grid.rows=0", "grid.rows: must be >= 1, got 0"),
    ("grid.max_steps=-1", "grid.max_steps: must be >= 1, got -1"),
    ("input.p=-1", "input.p: must be >= 0.0, got -1"),
    ("input.dt_ms=-1", "input.dt_ms: must be > 0.0, got -1"),
    ("neuron.tau_m_ms=-1", "neuron.tau_m_ms: must be > 0.0, got -1"),
    ("neuron.t_ref_ms=-1", "neuron.t_ref_ms: must be >= 0.0, got -1"),
    ("synapse.w_inh=-1", "synapse.w_inh: must be >= 0.0, got -1"),
    ("stdp.tau_plus_ms=-1", "stdp.tau_plus_ms: must be > 0.0, got -1"),
    ("astro.alpha_n_per_ms=-1", "astro.alpha_n_per_ms: must be > 0.0, got -1"),
    ("astro.eta=-1", "astro.eta: must be >= 0.0, got -1"),
])
def test_snan_set_outside_a_bound_names_the_field_and_the_bound(item, needle):
    with pytest.raises(ConfigError) as exc:
        load_config(preset="snan-3x3", overrides=[item])
    assert _one_line(exc) == f"--set {item}: {needle}"


def test_snan_file_outside_a_bound_names_the_file_and_the_field(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("input: {p: 1.5}\n")
    with pytest.raises(ConfigError) as exc:
        load_config(f)
    assert _one_line(exc) == f"config file {f}: input.p: must be <= 1.0, got 1.5"


def test_snan_built_in_code_is_checked_against_the_same_bounds():
    with pytest.raises(ConfigError) as exc:
        SnanConfig(input=InputConfig(dt_ms=-1.0))
    assert _one_line(exc) == "input.dt_ms: must be > 0.0, got -1.0"
    with pytest.raises(ConfigError, match=r"^stdp.k: must be >= 0.0, got -0.5$"):
        SnanConfig(stdp=StdpConfig(k=-0.5))
    with pytest.raises(ConfigError, match=r"^astro.tau_ca_s: must be > 0.0, got 0.0$"):
        SnanConfig().replace(**{"astro.tau_ca_s": 0.0})


def test_a_value_on_a_bound_is_accepted():
    cfg = load_config(preset="snan-3x3", overrides=["input.p=0", "neuron.t_ref_ms=0",
                                                     "stdp.k=0", "grid.rows=1", "grid.cols=2"])
    assert (cfg.input.p, cfg.neuron.t_ref_ms, cfg.stdp.k, cfg.n_cells) == (0.0, 0.0, 0.0, 2)
    assert load_config(preset="snan-3x3", overrides=["input.p=1"]).input.p == 1.0


def _bounded(cls: type) -> set[str]:
    """Dotted names of the fields of dataclass tree ``cls`` that declare a bound."""
    out: set[str] = set()
    for name, hint in typing.get_type_hints(cls, include_extras=True).items():
        if dataclasses.is_dataclass(hint):
            out |= {f"{name}.{k}" for k in _bounded(hint)}
        elif configio._bounds(hint):
            out.add(name)
    return out


def test_snan_time_constants_and_probabilities_declare_bounds():
    assert {"grid.rows", "grid.cols", "grid.max_steps", "input.p", "input.t_stim_ms",
            "input.dt_ms", "neuron.tau_m_ms", "neuron.t_ref_ms", "neuron.r_m",
            "stdp.tau_plus_ms", "stdp.tau_minus_ms", "astro.tau_ca_s",
            "astro.alpha_n_per_ms"} <= _bounded(SnanConfig)


# ---- write-and-verify and programming settings (built from CLI options) ----------------------
@pytest.mark.parametrize("kwargs, needle", [
    ({"tolerance": -1.0}, "tolerance: must be > 0.0, got -1.0"),
    ({"tolerance": 1.0}, "tolerance: must be < 1.0, got 1.0"),
    ({"width_us": 0}, "width_us: must be >= 1, got 0"),
    ({"max_pulses_stage2": -1}, "max_pulses_stage2: must be >= 1, got -1"),
    ({"prior_k_set": 0.0}, "prior_k_set: must be > 0.0, got 0.0"),
    ({"chip_forgetting": 1.0}, "chip_forgetting: must be < 1.0, got 1.0"),
    ({"open_below_s": -1e-6}, "open_below_s: must be >= 0.0, got -1e-06"),
])
def test_wv_config_outside_a_bound_names_the_field_and_the_bound(kwargs, needle):
    from snan_hil.calibration.wv import WVConfig
    with pytest.raises(ConfigError) as exc:
        WVConfig(**kwargs)
    assert _one_line(exc) == needle


@pytest.mark.parametrize("kwargs, needle", [
    ({"verify_reads": 0}, "verify_reads: must be >= 1, got 0"),
    ({"max_attempts": 0}, "max_attempts: must be >= 1, got 0"),
    ({"compliance_margin": 1.5}, "compliance_margin: must be <= 1.0, got 1.5"),
    ({"checkpoint_s": -1.0}, "checkpoint_s: must be >= 0.0, got -1.0"),
])
def test_program_config_outside_a_bound_names_the_field_and_the_bound(kwargs, needle):
    from snan_hil.calibration.programmer import ProgramConfig
    with pytest.raises(ConfigError) as exc:
        ProgramConfig(**kwargs)
    assert _one_line(exc) == needle



# ---- the CLI's defaults are the config classes' defaults ---------------------------------------
def _actions(command: str) -> dict[str, argparse.Action]:
    from snan_hil.tools import cli
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {a.dest: a for a in sub.choices[command]._actions}


def _defaults(command: str) -> dict[str, object]:
    return {k: a.default for k, a in _actions(command).items()}


def _helps(command: str) -> dict[str, str]:
    return {k: str(a.help) for k, a in _actions(command).items()}


def test_cli_defaults_come_from_the_config_classes():
    from snan_hil.calibration.mac import MacConfig
    from snan_hil.calibration.wv import WVConfig
    from snan_hil.host.experiments.common import RunOptions
    d = _defaults("program-weights")
    for option in ("tolerance", "width_us", "max_pulses_stage1", "max_pulses_stage2"):
        assert d[option] == configio.field_default(WVConfig, option), option
    # --v-max: not given, WVConfig's (or a lower --max-write-v: the host limit lowers it)
    from snan_hil.tools import cli
    from snan_hil.tools.commands import program_weights
    args = cli.build_parser().parse_args(["program-weights", "w.npy"])
    assert d["v_max"] is None
    assert program_weights._config(args).wv.v_max == configio.field_default(WVConfig, "v_max")
    args = cli.build_parser().parse_args(["program-weights", "w.npy", "--max-write-v", "1.1"])
    assert program_weights._config(args).wv.v_max == 1.1
    d = _defaults("experiment")
    for option in ("seed", "plasticity", "maze_rule", "route_task", "route_train_astro"):
        assert d[option] == configio.field_default(RunOptions, option), option
    d = _defaults("mac")
    assert (d["vectors"], d["seed"]) == (configio.field_default(MacConfig, "vectors"),
                                         configio.field_default(MacConfig, "seed"))
    from snan_hil.host.hil.compare import CompareRequest
    d = _defaults("compare")
    assert (d["launches"], d["seed"]) == (configio.field_default(CompareRequest, "launches"),
                                          configio.field_default(CompareRequest, "seed"))


def test_train_help_shows_the_default_tasks_values():
    from snan_hil.host.hil.config import HilTask, load_hil_config
    task = load_hil_config().task           # the default --config, configs/hil-6x6.yaml
    assert task == HilTask()                # the help's numbers are the file's too
    h = _helps("train")
    assert h["start"].endswith(f"task.start, {task.start})")
    assert h["goal"].endswith(f"task.goal, {task.goal})")
    assert h["cycles"].endswith(f"task.cycles, {task.cycles})")


def test_field_default_reads_the_declared_default_and_names_unknown_keys():
    assert configio.field_default(SnanConfig, "astro.tau_ca_s") == 1.2
    assert configio.field_default(SnanConfig, "grid").rows == 3
    with pytest.raises(ConfigError, match="unknown config key grid.colz"):
        configio.field_default(SnanConfig, "grid.colz")


def test_hil_task_outside_a_bound_names_the_file_and_the_field(tmp_path):
    from snan_hil.host.hil.config import load_hil_config
    f = tmp_path / "hil.yaml"
    f.write_text("base: snan-10x10\ntask: {start: 5, goal: 0, cycles: 0}\n")
    with pytest.raises(ConfigError) as exc:
        load_hil_config(f)
    assert _one_line(exc) == f"config file {f}: task.cycles: must be >= 1, got 0"


@pytest.mark.parametrize("kwargs, needle", [
    ({"reads": 1}, "reads: must be >= 2, got 1"),
    ({"noise_limit": 0.0}, "noise_limit: must be > 0.0, got 0.0"),
    ({"v_step": -0.1}, "v_step: must be > 0.0, got -0.1"),
    ({"max_restore_pulses": 1}, "max_restore_pulses: must be >= 2, got 1"),
])
def test_screen_config_outside_a_bound_names_the_field_and_the_bound(kwargs, needle):
    from snan_hil.calibration.screening import ScreenConfig
    with pytest.raises(ConfigError) as exc:
        ScreenConfig(**kwargs)
    assert _one_line(exc) == needle


# ---- the emulated chip's device config (configs/device-ysz.yaml) --------------------------------
@pytest.mark.parametrize("key, value, needle", [
    ("read_noise.relative_sigma", -0.01, "read_noise.relative_sigma: must be >= 0.0, got -0.01"),
    ("stuck.fraction", 1.5, "stuck.fraction: must be <= 1.0, got 1.5"),
    ("drift.t0_s", 0.0, "drift.t0_s: must be > 0.0, got 0.0"),
    ("rows", 0, "rows: must be >= 1, got 0"),
])
def test_device_config_outside_a_bound_names_the_field_and_the_bound(key, value, needle):
    from snan_hil.crossbar_model.config import ArrayConfig, DeviceConfigError
    with pytest.raises(DeviceConfigError) as exc:
        ArrayConfig.default().with_overrides({key: value})
    assert _one_line(exc) == needle


def test_device_config_built_in_code_is_checked_against_the_same_bounds():
    from snan_hil.crossbar_model.config import ArrayConfig
    cfg = ArrayConfig.default()
    with pytest.raises(ConfigError, match=r"^initial_state.sigma: must be >= 0.0, got -1.0$"):
        dataclasses.replace(cfg, initial_state=dataclasses.replace(cfg.initial_state,
                                                                   sigma=-1.0))


def test_a_set_outside_a_bound_on_the_command_line_is_one_line_and_exit_code_2(capsys):
    from snan_hil.tools import cli
    assert cli.main(["sim", "--trials", "2", "--set", "neuron.tau_m_ms=-1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    assert err.endswith("--set neuron.tau_m_ms=-1: neuron.tau_m_ms: must be > 0.0, got -1")
