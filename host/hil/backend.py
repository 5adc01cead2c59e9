"""Crossbar synapse back-end: the motor neurons' synaptic input read from the memristor array.

:class:`CrossbarSynapses` implements the agent's ``SynapseBackend`` (host/agent.py). For a
decision window of input neuron ``pre`` with spike train ``S`` (1 ms bins):

* ``mode="batch"`` (default): ONE SPIKE_BATCH request (the link splits it only if the reply
  would exceed the board's payload) applies every spike of ``S`` to ``pre``'s programmed cells:
  per spike the row of those cells is driven at the read code (<= 0.3 V; a neuron whose cells
  span two rows is one spike group per row, each row driven alone, so a column read never sums
  another synapse) and the columns of its <= 4 synapses are read;
* ``mode="per_spike"`` (fidelity check): one READ_COLUMN per spike and synapse, the same row
  code, the same column path.

Every ADC code is turned back into a weight with the layout's calibrated read chain and weight
map (``Layout.weight_from_column_code``, not clipped), and put into the per-ms drive array at
the spike's bin: ``drive[t, k] = w_read(t, k)`` at input spikes, 0 elsewhere. So each read's
analog error (programming error, read noise, ADC quantisation) reaches the motor neurons, as on
the real board, and the agent's event-driven engine still applies (drive is zero between
spikes).

The weights are fixed during launches: :meth:`apply_update` refuses (launch configs run with
``stdp.mode=off``; no write pulse is ever sent from here).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Literal, Sequence

import numpy as np

from snan_hil.calibration.layout import Layout
from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.messages import SpikeGroup

Mode = Literal["batch", "per_spike"]
MODES: tuple[str, ...] = ("batch", "per_spike")


class FixedWeightsError(RuntimeError):
    """STDP tried to change crossbar weights during a launch (they are fixed)."""


@dataclass
class _Neuron:
    """How to read one input neuron: its rows (spike groups), the columns to read, and for each
    motor neuron (post) the (group index, column index) of its cell."""

    rows: tuple[int, ...]
    columns: tuple[int, ...]
    where: dict[int, tuple[int, int]]


@dataclass
class ReadStats:
    """Counters of a back-end (host side): decisions, input spikes, requests, ADC codes used,
    and per synapse the sum and sum of squares of the weights read (for fidelity checks)."""

    decisions: int = 0
    spikes: int = 0
    requests: int = 0
    codes_read: int = 0
    codes_used: int = 0
    wall_s: float = 0.0
    waits: int = 0
    """On-board window: reads that waited for settling (host/hil/ceiling.py; the standard
    plan: every read)."""
    row_words: int = 0
    """On-board window: row-DAC words written."""
    request_bytes: int = 0
    """On-board window: request frames on the wire (first transmissions), bytes."""
    reply_bytes: int = 0
    """On-board window: reply frames on the wire, bytes."""
    conversions: int = 0
    """On-board window: ADC conversions a read (0: the standard plan)."""
    averages: int = 0
    """On-board window, the standard plan: the board's averaged conversions a read (INFO)."""
    n: dict[tuple[int, int], int] = field(default_factory=dict)
    s1: dict[tuple[int, int], float] = field(default_factory=dict)
    s2: dict[tuple[int, int], float] = field(default_factory=dict)

    def add(self, pre: int, post: int, w: np.ndarray) -> None:
        key = (pre, post)
        self.n[key] = self.n.get(key, 0) + int(w.size)
        self.s1[key] = self.s1.get(key, 0.0) + float(w.sum())
        self.s2[key] = self.s2.get(key, 0.0) + float((w * w).sum())

    def synapse_stats(self) -> dict[tuple[int, int], tuple[int, float, float]]:
        """{(pre, post): (reads, mean weight, std of one read)}."""
        out = {}
        for key, n in self.n.items():
            mean = self.s1[key] / n
            var = max(self.s2[key] / n - mean * mean, 0.0) * n / max(n - 1, 1)
            out[key] = (n, mean, float(np.sqrt(var)))
        return out

    def to_dict(self) -> dict:
        out = {"decisions": self.decisions, "spikes": self.spikes, "requests": self.requests,
               "codes_read": self.codes_read, "codes_used": self.codes_used,
               "wall_s": self.wall_s}
        if self.request_bytes:
            out.update(waits=self.waits, row_words=self.row_words,
                       request_bytes=self.request_bytes, reply_bytes=self.reply_bytes,
                       conversions=self.conversions, averages=self.averages)
        return out


def programmed_weights(layout: Layout, nbr: np.ndarray) -> np.ndarray:
    """float[n_cells, 4]: the weights the layout's synapses were programmed with, by input
    neuron and direction (``nbr``: the agent's neighbour table); 0 where none is programmed."""
    out = np.zeros(nbr.shape)
    for s in layout.synapses:
        if s.pre >= nbr.shape[0] or s.weight is None:
            continue
        d = np.nonzero(nbr[s.pre] == s.post)[0]
        if d.size:
            out[s.pre, d[0]] = s.weight
    return out


class FixedLayoutSynapses:
    """What the crossbar back-ends share (``SynapseBackend``, host/agent.py): the drive array
    and its counters, the fixed weights; a subclass reads the cells in :meth:`_read_spikes`.
    ``code``: DAC code of the reads (None: the layout's calibrated read code)."""

    def __init__(self, client: BoardClient, layout: Layout, nbr: np.ndarray, mode: str,
                 code: int | None) -> None:
        self.client = client
        self.layout = layout
        self.nbr = np.asarray(nbr)
        self.mode = mode
        self.code = int(layout.chain.read_code if code is None else code)
        self.stats = ReadStats()
        self._programmed = programmed_weights(layout, self.nbr)

    def drive(self, pre: int, dirs: Sequence[int], spikes: np.ndarray) -> np.ndarray:
        """float[T, len(dirs)]: weight read at each input spike, 0 between spikes."""
        t0 = time.perf_counter()
        spikes = np.asarray(spikes, dtype=bool)
        posts = [int(self.nbr[pre, d]) for d in dirs]
        out = np.zeros((spikes.shape[0], len(posts)))
        bins = np.flatnonzero(spikes)
        self.stats.decisions += 1
        self.stats.spikes += int(bins.size)
        if bins.size and posts:
            self._read_spikes(int(pre), posts, bins, out)
        self.stats.wall_s += time.perf_counter() - t0
        return out

    def _read_spikes(self, pre: int, posts: list[int], bins: np.ndarray,
                     out: np.ndarray) -> None:
        """Fill ``out[bins, k]`` with the weight of synapse ``pre -> posts[k]`` read at each
        input spike (bins: indices of the spikes)."""
        raise NotImplementedError

    def apply_update(self, pre: int, dirs: Sequence[int], dw: np.ndarray) -> None:
        raise FixedWeightsError("the crossbar weights are fixed during launches; run with "
                                "stdp.mode=off (no write pulses while the agent runs)")

    def weights(self) -> np.ndarray:
        """The programmed weights (layout), float[n_cells, 4]."""
        return self._programmed.copy()


class CrossbarSynapses(FixedLayoutSynapses):
    """The input->motor synapses on the crossbar behind ``client`` (see module doc).

    ``nbr`` is the agent's neighbour table (int [n_cells, 4]: motor-neuron cell per direction,
    -1 = none), so ``drive(pre, dirs, spikes)`` knows which synapses ``dirs`` are.
    """

    def __init__(self, client: BoardClient, layout: Layout, nbr: np.ndarray, *,
                 mode: Mode = "batch", bin_us: int = 1000, row_code: int | None = None) -> None:
        if mode not in MODES:
            raise ValueError(f"unknown back-end mode {mode!r} (one of {', '.join(MODES)})")
        super().__init__(client, layout, nbr, mode, row_code)
        self.bin_us = int(bin_us)
        self.n_rows = int(layout.array[0])
        self._neurons: dict[int, _Neuron] = {}
        for g in layout.groups():
            rows = tuple(int(r["row"]) for r in g["rows"])
            cols = tuple(sorted({int(c["col"]) for r in g["rows"] for c in r["cells"]}))
            where = {int(c["post"]): (gi, cols.index(int(c["col"])))
                     for gi, r in enumerate(g["rows"]) for c in r["cells"]}
            self._neurons[int(g["pre"])] = _Neuron(rows, cols, where)

    # ---- reading ----------------------------------------------------------------------
    def _read_spikes(self, pre: int, posts: list[int], bins: np.ndarray,
                     out: np.ndarray) -> None:
        neuron = self._neurons[pre]
        if self.mode == "batch":
            self._drive_batch(pre, neuron, posts, bins, out.shape[0], out)
        else:
            self._drive_per_spike(pre, neuron, posts, bins, out)

    def _drive_batch(self, pre: int, neuron: _Neuron, posts: list[int], bins: np.ndarray,
                     steps: int, out: np.ndarray) -> None:
        b = tuple(bins.tolist())
        groups = [SpikeGroup(((row, self.code),), b) for row in neuron.rows]
        res = self.client.spike_batch(groups, neuron.columns, n_bins=steps, bin_us=self.bin_us)
        self.stats.requests += int(res.round_trips)
        codes = np.asarray(res.codes, dtype=float).reshape(len(res.spikes), len(neuron.columns))
        self.stats.codes_read += int(codes.size)
        spk = np.asarray(res.spikes, dtype=np.int64).reshape(-1, 2)
        for k, post in enumerate(posts):
            gi, ci = neuron.where[post]
            sel = spk[:, 1] == gi
            w = np.asarray(self.layout.weight_from_column_code(codes[sel, ci], self.code),
                           dtype=float)
            out[spk[sel, 0], k] = w
            self.stats.codes_used += int(w.size)
            self.stats.add(pre, post, w)

    def _drive_per_spike(self, pre: int, neuron: _Neuron, posts: list[int], bins: np.ndarray,
                         out: np.ndarray) -> None:
        cells = []
        for post in posts:
            gi, ci = neuron.where[post]
            row_codes = [0] * self.n_rows
            row_codes[neuron.rows[gi]] = self.code
            cells.append((neuron.columns[ci], row_codes))
        codes = np.empty((bins.size, len(posts)))
        for i in range(bins.size):            # spike by spike, as the spikes arrive
            for k, (col, row_codes) in enumerate(cells):
                codes[i, k] = self.client.read_column(col, row_codes)
        self.stats.requests += int(codes.size)
        self.stats.codes_read += int(codes.size)
        self.stats.codes_used += int(codes.size)
        for k, post in enumerate(posts):
            w = np.asarray(self.layout.weight_from_column_code(codes[:, k], self.code),
                           dtype=float)
            out[bins, k] = w
            self.stats.add(pre, post, w)
