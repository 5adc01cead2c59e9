"""The on-board mode: the candidates' motor neurons run on the board, one DECISION_WINDOW
round trip per decision (issue 23; the paper: "synapses and motor neurons were implemented
on the MemriCore board").

:class:`OnBoardMotorNeurons` implements the agent's ``MotorBackend`` (host/agent.py). Per
decision window of input neuron ``pre`` the host draws the input spikes (its window stream),
runs the interneurons and astrocytes and sends the board, in one DECISION_WINDOW request: the
stream state (the board draws the same spikes), ``pre``'s rows and its candidates' cells,
and each candidate's interneuron spike steps. The board reads the synapses per input spike
(the same conversions as the ``batch`` mode's SPIKE_BATCH), integrates the motor neurons in
fixed point and answers the spike counts (and, when STDP is on, the motor spike steps). The
host checks the board drew as many input spikes as it did, then decides and moves.

:func:`window_params` turns the model (:class:`~snan_hil.host.kernel_params.KernelParams`)
and the layout's calibrated read chain and weight map into the board's parameter block
(:class:`~snan_hil.protocol.messages.DecisionParams`, formats in
:mod:`snan_hil.firmware_emu.lif_fixed` and docs/protocol.md).
"""

from __future__ import annotations

import math
import time
from fractions import Fraction
from collections.abc import Sequence
from typing import Any

import numpy as np

from snan_hil.calibration.layout import Layout
from snan_hil.calibration.readchain import ReadChain
from snan_hil.calibration.mapping import WeightMap
from snan_hil.common.errors import UserError
from snan_hil.host.agent import BoardWindow, MotorBackend
from snan_hil.host.config import SnanConfig
from snan_hil.host.hil.backend import FixedWeightsError, ReadStats, programmed_weights
from snan_hil.host.hil.ceiling import lean_window_counts
from snan_hil.host.kernel_params import kernel_params
from snan_hil.host.snan_kernel import KernelParams
from snan_hil.protocol.board import WINDOW_CONVERSIONS
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.errors import ProtocolError
from snan_hil.protocol.frames import wire_size
from snan_hil.protocol.messages import (DW_ALPHA_TABLE, DW_FIELD_LIMIT, DW_FIXED_ONE,
                                        Capability, DecisionCandidate, DecisionWindow,
                                        DecisionLifFlag, DecisionParams,
                                        decision_conversion_fits)

ONE = DW_FIXED_ONE


def _q32(value: float, what: str) -> int:
    """round(value * 2^32); UserError if it exceeds the board's field limit."""
    q = int(round(float(value) * ONE))
    if abs(q) > DW_FIELD_LIMIT:
        raise UserError(f"{what} = {value:g} is too large for the board's fixed point "
                        f"(|value| <= 2^24); the on-board mode cannot run this model")
    return q


def conversion_fields(chain: ReadChain, weight_map: WeightMap, r_m: float,
                      row_code: int) -> dict[str, Any]:
    """The code -> drive fields of the parameter block: ``drive = R w(code)`` with the
    layout's column chain at ``row_code`` (``x = code - offset``, ``G = (1/R_sw) x / (D - x)``,
    ``D = scale / R_sw``; ``w = (G - G_min) / span``), so ``k1 = R / (R_sw span)``,
    ``k0 = R G_min / span``. The shifts give the division as many bits as 32-bit operands
    allow: ``den_shift = 32 - s`` with the largest ``s`` such that ``D 2^s < 2^32``; ``q_shift``
    the headroom of ``y = x / (D - x)`` below 1 at the ADC's full scale."""
    scale = float(chain.column_scale(row_code))
    rsw = float(chain.r_switch_ohm)
    if rsw <= 0 or scale <= 0:
        raise UserError("the on-board mode needs a read chain with R_sw > 0 and a positive "
                        "column scale")
    d_codes = scale / rsw
    s = min(16, int(math.floor(math.log2((2.0 ** 32 - 1) / d_codes))))
    offset = max(0.0, float(chain.offset_column_code))
    x_max = chain.adc_full_scale_code - offset
    y_max = x_max / (d_codes - x_max) if d_codes > x_max else float("inf")
    e = max(0, min(31, int(math.floor(-math.log2(y_max))) if y_max > 0 else 31))
    fields: dict[str, Any] = {
        "offset": int(round(offset * ONE)), "d": int(round(d_codes * ONE)),
        "den_shift": 32 - s,
        "k1": _q32(r_m / (rsw * weight_map.span_s), "R / (R_sw span)"),
        "k0": _q32(r_m * weight_map.g_min_s / weight_map.span_s, "R G_min / span")}
    adc_full = int(chain.adc_full_scale_code)
    while e >= 0:
        fields.update(q_shift=e, num_shift=min(17, s + e))
        probe = DecisionParams(**fields)
        if decision_conversion_fits(probe, adc_full):
            return fields
        e -= 1
    raise UserError("the board's read chain does not fit the on-board fixed point "
                    f"(D = {d_codes:.4g} codes); use --mode batch")


def window_params(kp: KernelParams, chain: ReadChain, weight_map: WeightMap,
                  row_code: int, conversions: int = 0) -> DecisionParams:
    """The parameter block for model ``kp`` on a layout with ``chain`` / ``weight_map``,
    rows driven at ``row_code``, read with ``conversions`` ADC conversions a read (0: the
    board's standard reads; > 0 the lean read plan, READ_PLAN boards only). UserError where
    the model does not fit the board's fixed point (a threshold not above the reset, values
    beyond 2^24)."""
    if kp.v_thr_motor <= kp.v_reset or kp.v_thr_motor <= kp.v_rest:
        raise UserError("the on-board mode needs the motor threshold above the reset and the "
                        "resting potential")
    # alpha^k of the host's float alpha, exactly, rounded to Q0.64
    exact = Fraction(float(kp.alpha))
    alpha_pow = tuple(min(round(exact ** k * (1 << 64)), (1 << 64) - 1)
                      for k in range(1, DW_ALPHA_TABLE + 1))
    return DecisionParams(
        n_bins=int(kp.steps), bin_us=int(round(kp.dt_ms * 1000)), row_code=int(row_code),
        ref_steps=int(kp.ref_steps),
        lif_flags=int(DecisionLifFlag.INTEGRATE if kp.integrate else DecisionLifFlag.NONE),
        spike_threshold=int(kp.spike_threshold), alpha_pow=alpha_pow,
        thr=_q32(kp.v_thr_motor - kp.v_rest, "v_thr - v_rest"),
        reset=_q32(kp.v_reset - kp.v_rest, "v_reset - v_rest"),
        inh=_q32(kp.r_m * kp.w_inh, "R w_inh"), conversions=int(conversions),
        **conversion_fields(chain, weight_map, kp.r_m, row_code))


def read_plan(client: BoardClient, conversions: int | None = None) -> int:
    """ADC conversions a read for the decision windows on ``client``'s board: ``conversions``
    (None: :data:`WINDOW_CONVERSIONS` where the board has the READ_PLAN capability, else 0,
    its standard reads). UserError for a lean plan the board cannot run or outside 0 ..
    its ``adc_averages``."""
    info = getattr(client, "info", None)
    has = bool(info is not None and info.has(Capability.READ_PLAN))
    if conversions is None:
        return WINDOW_CONVERSIONS if has else 0
    n = int(conversions)
    limit = info.adc_averages if info is not None else WINDOW_CONVERSIONS
    if n and not has:
        raise UserError(f"the board on {getattr(client, 'name', '?')} has no READ_PLAN "
                        "(older firmware): it reads every window with its standard ten "
                        "averages; leave the conversions unset")
    if not 0 <= n <= limit:
        raise UserError(f"conversions a read must be 0 (the board's standard reads) or "
                        f"1..{limit}, got {n}")
    return n


class OnBoardMotorNeurons(MotorBackend):
    """The input->motor synapses and the motor neurons on the board behind ``client`` (see
    module doc). ``nbr``: the agent's neighbour table (int [n_cells, 4], -1 = none); ``cfg``:
    the launch config (its model becomes the board's parameter block). ``conversions``: ADC
    conversions a read (None: :data:`~snan_hil.protocol.board.WINDOW_CONVERSIONS` on a board
    with the READ_PLAN capability, else 0 = the board's standard ten-average reads). Weights
    are fixed (:meth:`apply_update` refuses: no write pulse while the agent runs)."""

    mode = "on_board"

    def __init__(self, client: BoardClient, layout: Layout, nbr: np.ndarray, cfg: SnanConfig,
                 *, row_code: int | None = None, conversions: int | None = None) -> None:
        if not cfg.neuron.reset_each_window:
            raise UserError("--mode on-board needs neuron.reset_each_window=true (the board "
                            "starts every window's motor neurons at rest); use --mode batch")
        self.client = client
        self.layout = layout
        self.nbr = np.asarray(nbr)
        self.code = int(layout.chain.read_code if row_code is None else row_code)
        self.conversions = read_plan(client, conversions)
        self.params = window_params(kernel_params(cfg), layout.chain, layout.weight_map,
                                    self.code, self.conversions)
        self.stats = ReadStats()
        self._programmed = programmed_weights(layout, self.nbr)
        #: per input neuron: its rows, and per motor neuron (post) its (row index, column)
        self._cells: dict[int, tuple[tuple[int, ...], dict[int, tuple[int, int]]]] = {}
        for g in layout.groups():
            rows = tuple(int(r["row"]) for r in g["rows"])
            where = {int(c["post"]): (ri, int(c["col"]))
                     for ri, r in enumerate(g["rows"]) for c in r["cells"]}
            self._cells[int(g["pre"])] = (rows, where)

    def motor_window(self, pre: int, dirs: Sequence[int], key: int, n_spikes: int,
                     inh: Sequence[np.ndarray], want_spikes: bool
                     ) -> tuple[np.ndarray, list[np.ndarray]]:
        """One DECISION_WINDOW (agent.MotorBackend): counts per candidate and, with
        ``want_spikes``, their motor spike steps."""
        return self.collect(self.submit(BoardWindow(pre, list(dirs), key, n_spikes,
                                                    list(inh), want_spikes)))

    def request(self, w: BoardWindow) -> DecisionWindow:
        """The DECISION_WINDOW of window ``w`` (host-side checks done)."""
        rows, where = self._cells[int(w.pre)]
        posts = [int(self.nbr[w.pre, d]) for d in w.dirs]
        cands = tuple(DecisionCandidate(where[post][1], where[post][0],
                                        tuple(int(t) for t in w.inh[k]))
                      for k, post in enumerate(posts))
        return self.client.window_request(w.key, rows, cands, self.params,
                                          motor_spikes=w.want_spikes)

    def pipelinable(self, req: DecisionWindow) -> bool:
        """Whether ``req`` may go on the line while another window runs (the client keeps two
        requests outstanding, the board holds the parameter block, the request fits the
        board's pipeline)."""
        return (self.client.pipelined and req.params is None
                and self.client.pipelinable(req))

    def submit(self, w: BoardWindow, req: DecisionWindow | None = None) -> Any:
        """Send window ``w`` (its request ``req`` if already built); a ticket for
        :meth:`collect`."""
        t0 = time.perf_counter()
        req = self.request(w) if req is None else req
        ticket = (w, req, self.client.submit(req))
        self.stats.wall_s += time.perf_counter() - t0
        return ticket

    def collect(self, ticket: Any) -> tuple[np.ndarray, list[np.ndarray]]:
        """The board's answer to a :meth:`submit` ticket: counts per candidate and, when the
        window wanted them, the motor spike steps per candidate."""
        t0 = time.perf_counter()
        w, req, inner = ticket
        reply = self.client.window_reply(req, self.params, self.client.collect(inner))
        if reply.n_input_spikes != w.n_spikes:
            raise ProtocolError(
                f"board on {getattr(self.client, 'name', '?')} drew {reply.n_input_spikes} input "
                f"spikes for this window, the host {w.n_spikes}: its spike stream differs "
                "(firmware and host disagree on DECISION_WINDOW)")
        st = self.stats
        st.decisions += 1
        st.spikes += int(w.n_spikes)
        st.requests += 1
        cands = req.candidates
        columns = {c.col for c in cands}
        st.codes_read += int(w.n_spikes) * (len({(c.row_index, c.col) for c in cands})
                                            if self.conversions else
                                            len(req.rows) * len(columns))
        st.codes_used += int(w.n_spikes) * len(cands)
        st.request_bytes += wire_size(len(req.encode()))
        st.reply_bytes += wire_size(len(reply.encode()))
        st.conversions = self.conversions
        if self.conversions:
            rows = req.rows
            waits, words = lean_window_counts([(rows[ri], col) for ri, col in req.reads()],
                                              int(w.n_spikes), req.paced)
            st.waits += waits
            st.row_words += words
        else:                           # per spike and row: up, every column read, down
            st.waits += int(w.n_spikes) * len(req.rows) * len(columns)
            st.row_words += 2 * int(w.n_spikes) * len(req.rows)
            info = getattr(self.client, "info", None)
            st.averages = int(info.adc_averages) if info is not None else 0
        counts = np.asarray(reply.counts, dtype=np.int64)
        spikes: list[np.ndarray] = [np.zeros(0, dtype=np.int64) for _ in cands]
        if w.want_spikes and reply.motor_spikes is not None:
            per: list[list[int]] = [[] for _ in cands]
            for t, lane in reply.motor_spikes:
                per[lane].append(t)
            spikes = [np.asarray(x, dtype=np.int64) for x in per]
        st.wall_s += time.perf_counter() - t0
        return counts, spikes

    def apply_update(self, pre: int, dirs: Sequence[int], dw: np.ndarray) -> None:
        raise FixedWeightsError("the crossbar weights are fixed during launches; run with "
                                "stdp.mode=off (no write pulses while the agent runs)")

    def weights(self) -> np.ndarray:
        """The programmed weights (layout), float[n_cells, 4]."""
        return self._programmed.copy()
