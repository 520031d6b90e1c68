"""
A grey-box model: one parameter of a second-order object (Voevoda & Troshina 2016)
==================================================================================

Voevoda & Troshina (2016) estimate one physical parameter ``theta`` of the object

``x(k+1) = [[0, 1], [-0.3, theta]] x(k) + [0, 1]^T u(k)``, ``y(k) = [1, 0] x(k)``

from its input and output only: they eliminate the state, which leaves an equation linear
in ``theta``, and run scalar recursive least squares with ``P0 = 0.5`` on 500 rows of a
meander input of period 6. ``AffineStateSpace`` derives that regression from the structure
and ``RecursiveLeastSquares`` fits it. The paper's garbled points (the sign of ``theta``,
the printed form of the eliminated equation) are read as in
``benchmarks/voevoda_troshina_2016.py``: ``theta = -0.5``.
"""

# %%
# The structure and its regression
# --------------------------------
# ``Phi(theta) = Phi0 + theta Phi_1``: the parameter multiplies one entry of ``Phi``. The
# output matrix is not invertible, so the state is eliminated (Cayley-Hamilton), and
# ``equations()`` prints the regression that results.
import gymnasium as gym
import matplotlib.pyplot as plt
import numpy as np

import stcgym.envs  # noqa: F401
from stcgym.adaptive import AffineStateSpace, RecursiveLeastSquares
from stcgym.agents.benchmark import style
from stcgym.envs import SquareWave

plt.rcParams.update(style.RC)  # the project's figure style: readable at page width

THETA, P0, ROWS, NOISE_VAR = -0.5, 0.5, 500, 0.025
PAPER_NOISE_FREE, PAPER_NOISY = -0.5008, -0.4613  # the paper's reported estimates

obj = AffineStateSpace(
    Phi0=[[0.0, 1.0], [-0.3, 0.0]],
    Gamma0=[0.0, 1.0],
    H=[1.0, 0.0],
    Phi_terms=[[[0.0, 0.0], [0.0, 1.0]]],
    names=["theta"],
)
regression = obj.regression()
print(regression.equations())


# %%
# Experiments in ``stcgym/StateSpace-v0``
# ---------------------------------------
# The plant is the object with the true ``theta``; the input is the meander, applied as the
# action; ``ROWS + 2`` samples of ``y`` give ``ROWS`` regression rows.
def record(seed, noise_var=0.0):
    """``u(0..ROWS+1)`` and the measured ``y(0..ROWS+1)`` of one experiment."""
    Phi, Gamma = obj.matrices([THETA])
    steps = ROWS + 2
    env = gym.make(
        "stcgym/StateSpace-v0",
        A=Phi,
        B=Gamma,
        C=obj.H,
        noise_std=float(np.sqrt(noise_var)),
        reference="zero",
        max_episode_steps=steps,
    )
    meander = SquareWave(period=6)
    u = np.array([meander(k) for k in range(steps)])
    y = np.empty(steps)
    obs, _ = env.reset(seed=seed)
    y[0] = obs[0]
    for k in range(steps - 1):
        obs, *_ = env.step(u[k : k + 1])
        y[k + 1] = obs[0]
    env.close()
    return u, y


u, y = record(seed=0)
phi, z = regression.build(u, y)
print(f"{len(z)} rows; regressor shape {phi.shape}")

# %%
# Recursive least squares, noise-free
# -----------------------------------
# The prior ``P0`` is one extra "observation" of ``theta0 = 0``, which pulls the estimate
# towards zero; with ``P0 = 1e6`` the pull vanishes, and with ``P0 = 0`` the gain is zero
# and the estimate never moves (the paper's remark).
runs = {
    f"P0 = {p0:g}": RecursiveLeastSquares(1, P0=p0).run(phi, z)[:, 0]
    for p0 in (P0, 1e6, 0.0)
}
for label, history in runs.items():
    print(f"noise-free, {label:10s} theta_hat = {history[-1]:.4f}")
print(f"paper, noise-free: {PAPER_NOISE_FREE}")
free = runs[f"P0 = {P0:g}"]
outside = np.flatnonzero(np.abs(free - THETA) > 0.05 * abs(THETA))
print(f"within 5 % of theta from row {outside[-1] + 1 if outside.size else 0} on")

# %%
# Measurement noise: the estimate is biased
# -----------------------------------------
# With noise of variance 0.025 on ``y`` the regressor ``y(k+1)`` is itself noisy
# (errors in variables), which biases least squares towards zero; the paper reports one run.
# Here 100 runs are the lanes of one estimator (``num_envs``).
seeds = range(100)
records = [regression.build(*record(s, NOISE_VAR)) for s in seeds]
phis, zs = np.array([r[0] for r in records]), np.array([r[1] for r in records])
noisy = RecursiveLeastSquares(1, P0=P0, num_envs=len(seeds)).run(phis, zs)[:, :, 0]
final = noisy[:, -1]
spread = f"{final.mean():.4f} +- {final.std(ddof=1):.4f}"
print(f"noisy (variance {NOISE_VAR}): {spread} over {len(seeds)} runs")
closer = np.mean(final >= PAPER_NOISY)
print(f"paper, one noisy run: {PAPER_NOISY}")
print(f"runs at least as close to zero: {closer:.0%}")

# %%
# The estimates against the row count
# ------------------------------------
rows = np.arange(1, ROWS + 1)
fig, ax = plt.subplots(figsize=(style.WIDTH, 4.5), layout="constrained")
lo, hi = np.percentile(noisy, [5, 95], axis=0)
ax.fill_between(rows, lo, hi, color="C1", alpha=0.3, label="noisy: 90 % of runs")
for i, (label, history) in enumerate(runs.items()):
    ax.plot(
        rows, history, color=["C0", "C2", "C3"][i], label=f"noise-free, {label}"
    )
ax.axhline(THETA, color="k", ls="--", lw=1, label="true theta")
ax.plot(
    [ROWS, ROWS], [PAPER_NOISE_FREE, PAPER_NOISY], "ko", mfc="none", label="paper"
)
ax.set_ylim(-0.7, 0.05)
ax.set_xlabel("rows")
ax.set_ylabel("theta_hat")
fig.legend(loc="outside lower center", ncol=3)
plt.show()
