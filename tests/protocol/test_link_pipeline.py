"""Two requests outstanding (docs/protocol.md section 4, issue 33): the host's next request on
the line while the board works, the replies told apart by their sequence numbers, each request
resent with its own, no window executed twice; the refusals of a link or board that cannot."""

import dataclasses
import shutil

import pytest

from snan_hil.firmware_emu.inprocess import emulator_of, open_inprocess_transport
from snan_hil.protocol import messages as m
from snan_hil.protocol.board import WINDOW_CONVERSIONS
from snan_hil.protocol.link import LinkClient
from snan_hil.protocol.testing import LossyTransport
from snan_hil.tools.window_agreement import calibrated_chain

CHAIN = calibrated_chain()


def _params() -> m.DecisionParams:
    from snan_hil.calibration.mapping import WeightMap
    from snan_hil.host.hil.board_window import window_params
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.kernel_params import kernel_params
    p = window_params(kernel_params(load_hil_config().launch_config(True)), CHAIN, WeightMap(),
                      CHAIN.read_code)
    return dataclasses.replace(p, conversions=WINDOW_CONVERSIONS)


PARAMS = _params()
CANDS = (m.DecisionCandidate(1, 0, (40, 300)), m.DecisionCandidate(4, 1),
         m.DecisionCandidate(6, 1, (700,)))


def _firmware_ready():
    pytest.importorskip("unicorn")
    from snan_hil.firmware_emu import mik32_native
    from snan_hil.firmware_emu.fw_image import default_elf_path
    if not default_elf_path().is_file() or mik32_native.load() is None:
        pytest.skip("firmware ELF or native MCU core not built ('make firmware')")


@pytest.fixture(params=["model", "firmware"])
def mcu(request):
    if request.param == "firmware":
        _firmware_ready()
    return request.param


@pytest.fixture
def chip(tmp_path, mcu):
    """A chip state file (seed 0) made on ``mcu``'s board and a way to open copies of it."""
    state = tmp_path / "chip.npz"
    t = open_inprocess_transport(state, seed=0, mcu=mcu)
    t.close()

    def copy(tag: str, *, drop: float = 0.0, seed: int = 0) -> LinkClient:
        dst = tmp_path / f"chip-{tag}.npz"
        shutil.copy(state, dst)
        transport = open_inprocess_transport(dst, seed=0, mcu=mcu)
        if drop:
            transport = LossyTransport(transport, drop=drop, seed=seed, directions="read")
        client = LinkClient(transport, timeout=0.2, retries=8, first_seq=0xFFF0)
        client.hello()
        return client
    return copy


def _windows(client: LinkClient, keys) -> list[m.DecisionWindow]:
    return [client.window_request(k, (3, 9), CANDS, PARAMS) for k in keys]


def _sequential(client: LinkClient, keys) -> list[tuple[int, tuple[int, ...]]]:
    out = []
    for k in keys:
        r = client.decision_window(k, (3, 9), CANDS, PARAMS)
        out.append((r.n_input_spikes, r.counts))
    return out


def _pipelined(client: LinkClient, keys, *, reverse: bool = False):
    """The first window alone (it carries the parameter block), then two at a time: the next
    submitted before the last is collected; ``reverse``: the later one collected first."""
    first = client.decision_window(keys[0], (3, 9), CANDS, PARAMS)
    out = {keys[0]: (first.n_input_spikes, first.counts)}
    client.pipelined = True
    try:
        rest = list(keys[1:])
        assert len(rest) % 2 == 0, "give the windows after the first in pairs"
        for a, b in zip(rest[::2], rest[1::2]):
            ra, rb = _windows(client, (a, b))
            assert ra.params is None and client.pipelinable(ra)
            ta, tb = client.submit(ra), client.submit(rb)
            order = [(b, rb, tb), (a, ra, ta)] if reverse else [(a, ra, ta), (b, rb, tb)]
            for key, req, ticket in order:
                r = client.window_reply(req, PARAMS, client.collect(ticket))
                out[key] = (r.n_input_spikes, r.counts)
    finally:
        client.pipelined = False
    return [out[k] for k in keys]


def test_two_outstanding_windows_answer_as_one_after_another(chip, mcu):
    keys = list(range(101, 110))
    seq = chip("seq")
    want = _sequential(seq, keys)
    t_seq = seq.clock().time_us
    pipe = chip("pipe")
    got = _pipelined(pipe, keys, reverse=True)
    t_pipe = pipe.clock().time_us
    assert got == want
    assert sum(n for n, _ in got) > 100                 # the windows read something
    # the board ran each window once, and the next request arrived while it worked: the
    # board's clock (wire included) is shorter than one after another
    assert pipe.status().spikes_applied == seq.status().spikes_applied
    assert t_pipe < t_seq
    assert pipe.counters.retries == 0
    emu = emulator_of(pipe.transport)
    if emu.backend is not None:
        assert emu.backend.mcu.faults == {}             # no host byte lost on the chip
    seq.close()
    pipe.close()


def test_lost_replies_are_resent_with_their_own_seq_and_no_window_runs_twice(chip, mcu):
    keys = list(range(201, 216))
    seq = chip("seq")
    want = _sequential(seq, keys)
    lossy = chip("lossy", drop=0.02, seed=5)
    got = _pipelined(lossy, keys)
    assert got == want
    assert lossy.counters.retries > 0                  # replies were lost and requests resent
    # the board answered the resent ones from its cache: every window ran once
    assert lossy.status().spikes_applied == seq.status().spikes_applied
    seq.close()
    lossy.close()


def test_a_second_request_needs_the_pipeline(chip, mcu):
    client = chip("refuse")
    client.decision_window(1, (3,), CANDS[:1], PARAMS)
    first = client.submit(client.window_request(2, (3,), CANDS[:1], PARAMS))
    with pytest.raises(RuntimeError, match="pipelined"):   # stop-and-wait: one at a time
        client.submit(client.window_request(3, (3,), CANDS[:1], PARAMS))
    client.collect(first)
    client.pipelined = True
    first = client.submit(client.window_request(4, (3,), CANDS[:1], PARAMS))
    big = m.DecisionWindow(5, (3,), CANDS[:1], PARAMS)   # the parameter block: too long for
    assert not client.pipelinable(big)                  # the board's receive ring
    with pytest.raises(RuntimeError, match="fits"):
        client.submit(big)
    client.collect(first)
    with pytest.raises(RuntimeError, match="collect"):  # never off with one outstanding
        t = client.submit(client.window_request(6, (3,), CANDS[:1], PARAMS))
        client.pipelined = False
    client.collect(t)
    client.pipelined = False
    client.close()


def test_a_board_without_the_capability_is_never_pipelined(chip):
    client = chip("old")
    client.info = dataclasses.replace(client.info, capabilities=client.info.capabilities
                                      & ~int(m.Capability.PIPELINE))
    with pytest.raises(ValueError, match="PIPELINE"):
        client.pipelined = True
    assert not client.pipelinable(client.window_request(1, (3,), CANDS[:1], PARAMS))
    client.close()
