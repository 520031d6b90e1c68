"""One look for every figure of the bench and the docs: a colour per controller, text sizes
readable at page width.

Figures are drawn :data:`WIDTH` inches wide at :data:`DPI` dots per inch (800 px), with text
of at least :data:`MIN_FONT` points, so that a page that shows them at their pixel width shows
text of at least 9 pt. :func:`color` gives every controller the same colour in every figure.
"""

from __future__ import annotations

import zlib
from typing import Any

__all__ = ["COLORS", "DPI", "MIN_FONT", "RC", "WIDTH", "color", "pyplot"]

WIDTH = 8.0
DPI = 100
MIN_FONT = 10
#: matplotlib settings of every bench figure
RC = {
    "font.size": 11,
    "axes.titlesize": 11,
    "axes.labelsize": 11,
    "xtick.labelsize": MIN_FONT,
    "ytick.labelsize": MIN_FONT,
    "legend.fontsize": MIN_FONT,
    "figure.titlesize": 12,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "savefig.dpi": DPI,
}

#: Fixed colours (colour-blind-safe, Okabe-Ito and Tol) of the controllers the bench runs.
COLORS = {
    "stc": "#0072B2",
    "stc_lq": "#56B4E9",
    "stc_kfmils": "#009E73",
    "stc_mimo": "#0072B2",
    "stc_nocd": "#CC6677",  # the self-tuning controller without change detection (gallery)
    "lqg": "#000000",
    "oracle": "#7F7F7F",
    "zero": "#BBBBBB",
    "ppo": "#D55E00",
    "sac": "#CC79A7",
    "td3": "#999933",
    "a2c": "#AA4499",
    "rppo": "#882255",
    "theta_ppo": "#E69F00",
    "theta_sac": "#44AA99",
    "residual_ppo": "#332288",
    "oracle_ppo": "#117733",
    "fixed_pi": "#661100",
}
_SPARE = ("#117733", "#661100", "#6699CC", "#DDCC77", "#88CCEE", "#AA4466")


def color(name: str) -> str:
    """The colour of controller ``name`` (a fixed one, else a stable pick by name)."""
    if name in COLORS:
        return COLORS[name]
    return _SPARE[zlib.crc32(name.encode()) % len(_SPARE)]


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend with :data:`RC` applied."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update(RC)
    return plt
