"""Readability of a matplotlib figure at the documentation's page width.

The gallery shows a figure at its pixel width (``savefig.dpi`` x its width in inches, as
sphinx-gallery saves it), shrunk to the page's :data:`PAGE_PX` when wider. A figure is
readable when every text is at least ``style.MIN_FONT`` points at that rendered size, no
legend lies on a plotting area or on a title or axis label, and a label names one colour in
every panel of the figure.
"""

from __future__ import annotations

from typing import Any

from matplotlib import colors as mcolors
from matplotlib import rcParams
from matplotlib.lines import Line2D
from matplotlib.text import Text
from matplotlib.transforms import Bbox

from stcgym.agents.benchmark import style

#: The page width the figures are checked at, in pixels.
PAGE_PX = style.WIDTH * style.DPI


def _dpi(fig: Any) -> float:
    dpi = rcParams["savefig.dpi"]
    return fig.dpi if dpi == "figure" else float(dpi)


def _overlap(a: Bbox, b: Bbox) -> bool:
    both = Bbox.intersection(a, b)
    return both is not None and both.width > 1 and both.height > 1


def problems(fig: Any) -> list[str]:
    """What makes ``fig`` hard to read at :data:`PAGE_PX` (empty when nothing does)."""
    out = []
    width_px = fig.get_size_inches()[0] * _dpi(fig)
    scale = min(1.0, PAGE_PX / width_px)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    for text in fig.findobj(Text):
        if text.get_visible() and text.get_text().strip():
            size = text.get_fontsize() * scale
            if size < style.MIN_FONT - 1e-9:
                out.append(f"text {text.get_text()!r}: {size:.1f} pt at {PAGE_PX:.0f} px")
    axes = [ax for ax in fig.axes if ax.get_visible() and ax.axison]
    legends = [*fig.legends, *(ax.get_legend() for ax in fig.axes)]
    # matplotlib keeps the figure's super-title and the axes' side titles in private fields
    sup = (getattr(fig, name, None) for name in ("_suptitle", "_supxlabel", "_supylabel"))
    titles = [*fig.texts, *filter(None, sup)]
    for ax in axes:
        sides = (getattr(ax, name, None) for name in ("_left_title", "_right_title"))
        titles += [ax.title, *filter(None, sides), ax.xaxis.label, ax.yaxis.label]
    titles = [t for t in dict.fromkeys(titles) if t.get_visible() and t.get_text().strip()]
    for legend in filter(None, legends):
        box = legend.get_window_extent(renderer)
        names = [t.get_text() for t in legend.get_texts()]
        for ax in axes:
            if _overlap(box, ax.get_window_extent(renderer)):
                out.append(f"legend {names} lies on the plotting area of {ax.get_title()!r}")
        for text in titles:
            if _overlap(box, text.get_window_extent(renderer)):
                out.append(f"legend {names} covers the text {text.get_text()!r}")
    seen: dict[str, str] = {}
    for ax in fig.axes:
        for line in ax.get_lines():
            label = line.get_label()
            if isinstance(line, Line2D) and label and not label.startswith("_"):
                color = mcolors.to_hex(line.get_color())
                if seen.setdefault(label, color) != color:
                    out.append(f"{label!r} is drawn in {seen[label]} and in {color}")
    return out
