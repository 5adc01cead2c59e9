"""DECISION_WINDOW's lean read plan (issue 33, docs/protocol.md "Read plan"): N conversions a
read of the candidates' own cells, no dummy, settling while the ADC converts. Both MCUs answer
it bit for bit and take the same board time; the Python MCU's fast path equals its per-frame
path; a window's noise is keyed by the window; the board setting and its refusals; an older
board (no READ_PLAN) keeps its ten averages; the ceiling's counts are the board's own."""

import dataclasses
import random

import pytest

from snan_hil.calibration.mapping import WeightMap
from snan_hil.common.errors import UserError
from snan_hil.firmware_emu.emulator import Emulator
from snan_hil.firmware_emu.testing import default_array
from snan_hil.host.hil.board_window import read_plan, window_params
from snan_hil.host.hil.ceiling import WindowCounts, ceiling, lean_window_counts
from snan_hil.host.hil.config import load_hil_config
from snan_hil.host.kernel_params import kernel_params
from snan_hil.protocol import messages as m
from snan_hil.protocol.board import WINDOW_CONVERSIONS
from snan_hil.protocol.frames import Frame, FrameDecoder, encode_frame
from snan_hil.protocol.link import LinkClient
from snan_hil.protocol.transport import CallbackTransport
from snan_hil.tools.window_agreement import calibrated_chain

NONCE = 0x5EED1234
CHAIN = calibrated_chain()
PARAMS = window_params(kernel_params(load_hil_config().launch_config(True)), CHAIN, WeightMap(),
                       CHAIN.read_code)


def _firmware_ready():
    pytest.importorskip("unicorn")
    from snan_hil.firmware_emu import mik32_native
    from snan_hil.firmware_emu.fw_image import default_elf_path
    if not default_elf_path().is_file() or mik32_native.load() is None:
        pytest.skip("firmware ELF or native MCU core not built ('make firmware')")


def _lean(rng: random.Random, with_params: bool) -> m.DecisionWindow:
    """A random lean window (conversions 1..5; paced, trace, motor spikes, interneurons)."""
    p = dataclasses.replace(PARAMS, n_bins=rng.choice([1, 60, 400, 1000]),
                            ref_steps=rng.choice([0, 5, 40]), lif_flags=rng.choice([0, 1]),
                            spike_threshold=rng.choice([PARAMS.spike_threshold, 1 << 52]),
                            conversions=rng.choice([1, 2, 2, 3, 5]), bin_us=rng.choice([0, 20]))
    rows = tuple(rng.sample(range(32), rng.randint(1, 3)))
    cands = []
    for _ in range(rng.randint(0, 4)):
        inh = tuple(sorted(rng.sample(range(p.n_bins), min(p.n_bins, rng.choice([0, 3, 9])))))
        cands.append(m.DecisionCandidate(rng.randrange(8), rng.randrange(len(rows)), inh))
    stride = rng.choice([0, 0, 50, 333])
    if stride and 4 * len(cands) * ((p.n_bins + stride - 1) // stride) > 2000:
        stride = 0
    return m.DecisionWindow(rng.getrandbits(64), rows, tuple(cands),
                            p if with_params else None, rng.random() < 0.5, stride,
                            p.bin_us > 0 and rng.random() < 0.3)


class _Boards:
    """Emulated boards fed the same frames; per board its decoded replies."""

    def __init__(self, boards: dict):
        self.boards = boards
        self.decoders = {k: FrameDecoder() for k in boards}

    def send(self, msg, seq, nonce=NONCE):
        out = {}
        for k, emu in self.boards.items():
            raw = emu.feed(encode_frame(Frame(msg.TYPE, seq, msg.encode(), nonce)))
            msgs = [f.message() for f in self.decoders[k].feed(raw)]
            out[k] = [(x.code, x.detail) if isinstance(x, m.ErrorReply) else x for x in msgs]
        return out


def test_both_mcus_answer_random_lean_windows_bit_for_bit_in_the_same_time():
    _firmware_ready()
    b = _Boards({mcu: Emulator(None, 3, array=default_array(3), mcu=mcu, boot_nonces=(NONCE,))
                 for mcu in ("model", "firmware")})
    b.send(m.Hello(), 1, 0)
    rng = random.Random(31)
    answered, rel = 0, []
    for seq in range(2, 40):
        req = _lean(rng, seq % 4 == 2)
        t0 = {k: e.clock.now_us for k, e in b.boards.items()}
        out = b.send(req, seq)
        assert out["model"] == out["firmware"], req
        reply = out["model"][0]
        if isinstance(reply, m.DecisionWindowReply):
            answered += 1
            if reply.n_input_spikes > 20 and not req.paced:
                t = {k: e.clock.now_us - t0[k] for k, e in b.boards.items()}
                rel.append(abs(t["model"] - t["firmware"]) / t["firmware"])
    assert answered >= 20 and len(rel) >= 8
    # the Python MCU times the firmware's steps with its fitted costs (window_reads.COSTS)
    assert max(rel) < 0.03 and sum(rel) / len(rel) < 0.012, rel
    for e in b.boards.values():
        e.close()


def test_the_python_mcus_fast_path_equals_its_per_frame_path():
    """Samples drawn at once, devices synced after: the same replies, SPI trace, clock,
    energy, noise streams and ADC state as frame by frame."""
    b = _Boards({fast: Emulator(None, 3, array=default_array(3), mcu="model", fast=fast,
                                boot_nonces=(NONCE,)) for fast in (True, False)})
    b.send(m.Hello(), 1, 0)
    rng = random.Random(5)
    for seq in range(2, 30):
        req = _lean(rng, True)
        state = {}
        for emu in b.boards.values():
            emu.board.bus.start_trace()
        out = b.send(req, seq)
        for fast, emu in b.boards.items():
            trace = [(t.t_us, t.cs, t.mosi, t.miso) for t in emu.board.bus.stop_trace()]
            fe, c = emu.board.front_end, emu.clock
            state[fast] = (trace, c.now_us, c.energy_j, dict(c.breakdown_us),
                           emu.array.rng_state(), fe._rng.bit_generator.state, fe.samples,
                           emu.board.adc.result, emu.board.adc.ready_at_us())
        assert out[True] == out[False], req
        assert state[True] == state[False], req


def test_a_lean_windows_reads_are_keyed_by_the_window():
    """The same lean window answers alike whatever the board did before it (interleaved
    launches take the decisions they take alone); the standard reads draw the chip's running
    noise (as SPIKE_BATCH)."""
    boards = _Boards({k: Emulator(None, 3, array=default_array(3), mcu="model",
                                  boot_nonces=(NONCE,)) for k in ("a", "b")})
    boards.send(m.Hello(), 1, 0)
    lean = dataclasses.replace(PARAMS, conversions=2, spike_threshold=1 << 52)
    cands = (m.DecisionCandidate(1, 0), m.DecisionCandidate(5, 0))
    win = m.DecisionWindow(77, (4,), cands, lean, True, 100, False)
    first = boards.send(win, 2)
    assert first["a"] == first["b"]
    codes = tuple(lean.row_code if r in (4, 9) else 0 for r in range(32))
    boards.boards["b"].feed(encode_frame(Frame(m.ReadColumn.TYPE, 3, m.ReadColumn(
        5, codes).encode(), NONCE)))                         # other reads on board b only
    again = boards.send(dataclasses.replace(win, params=None), 4)
    assert again["a"] == again["b"] == first["a"]
    reply = first["a"][0]
    assert reply.n_input_spikes > 100 and any(v for point in reply.trace for v in point)


def _window(rng: random.Random, conversions: int | None) -> m.DecisionWindow:
    """A random window of a random shape (1-4 rows, 1-4 candidates, a trace or not): with a
    parameter block of ``conversions`` a read (0: the standard reads), or without one
    (``None``: the stored block and its plan)."""
    p = dataclasses.replace(PARAMS, n_bins=rng.choice([40, 150, 300]),
                            lif_flags=rng.choice([0, 1]), spike_threshold=1 << 51,
                            conversions=conversions or 0)
    rows = tuple(rng.sample(range(32), rng.randint(1, 4)))
    cands = tuple(m.DecisionCandidate(rng.randrange(8), rng.randrange(len(rows)))
                  for _ in range(rng.randint(1, 4)))
    return m.DecisionWindow(rng.getrandbits(64), rows, cands,
                            None if conversions is None else p, rng.random() < 0.5,
                            rng.choice([0, 10]), False)


def test_both_mcus_key_lean_windows_whatever_ran_before():
    """Lean windows with and without a parameter block, of varying shapes, after standard
    windows and between them: both MCUs answer alike and leave the chip's running noise (the
    standard reads') where the other leaves it. (The instruction-level MCU keys a lean
    window's noise from run_lean's entry to its return; a return hook added once the code
    after the call was translated - a standard window ran it - never fired: the keyed stream
    stayed on, and the next lean window read the running noise instead of its own.)"""
    _firmware_ready()
    b = _Boards({mcu: Emulator(None, 5, array=default_array(5), mcu=mcu, boot_nonces=(NONCE,))
                 for mcu in ("model", "firmware")})
    b.send(m.Hello(), 1, 0)
    rng = random.Random(33)
    lean_seen = 0
    for seq in range(2, 26):
        plan = rng.choice([0, 0, 1, 2, 3, 5, 10, None, None, None])
        if seq == 2 and plan is None:
            plan = 0
        req = _window(rng, plan)
        out = b.send(req, seq)
        assert out["model"] == out["firmware"], (seq, req)
        assert isinstance(out["model"][0], m.DecisionWindowReply), out["model"]
        lean_seen += bool(req.params.conversions if req.params is not None else plan is None)
        streams = {k: (e.array.rng_state(), e.board.front_end._rng.bit_generator.state)
                   for k, e in b.boards.items()}
        assert streams["model"] == streams["firmware"], (seq, req)
    assert lean_seen >= 8
    for e in b.boards.values():
        e.close()


def _client(capabilities_off: int = 0):
    emu = Emulator(None, 0, array=default_array(0), mcu="model")
    client = LinkClient(CallbackTransport(emu.feed, name="emu"))
    client.hello()
    if capabilities_off:
        client.info = dataclasses.replace(client.info, capabilities=client.info.capabilities
                                          & ~capabilities_off)
    return client, emu


def test_the_board_setting_and_an_older_board():
    client, _ = _client()
    assert client.info.has(m.Capability.READ_PLAN)
    assert read_plan(client) == WINDOW_CONVERSIONS                # the named board setting
    assert read_plan(client, 0) == 0 and read_plan(client, 3) == 3
    with pytest.raises(UserError, match="1..10"):
        read_plan(client, 11)
    old, _ = _client(int(m.Capability.READ_PLAN))
    assert read_plan(old) == 0                                    # ten averages, as before
    with pytest.raises(UserError, match="no READ_PLAN"):
        read_plan(old, 2)
    # the standard window's bytes are those of a board before the read plan: no flag, no byte
    std = m.DecisionWindow(1, (0,), (m.DecisionCandidate(0, 0),), PARAMS)
    assert not std.encode()[0] & m.DecisionFlag.READ_PLAN
    lean = dataclasses.replace(std, params=dataclasses.replace(PARAMS, conversions=2))
    assert len(lean.encode()) == len(std.encode()) + 1
    assert m.DecisionWindow.decode(lean.encode()) == lean


def test_the_board_refuses_conversions_beyond_its_averages():
    client, _ = _client()
    bad = dataclasses.replace(PARAMS, conversions=client.info.adc_averages + 1)
    with pytest.raises(Exception) as e:
        client.request(m.DecisionWindow(1, (0,), (m.DecisionCandidate(0, 0),), bad))
    assert "conversions" in str(e.value)


@pytest.mark.parametrize("paced", [False, True])
def test_the_ceilings_counts_are_the_boards_own(paced):
    """lean_window_counts (the reads that wait, the row-DAC words) against the Python MCU's
    own frames of the same window: column-register writes, DAC words, ADC frames."""
    client, emu = _client()
    p = dataclasses.replace(PARAMS, conversions=3, spike_threshold=1 << 51, bin_us=20)
    cands = (m.DecisionCandidate(2, 0), m.DecisionCandidate(6, 1), m.DecisionCandidate(3, 1))
    rows = (5, 12)
    client.decision_window(1, rows, cands, p, paced=paced)        # the block stored
    bus = emu.board.bus
    before = {k: d.frames for k, d in bus.devices.items()}
    r = client.decision_window(2, rows, cands, p, paced=paced)
    frames = {k: d.frames - before[k] for k, d in bus.devices.items()}
    req = m.DecisionWindow(2, rows, cands, None)
    cells = [(rows[ri], col) for ri, col in req.reads()]
    waits, words = lean_window_counts(cells, r.n_input_spikes, paced)
    assert r.n_input_spikes > 10
    assert frames["ADC"] == 3 * len(cells) * r.n_input_spikes + 1     # no dummy: one at the end
    assert sum(v for k, v in frames.items() if k.startswith("DAC")) == words
    # the cells' columns differ: every wait follows a column write; the window ends with the
    # word line off (a paced window turns it off after every spike)
    assert len({c for _, c in cells}) == len(cells)
    assert frames["SR_COL"] == waits + (r.n_input_spikes if paced else 1)
    c = WindowCounts(spikes=r.n_input_spikes, reads=len(cells) * r.n_input_spikes,
                     selects=waits, row_words=words, conversions=3, request_bytes=30,
                     reply_bytes=20, mcu_us=1.0)
    ce = ceiling(c, 115200)
    # the analog chain: every conversion after a read's first one cycle (5 us), a read that
    # changed nothing one cycle, the end frame one; a change its frame, select and 6 us
    want_adc = ((3 - 1) * c.reads + (c.reads - waits) + 1) * 5.0
    assert ce.parts_us["ADC"] == pytest.approx(want_adc)
    assert ce.bound in ("ADC", "DAC") and ce.time_us == pytest.approx(ce.chain_us)

