"""
A multichannel static object (Voevoda & Troshina 2017)
======================================================

Voevoda & Troshina (2017) estimate the 2 x 2 matrix ``Theta`` of a static object
``y^T = x^T Theta + v`` by matrix recursive least squares, with two meanders of periods 6
and 4 samples as inputs, measurement noise of variance 0.01, ``Theta(0) = 0`` and the
initial covariance ``P0 = [[0.5, 0.4], [0.5, 1]]`` as printed (not symmetric). This example
runs their set-up in ``stcgym/MultichannelStatic-v0`` with ``MatrixRLS`` and sets the
estimates next to the paper's single run.
"""

# %%
# The object and the experiment
# -----------------------------
# The environment's default is the paper's object: ``Theta = [[1, 2], [0, 1]]`` and output
# noise of standard deviation 0.1. The action ``u(k)`` produces ``y(k+1)``, so the sample
# pairs for the estimator are ``(u(k), y(k+1))``.
import gymnasium as gym
import matplotlib.pyplot as plt
import numpy as np

import stcgym.envs  # noqa: F401
from stcgym.adaptive import MatrixRLS
from stcgym.agents.benchmark import style
from stcgym.envs import SquareWave

plt.rcParams.update(style.RC)  # the project's figure style: readable at page width

N = 500
P0 = np.array([[0.5, 0.4], [0.5, 1.0]])
meanders = (SquareWave(period=6), SquareWave(period=4))
X = np.array([[m(k) for m in meanders] for k in range(N)])
# The paper's reported estimates (theta11, theta12, theta21, theta22), and its gain
# at N = 100.
PAPER = {100: [0.9505, 1.935, 0.02, 1.034], 200: [0.9791, 1.962, 0.01646, 1.025]}
PAPER_K100 = [-0.01028, -0.01047]


def record(seed):
    """One run of the object: the measured outputs ``y(k+1)`` for ``k = 0..N-1``."""
    env = gym.make(
        "stcgym/MultichannelStatic-v0", reference="zero", max_episode_steps=N
    )
    env.reset(seed=seed)
    Y = np.empty((N, 2))
    for k in range(N):
        obs, *_ = env.step(X[k])  # obs = [y(k+1) (2 values), r(k+1) (2 values)]
        Y[k] = obs[:2]
    env.close()
    return Y


def estimate(Y, P0=P0):
    """``Theta(N)`` for ``N = 1..500`` (rows flattened) and the gain ``K`` at
    ``N = 100``."""
    est = MatrixRLS(2, 2, P0=P0)
    history = np.empty((N, 4))
    for k in range(N):
        est.update(X[k], Y[k])
        history[k] = est.theta.ravel()
        if k + 1 == 100:
            K100 = est.K.copy()
    return history, K100


theta_true = gym.make("stcgym/MultichannelStatic-v0").unwrapped.theta
print(f"true Theta = {theta_true.tolist()}")
history, K100 = estimate(record(seed=0))
for n in (100, 200, 500):
    print(f"N = {n}: Theta = {np.round(history[n - 1], 4).tolist()}")
print(f"gain at N = 100: K = {np.round(K100, 5).tolist()} (paper {PAPER_K100})")

# %%
# The paper's single run against the spread over runs
# ---------------------------------------------------
# The paper reports one run, so its numbers are compared with the spread of single-run
# estimates over 50 noise seeds. The small, non-symmetric ``P0`` is a prior that pulls the
# estimate towards ``Theta(0) = 0``; with an uninformative ``P0 = 1e6 I`` that pull is gone.
# The lines ``(paper - mean) / std`` say how many standard deviations of a single run the
# paper's values lie from the mean of the runs.
seeds = range(50)
records = [record(s) for s in seeds]
runs = np.array([estimate(Y)[0] for Y in records])
flat = np.array([estimate(Y, P0=1e6 * np.eye(2))[0] for Y in records])
names = ["theta11", "theta12", "theta21", "theta22"]
for n, paper in PAPER.items():
    mean, std = runs[:, n - 1].mean(axis=0), runs[:, n - 1].std(axis=0, ddof=1)
    z = (np.array(paper) - mean) / std
    print(f"N = {n}: mean over seeds {np.round(mean, 4).tolist()}")
    print(f"        std {np.round(std, 4).tolist()}")
    print(
        f"        paper {paper}, (paper - mean) / std = {np.round(z, 2).tolist()}"
    )
    flat_mean = flat[:, n - 1].mean(axis=0)
    print(f"        P0 = 1e6 I: mean {np.round(flat_mean, 4).tolist()}")

# %%
# Estimates against N
# -------------------
# Each panel is one entry of ``Theta``: the band holds 90 % of the runs with the paper's
# ``P0``, the thin line is seed 0, the dashed line the truth and the dots the paper's run.
t = np.arange(1, N + 1)
fig, axes = plt.subplots(
    2, 2, sharex=True, figsize=(style.WIDTH, 5.5), layout="constrained"
)
for i, ax in enumerate(axes.flat):
    lo, hi = np.percentile(runs[:, :, i], [5, 95], axis=0)
    ax.fill_between(
        t, lo, hi, color="C0", alpha=0.3, label="90 % of runs, paper's P0"
    )
    ax.plot(t, runs[0, :, i], color="C0", lw=0.8, label="seed 0")
    ax.plot(
        t, flat[:, :, i].mean(axis=0), color="C1", lw=1, label="mean, P0 = 1e6 I"
    )
    ax.axhline(theta_true.ravel()[i], color="k", ls="--", lw=1, label="true")
    ax.plot(list(PAPER), [PAPER[n][i] for n in PAPER], "ro", ms=4, label="paper")
    ax.set_ylim(theta_true.ravel()[i] - 0.15, theta_true.ravel()[i] + 0.15)
    ax.set_title(names[i])
for ax in axes[1]:
    ax.set_xlabel("N (samples)")
fig.legend(
    *axes[0, 0].get_legend_handles_labels(), loc="outside lower center", ncol=3
)
plt.show()
