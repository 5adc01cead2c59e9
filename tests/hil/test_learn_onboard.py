"""On-board learning end to end (issue 34 stage 1): paired sessions on copies of one emulated
chip, learnt by the host's STDP (WRITE_PULSE per pulse) and by the board (LEARN_WINDOW /
LEARN_APPLY) — the board's learner sends no pulse, its ledger equals its pulse counter, its
cycles cost fewer wire bytes; a budget and another rule are refused in one line."""

import argparse
import dataclasses

import pytest

from snan_hil.common.errors import UserError
from snan_hil.firmware_emu.testing import learning_client
from snan_hil.host.hil.board_learning import check_learnable
from snan_hil.host.hil.learn_arms import LearnConfig, LearnTask
from snan_hil.host.hil.learn_onboard import paired_session
from snan_hil.host.hil.learning import PulseBudget
from snan_hil.host.hil.testing import program_session
from snan_hil.tools.commands.learn import model_config
from snan_hil.tools.learn_agreement import fitted_chip_model



def _task(grid=3, cycles=3):
    cfg, start, goal = model_config(argparse.Namespace(grid=grid, start=None, goal=None,
                                                       config=None, overrides=[]))
    return LearnTask(cfg, LearnConfig(start=start, goal=goal, sessions=1, cycles=cycles))


def test_the_board_learns_without_a_host_pulse_and_keeps_the_ledger(tmp_path):
    task = _task()
    runs = {}
    for name in ("host", "board"):
        client = learning_client(0)
        layout = program_session(client, task, 0, tmp_path / f"{name}.json")
        runs[name] = paired_session(task, 0, client, layout, fitted_chip_model(), name)
    host, board = runs["host"], runs["board"]
    assert sum(board.host_pulses) == 0 and sum(host.host_pulses) > 0
    total = sum(s + r for s, r in board.pulses)
    assert total > 0
    assert board.ledger["set"] + board.ledger["reset"] == total == board.board_counter
    assert host.board_counter == sum(host.host_pulses)
    for c, (nb, nh) in enumerate(zip(board.wire_bytes, host.wire_bytes)):
        if host.host_pulses[c]:                     # a cycle with pulses: far fewer bytes
            assert nb < nh


def test_what_the_board_cannot_learn_is_refused_in_one_line():
    task = _task()
    cfg = task.train_cfg
    check_learnable(cfg)
    with pytest.raises(UserError, match="target chosen only"):
        check_learnable(dataclasses.replace(cfg, stdp=dataclasses.replace(cfg.stdp,
                                                                          target="all")))
    with pytest.raises(UserError, match="pulse budget"):
        check_learnable(cfg, PulseBudget(session_pulses=200))
