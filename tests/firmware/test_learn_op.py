"""On-board learning on the Python MCU (issue 34 stage 1; docs/protocol.md "On-board
learning"): LEARN_SETUP / LEARN_WINDOW / LEARN_APPLY / LEARN_STATE over the framed link; the
board's state equals the fixed-point reference fed with the same spikes; no pulse twice across
a lost reply, a HELLO (host crash) or a repeated window; RESET loses the state; boards
without the capability answer UNKNOWN_TYPE and announce no bit."""

import dataclasses

import numpy as np
import pytest

from snan_hil.calibration.mapping import WeightMap
from snan_hil.firmware_emu import learn_fixed as lf
from snan_hil.firmware_emu import lif_fixed as fx
from snan_hil.firmware_emu.config import BoardConfig
from snan_hil.firmware_emu.emulator import Emulator
from snan_hil.firmware_emu.testing import default_array
from snan_hil.host.hil.board_learning import learn_block, to_q30, with_synapses
from snan_hil.host.hil.board_window import window_params
from snan_hil.host.kernel_params import kernel_params
from snan_hil.protocol import learn_messages as lm
from snan_hil.protocol import messages as m
from snan_hil.protocol.errors import OutOfRangeError, UnsupportedError, UnsupportedRequestError
from snan_hil.protocol.link import LinkClient
from snan_hil.protocol.transport import CallbackTransport
from snan_hil.tools.window_agreement import calibrated_chain

from snan_hil.tools.learn_agreement import fitted_chip_model as chip_model
from snan_hil.tools.learn_agreement import train_config

def _client(learning=True):
    emu = Emulator(None, 0, array=default_array(0),
                   config=BoardConfig(on_board_learning=learning))
    client = LinkClient(CallbackTransport(emu.feed, name="emu"))
    client.hello()
    return client, emu


KEYS = [(r, c) for r in range(4) for c in range(4)]          # synapse = its cell here


def _setup(client, w=0.45):
    info = client.info
    block = learn_block(train_config(), chip_model(), WeightMap(),
                        set_code=info.write_dac_code(1.2), reset_code=info.write_dac_code(0.6),
                        width_us=100)
    cells = {k: k for k in KEYS}
    weights = {k: w + 0.02 * i for i, k in enumerate(KEYS)}
    return with_synapses(block, cells, weights, weights)


def _params():
    chain = calibrated_chain()
    return window_params(kernel_params(train_config()), chain, WeightMap(), chain.read_code)


def _trial(client, trial, n_windows, rng, decide):
    """Learning windows on rows 0..3 (two candidates each); returns each window's (rows,
    candidates, key, motor spikes) and the host's decisions."""
    p = _params()
    out = []
    decided = lm.LEARN_NO_LANE
    for w in range(n_windows):
        row = int(rng.integers(0, 4))
        cands = (m.DecisionCandidate(int(rng.integers(0, 2)), 0),
                 m.DecisionCandidate(int(rng.integers(2, 4)), 0))
        key = int(rng.integers(0, 2**63))
        r = client.learn_window(trial, w, decided, key, (row,), cands, p)
        decided = decide(r.counts)
        out.append(((row,), cands, key, decided))
    return out, decided



def test_capability_is_announced_only_where_switched_on():
    client, _ = _client(learning=False)
    assert not client.info.has(m.Capability.LEARN)
    with pytest.raises(UnsupportedError):
        client.learn_state()
    with pytest.raises(UnsupportedRequestError):
        client.request(lm.LearnState(0, 1))
    on, _ = _client()
    assert on.info.has(m.Capability.LEARN)
    assert on.learn_state().n_syn == 0


def test_board_learns_as_the_reference_and_never_applies_a_trial_twice():
    client, emu = _client()
    setup = _setup(client)
    assert client.learn_setup(setup).n_syn == len(KEYS)
    op = emu.dispatcher.learn
    ref = lf.LearnState(lf.rule_of(setup), [s.cell for s in setup.synapses],
                        [s.w_int for s in setup.synapses], [s.w_est for s in setup.synapses])
    rng = np.random.default_rng(4)
    pulses0 = client.status().pulses_applied
    total = 0
    for trial in (1, 2, 3):
        # mirror every window in the reference from the board's own pairs (its op keeps them)
        seen = []
        real_window = op.window

        def spy(fw, wop, req, real=real_window, seen=seen):
            reply = real(fw, wop, req)
            seen.append((req, list(wop.last_pre), list(wop.last_post)))
            return reply

        op.window = spy
        windows, last = _trial(client, trial, 12, rng, lambda c: int(np.argmax(c)))
        op.window = real_window
        for i, (req, pre, post) in enumerate(seen):
            if i:
                ref.decide(windows[i - 1][3])
            posts = [[t for t, k in post if k == lane] for lane in range(2)]
            lanes = [ref.index(lm.cell_byte(req.window_req.rows[0], c.col))
                     for c in req.window_req.candidates]
            ref.window(lanes, pre, posts)
            assert pre == fx.spike_steps_ref(req.window_req.key, _params().n_bins,
                                             _params().spike_threshold)
        ref.decide(last)
        want = ref.plan()
        reply = client.learn_apply(trial, 11, last)
        assert not reply.already
        assert [(o.synapse, o.polarity, o.count) for o in reply.orders] == want
        total += reply.pulses
        assert reply.pulses_applied - pulses0 == total
        # every synapse the trial changed or pulsed, with its state (the host's mirror)
        assert [t.synapse for t in reply.touched] == sorted(ref.touched)
        ref.touched = []
        for t in reply.touched:
            assert (t.w_int, t.w_est) == (ref.w_int[t.synapse], ref.w_est[t.synapse])
    assert total > 0
    state = client.learn_state()
    assert [(s.n_set, s.n_reset) for s in state.synapses] == list(zip(ref.n_set, ref.n_reset))
    assert state.last_trial == 3
    # the host crashed after LEARN_APPLY 3 and comes back: HELLO clears the reply cache, the
    # repeat is answered ALREADY and applies nothing; a window of trial 3 is refused
    client.hello()
    again = client.learn_apply(3, 11, last)
    assert again.already and not again.orders
    assert client.status().pulses_applied - pulses0 == total
    with pytest.raises(OutOfRangeError) as e:
        client.learn_window(3, 0, lm.LEARN_NO_LANE, 5, (0,), (m.DecisionCandidate(0, 0),),
                            _params())
    assert e.value.detail == 3


def test_a_repeated_window_applies_no_decision_twice():
    client, emu = _client()
    setup = _setup(client)
    client.learn_setup(setup)
    p = _params()
    cand = (m.DecisionCandidate(1, 0),)
    client.learn_window(1, 0, lm.LEARN_NO_LANE, 11, (2,), cand, p)
    client.learn_window(1, 1, 0, 12, (2,), cand, p)
    st = emu.dispatcher.learn.state
    once = list(st.w_int)
    client.hello()                                  # host crash: the cache is gone
    client.learn_window(1, 1, 0, 12, (2,), cand, p)  # the same window again
    assert st.w_int == once
    client.learn_window(1, 2, 0, 13, (2,), cand, p)  # window 1's decision: applied once
    j = st.index(lm.cell_byte(2, 1))
    changed = [i for i, (a, b) in enumerate(zip(once, st.w_int)) if a != b]
    assert changed in ([], [j])


def test_reset_loses_the_learning_state_and_the_setup_is_checked():
    client, _ = _client()
    setup = _setup(client)
    client.learn_setup(setup)
    client.reset()
    assert client.learn_state().n_syn == 0
    with pytest.raises(OutOfRangeError) as e:
        client.learn_apply(1, 0)
    assert e.value.detail == 0
    bad = dataclasses.replace(setup, synapses=setup.synapses + (setup.synapses[0],))
    with pytest.raises(OutOfRangeError) as e:
        client.learn_setup(bad)
    assert e.value.detail == setup.synapses[0].cell
    with pytest.raises(OutOfRangeError) as e:
        client.request(dataclasses.replace(setup, max_pulses=0))
    assert e.value.detail == 2
    assert client.learn_state().n_syn == 0          # a refused block changes nothing
    assert to_q30(1.0) == lm.LEARN_W_ONE
