"""Speed and energy per agent decision (the paper's Fig. 10D), from measurements.

The paper's method (section "Hardware implementation"):

* CPU (Intel Core i5-12450H): operations per decision = ``N * N * 2 * 1000`` for an N-cell
  field (1000 steps of 1 ms), time = ops / 40.3 GOPS, energy = time x 45 W (TDP), normalised
  speed = 1 / time / 217 mm^2 (chip area);
* memristor crossbar: time = 700 us per spike (one spike on 15 rows, 8 columns read) x 12
  spikes per step, energy = (0.1 V)^2 / 1.5 kOhm x time, normalised speed = 1 / time /
  0.368 mm^2 (area of the 32x8 1T1R array).

Next to those, the rows computed from what this project measured on the board (emulator) and
the ceiling its parts allow (``board ceiling, datasheets``: the run's read plan on the
datasheet figures, :mod:`snan_hil.host.hil.ceiling`); every crossbar row says how many input
spikes a decision it counts (the paper 12, this HIL the whole window's ~150) and its time per
spike (the paper's 700 us). The measured rows:
the board clock (CLOCK before/after) with the UART share removed (bytes x 10 / baud), and the
array energy the board reports; once for the paper's spike geometry (15 rows x 8 columns,
x 12 spikes) and once for this HIL run (only the rows and columns a spike needs, all the input
spikes of a 1 s window) — in the ``on_board`` mode (``hw["mode"]``) the board also runs the
motor neurons and one DECISION_WINDOW round trip carries the decision, in the others the host
does and a SPIKE_BATCH carries every read. Launches interleaved on the board (``hw
["interleaved"]``: the next request on the line while the board works) overlap the UART with
the board's work: their board time without the UART is not separable, only the row with it is
given. Every row states its method.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from snan_hil.protocol.client import BoardClient
from snan_hil.protocol.messages import SpikeGroup
from snan_hil.protocol.transport import wire_seconds


@dataclass(frozen=True)
class PaperConstants:
    """Constants of the paper's estimate (its section "Hardware implementation")."""

    cpu_gops: float = 40.3            #: Intel Core i5-12450H, operations per ns
    cpu_tdp_w: float = 45.0
    cpu_area_mm2: float = 217.0
    crossbar_area_mm2: float = 0.368  #: 32x8 1T1R array
    spike_us: float = 700.0           #: one spike on 15 rows, 8 columns read
    spikes_per_step: float = 12.0
    synapse_ohm: float = 1500.0       #: mean motor-synapse resistance
    spike_v: float = 0.1
    steps_per_decision: int = 1000    #: 1 s of 1 ms steps


PAPER = PaperConstants()


def _row(implementation: str, method: str, time_us: float, energy_j: float | None,
         area_mm2: float, source: str, spikes: float | None = None) -> dict[str, Any]:
    """One row; ``spikes``: the input spikes per decision the row counts (crossbar rows: the
    paper's 12, this HIL's whole window), so its time per spike is comparable."""
    return {"implementation": implementation, "method": method, "source": source,
            "time_per_decision_us": float(time_us),
            "energy_per_decision_j": None if energy_j is None else float(energy_j),
            "area_mm2": area_mm2,
            "norm_speed_per_us_mm2": 1.0 / time_us / area_mm2 if time_us > 0 else None,
            "spikes_per_decision": None if spikes is None else float(spikes),
            "time_per_spike_us": float(time_us) / spikes if spikes else None}


def cpu_paper_row(n_cells: int, c: PaperConstants = PAPER) -> dict[str, Any]:
    ops = n_cells * n_cells * 2 * c.steps_per_decision
    t_us = ops / (c.cpu_gops * 1e9) * 1e6
    return _row("CPU i5-12450H, paper",
                f"paper method: {n_cells}x{n_cells}x2x{c.steps_per_decision} = {ops:,} ops / "
                f"{c.cpu_gops} GOPS; x {c.cpu_tdp_w:g} W TDP; / {c.cpu_area_mm2:g} mm2",
                t_us, t_us * 1e-6 * c.cpu_tdp_w, c.cpu_area_mm2, "paper constants")


def crossbar_paper_row(c: PaperConstants = PAPER) -> dict[str, Any]:
    t_us = c.spike_us * c.spikes_per_step
    e = c.spike_v ** 2 / c.synapse_ohm * t_us * 1e-6
    return _row("crossbar, paper", f"paper numbers: {c.spike_us:g} us/spike x "
                f"{c.spikes_per_step:g} spikes; ({c.spike_v} V)^2 / {c.synapse_ohm:g} Ohm x time; "
                f"/ {c.crossbar_area_mm2} mm2", t_us, e, c.crossbar_area_mm2, "paper constants",
                c.spikes_per_step)


def crossbar_geometry_row(spike_us: float, spike_energy_j: float | None, read_v: float,
                          c: PaperConstants = PAPER) -> dict[str, Any]:
    """Paper's geometry (15 rows x 8 columns per spike, 12 spikes), measured spike time."""
    t_us = spike_us * c.spikes_per_step
    e = None if spike_energy_j is None else spike_energy_j * c.spikes_per_step
    return _row("emu board 15x8 x 12", f"measured: one spike on 15 rows x 8 columns "
                f"= {spike_us:.1f} us on board (no UART) x {c.spikes_per_step:g} spikes; array "
                f"energy measured at {read_v:.3f} V", t_us, e, c.crossbar_area_mm2,
                "measured (emulator)", c.spikes_per_step)


def crossbar_hil_rows(hw: dict[str, Any], c: PaperConstants = PAPER) -> list[dict[str, Any]]:
    """From the hardware launches: per decision board time without / with UART, energy; for a
    board without CLOCK (legacy protocol) the wire-limited time instead."""
    d = hw.get("decisions") or 0
    if d and hw.get("virtual_us") is None and hw.get("wire_us") is not None:
        return [crossbar_wire_row(hw, c)]
    if not d or hw.get("virtual_us") is None:
        return []
    spikes = hw["spikes"] / d
    on_board = hw.get("mode") == "on_board"
    plan = hw.get("plan")
    rows = []
    if plan and hw.get("baud"):
        rows.append(ceiling_row(hw, c))
    interleaved = bool(hw.get("interleaved"))
    if hw.get("wire_us") is not None and not interleaved:
        board = (hw["virtual_us"] - hw["wire_us"]) / d
        if on_board:
            reads = (f"{plan['conversions']} conversions a read, only the candidates' cells "
                     "(the lean read plan)" if plan and plan["conversions"] else
                     "a dummy and 10 conversions a read, 2-4 columns a spike")
            rows.append(_row("emu board, on-board window",
                             f"measured: board time per decision without UART ({spikes:.0f} "
                             f"input spikes/decision, 1 row driven, {reads}; the board "
                             "integrates the candidate motor neurons in fixed point: one "
                             "DECISION_WINDOW); array energy from CLOCK", board,
                             hw["energy_j"] / d, c.crossbar_area_mm2, "measured (emulator)",
                             spikes))
        else:
            rows.append(_row("emu board, this HIL",
                             f"measured: board time per decision without UART ({spikes:.0f} "
                             "input spikes/decision, 1 row driven, 2-4 columns read per spike); "
                             "array energy from CLOCK", board, hw["energy_j"] / d,
                             c.crossbar_area_mm2, "measured (emulator)", spikes))
    request = "DECISION_WINDOW" if on_board else "SPIKE_BATCH"
    rows.append(_row("emu board on-board + UART" if on_board else "emu board HIL + UART",
                     f"measured: board clock per decision including the {request} round trip "
                     f"at {hw.get('baud') or '?'} baud"
                     + (" (launches interleaved: the next window's request on the line while "
                        "the board works, so the UART overlaps the board's own time, which is "
                        "not separable here; bench/bench_window.py measures it one launch after "
                        "another)" if interleaved else ""), hw["virtual_us"] / d,
                     hw["energy_j"] / d, c.crossbar_area_mm2, "measured (emulator)", spikes))
    return rows


def ceiling_row(hw: dict[str, Any], c: PaperConstants = PAPER) -> dict[str, Any]:
    """The physical ceiling of this run's decisions (:mod:`snan_hil.host.hil.ceiling`): the
    same read plan on the datasheet parts, the wire at the baud; the MCU's time is not seen
    from the host (the emulated board's is in bench/bench_window.py)."""
    from snan_hil.host.hil.ceiling import WindowCounts, ceiling
    from snan_hil.protocol.board import MEMRICORE
    plan, d = hw["plan"], hw["plan"]["decisions"]
    spikes = hw["spikes"] / hw["decisions"]
    standard = not plan["conversions"]
    counts = WindowCounts(spikes=spikes, reads=plan["codes_read"] / d,
                          selects=plan["waits"] / d, row_words=plan["row_words"] / d,
                          conversions=(plan.get("averages") or MEMRICORE.adc_averages)
                          if standard else plan["conversions"],
                          request_bytes=plan["request_bytes"] / d,
                          reply_bytes=plan["reply_bytes"] / d, standard=standard)
    ce = ceiling(counts, int(hw["baud"]))
    parts = ", ".join(f"{k} {v / 1e3:.2f} ms" for k, v in ce.parts_us.items() if k != "MCU")
    return _row("board ceiling, datasheets",
                f"computed: this run's read plan ({counts.reads:.0f} reads of "
                f"{counts.conversions} conversions{' after a dummy' if standard else ''}, "
                f"{spikes:.0f} input spikes a decision) on "
                f"the datasheet parts (ADC 200 kS/s, settling 6 us, SPI 15 MHz; {parts}), the "
                f"larger direction of the wire at the baud; of these parts the {ce.bound} "
                "bounds it; the MCU's instruction time is not seen from the host (on the "
                "emulated board it is longer and the bound: bench/bench_window.py)",
                ce.time_us, None, c.crossbar_area_mm2, "computed (datasheets)", spikes)


def crossbar_wire_row(hw: dict[str, Any], c: PaperConstants = PAPER) -> dict[str, Any]:
    """Wire-limited time per decision of a real board over a line without CLOCK (legacy):
    the bytes of the launches on the line at the baud, plus the board's documented conversion
    time (``conversion_us``: DAC settling + dummy + averaged ADC conversions) per read; MCU and
    SPI time are not included (unknown for the existing firmware)."""
    d = hw["decisions"]
    reads = hw.get("requests") or 0
    conv = hw.get("conversion_us") or 0.0
    t_us = (hw["wire_us"] + reads * conv) / d
    return _row("board over the line, wire-limited",
                f"computed: {hw['wire_us'] / d / 1e3:.2f} ms of line time per decision at "
                f"{hw.get('baud') or '?'} baud ({reads / d:.1f} reads/decision) + "
                f"{conv:.0f} us documented conversion time per read; no CLOCK over this "
                "protocol, so no energy", t_us, None, c.crossbar_area_mm2,
                "computed from the measured traffic")


def cpu_measured_row(sw: dict[str, Any], c: PaperConstants = PAPER) -> dict[str, Any] | None:
    d = sw.get("decisions") or 0
    if not d or not sw.get("wall_s"):
        return None
    t_us = sw["wall_s"] / d * 1e6
    return _row("this PC, software", f"measured: wall time per decision of "
                f"the software launches (numba, 1 core, incl. Python per launch); energy x "
                f"{c.cpu_tdp_w:g} W (the paper's CPU TDP, assumed); / {c.cpu_area_mm2:g} mm2 "
                "(paper's CPU area, assumed)", t_us, t_us * 1e-6 * c.cpu_tdp_w, c.cpu_area_mm2,
                "measured (this machine)")


def speed_energy_table(n_cells: int, *, hw: dict[str, Any] | None = None,
                       geometry: dict[str, Any] | None = None, sw: dict[str, Any] | None = None,
                       c: PaperConstants = PAPER) -> dict[str, Any]:
    """All rows, each with ratios to the CPU paper-method row (speed: x faster per mm2;
    energy: x less energy per decision)."""
    cpu = cpu_paper_row(n_cells, c)
    rows = [cpu, crossbar_paper_row(c)]
    if geometry:
        rows.append(crossbar_geometry_row(geometry["spike_us"], geometry.get("spike_energy_j"),
                                          geometry.get("read_v", 0.0), c))
    if hw:
        rows += crossbar_hil_rows(hw, c)
    if sw:
        r = cpu_measured_row(sw, c)
        if r:
            rows.append(r)
    for r in rows:
        r["speed_vs_cpu"] = (r["norm_speed_per_us_mm2"] / cpu["norm_speed_per_us_mm2"]
                             if r["norm_speed_per_us_mm2"] else None)
        e = r["energy_per_decision_j"]
        r["energy_gain_vs_cpu"] = cpu["energy_per_decision_j"] / e if e else None
    return {"n_cells": n_cells, "constants": asdict(c), "rows": rows,
            "measured_inputs": {"hw": hw, "geometry": geometry, "sw": sw}}


def measure_spike_geometry(client: BoardClient, *, rows: int = 15, cols: int = 8, spikes: int = 20,
                           row_code: int, baud: int | None) -> dict[str, Any] | None:
    """Time and array energy of one spike on ``rows`` rows with ``cols`` columns read (the
    paper's 15 x 8), from CLOCK before/after one SPIKE_BATCH of ``spikes`` spikes (reads only,
    at ``row_code`` <= 0.3 V). The UART share (bytes x 10 / baud) is removed. None without
    CLOCK or baud."""
    if not baud:
        return None
    try:
        c0 = client.clock()
        b0 = _bytes(client)
        group = SpikeGroup(tuple((r, int(row_code)) for r in range(rows)),
                           tuple(range(spikes)))
        client.spike_batch([group], list(range(cols)), n_bins=spikes, bin_us=1000)
        c1 = client.clock()
        b1 = _bytes(client)
    except Exception:   # noqa: BLE001 - an optional measurement; report without it
        return None
    wire = wire_seconds(b1 - b0, baud) * 1e6
    info = getattr(client, "info", None)
    read_v = info.dac_volts(row_code) if info is not None else float("nan")
    return {"rows": rows, "cols": cols, "spikes": spikes, "read_code": int(row_code),
            "read_v": float(read_v),
            "spike_us": float((c1.time_us - c0.time_us - wire) / spikes),
            "spike_energy_j": float((c1.energy_j - c0.energy_j) / spikes),
            "wire_us": float(wire)}


def _bytes(client: BoardClient) -> int:
    c = client.counters_dict()
    return int(c.get("bytes_in", 0)) + int(c.get("bytes_out", 0))


def format_si(x: float | None, unit: str) -> str:
    if x is None or not np.isfinite(x):
        return "-"
    for scale, prefix in ((1.0, ""), (1e-3, "m"), (1e-6, "u"), (1e-9, "n"), (1e-12, "p")):
        if abs(x) >= scale:
            return f"{x / scale:.3g} {prefix}{unit}"
    return f"{x:.3g} {unit}"
