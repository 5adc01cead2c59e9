"""The notebook API refuses bad input with one UserError line and sends nothing (found by a
new user: a 5 V pulse was sent at the 1.4 V limit, NaN or a negative width or row gave wire
format errors, a closed board blamed the cable)."""

import numpy as np
import pytest

import snan_hil
from snan_hil.common.errors import UserError


@pytest.fixture
def board(tmp_path):
    b = snan_hil.open_board(f"emu://?state={tmp_path / 'chip.npz'}&seed=3")
    yield b
    b.close()


def _pulses(board) -> int:
    return board.session.client.status().pulses_applied


@pytest.mark.parametrize("amplitude, words", [(5.0, "write limit"), (float("nan"), "nan"),
                                              (-1.0, "(0, 1.4]"), (0.0, "(0, 1.4]")])
def test_a_pulse_outside_the_limit_is_refused_not_clipped(board, amplitude, words):
    before = _pulses(board)
    with pytest.raises(UserError, match="amplitude_v") as err:
        board.pulse(0, 0, polarity="set", amplitude_v=amplitude, width_us=100)
    assert words in str(err.value) and "\n" not in str(err.value)
    assert _pulses(board) == before                      # nothing was sent


@pytest.mark.parametrize("row, col, words", [(-1, 0, "row -1 outside 0..31"),
                                             ("a", 0, "row must be an integer"),
                                             (1.5, 0, "row must be an integer"),
                                             (True, 0, "row must be an integer"),
                                             (0, 8, "col 8 outside 0..7")])
def test_bad_cells_are_one_line(board, row, col, words):
    with pytest.raises(UserError, match=words):
        board.read_cell(row, col)


def test_bad_width_and_weights_and_port(board):
    with pytest.raises(UserError, match="width_us must be an integer"):
        board.pulse(0, 0, amplitude_v=1.0, width_us=-5)
    with pytest.raises(UserError, match="N x N matrix"):
        board.program_weights(np.zeros(3))
    with pytest.raises(UserError, match="port must be a text"):
        snan_hil.open_board(5)                            # type: ignore[arg-type]


def test_a_closed_board_says_so(board):
    board.close()
    with pytest.raises(UserError, match="this board is closed"):
        board.read_cell(0, 0)
    board.close()                                         # twice is harmless


@pytest.mark.parametrize("value, words", [(1.7, r"outside \[0, 1\]"), (float("nan"), "non-finite")])
def test_weights_the_cli_refuses_are_refused_not_clipped(board, value, words):
    # issue 38 item 5: weights of 1.7 were clipped to the largest conductance and reported ok
    from snan_hil.calibration.testing import grid_weights
    w = grid_weights(6, 6, seed=1)
    w[w > 0] = value
    before = _pulses(board)
    with pytest.raises(UserError, match=words) as err:
        board.program_weights(w)
    assert "\n" not in str(err.value)
    assert _pulses(board) == before                      # nothing was sent


@pytest.mark.parametrize("kwargs, words", [({"read_code": float("nan")}, "read_code must be"),
                                           ({"read_code": 2.7}, "read_code must be"),
                                           ({"read_code": -5}, "read_code -5 outside")])
def test_a_bad_read_code_names_the_keyword_and_is_never_truncated(board, kwargs, words):
    # found by a new user: read_code=2.7 read at code 2, NaN and -5 were deep ValueErrors
    with pytest.raises(UserError, match=words) as err:
        board.read_cell(0, 0, **kwargs)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("kwargs, words", [({"launches": "3"}, "launches must be"),
                                           ({"launches": 2.5}, "launches must be"),
                                           ({"seed": float("nan")}, "seed must be"),
                                           ({"weight_set": "0"}, "weight_set must be")])
def test_run_scenario_names_the_keyword(board, tmp_path, kwargs, words):
    with pytest.raises(UserError, match=words):
        board.run_scenario("sw_astro", tmp_path / "w.npz", **kwargs)
    with pytest.raises(UserError, match="weights must be a weights file"):
        board.run_scenario("sw_astro", np.zeros((36, 36)))


@pytest.mark.parametrize("kwargs, words", [({"max_write_v": 2.0}, "max_write_v 2.0: above"),
                                           ({"timeout": -1}, "timeout (seconds)"),
                                           ({"baud": 0}, "baud must be positive"),
                                           ({"tags": "abc"}, "tags must be a list")])
def test_open_board_names_its_keywords_not_the_commands_options(tmp_path, kwargs, words):
    # found by a new user: the shared checks said --max-write-v, --timeout, --baud; tags="abc"
    # was recorded as the tags a, b, c
    with pytest.raises(UserError) as err:
        snan_hil.open_board(f"emu://?state={tmp_path / 'c.npz'}", **kwargs)
    text = str(err.value)
    assert words in text and "--" not in text and "\n" not in text, text
