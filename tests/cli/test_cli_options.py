"""One name per meaning on the command line (issue 14): --set KEY=VALUE is a config override on
every command with a config, --weight-set K the weight-set index, old spellings give one line
naming the new one, and every option's help states its default once."""

from __future__ import annotations

import argparse

import pytest

from snan_hil.tools import cli

CONFIG_COMMANDS = ("sim", "experiment", "demo", "train", "run", "compare")
WEIGHT_SET_COMMANDS = ("program-weights", "read-weights", "run", "compare")


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def _option(parser: argparse.ArgumentParser, name: str) -> argparse.Action | None:
    return next((a for a in parser._actions if name in a.option_strings), None)


def test_config_overrides_are_set_everywhere_and_weight_sets_weight_set():
    subs = _subparsers()
    for name in CONFIG_COMMANDS:
        act = _option(subs[name], "--set")
        assert act is not None and act.dest == "overrides" and act.metavar == "KEY=VALUE", name
    for name in WEIGHT_SET_COMMANDS:
        act = _option(subs[name], "--weight-set")
        assert act is not None and act.metavar.startswith("K"), name
    for name, parser in subs.items():                 # no visible --override anywhere
        act = _option(parser, "--override")
        assert act is None or act.help == argparse.SUPPRESS, name


def _help_entries(parser: argparse.ArgumentParser) -> dict[str, str]:
    """Option -> its rendered help text (one string, wrapped lines joined)."""
    fmt = parser._get_formatter()
    out = {}
    for act in parser._actions:
        if not act.option_strings or act.help == argparse.SUPPRESS:
            continue
        out[act.option_strings[-1]] = " ".join(fmt._expand_help(act).split()) if act.help else ""
    return out


def test_every_help_states_its_default_once():
    for name, parser in _subparsers().items():
        text = parser.format_help()
        assert "(default: None)" not in text, name
        assert "(default: False)" not in text and "(default: [])" not in text, name
        for act in parser._actions:
            if not act.option_strings or act.help == argparse.SUPPRESS or act.required:
                continue
            help_text = _help_entries(parser)[act.option_strings[-1]]
            where = f"{name} {act.option_strings[-1]}: {help_text!r}"
            assert help_text.count("default") <= 1, where
            flag = isinstance(act, (argparse._StoreTrueAction, argparse._StoreFalseAction,
                                    argparse._HelpAction, argparse._AppendAction))
            if not flag:
                assert "default" in help_text, where       # stated, in words or the value
            if act.default not in (None, [], False, argparse.SUPPRESS) and not flag \
                    and "(default: " in help_text and "%" not in str(act.default):
                assert f"(default: {act.default})" in help_text or \
                    str(act.default) in help_text, where


@pytest.mark.parametrize("argv, needle", [
    (["train", "-o", "w.npz", "--override", "astro.a=3"], "--override is now --set KEY=VALUE"),
    (["run", "--scenario", "sw_astro", "--weights", "w.npz", "--override", "astro.a=3"],
     "--override is now --set KEY=VALUE"),
    (["compare", "--weights", "w.npz", "--override", "x=1"], "--override is now --set"),
    (["run", "--scenario", "sw_astro", "--weights", "w.npz", "--set", "1"],
     "--set 1: a weight set is chosen with --weight-set 1 now"),
    (["program-weights", "w.npz", "--set", "0"], "--set 0: --set is now --weight-set K"),
    (["read-weights", "--set", "2"], "--set 2: --set is now --weight-set K"),
    (["mac", "--set", "1"], "--set 1: --set is now --weight-set K"),
    (["mac", "--set", "astro.a=1"], "--set astro.a=1: snan-hil mac takes no config overrides"),
    (["read-weights", "--set", "x=1"], "a weight set is chosen with --weight-set K"),
    (["compare", "--weights", "w.npz", "--only", "0,3"], "--only is now --weight-set K[,K...]"),
    (["sim", "--set", "3"], "--set 3: expected KEY=VALUE"),    # no weight sets in sim
])
def test_old_spellings_give_one_line_naming_the_new_option(argv, needle, capsys):
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and "\n" not in err and "Traceback" not in err
    assert err.startswith(f"snan-hil {argv[0]}: error: ")


def test_set_values_are_read_as_yaml_1_2_on_the_command_line(capsys):
    import json
    assert cli.main(["sim", "--trials", "2", "--seed", "1", "--json", "--set",
                     "astro.alpha_n_per_ms=1e-3", "--set", "grid.max_steps=010"]) == 0
    cfg = json.loads(capsys.readouterr().out)["config"]
    assert cfg["astro"]["alpha_n_per_ms"] == 0.001 and cfg["grid"]["max_steps"] == 10
    assert cli.main(["sim", "--trials", "2", "--set", "grid.max_steps=1:40"]) == 2
    err = capsys.readouterr().err.strip()
    assert "grid.max_steps: expected an integer, got '1:40'" in err and "\n" not in err


@pytest.mark.parametrize("argv, needle", [
    (["sim", "--trials", "2", "--no-astro", "--set", "astro.enabled=true"],
     "--no-astro and --set astro.enabled=true give astro.enabled different values"),
    (["sim", "--trials", "2", "--astro", "--set", "astro.enabled=false"],
     "--astro and --set astro.enabled=false"),
    (["sim", "--trials", "2", "--max-steps", "7", "--set", "grid.max_steps=9"],
     "--max-steps 7 and --set grid.max_steps=9 give grid.max_steps different values (7 vs 9)"),
    (["sim", "--trials", "2", "--grid", "4", "--set", "grid.rows=5"],
     "--grid 4 and --set grid.rows=5 give grid.rows different values (4 vs 5)"),
    (["sim", "--trials", "2", "--grid", "4", "--set", "grid={cols: 6}"],
     "--grid 4 and --set grid.cols=6"),
    (["train", "-o", "w.npz", "--grid", "5", "--set", "grid.cols=6"],
     "--grid 5 and --set grid.cols=6"),
    (["train", "-o", "w.npz", "--set", "astro.enabled=false"],
     "--set astro.enabled=false would not reach the training"),
    (["train", "-o", "w.npz", "--set", "stdp.target=chosen"],
     "--set stdp.target=chosen would not reach the training: the HIL config's train_set"),
    (["run", "--scenario", "sw_astro", "--weights", "w.npz", "--set", "astro.enabled=false"],
     "--scenario sw_astro and --set astro.enabled=false"),
    (["compare", "--weights", "w.npz", "--set", "astro.enabled=true"],
     "--scenarios (sw_noastro) and --set astro.enabled=true"),
    (["experiment", "fig7", "--route-target", "all", "--set", "stdp.target=chosen"],
     "--route-target all and --set stdp.target=chosen give stdp.target different values"),
    (["demo", "--software-only", "--set", "astro.enabled=false"],
     "--set astro.enabled: every stage runs with and without astrocytes"),
    (["demo", "--set", "grid.rows=4"], "--set grid.rows: the stages run the paper's grids"),
    (["demo", "--set", "stdp.target=chosen"], "would not reach the training"),
])
def test_an_option_and_a_set_of_the_same_key_must_agree(argv, needle, tmp_path, monkeypatch,
                                                        capsys):
    """An explicit option and a --set naming the same config key with different values are
    refused in one line naming both, before any work (no output file, no folder)."""
    monkeypatch.chdir(tmp_path)
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and "\n" not in err and "Traceback" not in err, err
    assert list(tmp_path.iterdir()) == []


def test_an_option_and_an_equal_set_are_fine(capsys):
    import json
    assert cli.main(["sim", "--trials", "2", "--json", "--grid", "4", "--max-steps", "7",
                     "--no-astro", "--set", "grid.rows=4", "--set", "grid.max_steps=7",
                     "--set", "astro.enabled=false"]) == 0
    cfg = json.loads(capsys.readouterr().out)["config"]
    assert cfg["grid"]["rows"] == 4 and cfg["grid"]["max_steps"] == 7
    assert cfg["astro"]["enabled"] is False


def test_experiment_route_target_follows_a_set_of_stdp_target():
    """Without --route-target, fig7 trains with the --set stdp.target (the value its config
    records), not with a default that disagrees with it."""
    from snan_hil.tools.commands.experiment import route_target
    ns = argparse.Namespace
    assert route_target(ns(route_target=None, overrides=["stdp.target=all"])) == "all"
    assert route_target(ns(route_target=None, overrides=[])) == "chosen"
    assert route_target(ns(route_target="all", overrides=["stdp.target=all"])) == "all"


@pytest.mark.parametrize("argv,needle", [
    (["sim", "--grid", "3", "--bogus"], "snan-hil sim: error: unrecognized arguments: --bogus"),
    (["retention", "--reads", "1e10"], "snan-hil retention: error: argument --reads: invalid int"),
    (["nosuchcommand"], "snan-hil: error: argument COMMAND: invalid choice"),
])
def test_a_usage_error_is_one_line_naming_the_command_and_its_help(capsys, argv, needle):
    """Issue 27 item 13: argparse printed a 16-line usage block before the one line."""
    from snan_hil.tools import cli
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(needle) and "--help'" in err, err


def _all_parsers(parser: argparse.ArgumentParser, prog: tuple[str, ...] = ()):
    """(words, parser) of every sub-command parser, nested ones too (plan run, cells test)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield (*prog, name), sub
                yield from _all_parsers(sub, (*prog, name))


def _a_value(action: argparse.Action) -> str | None:
    if action.choices:
        return str(list(action.choices)[0])
    for text in ("1", "0.5", "1,1", "3,5", "x", "a.yaml", "emu"):
        try:
            if action.type is None or action.type(text) is not None:
                return text
        except (ValueError, TypeError, argparse.ArgumentTypeError):
            continue
    return None


def test_an_option_given_twice_is_refused_on_every_command(capsys):
    # issue 38 item 9: argparse kept the last value silently (--cells 20,0 --cells 20,1
    # planned only 20,1; --sample A --sample B recorded B)
    checked = 0
    for words, parser in _all_parsers(cli.build_parser()):
        for action in parser._actions:
            if type(action).__name__ != "Once_StoreAction" or not action.option_strings:
                continue
            value = _a_value(action)
            if value is None:
                continue
            opt = action.option_strings[-1]
            with pytest.raises(SystemExit) as exc:
                cli.build_parser().parse_args([*words, opt, value, opt, value])
            err = capsys.readouterr().err.strip()
            assert exc.value.code == 2 and "\n" not in err, (words, opt, err)
            assert f"argument {'/'.join(action.option_strings)}: given twice" in err, err
            checked += 1
    assert checked > 200


@pytest.mark.parametrize("argv", [
    ["read-cell", "--cell", "1,1", "--tag", "a", "--tag", "b"],
    ["readings", "--vary", "synapse.w_inh=1,2", "--vary", "stdp.k=1,2"],
    ["sim", "--set", "grid.max_steps=10", "--set", "astro.enabled=true"],
    ["-v", "-v", "sim"],
    ["read-cell", "--cell", "1,1", "--json", "--json"],
])
def test_options_meant_to_repeat_still_do(argv):
    cli.build_parser().parse_args(argv)


def test_main_refuses_the_second_value_in_one_line(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("SNAN_HIL_EMU_STATE", str(tmp_path / "chip.npz"))
    with pytest.raises(SystemExit) as exc:
        cli.main(["plan", "run", "set", "--cells", "20,0", "--cells", "20,1", "--dry-run"])
    err = capsys.readouterr().err.strip()
    assert exc.value.code == 2 and err == (
        "snan-hil plan run: error: argument --cells: given twice (--cells 20,0, then --cells "
        "20,1); an option takes one value: give it once; see 'snan-hil plan run --help'")
    assert not (tmp_path / "chip.npz").exists()
