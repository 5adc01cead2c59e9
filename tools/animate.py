"""``sim --animate`` / ``run --animate``: a GIF of the agent moving on the grid over each cell's
astrocyte calcium as a heat map (the paper's Fig. 3 D2 shows the calcium; here it is drawn per
decision on the grid).

Frames are drawn with matplotlib and written as one animated GIF with Pillow (matplotlib's
dependency), atomically, carrying a comment that marks it as snan-hil's
(:data:`ANIMATION_FORMAT`), so a later run recognises its own file.
"""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import Any

import numpy as np

from snan_hil.files.atomicio import atomic_path
from snan_hil.common.errors import UserError
from snan_hil.host.calcium_trace import CalciumTrace
from snan_hil.host.plots import pyplot
from snan_hil.files.outputs import OutputKind

__all__ = ["ANIMATION_FORMAT", "ANIMATION", "animate_trace", "MAX_FRAMES"]

ANIMATION_FORMAT = "snan-hil-animation/1"
MAX_FRAMES = 400
"""At most this many frames (a longer trial is shown every n-th decision)."""


def _owns(path: Path) -> bool:
    try:
        from PIL import Image
        with Image.open(path) as im:
            comment = im.info.get("comment", b"")
    except Exception:       # noqa: BLE001 - any unreadable file is simply not ours
        return False
    if isinstance(comment, bytes):
        comment = comment.decode("utf-8", "replace")
    return str(comment).startswith(ANIMATION_FORMAT.split("/")[0] + "/")


ANIMATION = OutputKind("a snan-hil animation", _owns)


def check_gif_name(option: str, path: str) -> None:
    """UserError unless ``path`` names a .gif file."""
    if Path(path).suffix.lower() != ".gif":
        raise UserError(f"{option} {path}: the animation is a GIF; give a file name ending in "
                        ".gif")


def animate_trace(trace: CalciumTrace, goals: list[int], out: str | os.PathLike[str], *,
                  title: str, fps: float = 4.0) -> Path:
    """Write the animation of ``trace`` (one frame per decision, the first before the first
    move): calcium heat map (fixed colour scale from 0 to the trial's largest calcium; cells
    above the threshold Ca_thr outlined; cells not visited yet, holding no calcium, grey), the
    agent, its path so far, start and goal."""
    plt = pyplot("--animate needs matplotlib")
    try:
        from matplotlib.lines import Line2D
        from matplotlib.patches import Patch, Rectangle
        from PIL import Image
    except ImportError:  # pragma: no cover - depends on the installation
        raise UserError("--animate needs matplotlib: pip install 'snan-hil[plots]'") from None
    rows, cols = trace.grid
    n = trace.steps
    stride = max(1, int(np.ceil((n + 1) / MAX_FRAMES)))
    frames_k = list(range(0, n + 1, stride))
    if frames_k[-1] != n:
        frames_k.append(n)
    top = max(float(trace.ca.max()), trace.ca_thr * 1.2, 1e-9)
    path = np.array(trace.path)
    pr, pc = np.divmod(path, cols)
    start = trace.path[0]
    size = min(7.0, max(4.6, 2.2 + 0.45 * max(rows, cols)))
    fig, ax = plt.subplots(figsize=(size + 1.6, size + 1.2), dpi=80)
    # grey: cells not visited yet (and without calcium)
    cmap = plt.get_cmap("magma").with_extremes(bad="0.62")
    visited = np.zeros(rows * cols, dtype=bool)

    def shown(k: int, frame: np.ndarray) -> np.ndarray:
        """The frame with the cells not visited up to decision k (and holding no calcium)
        masked, so they are grey, not the colour of a visited cell with little calcium."""
        seen = visited.copy()
        seen[np.asarray(trace.path[:k + 1], dtype=int)] = True
        hide = ~seen.reshape(rows, cols) & (np.asarray(frame) <= 0)
        return np.ma.masked_array(frame, mask=hide)

    im = ax.imshow(shown(0, trace.frame(0)), cmap=cmap, vmin=0.0, vmax=top, origin="upper",
                   interpolation="nearest")
    cbar = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
    cbar.set_label("astrocyte calcium Ca (a.u.)")
    cbar.ax.axhline(trace.ca_thr, color="cyan", lw=1.5)
    ax.set_xticks(range(cols))
    ax.set_yticks(range(rows))
    ax.tick_params(labelsize=7)
    ax.set_xlim(-0.5, cols - 0.5)
    ax.set_ylim(rows - 0.5, -0.5)
    ax.plot(start % cols, start // cols, "s", ms=14, mfc="none", mec="lime", mew=2)
    ax.annotate("start", (start % cols, start // cols), xytext=(0, 11),
                textcoords="offset points", ha="center", color="lime", fontsize=8,
                fontweight="bold")
    for gcell in goals:
        ax.plot(gcell % cols, gcell // cols, "*", ms=16, color="gold", mec="black")
        ax.annotate("goal", (gcell % cols, gcell // cols), xytext=(0, -15),
                    textcoords="offset points", ha="center", color="gold", fontsize=8,
                    fontweight="bold")
    trail, = ax.plot([], [], "-", color="white", lw=1.2, alpha=0.8)
    agent, = ax.plot([], [], "o", ms=11, color="deepskyblue", mec="white", mew=1.5)
    outlines: list[Any] = []
    fig.legend(handles=[
        Line2D([], [], ls="", marker="o", color="deepskyblue", mec="white", ms=8,
               label="agent"),
        Line2D([], [], color="white", lw=1.2, label="path so far"),
        Line2D([], [], ls="", marker="s", mfc="none", mec="lime", mew=2, ms=9, label="start"),
        Line2D([], [], ls="", marker="*", color="gold", mec="black", ms=11, label="goal"),
        Patch(fc="0.62", ec="0.4", label="not visited yet"),
        Patch(fill=False, ec="cyan", lw=1.5,
              label=f"Ca > Ca_thr = {trace.ca_thr:g} (interneuron threshold lowered)")],
        fontsize=7, loc="lower center", ncol=2, frameon=True,
        facecolor="0.25", edgecolor="0.25", labelcolor="white")
    fig.subplots_adjust(bottom=0.2, top=0.9)
    images = []
    for k in frames_k:
        frame = trace.frame(k)
        im.set_data(shown(k, frame))
        trail.set_data(pc[:k + 1], pr[:k + 1])
        agent.set_data([pc[k]], [pr[k]])
        for o in outlines:
            o.remove()
        outlines = [ax.add_patch(Rectangle((c - 0.46, r - 0.46), 0.92, 0.92, fill=False,
                                           ec="cyan", lw=1.5))
                    for r, c in zip(*np.nonzero(frame > trace.ca_thr))]
        ax.set_title(f"{title}\ndecision {k} of {n}", fontsize=8)
        buf = io.BytesIO()
        fig.savefig(buf, format="png")
        buf.seek(0)
        with Image.open(buf) as img:
            images.append(img.convert("P", palette=Image.Palette.ADAPTIVE, colors=128))
    plt.close(fig)
    out = Path(out)
    with atomic_path(out, suffix=".gif") as tmp:
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:],
                       duration=int(1000 / fps), loop=0,
                       comment=ANIMATION_FORMAT.encode())
    return out
