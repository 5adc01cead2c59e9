"""Cross-check of the SNAN kernel against an external simulator, Brian2 (docs/model.md,
"Cross-check with Brian2"; the ``test`` extra installs Brian2).

The network of sections 2.2.2-2.2.4 is written as Brian2 objects: LIF motor neurons and
interneurons (``NeuronGroup`` with ``dv/dt = -(v - v_rest)/tau_m``, integrated exactly, a
threshold, a reset and an absolute refractory period), the interneuron's bias current, the
glutamate of every input neuron (``dG/dt = -alpha_n G``, Euler, plus ``k_n`` per input spike),
the reduced second-order calcium model (Euler; ``J = A`` while ``G > G_thr``), the
astrocyte-lowered interneuron threshold ``v_thr*/(1 + eta H(Ca - Ca_thr))``, the fixed
input->interneuron and interneuron->motor synapses and the plastic input->motor synapses with
pair-based STDP traces (event-driven, all-to-all or nearest pairing). The input is a
``SpikeGeneratorGroup`` fed with the project's recorded input spike trains, window by window.

The schedule of one Brian2 time step is set to the order of the project's reference
(:mod:`snan_hil.host.snan_reference`): decay of every potential and of the glutamate
(``groups``), the interneurons' bias, then the input spike of this step and its synapses
(``thresholds``/``synapses``), then (``after_synapses``) the calcium step from the new
glutamate, the interneurons' threshold with this step's calcium and their reset, their
inhibition of the motor neurons, the motor neurons' threshold and reset, and the STDP update
of the post spikes. A refractory neuron (``neuron.refractory = clamp``) ignores its input: the
synapses add only while ``not_refractory``; Brian2 counts refractoriness from the spike step
on, so its period is ``t_ref + dt`` for the reference's ``t_ref`` steps after the spike step.

What stays with the host (it is not the network): the decision at the end of a window (most
spikes, ties broken by the project's window stream), the factor ``k`` and the target rule of the
window's STDP change, and the weights' bounds (:func:`snan_hil.host.snan_reference.choose`,
:func:`~snan_hil.host.snan_reference.window_changes`,
:class:`snan_hil.host.agent.SoftwareSynapses`). :func:`compare_trial` runs one trial in the
project's kernel (recording its input trains through the synapse back-end seam) and in Brian2
and lists every window whose spike counts or decision differ.

Brian2 runs with its ``numpy`` code generation target (no compiler needed); it is slow (about
0.2 s per decision window on 3x3) and meant for small grids.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from snan_hil.common.errors import UserError
from snan_hil.host.agent import SoftwareSynapses, run_trial, synapse_tables
from snan_hil.host.config import SnanConfig
from snan_hil.host.grid import GridWorld
from snan_hil.host.rng import WindowStream, trial_keys
from snan_hil.host.snan_reference import choose, window_changes
from snan_hil.host.state import initial_weights


def _brian2() -> Any:
    try:
        import brian2  # type: ignore[import-untyped]
    except ImportError:
        raise UserError("the Brian2 cross-check needs brian2: pip install 'snan-hil[test]'"
                        ) from None
    return brian2


class RecordingSynapses(SoftwareSynapses):
    """Software synapses that keep every window's input spike train (the recorded input of the
    cross-check) and the cell it belonged to."""

    def __init__(self, *args: Any, **kw: Any) -> None:
        super().__init__(*args, **kw)
        self.trains: list[np.ndarray] = []
        self.cells: list[int] = []

    def drive(self, pre: int, dirs: Sequence[int], spikes: np.ndarray) -> np.ndarray:
        self.trains.append(np.array(spikes, dtype=bool))
        self.cells.append(int(pre))
        return super().drive(pre, dirs, spikes)


@dataclass
class TrialRecord:
    """One trial: path, per-window spike counts of the candidates (in direction order),
    interneuron spikes per window and cell (Brian2 only), wall time of the simulation."""

    path: list[int]
    counts: list[list[int]]
    success: bool
    wall_s: float
    cpu_s: float = 0.0
    inter_spikes: list[list[int]] = field(default_factory=list)
    trains: list[np.ndarray] = field(default_factory=list)


def kernel_trial(cfg: SnanConfig, start: int, goal: int, seed: int, trial: int) -> TrialRecord:
    """The project's trial kernel on one trial, through the synapse back-end seam so that its
    input spike trains are recorded (same trial as ``run_trial(..., seed, trial)``)."""
    env = GridWorld(cfg.grid.rows, cfg.grid.cols)
    nbr, _move = synapse_tables(env, cfg)
    _key, _ts, w_seed = trial_keys(seed, trial)
    w0 = initial_weights(cfg, nbr, np.random.default_rng(w_seed))
    rec = RecordingSynapses(w0, cfg.stdp.w_min, cfg.stdp.w_max,
                            normalize=cfg.stdp.target == "normalize")
    t0 = time.perf_counter()
    res = run_trial(env, cfg, start, goal, seed=seed, trial=trial, backend=rec, record=True)
    wall = time.perf_counter() - t0
    counts = [[int(c) for c in w.counts] for w in res.windows]
    return TrialRecord([int(c) for c in res.path], counts, bool(res.success), wall,
                       trains=rec.trains)


class Brian2Network:
    """The SNAN of one grid in Brian2 (module doc). ``run_window(cell, train, weights)`` runs
    one decision window with the agent on ``cell``; weights are the host's
    (``float[n_cells, 4]``, set before every window)."""

    def __init__(self, cfg: SnanConfig, nbr: np.ndarray) -> None:
        b2 = _brian2()
        b2.prefs.codegen.target = "numpy"
        b2.prefs.core.default_float_dtype = np.float64
        self.b2 = b2
        self.cfg = cfg
        n = cfg.n_cells
        nc, a, st, syn = cfg.neuron, cfg.astro, cfg.stdp, cfg.synapse
        ms = b2.ms
        self.dt = cfg.input.dt_ms * ms
        self.steps = cfg.window_steps
        self.t_window = self.steps * self.dt
        clamp = nc.refractory == "clamp"
        unless = " (unless refractory)" if clamp else ""
        guard = "*int(not_refractory_post)" if clamp else ""
        ref = (cfg.ref_steps + 1) * self.dt            # Brian2 counts from the spike step
        ns = {"v_rest": nc.v_rest, "v_reset": nc.v_reset, "tau_m": nc.tau_m_ms * ms,
              "v_thr_motor": nc.v_thr_motor, "v_thr_inter": nc.v_thr_inter,
              "r_m": nc.r_m, "i_bias": nc.i_bias, "eta": a.eta if a.enabled else 0.0,
              "ca_thr": a.ca_thr, "g_thr": a.g_thr, "a_ca": a.a, "tau_ca": a.tau_ca_ms,
              "alpha_n": a.alpha_n_per_ms / ms, "kn_dt": a.k_n * cfg.input.dt_ms,
              "a_plus": st.a_plus, "a_minus": st.a_minus, "tau_plus": st.tau_plus_ms * ms,
              "tau_minus": st.tau_minus_ms * ms, "w_in_inter": syn.w_in_inter,
              "w_inh": syn.w_inh}
        objs: list[Any] = []
        self.inp = b2.SpikeGeneratorGroup(n, [], [] * ms, dt=self.dt, name="input")
        objs.append(self.inp)
        self.motor = b2.NeuronGroup(
            n, f"dv/dt = -(v - v_rest)/tau_m : 1{unless}\ncount : 1",
            threshold="v > v_thr_motor", reset="v = v_reset\ncount += 1", refractory=ref,
            method="exact", namespace=ns, dt=self.dt, name="motor")
        self.motor.v = nc.v_rest
        inter_eq = f"dv/dt = -(v - v_rest)/tau_m : 1{unless}\ncount : 1"
        if a.enabled:
            inter_eq += "\nca_i : 1 (linked)"
            thr = "v > v_thr_inter/(1 + eta*int(ca_i > ca_thr))"
        else:
            thr = "v > v_thr_inter"
        self.inter = b2.NeuronGroup(n, inter_eq, threshold=thr, reset="v = v_reset\ncount += 1",
                                    refractory=ref, method="exact", namespace=ns,
                                    dt=self.dt, name="inter")
        self.inter.v = nc.v_rest
        bias = self.inter.run_regularly(
            "v += r_m*i_bias" + ("*int(not_refractory)" if clamp else ""), when="groups",
            order=10, name="inter_bias")
        objs += [self.motor, self.inter, bias]
        if a.enabled:
            self.glu = b2.NeuronGroup(n, "dG/dt = -alpha_n*G : 1", method="euler", namespace=ns,
                                      dt=self.dt, name="glutamate")
            self.astro = b2.NeuronGroup(
                n, "dca/dt = y/ms : 1\n"
                   "dy/dt = (J - 2*tau_ca*y - ca)/(tau_ca**2)/ms : 1\n"
                   "J = a_ca*int(G_a > g_thr) : 1\nG_a : 1 (linked)",
                method="euler", namespace=ns, dt=self.dt, name="astrocyte")
            self.astro.G_a = b2.linked_var(self.glu, "G")
            self.astro.state_updater.when = "after_synapses"
            self.astro.state_updater.order = 0
            self.inter.ca_i = b2.linked_var(self.astro, "ca")
            s_glu = b2.Synapses(self.inp, self.glu, on_pre="G_post += kn_dt", namespace=ns,
                                dt=self.dt, name="input_glutamate")
            s_glu.connect(j="i")
            objs += [self.glu, self.astro, s_glu]
        for obj, order in ((self.inter.thresholder["spike"], 1),
                           (self.inter.resetter["spike"], 2),
                           (self.motor.thresholder["spike"], 4),
                           (self.motor.resetter["spike"], 5)):
            obj.when = "after_synapses"
            obj.order = order
        s_ii = b2.Synapses(self.inp, self.inter, on_pre=f"v_post += r_m*w_in_inter{guard}",
                           namespace=ns, dt=self.dt, name="input_inter")
        s_ii.connect(j="i")
        s_im_inh = b2.Synapses(self.inter, self.motor, on_pre=f"v_post -= r_m*w_inh{guard}",
                               namespace=ns, dt=self.dt, name="inter_motor")
        s_im_inh.connect(j="i")
        s_im_inh.pre.when = "after_synapses"
        s_im_inh.pre.order = 3
        nearest = st.pairing == "nearest"
        self.plastic = b2.Synapses(
            self.inp, self.motor,
            model="w : 1\ndw : 1\n"
                  "dapre/dt = -apre/tau_plus : 1 (event-driven)\n"
                  "dapost/dt = -apost/tau_minus : 1 (event-driven)",
            on_pre={"pre": f"v_post += r_m*w{guard}\n"
                           + ("apre = 1" if nearest else "apre += 1")
                           + "\ndw += -a_minus*apost"},
            on_post={"post": "dw += a_plus*apre\n"
                             + ("apost = 1" if nearest else "apost += 1")},
            namespace=ns, dt=self.dt, name="input_motor")
        pre: list[int] = []
        post: list[int] = []
        self.index: dict[tuple[int, int], int] = {}
        for i in range(n):
            for d in range(4):
                if nbr[i, d] >= 0:
                    self.index[(i, d)] = len(pre)
                    pre.append(i)
                    post.append(int(nbr[i, d]))
        self.plastic.connect(i=np.array(pre), j=np.array(post))
        self.plastic.post.when = "after_synapses"
        self.plastic.post.order = 6
        objs += [s_ii, s_im_inh, self.plastic]
        self.net = b2.Network(*objs)
        self.windows = 0

    def run_window(self, cell: int, dirs: Sequence[int], train: np.ndarray,
                   weights: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[int]]:
        """One window: (spike counts of the candidates in ``dirs`` order, their accumulated
        STDP change, interneuron spikes per cell)."""
        b2 = self.b2
        t0 = self.windows * self.t_window
        if self.cfg.neuron.reset_each_window:
            for g in (self.motor, self.inter):
                g.v = self.cfg.neuron.v_rest
                g.lastspike = -1e9 * b2.second
                g.not_refractory = True
        idx = [self.index[(cell, d)] for d in dirs]
        w = np.array(self.plastic.w[:])
        for (i, d), k in self.index.items():
            w[k] = weights[i, d]
        self.plastic.w[:] = w
        self.plastic.dw[:] = 0.0
        self.plastic.apre[:] = 0.0
        self.plastic.apost[:] = 0.0
        self.motor.count = 0
        self.inter.count = 0
        steps = np.nonzero(train)[0]
        self.inp.set_spikes(np.full(steps.size, cell, dtype=int), t0 + steps * self.dt)
        self.net.run(self.t_window, namespace={})
        self.windows += 1
        post = [int(self.plastic.j[k]) for k in idx]
        counts = np.array([int(round(self.motor.count[p])) for p in post], dtype=np.int64)
        dw = np.array([float(self.plastic.dw[k]) for k in idx])
        return counts, dw, [int(round(float(c))) for c in self.inter.count[:]]


def brian2_trial(cfg: SnanConfig, start: int, goal: int, seed: int, trial: int,
                 trains: Sequence[np.ndarray] | None = None) -> TrialRecord:
    """The same trial in Brian2, driven with ``trains`` (the kernel's recorded input spike
    trains, window by window; the window stream's where the Brian2 trial runs longer) and the
    window stream's tie-break draws; decisions, ``k``, the target rule and the weight bounds
    as the project's reference does them."""
    env = GridWorld(cfg.grid.rows, cfg.grid.cols)
    nbr, move = synapse_tables(env, cfg)
    key, _ts, w_seed = trial_keys(seed, trial)
    syn = SoftwareSynapses(initial_weights(cfg, nbr, np.random.default_rng(w_seed)),
                           cfg.stdp.w_min, cfg.stdp.w_max,
                           normalize=cfg.stdp.target == "normalize")
    net = Brian2Network(cfg, nbr)
    stream = WindowStream(key)
    pos, path, counts_all, inter = int(start), [int(start)], [], []
    deferred = []
    success = False
    t0 = time.perf_counter()
    c0 = time.process_time()
    for step in range(cfg.grid.max_steps):
        dirs = [d for d in range(4) if nbr[pos, d] >= 0]
        drawn = stream.spikes(cfg.window_steps, cfg.input.p)
        train = trains[step] if trains is not None and step < len(trains) else drawn
        counts, dw, n_int = net.run_window(pos, dirs, train, syn.w)
        counts_all.append([int(c) for c in counts])
        inter.append(n_int)
        chosen = choose(counts, cfg, stream.choice)
        if cfg.stdp.mode != "off" and dirs:
            scaled = window_changes(dw, chosen, cfg)
            if cfg.stdp.mode == "window":
                syn.apply_update(pos, dirs, scaled)
            else:
                deferred.append((pos, dirs, scaled))
        if chosen >= 0 and move[pos, dirs[chosen]] >= 0:
            pos = int(move[pos, dirs[chosen]])
        path.append(pos)
        if pos == goal:
            success = True
            break
    return TrialRecord(path, counts_all, success, time.perf_counter() - t0,
                       time.process_time() - c0, inter)


@dataclass
class Comparison:
    """Kernel vs Brian2 on one trial: windows compared, windows whose counts differ, the first
    window whose decision differs (None: the same path), both records."""

    windows: int
    count_mismatches: list[int]
    first_divergence: int | None
    kernel: TrialRecord
    brian2: TrialRecord
    #: interneuron spikes per window and cell in the project's per-step reference, when run
    reference_inter: list[list[int]] = field(default_factory=list)

    @property
    def agree(self) -> bool:
        inter_ok = not self.reference_inter or self.reference_inter == self.brian2.inter_spikes
        return not self.count_mismatches and self.first_divergence is None and inter_ok


def compare_trial(cfg: SnanConfig, start: int, goal: int, seed: int = 1, trial: int = 0,
                  interneurons: bool = False) -> Comparison:
    """Run one trial in the kernel and in Brian2 (driven with the kernel's recorded input)
    and compare spike counts window by window and the decisions (the paths). With
    ``interneurons`` also the interneuron spikes per window (all cells: the astrocyte
    threshold switch at work) against the per-step reference (the kernel does not simulate
    interneurons nobody looks at)."""
    k = kernel_trial(cfg, start, goal, seed, trial)
    b = brian2_trial(cfg, start, goal, seed, trial, trains=k.trains)
    n = min(len(k.counts), len(b.counts))
    mism = [i for i in range(n) if k.counts[i] != b.counts[i]]
    div = None
    for i in range(1, min(len(k.path), len(b.path))):
        if k.path[i] != b.path[i]:
            div = i - 1
            break
    if div is None and len(k.path) != len(b.path):
        div = min(len(k.path), len(b.path)) - 1
    ref_inter: list[list[int]] = []
    if interneurons:
        env = GridWorld(cfg.grid.rows, cfg.grid.cols)
        ref = run_trial(env, cfg, start, goal, seed=seed, trial=trial, engine="reference",
                        record=True)
        ref_inter = [[sum(1 for _t, i in w.inter_spikes if i == c) for c in range(cfg.n_cells)]
                     for w in ref.windows]
    return Comparison(n, mism, div, k, b, ref_inter)
