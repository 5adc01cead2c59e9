"""The project's one configuration loader (snan_hil.config.loader): YAML 1.2 numbers, strict types,
dotted overrides on typed values, unknown keys named, one-line errors."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Annotated, Literal

import pytest
from annotated_types import Ge, Interval

from snan_hil.config import loader as configio
from snan_hil.config.loader import ConfigError
from snan_hil.common.errors import UserError


@dataclass
class Inner:
    count: Annotated[int, Ge(1)] = 3
    rate_per_s: float = 0.5
    mode: Literal["off", "on"] = "off"
    enabled: bool = True
    label: str = "x"
    fraction: Annotated[float, Interval(ge=0.0, le=1.0)] = 0.5
    pair: tuple[int, int] = (1, 2)


@dataclass(frozen=True)
class Required:
    g_min_s: float
    g_max_s: float

    def __post_init__(self) -> None:
        if not self.g_min_s < self.g_max_s:
            raise ValueError("needs g_min_s < g_max_s")


@dataclass
class Outer:
    name: str = "outer"
    inner: Inner = field(default_factory=Inner)
    steps: int = 10

    def __post_init__(self) -> None:
        if self.steps > 1000:
            raise UserError(f"steps must be <= 1000, got {self.steps}")


def one_line(exc: pytest.ExceptionInfo) -> str:
    msg = str(exc.value)
    assert "\n" not in msg and isinstance(exc.value, UserError)
    return msg


# ---- YAML 1.2 ---------------------------------------------------------------------------------
@pytest.mark.parametrize("text, value", [
    ("1e-3", 0.001), ("1.0e-5", 1e-5), ("1e3", 1000.0), ("0.00001", 1e-5),
    ("010", 10), ("0o10", 8), ("1:40", "1:40"), ("off", "off"), ("yes", "yes"),
    ("true", True), ("false", False),
])
def test_numbers_and_words_read_as_yaml_1_2(text, value):
    got = configio.parse_yaml(f"k: {text}")["k"]
    assert got == value and type(got) is type(value)


def test_yaml_1_1_directive_duplicate_keys_and_syntax_errors_are_refused():
    with pytest.raises(ConfigError, match="YAML 1.1") as exc:
        configio.parse_yaml("%YAML 1.1\n---\nk: 010\n", "f.yaml")
    one_line(exc)
    with pytest.raises(ConfigError, match=r"f.yaml is not valid YAML \(line 2: .*duplicate key") \
            as exc:
        configio.parse_yaml("a: 1\na: 2\n", "f.yaml")
    one_line(exc)
    with pytest.raises(ConfigError, match="not valid YAML"):
        configio.parse_yaml("a: [1, 2", "f.yaml")
    with pytest.raises(ConfigError, match="not valid YAML"):
        configio.parse_yaml("a: !!python/object:os.system x\n", "f.yaml")


def test_read_yaml_names_a_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="cannot read config file .*nope.yaml: no such file"):
        configio.read_yaml(tmp_path / "nope.yaml")


def test_a_config_that_is_a_folder_is_named_a_folder(tmp_path, monkeypatch, capsys):
    (tmp_path / "bad" / "dir.npz").mkdir(parents=True)
    with pytest.raises(ConfigError, match=r"cannot read config file .*dir.npz: is a folder"):
        configio.read_yaml(tmp_path / "bad" / "dir.npz")
    from snan_hil.tools import cli
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    import numpy as np
    from snan_hil.calibration.testing import grid_weights
    np.save(tmp_path / "w.npy", grid_weights(6, 6, seed=1))
    for argv in (["run", "--scenario", "sw_astro", "--weights", str(tmp_path / "w.npy")],
                 ["sim"]):
        assert cli.main([*argv, "--config", str(tmp_path / "bad" / "dir.npz")]) == 2
        err = capsys.readouterr().err.strip()
        assert err.endswith("dir.npz: is a folder; give a YAML file") and "\n" not in err, err


# ---- building from a tree -------------------------------------------------------------------
def test_from_tree_takes_defaults_and_checks_types_strictly():
    obj = configio.from_tree(Outer, configio.parse_yaml(
        "inner: {count: 010, rate_per_s: 1e-3, mode: off, pair: [3, 4]}"))
    assert obj.inner == Inner(count=10, rate_per_s=0.001, mode="off", pair=(3, 4))
    assert obj.steps == 10 and obj.name == "outer"
    assert isinstance(configio.from_tree(Outer, {"inner": {"rate_per_s": 2}}).inner.rate_per_s,
                      float)


BUILD = {
    "tree": lambda arg: configio.from_tree(Outer, arg, where="f.yaml"),
    "apply": lambda arg: configio.apply(Outer(), {arg: 1}),
    "set": lambda arg: configio.parse_assignments(Outer, [arg]),
}


@pytest.mark.parametrize("kind, arg, fragment", [
    ("tree", {"inner": {"count": 2.5}}, "inner.count: expected an integer, got 2.5"),
    ("tree", {"inner": {"count": "3"}}, "inner.count: expected an integer, got '3'"),
    ("tree", {"inner": {"count": True}}, "inner.count: expected an integer, got True"),
    ("tree", {"inner": {"count": "1:40"}}, "inner.count: expected an integer, got '1:40'"),
    ("tree", {"inner": {"count": 0}}, "inner.count: must be >= 1, got 0"),
    ("tree", {"inner": {"fraction": 1.5}}, "inner.fraction: must be <= 1.0, got 1.5"),
    ("tree", {"inner": {"rate_per_s": "1e-3"}},
     "inner.rate_per_s: expected a number, got '1e-3'"),
    ("tree", {"inner": {"rate_per_s": float("inf")}},
     "inner.rate_per_s: expected a finite number"),
    ("tree", {"inner": {"enabled": "yes"}}, "inner.enabled: expected true or false, got 'yes'"),
    ("tree", {"inner": {"mode": False}}, "inner.mode: expected one of 'off' or 'on', got False"),
    ("tree", {"inner": {"label": 3}}, "inner.label: expected a text, got 3"),
    ("tree", {"inner": {"pair": [1]}}, "inner.pair"),
    ("tree", {"inner": 3}, "inner: expected a mapping"),
    ("tree", {"inner": {"cuont": 3}}, "unknown config key inner.cuont (known in inner: count, "
                                      "enabled, fraction, label, mode, pair, rate_per_s)"),
    ("tree", {"colour": "red"}, "unknown config key colour (known: inner, name, steps)"),
    ("tree", {"steps": 5000}, "f.yaml: steps must be <= 1000, got 5000"),
    ("apply", "inner.nope", "unknown config key inner.nope (known in inner:"),
    ("apply", "nope.x", "unknown config key nope (known: inner, name, steps)"),
    ("apply", "inner.count.x", "unknown config key inner.count.x (inner.count is a value"),
    ("apply", "inner..count", "is not a dotted key"),
    ("set", "inner.count=1:40",
     "--set inner.count=1:40: inner.count: expected an integer, got '1:40'"),
    ("set", "inner.count=2.5", "expected an integer, got 2.5"),
    ("set", "inner.rate_per_s=abc", "inner.rate_per_s: expected a number, got 'abc'"),
    ("set", "inner.enabled=yes", "expected true or false, got 'yes'"),
    ("set", "inner.mode=maybe", "expected one of 'off' or 'on', got 'maybe'"),
    ("set", "inner.count", "--set inner.count: expected KEY=VALUE"),
    ("set", "inner.cuont=3", "unknown config key inner.cuont (known in inner:"),
    ("set", "inner.count=", "expected an integer, got None"),
])
def test_bad_input_gives_one_line_naming_the_key(kind, arg, fragment):
    with pytest.raises(ConfigError) as exc:
        BUILD[kind](arg)
    msg = one_line(exc)
    assert fragment in msg
    assert kind != "tree" or msg.startswith("f.yaml: ")


def test_required_fields_and_post_init_errors_of_frozen_classes():
    with pytest.raises(ConfigError, match="dev.yaml: missing config key g_max_s"):
        configio.from_tree(Required, {"g_min_s": 1e-5}, where="dev.yaml")
    with pytest.raises(ConfigError, match="dev.yaml: needs g_min_s < g_max_s"):
        configio.from_tree(Required, {"g_min_s": 1e-3, "g_max_s": 1e-5}, where="dev.yaml")
    r = configio.from_tree(Required, {"g_min_s": 1e-5, "g_max_s": 1e-3})
    assert configio.apply(r, {"g_max_s": 2e-3}) == Required(1e-5, 2e-3)
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.g_min_s = 0.0                                          # type: ignore[misc]


def test_renamed_keys_give_their_advice():
    with pytest.raises(ConfigError, match="config key inner.n is gone: give inner.count"):
        configio.from_tree(Outer, {"inner": {"n": 3}}, renamed={"inner.n": "give inner.count"})


# ---- dotted overrides -----------------------------------------------------------------------
def test_apply_sets_typed_values_without_text_and_merges_sections():
    base = Outer()
    out = configio.apply(base, {"inner.rate_per_s": 1e-5, "inner": {"count": 4}, "steps": 7})
    assert out.inner.rate_per_s == 1e-5 and out.inner.count == 4 and out.steps == 7
    assert out.inner.mode == "off" and base == Outer()             # the original is unchanged
    assert configio.apply(base, {"inner": Inner(count=9)}).inner.count == 9
    assert configio.apply(base, {}) is base


@pytest.mark.parametrize("item, key, value", [
    ("inner.rate_per_s=1e-3", "inner.rate_per_s", 0.001),
    ("inner.rate_per_s=1.0e-5", "inner.rate_per_s", 1e-5),
    ("inner.rate_per_s=1e3", "inner.rate_per_s", 1000.0),
    ("inner.rate_per_s=2", "inner.rate_per_s", 2.0),
    ("inner.count=010", "inner.count", 10),
    ("inner.mode=off", "inner.mode", "off"),
    ("inner.enabled=false", "inner.enabled", False),
    ("name=a b", "name", "a b"),
    ("name=010", "name", "010"),                      # text fields take the text as written
    ("inner={count: 4, mode: on}", "inner", {"count": 4, "mode": "on"}),
])
def test_set_texts_are_read_for_the_fields_type(item, key, value):
    got = configio.parse_assignments(Outer, [item])
    assert got == {key: value} and type(got[key]) is type(value)
    configio.apply(Outer(), got)                      # and they apply


def test_check_keys_converts_without_building():
    assert configio.check_keys(Outer, {"inner.rate_per_s": 1, "steps": 5000}) == {
        "inner.rate_per_s": 1.0, "steps": 5000}               # no __post_init__ run here
    with pytest.raises(ConfigError, match="set: unknown config key inner.x"):
        configio.check_keys(Outer, {"inner.x": 1}, where="set")


def test_load_reads_file_then_typed_overrides_then_set_texts(tmp_path):
    f = tmp_path / "c.yaml"
    f.write_text("inner:\n  rate_per_s: 1e-3\nsteps: 010\n")
    obj = configio.load(Outer, f, overrides={"inner.count": 5}, sets=["inner.count=6"])
    assert (obj.inner.rate_per_s, obj.steps, obj.inner.count) == (0.001, 10, 6)
    f.write_text("inner:\n  count: 1\n  count: 2\n")
    with pytest.raises(ConfigError, match="duplicate key"):
        configio.load(Outer, f)


def test_differences_lists_dotted_keys_that_differ():
    a = configio.to_tree(Outer())
    b = configio.to_tree(configio.apply(Outer(), {"inner.rate_per_s": 0.25, "name": "b"}))
    assert configio.differences(a, b) == [("name", "outer", "b"),
                                          ("inner.rate_per_s", 0.5, 0.25)]
    assert configio.differences({"x": 6, "y": [1, 2]}, {"x": 6.0, "y": (1, 2)}) == []
    assert configio.differences({"x": 1}, {"x": True}) == [("x", 1, True)]
    d = configio.differences({"s": {"old": 1}}, {"s": {"new": 2}})
    assert d == [("s.old", 1, configio.MISSING), ("s.new", configio.MISSING, 2)]


@dataclass(frozen=True)
class Timing:
    spi_hz: float = 15e6
    settle_us: float = 6.0


@dataclass(frozen=True)
class Board:
    """Shaped like the emulator's board config: frozen, a nested frozen section, properties."""

    rows: int = 32
    v_read_max_v: float = 0.3
    timing: Timing = field(default_factory=Timing)

    @property
    def cells(self) -> int:
        return self.rows * 8


def test_a_frozen_board_like_tree_loads_from_a_file_with_overrides(tmp_path):
    f = tmp_path / "board.yaml"
    f.write_text("rows: 16\ntiming:\n  spi_hz: 1e6\n")
    board = configio.load(Board, f, sets=["timing.settle_us=1.0e-1"])
    assert board == Board(rows=16, timing=Timing(spi_hz=1e6, settle_us=0.1))
    assert board.cells == 128
    assert configio.to_tree(board) == {"rows": 16, "v_read_max_v": 0.3,
                                       "timing": {"spi_hz": 1e6, "settle_us": 0.1}}
    assert configio.from_tree(Board, configio.to_tree(board)) == board     # round trip
    f.write_text("timing:\n  spi_mhz: 15\n")
    with pytest.raises(ConfigError, match=r"board.yaml: unknown config key timing.spi_mhz "
                                          r"\(known in timing: settle_us, spi_hz\)"):
        configio.load(Board, f)


def test_a_file_whose_keys_are_not_names_is_not_a_mapping_of_keys(tmp_path):
    """``: : :`` is a mapping whose keys are None: the message says the file is not a mapping
    of keys, not "unknown config key None"."""
    from snan_hil.host.config import load_config
    bad = tmp_path / "colons.yaml"
    bad.write_text(": : :\n")
    with pytest.raises(ConfigError) as exc:
        load_config(bad)
    msg = str(exc.value)
    assert "not a mapping of config keys" in msg and "unknown config key" not in msg, msg
    assert "\n" not in msg
    sub = tmp_path / "sub.yaml"
    sub.write_text("grid:\n  1: 2\n")
    with pytest.raises(ConfigError, match=r"grid: not a mapping of config keys \(found the key 1"):
        load_config(sub)


def _alias_bomb(levels: int) -> str:
    """~400 bytes of nested YAML aliases under a real key: 9**levels values once expanded."""
    lines = ["grid:", "  rows:", '    - &l0 ["x","x","x","x","x","x","x","x","x"]']
    lines += [f"    - &l{k} [{','.join([f'*l{k - 1}'] * 9)}]" for k in range(1, levels)]
    return "\n".join(lines) + "\n"


def test_an_alias_bomb_is_refused_in_one_short_line(tmp_path):
    """Issue 27 item 11: a config is untrusted input; 395 bytes of nested aliases made a
    1.4 GB error line. The expansion is bounded (counted per distinct node) and messages
    show values cut short."""
    from snan_hil.host.config import SnanConfig
    text = _alias_bomb(7)                    # 9**7 = 4.8 million values once expanded
    assert len(text) < 600
    path = tmp_path / "bomb.yaml"
    path.write_text(text)
    with pytest.raises(configio.ConfigError) as exc:
        configio.load(SnanConfig, path)
    msg = str(exc.value)
    assert "more than 100,000 values once its YAML aliases are expanded" in msg
    assert len(msg) < 300 and "\n" not in msg


def test_a_self_referring_alias_is_refused():
    with pytest.raises(configio.ConfigError, match="refers to the value it is part of"):
        configio.parse_yaml("grid: &a\n  rows: *a\n", "c.yaml")


def test_a_small_aliased_config_still_loads_and_long_values_are_cut_in_messages():
    tree = configio.parse_yaml(_alias_bomb(3), "c.yaml")       # 9**3 values: allowed
    assert len(tree["grid"]["rows"][2]) == 9
    from snan_hil.host.config import SnanConfig
    with pytest.raises(configio.ConfigError) as exc:
        configio.from_tree(SnanConfig, {"grid": {"rows": list(range(10_000))}}, where="c")
    assert "expected an integer" in str(exc.value) and len(str(exc.value)) < 200
