"""Fit the Python MCU's time of DECISION_WINDOW to the C firmware's (a tool, not a target).

Usage: ``python bench/fit_window_costs.py [--windows N] [--seed S]`` (needs ``make firmware``).

The Python MCU does not execute the firmware: it advances its clock by the firmware's own cost
of each step, fitted here to the instruction-level MCU (one instruction a cycle at 32 MHz) on
random windows of the 6x6 HIL model on a default chip, both MCUs side by side:

* the lean read plan (:class:`~snan_hil.firmware_emu.window_reads.LeanCosts`): every interval
  between two SPI frames of the firmware's trace without a wait in it is the sum of the model's
  MCU steps in that interval (their ledger) plus the frame's bits; least squares over all of
  them;
* ``search_call`` (the search for the next spike called outright, never between two frames):
  from lean windows without candidates, their time per call;
* the standard plan (``decision_window.MCU_US_PER_*``): the firmware's window time minus the
  model's with those constants at 0, against (steps, candidates x input spikes, interneuron
  spikes, column reads).

It prints both fits, their residuals and the literals to paste; ``tests/firmware/
test_decision_window.py`` checks that the two MCUs' window times then agree.
"""

from __future__ import annotations

import argparse
import dataclasses
import random
import sys

import numpy as np


def _windows(n: int, seed: int, lean: bool):
    from snan_hil.calibration.mapping import WeightMap
    from snan_hil.host.hil.board_window import window_params
    from snan_hil.host.hil.config import load_hil_config
    from snan_hil.host.kernel_params import kernel_params
    from snan_hil.protocol import messages as m
    from snan_hil.tools.window_agreement import calibrated_chain
    chain = calibrated_chain()
    base = window_params(kernel_params(load_hil_config().launch_config(True)), chain,
                         WeightMap(), chain.read_code)
    rng = random.Random(seed)
    for _ in range(n):
        p = dataclasses.replace(base, n_bins=rng.choice([300, 1000]),
                                spike_threshold=int(rng.choice([0.15, 0.3]) * (1 << 53)),
                                conversions=rng.choice([1, 2, 2, 3, 4]) if lean else 0)
        rows = tuple(rng.sample(range(32), rng.choice([1, 1, 2])))
        cands = tuple(m.DecisionCandidate(c, rng.randrange(len(rows)), tuple(sorted(
            rng.sample(range(p.n_bins), rng.choice([0, 5, 20, 60])))))
            for c in rng.sample(range(8), rng.randint(1, 4)))
        yield m.DecisionWindow(rng.getrandbits(64), rows, cands, p, False,
                               rng.choice([0, 0, 97]), False)


def _boards():
    from snan_hil.firmware_emu.emulator import Emulator
    from snan_hil.firmware_emu.testing import default_array
    from snan_hil.protocol import messages as m
    from snan_hil.protocol.frames import Frame, encode_frame
    boards = {mcu: Emulator(None, 3, array=default_array(3), mcu=mcu, boot_nonces=(0x5EED1234,))
              for mcu in ("model", "firmware")}
    for emu in boards.values():
        emu.feed(encode_frame(Frame(m.Hello.TYPE, 1, m.Hello().encode(), 0)))
    return boards


def _send(emu, req, seq):
    from snan_hil.protocol.frames import Frame, encode_frame
    emu.board.bus.start_trace()
    t0 = emu.clock.now_us
    emu.feed(encode_frame(Frame(req.TYPE, seq, req.encode(), 0x5EED1234)))
    return emu.clock.now_us - t0, emu.board.bus.stop_trace()


def fit_lean(n: int, seed: int) -> None:
    from snan_hil.firmware_emu import decision_window as dw, window_reads as wr
    ledgers: list = []
    real = wr.run_lean

    def recording(fw, req, p, bins, costs=wr.COSTS, ledger=None):
        led: list = []
        ledgers.append(led)
        return real(fw, req, p, bins, costs, led)

    dw.run_lean = recording
    boards = _boards()
    names = [f.name for f in dataclasses.fields(wr.LeanCosts)]
    rows, ys = [], []
    bits = boards["model"].clock.spi_bits_us
    try:
        for seq, req in enumerate(_windows(n, seed, True), 2):
            ledgers.clear()
            _send(boards["model"], req, seq)
            _, trace = _send(boards["firmware"], req, seq)
            led = ledgers[0]
            assert len(led) == len(trace), (len(led), len(trace))
            for i in range(1, len(trace)):
                if any(name == "wait" for name, _ in led[i]):
                    continue
                x = np.zeros(len(names))
                for name, count in led[i]:
                    x[names.index(name)] += count
                rows.append(x)
                ys.append(trace[i].t_us - trace[i - 1].t_us - bits(len(trace[i - 1].mosi)))
    finally:
        dw.run_lean = real
    x, y = np.array(rows), np.array(ys)
    # search_call is fitted by fit_search (the few intervals here that hold one cannot tell it
    # from the steps beside it): taken as it is
    k = names.index("search_call")
    y = y - x[:, k] * wr.COSTS.search_call
    x[:, k] = 0.0
    used = x.any(axis=0)
    sol, *_ = np.linalg.lstsq(x[:, used], y, rcond=None)
    res = y - x[:, used] @ sol
    fit = dict(zip([k for k, u in zip(names, used) if u], sol))
    print(f"lean plan: {len(y)} intervals between frames, residual rms "
          f"{np.sqrt(np.mean(res ** 2)):.3f} us, max {np.abs(res).max():.2f} us")
    print("  LeanCosts(" + ", ".join(f"{k}={fit.get(k, getattr(wr.COSTS, k)):.3f}"
                                     for k in names) + ")")


def fit_search(n: int, seed: int) -> None:
    """``LeanCosts.search_call`` (never between two frames) and ``MCU_US_PER_PARAMS``: lean
    windows without candidates (nothing read: per spike the motor neurons' bookkeeping and the
    search called outright), each with and without its parameter block; the firmware's window
    time minus the model's with both at 0, against (the block, the calls)."""
    from snan_hil.firmware_emu import decision_window as dw
    from snan_hil.firmware_emu import lif_fixed as fx
    from snan_hil.firmware_emu import window_reads as wr
    real, saved = dw.run_lean, dw.MCU_US_PER_PARAMS
    costs = dataclasses.replace(wr.COSTS, search_call=0.0)
    dw.run_lean = lambda fw, req, p, bins: real(fw, req, p, bins, costs)
    dw.MCU_US_PER_PARAMS = 0.0
    boards = _boards()
    x, y = [], []
    try:
        seq = 2
        for req in _windows(n, seed, True):
            p = req.params
            calls = fx.spike_steps(req.key, p.n_bins, p.spike_threshold).size + 1
            for block in (p, None):
                r = dataclasses.replace(req, candidates=(), params=block)
                t_model, _ = _send(boards["model"], r, seq)
                t_fw, _ = _send(boards["firmware"], r, seq + 1)
                seq += 2
                x.append([block is not None, calls])
                y.append(t_fw - t_model)
    finally:
        dw.run_lean, dw.MCU_US_PER_PARAMS = real, saved
    a, b = np.array(x, dtype=float), np.array(y)
    sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    res = b - a @ sol
    print(f"windows without reads: {len(b)}, residual rms {np.sqrt(np.mean(res ** 2)):.2f} us")
    print(f"  search_call={sol[1]:.3f}; MCU_US_PER_PARAMS = {sol[0]:.1f}")


def fit_standard(n: int, seed: int) -> None:
    from snan_hil.firmware_emu import decision_window as dw
    boards = _boards()
    saved = (dw.MCU_US_PER_STEP, dw.MCU_US_PER_LANE_SPIKE, dw.MCU_US_PER_INHIBITION,
             dw.MCU_US_PER_READ, dw.MCU_US_PER_ROW_SPIKE)
    dw.MCU_US_PER_STEP = dw.MCU_US_PER_LANE_SPIKE = dw.MCU_US_PER_INHIBITION = 0.0
    dw.MCU_US_PER_READ = dw.MCU_US_PER_ROW_SPIKE = 0.0
    from snan_hil.firmware_emu import lif_fixed as fx
    x, y = [], []
    try:
        for seq, req in enumerate(_windows(n, seed, False), 2):
            t_model, _ = _send(boards["model"], req, seq)
            t_fw, _ = _send(boards["firmware"], req, seq)
            p = req.params
            spikes = fx.spike_steps(req.key, p.n_bins, p.spike_threshold).size
            x.append([p.n_bins, len(req.candidates) * spikes,
                      sum(len(c.inh) for c in req.candidates),
                      spikes * len(req.rows) * len(req.union_columns()),
                      spikes * len(req.rows)])
            y.append(t_fw - t_model)
    finally:
        (dw.MCU_US_PER_STEP, dw.MCU_US_PER_LANE_SPIKE, dw.MCU_US_PER_INHIBITION,
         dw.MCU_US_PER_READ, dw.MCU_US_PER_ROW_SPIKE) = saved
    a, b = np.array(x, dtype=float), np.array(y)
    sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    res = b - a @ sol
    print(f"standard plan: {len(b)} windows, residual rms {np.sqrt(np.mean(res ** 2)):.1f} us")
    print(f"  MCU_US_PER_STEP = {sol[0]:.3f}; MCU_US_PER_LANE_SPIKE = {sol[1]:.3f}; "
          f"MCU_US_PER_INHIBITION = {sol[2]:.3f}; MCU_US_PER_READ = {sol[3]:.3f}; "
          f"MCU_US_PER_ROW_SPIKE = {sol[4]:.3f}")


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--windows", type=int, default=60)
    ap.add_argument("--seed", type=int, default=11)
    args = ap.parse_args(argv)
    fit_lean(args.windows, args.seed)
    fit_search(args.windows, args.seed)
    fit_standard(max(args.windows, 60), args.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
