"""Fixed point against float for on-board learning: the board's STDP update and pulse plan
(``firmware_emu.learn_fixed``, the arithmetic the Python MCU runs) against the host's float
STDP (``host.snan_kernel.stdp_lane`` times ``stdp.k``, the chosen lane, as
``window_changes``) and pulse planning (``host.hil.learning.PulsePlanner`` without a budget,
the chip-level curve).

:func:`agreement_sample` draws random training trials as the 6x6 HIL task sees them: 24
synapses, 1-29 windows a trial, each window's input spike train at p = 0.15 over the
window's steps and 0-11 motor spikes at random steps, the window's change going to one random
synapse; after each trial both sides plan, and the plans (synapse, polarity, pulses) are
compared. Before every trial the board's state is set to the host's, rounded to Q1.30, so
each plan is compared from equal states (the per-plan agreement); every 40 trials the weights
are drawn afresh over the whole window (0..1) so the plans cover the step curve. Lives in
``tools`` because it joins the emulator's fixed point and the host's planner, which the
layers keep apart. Used by ``tests/firmware/test_learn_fixed.py`` (a quick sample) and
``bench/bench_learn_fixed.py`` (a large one).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field

import numpy as np

from snan_hil.calibration.mapping import WeightMap
from snan_hil.common.polarity import Polarity
from snan_hil.crossbar_model.fitted import DeviceModel, LearningPulse
from snan_hil.firmware_emu import learn_fixed as lf
from snan_hil.host import snan_kernel as K
from snan_hil.host.config import SnanConfig
from snan_hil.host.hil.board_learning import from_q30, learn_block, to_q30
from snan_hil.host.hil.learning import PulsePlanner
from snan_hil.host.kernel_params import kernel_params

__all__ = ["Agreement", "agreement_sample", "fitted_chip_model", "train_config"]

N_SYNAPSES = 24


def fitted_chip_model() -> DeviceModel:
    """A chip-level model with the fitted values of a fresh emulated chip at the 0.8 V / 0.6 V
    learning pulse (docs/learning.md §1's table, rounded)."""
    return DeviceModel(LearningPulse(), 525e-6, dw_min=0.034, up_down=0.2, dw_min_dtod=0.18,
                       up_down_dtod=0.17, dw_min_std=0.3, g_min_s=33e-6, g_max_s=1.25e-3,
                       g_min_dtod=0.07, g_max_dtod=0.06, read_noise=0.0027, up_rate=0.047,
                       up_slope=-0.08, down_rate=0.0095, down_slope=-0.39)


def train_config(grid: int = 6) -> SnanConfig:
    """The training trials' config of ``snan-hil learn --grid GRID`` (astrocytes on, STDP at
    the trial's end)."""
    from snan_hil.host.hil.learn_arms import LearnConfig, LearnTask
    from snan_hil.tools.commands.learn import model_config
    cfg, start, goal = model_config(argparse.Namespace(grid=grid, start=None, goal=None,
                                                       config=None, overrides=[]))
    return LearnTask(cfg, LearnConfig(start=start, goal=goal)).train_cfg


@dataclass
class Agreement:
    """Counts of a sample: plans compared, plans equal, pulses planned (host), the largest
    difference of a window's change (weight units), and the first differing plans."""

    plans: int = 0
    equal: int = 0
    pulses: int = 0
    max_dw_error: float = 0.0
    examples: list[tuple[list, list]] = field(default_factory=list)

    @property
    def rate(self) -> float:
        return self.equal / self.plans if self.plans else float("nan")


def _resync(pl: PulsePlanner, st: lf.LearnState, keys: list, w: dict | None = None) -> None:
    """Both sides to the host's state (or ``w``) rounded to Q1.30."""
    for j, k in enumerate(keys):
        wi = to_q30(pl.w_int[k] if w is None else w[k])
        we = to_q30(pl.w_est[k] if w is None else w[k])
        pl.w_int[k], pl.w_est[k] = from_q30(wi), from_q30(we)
        st.w_int[j], st.w_est[j] = wi, we


def agreement_sample(cfg: SnanConfig, model: DeviceModel, trials: int, *, seed: int = 1,
                     table_bits: int = 6, weight_map: WeightMap | None = None) -> Agreement:
    """Compare ``trials`` random training trials' plans (module doc) under ``cfg``'s STDP and
    ``model``'s chip curve."""
    wm = weight_map or WeightMap()
    kp = kernel_params(cfg)
    setup = learn_block(cfg, model, wm, set_code=1, reset_code=1, width_us=100,
                        table_bits=table_bits)
    rule = lf.rule_of(setup)
    rng = np.random.default_rng(seed)
    keys = [(i, d) for i in range(N_SYNAPSES // 4) for d in range(4)]
    cells = {k: (j // 8, j % 8) for j, k in enumerate(keys)}
    pl = PulsePlanner(model, wm, cells, cfg.stdp.w_min, cfg.stdp.w_max, per_cell=False,
                      max_pulses=rule.max_pulses)
    w0 = {k: float(rng.uniform(0.2, 0.9)) for k in keys}
    pl.start(w0)
    st = lf.LearnState(rule, list(range(len(keys))), [0] * len(keys), [0] * len(keys))
    _resync(pl, st, keys)
    out = Agreement()
    steps = int(kp.steps)
    for tr in range(trials):
        if tr and tr % 40 == 0:
            _resync(pl, st, keys, {k: float(rng.uniform(0.0, 1.0)) for k in keys})
        for _ in range(int(rng.integers(1, 30))):
            j = int(rng.integers(len(keys)))
            pre = np.flatnonzero(rng.random(steps) < 0.15).astype(np.int64)
            post = np.sort(rng.choice(steps, int(rng.integers(0, 12)), replace=False)
                           ).astype(np.int64)
            dw = kp.k * K.stdp_lane(kp, pre, len(pre), post, len(post))
            pl.update(keys[j], dw)
            st.window([j], pre.tolist(), [post.tolist()])
            out.max_dw_error = max(out.max_dw_error,
                                   abs(from_q30(st.pending[0][1]) - dw))
            st.decide(0)
        host = [(keys.index(o.key), 0 if o.polarity == Polarity.SET else 1, o.count)
                for o in pl.plan()]
        board = st.plan()
        out.plans += 1
        out.pulses += sum(o[2] for o in host)
        if host == board:
            out.equal += 1
        elif len(out.examples) < 5:
            out.examples.append((host, board))
        _resync(pl, st, keys)
    return out
