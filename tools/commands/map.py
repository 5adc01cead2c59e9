"""``snan-hil map``: read every cell of the crossbar and show the conductance map."""

from __future__ import annotations

import argparse
import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from snan_hil.atomicio import atomic_path
from snan_hil.errors import UserError
from snan_hil.tools.console import console, progress_bar
from snan_hil.tools.ports import add_port_arguments, client_from_args

NAME = "map"
HELP = "read all cells through the board protocol and print the conductance map (log-shaded)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_port_arguments(parser)
    parser.add_argument("--read-code", type=int, default=None,
                        help="DAC code of the read voltage (default: the board's read_code "
                             "from INFO, 245 = 0.2991 V on MemriCore)")
    parser.add_argument("--csv", metavar="FILE", default=None,
                        help="also write row,col,adc,resistance_ohm,conductance_s per cell "
                             "(default: no CSV)")
    parser.add_argument("--png", metavar="FILE", default=None,
                        help="also write the map as an image (needs matplotlib; default: no image)")


@dataclass(frozen=True)
class CellMap:
    """ADC codes of all cells and the read-chain constants used to convert them."""

    adc: np.ndarray          # (rows, cols) int
    read_volts: float
    gain: float
    r_load: float
    r_switch: float
    adc_bits: int
    adc_vref: float

    def resistance(self) -> np.ndarray:
        """Cell + transistor resistance (Ohm) from the host's formula
        ``R = gain * R_load * V_read * 2^bits / (adc * Vref) - R_sw - R_load`` (inf for adc 0)."""
        adc = self.adc.astype(float)
        with np.errstate(divide="ignore"):
            r = (self.gain * self.r_load * self.read_volts * 2 ** self.adc_bits
                 / (adc * self.adc_vref) - self.r_switch - self.r_load)
        return np.where(adc > 0, np.maximum(r, 0.0), np.inf)

    def conductance(self) -> np.ndarray:
        """1 / resistance (S); 0 for open cells, inf for cells that read as shorts."""
        r = self.resistance()
        with np.errstate(divide="ignore"):
            return np.where(np.isinf(r), 0.0, 1.0 / r)


def read_map(client, read_code: int | None = None, progress=None) -> CellMap:
    """Read all cells with ``client.read_cell``; ``progress(done)`` is called per cell."""
    info = client.info or client.hello()
    code = info.read_code if read_code is None else int(read_code)
    adc = np.zeros((info.rows, info.cols), dtype=int)
    done = 0
    for row in range(info.rows):
        for col in range(info.cols):
            adc[row, col] = client.read_cell(row, col, code)
            done += 1
            if progress is not None:
                progress(done)
    return CellMap(adc, info.dac_volts(code), info.gain, info.r_load_ohm, info.r_switch_ohm,
                   info.adc_bits, info.adc_vref_v)


def _shade(g: float, lo: float, hi: float) -> str:
    """Background colour on a log scale from dark blue (lo) to yellow (hi)."""
    if g <= 0 or not math.isfinite(g):
        return "on grey15"
    t = 0.0 if hi <= lo else (math.log10(g) - lo) / (hi - lo)
    t = min(max(t, 0.0), 1.0)
    # A short viridis-like ramp.
    stops = [(68, 1, 84), (59, 82, 139), (33, 145, 140), (94, 201, 98), (253, 231, 37)]
    x = t * (len(stops) - 1)
    i = min(int(x), len(stops) - 2)
    f = x - i
    r, gg, b = (round(a + (c - a) * f) for a, c in zip(stops[i], stops[i + 1]))
    fg = "black" if t > 0.55 else "white"
    return f"{fg} on rgb({r},{gg},{b})"


def render_table(cmap: CellMap):
    """A rich Table of conductances in uS, log-shaded per cell."""
    from rich.table import Table

    g = cmap.conductance()
    finite = g[(g > 0) & np.isfinite(g)]
    lo, hi = (math.log10(finite.min()), math.log10(finite.max())) if finite.size else (0, 1)
    table = Table(title=f"conductance (uS) read at {cmap.read_volts:.3f} V; rows = bit lines, "
                        "columns = word lines", show_lines=False, pad_edge=False)
    table.add_column("row", justify="right", style="bold")
    for col in range(g.shape[1]):
        table.add_column(f"WL{col}", justify="right")
    full = 2 ** cmap.adc_bits - 1
    for row in range(g.shape[0]):
        cells = []
        for col in range(g.shape[1]):
            value = g[row, col]
            if cmap.adc[row, col] >= full:
                text = "sat"
            elif value <= 0:
                text = "open"
            else:
                us = value * 1e6
                text = f"{us:.1f}" if us < 100 else f"{us:.0f}"
            cells.append(f"[{_shade(value, lo, hi)}]{text:>6}[/]")
        table.add_row(str(row), *cells)
    return table


def write_csv(cmap: CellMap, path: str) -> None:
    r, g = cmap.resistance(), cmap.conductance()
    try:
        with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["row", "col", "adc", "resistance_ohm", "conductance_s"])
            for row in range(r.shape[0]):
                for col in range(r.shape[1]):
                    w.writerow([row, col, int(cmap.adc[row, col]), f"{r[row, col]:.6g}",
                                f"{g[row, col]:.6g}"])
    except OSError as exc:
        raise UserError(f"cannot write --csv {path}: {exc.strerror or exc}") from None


def write_png(cmap: CellMap, path: str) -> None:
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.colors import LogNorm
    except ImportError:
        raise UserError("--png needs matplotlib: pip install 'snan-hil[plots]'") from None
    g = cmap.conductance() * 1e6
    masked = np.ma.masked_where(~(g > 0) | ~np.isfinite(g), g)
    fig, ax = plt.subplots(figsize=(4, 9))
    im = ax.imshow(masked, aspect="auto", cmap="viridis", norm=LogNorm())
    ax.set_xlabel("word line (column)")
    ax.set_ylabel("bit line (row)")
    ax.set_title("conductance map")
    fig.colorbar(im, ax=ax, label="conductance (uS)")
    fig.tight_layout()
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=120, format="png")
    except OSError as exc:
        raise UserError(f"cannot write --png {path}: {exc.strerror or exc}") from None
    finally:
        plt.close(fig)


def run(args: argparse.Namespace) -> int:
    for opt in (args.csv, args.png):
        if opt and not Path(opt).resolve().parent.is_dir():
            raise UserError(f"cannot write {opt}: its folder does not exist")
    client = client_from_args(args)
    try:
        info = client.info
        with progress_bar(transient=True) as bar:
            task = bar.add_task("reading cells", total=info.rows * info.cols)
            cmap = read_map(client, args.read_code,
                            progress=lambda done: bar.update(task, completed=done))
    finally:
        client.close()
    console.print(render_table(cmap))
    g = cmap.conductance()
    ok = g[(g > 0) & np.isfinite(g)]
    if ok.size:
        console.print(f"{ok.size} readable cells: median {np.median(ok) * 1e6:.1f} uS "
                      f"({1 / np.median(ok):.0f} Ohm incl. transistor), range "
                      f"{ok.min() * 1e6:.1f}..{ok.max() * 1e6:.1f} uS", highlight=False)
    if args.csv:
        write_csv(cmap, args.csv)
        console.print(f"wrote {args.csv}")
    if args.png:
        write_png(cmap, args.png)
        console.print(f"wrote {args.png}")
    return 0
