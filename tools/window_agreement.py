"""Fixed point against float: the board's DECISION_WINDOW integration (``firmware_emu.lif_fixed``,
the arithmetic the Python MCU and the C firmware run) against the host's float64 LIF
(``host.snan_kernel.float_motor_window``, what the ``batch`` mode runs), on the same reads.

:func:`agreement_sample` draws random decision windows as the 6x6 HIL task sees them: 2-4
candidates, the input spike train of a random stream state (p = 0.15, 1000 steps), per
candidate a programmed weight in [0.5, 0.8] (the paper's range) read at every input spike as
an ADC code with Gaussian read noise, and for some candidates a periodic interneuron spike
train (an astrocyte-lowered threshold: period 60-130 steps). Both sides get exactly the same
codes and interneuron spikes; the board converts the codes with its parameter block, the host
with the calibrated chain (``column_cell_conductance`` and the weight map). It counts the
windows whose spike counts (and spike steps) differ. Used by ``bench/bench_window.py`` (a
large sample) and ``tests/firmware/test_decision_window.py`` (a quick one). Lives in ``tools``
because it
joins the emulator's fixed point and the host's kernel, which the layers keep apart.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from snan_hil.calibration.mapping import WeightMap
from snan_hil.calibration.readchain import ReadChain
from snan_hil.firmware_emu import lif_fixed as fx
from snan_hil.host import snan_kernel as K
from snan_hil.host.config import SnanConfig
from snan_hil.host.hil.board_window import window_params
from snan_hil.host.kernel_params import kernel_params
from snan_hil.protocol.board import MEMRICORE


@dataclass
class Agreement:
    """Outcome of :func:`agreement_sample`: windows compared, windows whose counts differ,
    windows whose motor spike steps differ, and the differing windows' (board, host) counts."""

    windows: int = 0
    count_mismatch: int = 0
    time_mismatch: int = 0
    lanes: int = 0
    motor_spikes: int = 0
    examples: list[tuple[list[int], list[int]]] = field(default_factory=list)

    @property
    def rate(self) -> float:
        """Share of windows with equal counts."""
        return 1.0 - self.count_mismatch / self.windows if self.windows else float("nan")

    def to_dict(self) -> dict:
        return {"windows": self.windows, "count_mismatch": self.count_mismatch,
                "time_mismatch": self.time_mismatch, "agreement": self.rate,
                "lanes": self.lanes, "motor_spikes": self.motor_spikes,
                "examples": self.examples[:10]}


def calibrated_chain(offset_code: float = 12.37, gain_factor: float = 1.013) -> ReadChain:
    """MemriCore's chain as a calibration leaves it: a fractional column offset and a gain
    factor off 1 (so the conversion's constants are not round numbers)."""
    base = ReadChain.nominal(MEMRICORE)
    return ReadChain(**{**{k: getattr(base, k) for k in ReadChain.__dataclass_fields__
                           if k not in ("details",)},
                        "offset_column_code": offset_code, "gain_factor": gain_factor,
                        "calibrated": True})


def agreement_sample(cfg: SnanConfig, windows: int, *, seed: int = 0,
                     read_noise: float = 0.01, inh_share: float = 0.5,
                     chain: ReadChain | None = None,
                     weight_map: WeightMap | None = None) -> Agreement:
    """Compare the board's fixed point with the host's float LIF on ``windows`` random
    windows of model ``cfg`` (module doc). ``read_noise``: relative std of a read;
    ``inh_share``: probability that a candidate's interneuron fires (periodically)."""
    chain = chain or calibrated_chain()
    wmap = weight_map or WeightMap()
    kp = kernel_params(cfg)
    row_code = chain.read_code
    p = window_params(kp, chain, wmap, row_code)
    rng = np.random.default_rng(seed)
    steps = kp.steps
    full = chain.adc_full_scale_code
    out = Agreement()
    isp = np.zeros((4, steps + 1), dtype=np.int64)
    n_isp = np.zeros(4, dtype=np.int64)
    post = np.zeros((4, steps + 1), dtype=np.int64)
    for _ in range(windows):
        key = int(rng.integers(0, 2 ** 63))
        sp = fx.spike_steps(key, steps, p.spike_threshold)
        lanes = int(rng.integers(2, 5))
        w = rng.uniform(0.5, 0.8, lanes)
        expected = np.asarray(chain.column_code(wmap.conductance(w), row_code))
        codes = np.clip(np.rint(expected[None, :] * (1 + read_noise
                                                     * rng.standard_normal((sp.size, lanes)))),
                        0, full).astype(np.int64)
        drive_q = np.zeros((steps, lanes), dtype=np.int64)
        drive_f = np.zeros((steps, 4))
        inhibited = np.zeros((steps, lanes), dtype=np.bool_)
        if sp.size:
            drive_q[sp, :] = fx.drives(codes, p.offset, p.d, p.num_shift, p.den_shift,
                                       p.q_shift, p.k1, p.k0)
            g = np.asarray(chain.column_cell_conductance(codes.astype(float), row_code))
            drive_f[sp, :lanes] = np.asarray(wmap.weight(g, clip=False))
        n_isp[:] = 0
        for k in range(lanes):
            if rng.random() < inh_share:
                period = int(rng.integers(60, 131))
                times = np.arange(int(rng.integers(0, period)), steps, period)
                isp[k, :times.size] = times
                n_isp[k] = times.size
                inhibited[times, k] = True
        spiking = np.zeros(steps, dtype=np.bool_)
        spiking[sp] = True
        counts_q, spikes_q, _ = fx.integrate(steps, spiking, drive_q, inhibited, p.alpha_pow,
                                             p.thr, p.reset, p.inh, p.ref_steps, p.integrate)
        counts_f = K.float_motor_window(kp, sp, sp.size, drive_f, lanes, isp, n_isp, post)
        out.windows += 1
        out.lanes += lanes
        out.motor_spikes += int(counts_f.sum())
        same_counts = np.array_equal(counts_q, counts_f)
        if not same_counts:
            out.count_mismatch += 1
            out.examples.append(([int(c) for c in counts_q], [int(c) for c in counts_f]))
        times_f = sorted((int(post[k, j]), k) for k in range(lanes)
                         for j in range(int(counts_f[k])))
        if [tuple(x) for x in spikes_q.tolist()] != times_f:
            out.time_mismatch += 1
    return out
