"""
A small sweep over a random plant family
========================================

On which plants does the self-tuning controller hold, and at what cost? A sweep draws
plants from a *family spec*, runs the self-tuning controller (``stc``), the known-model
oracle and LQG on every plant with the same noise and reference, and tabulates the result
per plant, with a robustness map over two plant features. This is what ``stcgym sweep``
does from the command line; here a tiny family runs from Python, on one process.
"""

# %%
# The family
# ----------
# A family spec is data (a dict here, a YAML or JSON file for the command). Plant ``i`` is
# drawn from ``SeedSequence([seed, i])``, so the same spec gives the same plants anywhere.
# Each plant is open-loop unstable with probability 0.2 and non-minimum phase with
# probability 0.2 (``unstable_share``, ``nonminimum_phase_share``).
import tempfile

import matplotlib.pyplot as plt
import numpy as np

from stcgym.agents.benchmark import style
from stcgym.agents.sweeps import SweepConfig, run_sweep

plt.rcParams.update(style.RC)  # the project's figure style: readable at page width

family = {
    "name": "gallery",
    "seed": 0,
    "count": 200,
    "order": 2,
    "poles": {
        "magnitude": [0.3, 0.95],
        "unstable_share": 0.2,
        "unstable_magnitude": [1.02, 1.2],
    },
    "zeros": {"magnitude": [0.0, 0.9], "nonminimum_phase_share": 0.2},
    "dc_gain": [0.5, 5.0],
    "noise_std": 0.05,
    "reference": {"kind": "square", "period": 100},
    "steps": 600,
}
config = SweepConfig.build(family, ["stc", "oracle", "lqg"], seeds=1)
print(f"{config.num_lanes} lanes (plant, seed)")
print(f"controllers {list(config.controllers)}")

# %%
# Run it
# ------
# ``run_sweep`` writes ``metrics.csv`` (or ``.parquet``), ``config.json`` and
# ``robustness.png`` into ``out/run``; a temporary folder keeps this example tidy.
# ``jobs=1`` simulates in this process; ``jobs=N`` or ``executor="ray"`` spread the chunks
# of lanes over processes or a cluster with identical results.
with tempfile.TemporaryDirectory() as out:
    result = run_sweep(config, out=out, run="gallery", jobs=1, progress=False)
    table = result.table
    robustness = plt.imread(result.plot_path)
print(f"table: {len(table)} rows, columns include {list(table.columns[:8])}")

# %%
# Summary per controller
# ----------------------
# ``ratio`` is the episode cost over the oracle's on the same lane; ``bounded`` is 0 for an
# episode whose output left the environment's bound (it is charged its last cost to the end).
for name, rows in table.groupby("controller", sort=False):
    ratio = rows.loc[rows["bounded"] == 1, "ratio"]
    print(
        f"{name:7s} bounded {100 * rows['bounded'].mean():5.1f} %, "
        f"ratio to the oracle on the bounded lanes: median {ratio.median():.3f}, "
        f"90th percentile {np.percentile(ratio, 90):.3f}"
    )
stc = table[table["controller"] == "stc"]
n_unstable, n_nmp = int(stc["unstable"].sum()), int(stc["nonminimum_phase"].sum())
print(f"{n_unstable} of {len(stc)} plants open-loop unstable")
print(f"{n_nmp} of {len(stc)} plants non-minimum phase")
lost = stc[stc["bounded"] == 0]
n_lost_unstable = int(lost["unstable"].sum())
print(
    f"stc loses {len(lost)} plant(s), {n_lost_unstable} of them open-loop unstable"
)

# %%
# The robustness map
# ------------------
# Bounded share (top) and median cost ratio to the oracle (bottom) over the largest pole
# magnitude and the absolute DC gain, one column per controller, as ``run_sweep`` drew it.
# The image is shown at its own size (800 px wide for two controllers, in the shared style of
# ``stcgym.agents.benchmark.style``), so that its text stays as ``run_sweep`` wrote it.
height, width = robustness.shape[:2]
fig = plt.figure(figsize=(width / style.DPI, height / style.DPI), dpi=style.DPI)
ax = fig.add_axes((0, 0, 1, 1))
ax.imshow(robustness)
ax.set_axis_off()

# %%
# The same table, plant by plant
# ------------------------------
# The table is a pandas DataFrame with the plant features on every row, so any other view
# is a few lines: here the self-tuning controller's ratio against the largest pole
# magnitude, open-loop unstable plants in orange.
fig, ax = plt.subplots(figsize=(style.WIDTH, 3.5), layout="constrained")
for unstable, color, label in (
    (0, "C0", "open-loop stable"),
    (1, "C1", "open-loop unstable"),
):
    rows = stc[stc["unstable"] == unstable]
    ax.scatter(rows["pole_mag_max"], rows["ratio"], color=color, s=12, label=label)
ax.set_yscale("log")
ax.set_xlabel("largest pole magnitude")
ax.set_ylabel("stc cost / oracle")
ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1))
plt.show()
