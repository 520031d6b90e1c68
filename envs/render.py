"""Episode pictures for ``render_mode="rgb_array"`` (matplotlib with the Agg backend)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def render_traces(trace: dict[str, list], title: str = "") -> NDArray:
    """Draw y and r (top) and u (bottom) against the step; return an ``(H, W, 3)`` uint8 array."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise ImportError("rendering needs matplotlib: pip install 'stcgym[plot]'") from exc

    fig = Figure(figsize=(6.4, 4.0), dpi=80)
    canvas = FigureCanvasAgg(fig)
    ax_y, ax_u = fig.subplots(2, 1, sharex=True)
    y, r = np.asarray(trace["y"]), np.asarray(trace["r"])
    ax_y.plot(np.arange(len(y)), y, lw=1.0, label="y")
    ax_y.plot(np.arange(len(r)), r, "--", lw=1.0, label="r")
    ax_y.set_ylabel("output")
    ax_y.legend(loc="upper right", fontsize="small")
    ax_y.set_title(title)
    if trace["u"]:
        u = np.asarray(trace["u"])
        ax_u.step(np.arange(len(u)), u, where="post", lw=1.0)
    ax_u.set_ylabel("u")
    ax_u.set_xlabel("step k")
    fig.tight_layout()
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()
