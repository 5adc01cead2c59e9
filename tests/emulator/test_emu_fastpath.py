"""The fast paths (batched ADC frames, whole SPIKE_BATCH in one pass, vectorised noise) against
the per-frame reference path.

Same seeds: identical bytes, frame times, codes, clock (per category), energy, counters and
random-generator states. Independent seeds on the same chip: the code statistics agree (mean
within a few standard errors, same spread), for cell reads, column reads and spike batches.
"""

import copy
import shutil

import numpy as np
import pytest

from snan_hil.crossbar_model import ArrayConfig, CrossbarArray
from snan_hil.firmware_emu import registers as reg
from snan_hil.firmware_emu import spike_fastpath
from snan_hil.firmware_emu.spike_group import SpikeGroupSpec
from snan_hil.firmware_emu.spi_devices import AD5328
from snan_hil.firmware_emu.testing import default_array, ideal_array, make_firmware
from snan_hil.common.polarity import Polarity

READ_NOISE = {"read_noise.relative_sigma": 0.01, "read_noise.absolute_sigma_s": 2e-7}


def noisy_uniform_chip(seed):
    """A chip that is the same for every seed (no variability, no stuck cells) but whose read
    noise stream depends on the seed; conductances from a fixed generator, 50 uS..1 mS."""
    array = CrossbarArray(ArrayConfig.default().ideal().with_overrides(READ_NOISE), seed=seed)
    g = np.random.default_rng(99).uniform(5e-5, 1e-3, size=(array.rows, array.cols))
    for r in range(array.rows):
        for c in range(array.cols):
            array.set_conductance(r, c, g[r, c])
    return array


def workload(fw):
    """Cell reads, column reads, an unpaced and a paced spike batch, a pulse, a saturating read."""
    rng = np.random.default_rng(5)
    out = [fw.read_cell(r, (3 * r) % 8, 245) for r in range(0, 32, 3)]
    out += [fw.read_column(list(rng.integers(0, 120, 32)), c) for c in range(8)]
    bins = tuple(int(b) for b in np.flatnonzero(rng.random(60) < 0.3))
    groups = [SpikeGroupSpec(((5, 245),), bins), SpikeGroupSpec(((9, 200), (30, 100)), bins[::2])]
    out += sum(fw.spike_batch(groups, [0, 2, 3, 7], n_bins=60, bin_us=500, paced=True), [])
    out += sum(fw.spike_batch([SpikeGroupSpec(tuple((r, 82) for r in range(15)), bins)],
                              list(range(8)), n_bins=60, bin_us=1000), [])
    out.append(fw.write_pulse(4, 4, Polarity.SET, 700, 100))
    out += sum(fw.spike_batch([SpikeGroupSpec(tuple((r, 245) for r in range(32)), (0, 1))],
                              [1], n_bins=2, bin_us=1000), [])      # saturates
    return out


def observables(fw):
    board = fw.board
    fe = board.front_end
    return {
        "now_us": fw.clock.now_us, "energy_j": fw.clock.energy_j,
        "breakdown": dict(fw.clock.breakdown_us), "status": fw.status(),
        "samples": (fe.samples, fe.saturated_samples), "adc": (board.adc.result,
                                                               board.adc.conversions,
                                                               board.adc.frames),
        "bus": (board.bus.transactions, board.bus.bytes),
        "array_rng": board.array._rng.bit_generator.state,
        "adc_rng": fe._rng.bit_generator.state,
        "conductance": board.array.conductance().tobytes(),
    }


def test_fast_and_reference_paths_are_identical_for_the_same_seeds():
    runs = {}
    for fast in (True, False):
        fw = make_firmware(default_array(3), adc_noise_lsb=0.5, seed=4, fast=fast)
        assert fw.fast is fast
        runs[fast] = (workload(fw), observables(fw))
    (codes_fast, obs_fast), (codes_ref, obs_ref) = runs[True], runs[False]
    assert codes_fast == codes_ref
    assert obs_fast == obs_ref                 # exact floats: time, energy, every category
    assert obs_fast["samples"][1] > 0          # the saturating read was part of it
    assert obs_fast["breakdown"]["idle"] > 0   # and the paced batch


def test_the_random_stream_is_deterministic_for_a_seed():
    first, second, other = (make_firmware(default_array(s), adc_noise_lsb=0.5, seed=s)
                            for s in (7, 7, 8))
    assert workload(first) == workload(second)
    assert observables(first) == observables(second)
    assert workload(other) != workload(make_firmware(default_array(7), adc_noise_lsb=0.5,
                                                     seed=7))


def test_spi_trace_is_the_same_in_both_paths():
    traces = {}
    for fast in (True, False):
        fw = make_firmware(default_array(1), adc_noise_lsb=0.5, seed=1, fast=fast)
        fw.board.bus.start_trace()
        fw.read_cell(21, 6, 245)
        fw.spike_batch([SpikeGroupSpec(((3, 200),), (0, 1))], [1, 4], n_bins=2, bin_us=1000)
        traces[fast] = [(t.t_us, t.cs, t.mosi, t.miso) for t in fw.board.bus.stop_trace()]
    assert traces[True] == traces[False]
    adc = [t for t in traces[True] if t[1] == reg.CS_ADC]
    assert len(adc) == 5 * 11                   # 1 cell read + 2 spikes x 2 columns
    assert traces[True][0][1:3] == (reg.CS_SR_COL, bytes((reg.WL_EN | 6,)))


def _stats_close(fast, ref, what):
    fast, ref = np.asarray(fast, float), np.asarray(ref, float)
    assert fast.std() > 0.3 and ref.std() > 0.3, f"{what}: no noise to compare"
    se = np.sqrt(fast.var(ddof=1) / fast.size + ref.var(ddof=1) / ref.size)
    assert abs(fast.mean() - ref.mean()) < 4.5 * se, what
    # The sample std of n normal values has a relative sd of ~1/sqrt(2n) (3.2 % at n = 500).
    tol = 5.0 / np.sqrt(2 * min(fast.size, ref.size))
    assert abs(fast.std(ddof=1) / ref.std(ddof=1) - 1.0) < tol, what


def paths_with_independent_noise(adc_noise_lsb=0.5, chip=noisy_uniform_chip):
    """Fast and reference firmware on identical chips whose noise streams differ."""
    return (make_firmware(chip(11), adc_noise_lsb=adc_noise_lsb, seed=21, fast=True),
            make_firmware(chip(12), adc_noise_lsb=adc_noise_lsb, seed=22, fast=False))


def test_cell_read_statistics_agree():
    fast, ref = paths_with_independent_noise()
    n = 1500
    _stats_close([fast.read_cell(6, 2, 245) for _ in range(n)],
                 [ref.read_cell(6, 2, 245) for _ in range(n)], "cell read")


def test_adc_noise_statistics_agree_without_read_noise():
    from snan_hil.firmware_emu.testing import ideal_array
    fast, ref = paths_with_independent_noise(adc_noise_lsb=3.0, chip=ideal_array)
    codes = [0] * 32
    codes[:8] = [100] * 8
    n = 1500
    # ~3 / sqrt(10) LSB per reading: only the ADC's per-sample noise spreads these codes.
    _stats_close([fast.read_column(codes, 5) for _ in range(n)],
                 [ref.read_column(codes, 5) for _ in range(n)], "ADC noise")


def test_column_read_statistics_agree():
    fast, ref = paths_with_independent_noise()
    codes = list(np.random.default_rng(2).integers(0, 120, 32))
    n = 1500
    _stats_close([fast.read_column(codes, 3) for _ in range(n)],
                 [ref.read_column(codes, 3) for _ in range(n)], "column read")


@pytest.mark.parametrize("rows, columns", [(((5, 245),), [0, 2, 3, 6]),
                                           (tuple((r, 82) for r in range(15)), list(range(8)))])
def test_spike_batch_statistics_agree(rows, columns):
    fast, ref = paths_with_independent_noise()
    spikes = 600 if len(columns) == 4 else 300
    group = [SpikeGroupSpec(rows, tuple(range(spikes)))]
    a = np.array(fast.spike_batch(group, columns, n_bins=spikes, bin_us=1000))
    b = np.array(ref.spike_batch(group, columns, n_bins=spikes, bin_us=1000))
    assert fast.clock.now_us == ref.clock.now_us and fast.clock.energy_j == ref.clock.energy_j
    for k, col in enumerate(columns):
        _stats_close(a[:, k], b[:, k], f"spike column {col}")


class OldInterfaceArray:
    """A crossbar offering only the original read interface (no vectorised reads, no revision)."""

    HIDDEN = {"cell_currents", "column_currents", "multi_column_currents", "revision"}

    def __init__(self, array):
        self._array = array

    def __getattr__(self, name):
        if name in self.HIDDEN:
            raise AttributeError(name)
        return getattr(self._array, name)


def test_arrays_without_vectorised_reads_give_the_same_results():
    runs = {}
    for fast in (True, False):
        fw = make_firmware(OldInterfaceArray(default_array(2)), adc_noise_lsb=0.5, seed=2,
                           fast=fast)
        runs[fast] = (workload(fw), fw.clock.now_us, fw.clock.energy_j)
    assert runs[True] == runs[False]


def test_spike_energy_follows_conductance_changes_between_batches():
    group = [SpikeGroupSpec(((5, 245), (6, 200)), (0, 1, 2))]

    def spike_energy(fw):
        e0 = fw.clock.energy_j
        fw.spike_batch(group, [1, 2], n_bins=3, bin_us=1000)
        return fw.clock.energy_j - e0

    fw = make_firmware()
    before = spike_energy(fw)                      # caches the power of these columns
    fw.board.array.set_conductance(5, 1, 9e-4)
    after = spike_energy(fw)
    fresh = make_firmware()
    fresh.board.array.set_conductance(5, 1, 9e-4)
    assert after == pytest.approx(spike_energy(fresh), rel=1e-12)
    assert abs(after / before - 1) > 0.05


def test_transfer_many_equals_single_transfers_for_every_device():
    """Batched where the device allows it (full ADC frames), frame by frame otherwise."""
    sequence = [(reg.CS_SR_ROW, bytes((reg.ROWDAC_EN,)), 1), (reg.CS_ROW_DAC[0], b"\x10\x80", 1),
                (reg.CS_SR_COL, bytes((reg.col_select_byte(1, sum_path=True),)), 2),
                (reg.CS_ADC, b"\0\0", 7), (reg.CS_ADC, b"\0", 3), (reg.CS_ADC, b"\0\0\0", 2),
                (reg.CS_ADC, b"\0\0", 1), (reg.CS_SR_COL, b"\0", 1)]
    results = []
    for batched in (True, False):
        fw = make_firmware(default_array(5), adc_noise_lsb=0.5, seed=5)
        bus = fw.board.bus
        bus.start_trace()
        for cs, mosi, count in sequence:
            if batched:
                bus.transfer_many(cs, mosi, count)
            else:
                for _ in range(count):
                    bus.transfer(cs, mosi)
        trace = [(t.t_us, t.cs, t.mosi, t.miso) for t in bus.stop_trace()]
        results.append((trace, observables(fw)))
    assert results[0] == results[1]
    assert sum(1 for t in results[0][0] if t[1] == reg.CS_ADC) == 13


# ------------------------------------------------------------------ whole-batch SPIKE_BATCH path
@pytest.fixture
def batch_calls(monkeypatch):
    """Number of spikes each whole-batch fast-path call handled."""
    calls = []
    run = spike_fastpath.run_spike_batch

    def counting(board, groups, columns, *args):
        calls.append(sum(len(g.bins) for g in groups))
        return run(board, groups, columns, *args)

    monkeypatch.setattr(spike_fastpath, "run_spike_batch", counting)
    return calls


def _bins(seed, n_bins, p):
    return tuple(int(b) for b in np.flatnonzero(np.random.default_rng(seed).random(n_bins) < p))


BATCHES = {
    # the HIL back-end: a neuron whose cells span two rows, each row its own group
    "hil two rows": ([SpikeGroupSpec(((5, 245),), _bins(1, 1000, 0.15)),
                      SpikeGroupSpec(((6, 245),), _bins(1, 1000, 0.15))], [0, 1, 2, 3], False),
    "15 rows x 8 columns": ([SpikeGroupSpec(tuple((r, 82) for r in range(15)), _bins(2, 80, 0.3))],
                            list(range(8)), False),
    # rows in several DACs, a row at code 0 (not driven), a group of only code 0 (no row
    # driven), one column, paced bins (a row repeated in a group is refused: docs/protocol.md)
    "mixed groups, paced": (
        [SpikeGroupSpec(((3, 50), (17, 245), (28, 0)), _bins(3, 90, 0.2)),
         SpikeGroupSpec(((9, 200), (10, 30), (31, 245)), _bins(4, 90, 0.2)),
         SpikeGroupSpec(((12, 0),), _bins(5, 90, 0.1))], [6], True),
}


def _run_batches(fw, batch):
    groups, columns, paced = batch
    n_bins = 1 + max(max(g.bins, default=0) for g in groups)
    out = []
    for _ in range(2):                              # twice: the second starts from the first's end
        out += fw.spike_batch(groups, columns, n_bins=n_bins, bin_us=700, paced=paced)
        out.append(fw.read_cell(4, 5, 245))
    return out


@pytest.mark.parametrize("name", list(BATCHES))
@pytest.mark.parametrize("chip", ["default", "ideal"])
def test_whole_batch_path_equals_the_per_frame_path(name, chip, batch_calls):
    runs = {}
    for fast in (True, False):
        array = default_array(6) if chip == "default" else ideal_array(6)
        fw = make_firmware(array, adc_noise_lsb=0.5 if chip == "default" else 0.0, seed=6,
                           fast=fast)
        fw.board.bus.start_trace()
        codes = _run_batches(fw, BATCHES[name])
        trace = [(t.t_us, t.cs, t.mosi, t.miso) for t in fw.board.bus.stop_trace()]
        dacs = [(d.frames, d.input_reg, d.dac_reg) for d in fw.board.row_dacs]
        regs = (fw.board.sr_col.frames, fw.board.sr_col.shift, fw.board.sr_col.latch,
                fw.board.adc._busy_until, fw.last_saturated, fw.clock.power_w)
        runs[fast] = (codes, observables(fw), trace, dacs, regs)
    assert len(batch_calls) == 2 and batch_calls[0] > 5          # the fast run took the batch path
    for got, want in zip(runs[True], runs[False]):
        assert got == want


def test_a_saturating_batch_counts_like_the_per_frame_path(batch_calls):
    runs = {}
    group = [SpikeGroupSpec(tuple((r, 245) for r in range(32)), (0, 1, 3))]
    for fast in (True, False):
        fw = make_firmware(default_array(8), adc_noise_lsb=0.5, seed=8, fast=fast)
        codes = fw.spike_batch(group, [1, 4], n_bins=4, bin_us=1000)
        runs[fast] = (codes, observables(fw), fw.last_saturated)
    assert batch_calls == [3]
    assert runs[True] == runs[False]
    assert runs[True][1]["status"]["saturated_reads"] > 0


def test_outside_the_steady_state_spikes_run_one_by_one_with_the_same_result(batch_calls):
    """Row DACs left in LDAC 'hold' mode (outputs do not follow the writes): not the state the
    batch path replays, so the firmware applies the spikes one at a time."""
    runs = {}
    for fast in (True, False):
        fw = make_firmware(default_array(9), adc_noise_lsb=0.5, seed=9, fast=fast)
        fw.bus.transfer(reg.CS_ROW_DAC[0], AD5328.control_word(0b01, 0b01))   # hold
        assert not spike_fastpath.applicable(fw.board, [2])
        codes = _run_batches(fw, BATCHES["mixed groups, paced"])
        runs[fast] = (codes, observables(fw))
    assert batch_calls == []
    assert runs[True] == runs[False]


@pytest.mark.parametrize("noisy", [True, False])
@pytest.mark.parametrize("patterns", ["mixed", "uniform"])
def test_column_currents_sequence_equals_one_drive_at_a_time(noisy, patterns):
    """Patterns driving different numbers of rows (one draw cut up per spike) and patterns
    all driving two rows (one draw reshaped): the reads of one drive at a time."""
    array = default_array(4) if noisy else ideal_array(4)
    twin = copy.deepcopy(array)
    rng = np.random.default_rng(0)
    volts = np.zeros((4, array.rows))
    if patterns == "mixed":
        volts[0, 5] = 0.299                              # one row
        volts[1, [2, 9, 30]] = [0.1, 0.2, 0.05]          # three rows
        volts[2] = rng.uniform(0.01, 0.1, array.rows)    # every row; pattern 3: none
    else:
        for p, rows in enumerate(([5, 6], [0, 31], [12, 13], [7, 20])):
            volts[p, rows] = [0.299, 0.15]
    drive = rng.integers(0, 4, 60)
    got = array.column_currents_sequence(volts, drive, [0, 3, 7], 11)
    want = np.array([twin.multi_column_currents(volts[d], [0, 3, 7], 11) for d in drive])
    assert got.shape == (60, 3, 11)
    assert np.array_equal(got, want)
    assert np.all(got[drive == 3] == 0.0) == (patterns == "mixed")
    assert array._rng.bit_generator.state == twin._rng.bit_generator.state


@pytest.mark.parametrize("conversions", [0, None], ids=["standard reads", "lean reads"])
def test_a_hil_launch_gives_identical_reply_bytes_on_both_paths(tmp_path, batch_calls,
                                                                monkeypatch, conversions):
    """End to end: the same programmed chip, the same requests -> the same reply bytes, path,
    virtual time and energy with the fast path as with the per-frame reference: the whole-batch
    spike path (the standard reads, conversions 0) and the window's samples drawn at once
    (the lean read plan, the board's default)."""
    from snan_hil.calibration.weights_io import load_weight_set
    from snan_hil.firmware_emu.inprocess import emulator_of, open_inprocess_transport
    from snan_hil.host.hil.runner import run_scenario
    from snan_hil.host.hil.testing import make_weights, program_set, small_hil_config
    from snan_hil.protocol.link import LinkClient
    from snan_hil.tools.ports import open_client

    hil = small_hil_config(max_steps=4)
    wpath = make_weights(tmp_path / "w.npz", sets=1, cycles=2, hil=hil)
    client = open_client("emu", state_file=str(tmp_path / "chip.npz"), seed=0)
    layout = program_set(client, wpath, 0, tmp_path / "layout.json")
    client.close()
    w, _ = load_weight_set(wpath, 0)
    lean_calls = []
    column_reads = CrossbarArray.column_reads

    def counting_reads(self, *args, **kw):
        lean_calls.append(1)
        return column_reads(self, *args, **kw)

    monkeypatch.setattr(CrossbarArray, "column_reads", counting_reads)
    runs = {}
    for fast in (True, False):
        state = tmp_path / f"chip-{fast}.npz"
        shutil.copy(tmp_path / "chip.npz", state)
        transport = open_inprocess_transport(str(state), seed=0)
        emu = emulator_of(transport)
        emu.firmware.fast = fast
        emu.endpoint.boot_nonce = 0x5EED                 # a real board draws one at boot
        replies = []
        feed = emu.endpoint.feed

        def recording_feed(data, feed=feed, replies=replies):
            replies.append(feed(data))
            return replies[-1]

        emu.endpoint.feed = recording_feed
        link = LinkClient(transport, first_seq=1)         # a session starts at a random seq
        link.hello()
        res = run_scenario("hw_astro", w, hil, launches=1, seed=1, client=link, layout=layout,
                           baud=115200, conversions=conversions)
        launch = res.launches[0].to_dict()
        launch.pop("wall_s")
        runs[fast] = (launch, b"".join(replies))
        link.close()
    if conversions == 0:
        assert batch_calls                               # the fast run used the batch path
    else:
        assert not batch_calls and lean_calls            # ... the window's samples at once
    assert runs[True] == runs[False]
    assert runs[True][0]["virtual_us"] > 0 and runs[True][0]["spikes"] > 100


def test_spike_order_is_bin_order_then_group_order():
    rng = np.random.default_rng(3)
    groups = [SpikeGroupSpec(((g, 100),), tuple(sorted(rng.choice(50, size=n, replace=False))))
              for g, n in enumerate((20, 0, 35, 1, 20))]
    bins, group = spike_fastpath.spike_order(groups)
    want = sorted((b, gi) for gi, g in enumerate(groups) for b in g.bins)
    assert list(zip(bins.tolist(), group.tolist())) == want
