"""
The self-tuning controller on an unstable plant
===============================================

``unstable2`` has a real pole at 1.1: without feedback its output grows without bound. The
self-tuning controller knows only the plant order. Every sample it updates its estimate of
``theta = [a; b]``, designs a pole-placement gain on that estimate and applies it; for the
first few samples it probes the plant with a small input. This example runs one episode,
plots ``y``, ``r`` and ``u`` with the known-model oracle for comparison, and the estimates
against the true parameters.
"""

# %%
# One episode through the policy protocol
# ---------------------------------------
# ``SelfTuningController`` follows the ``predict``/``reset`` protocol of stable-baselines3
# models: ``action, _ = ctl.predict(obs)``. The closed-loop poles are all at 0.5.
import gymnasium as gym
import matplotlib.pyplot as plt
import numpy as np

import stcgym.envs  # noqa: F401
from stcgym.adaptive import KnownModelController, SelfTuningController
from stcgym.agents.benchmark import style
from stcgym.envs import get_plant

plt.rcParams.update(style.RC)  # the project's figure style: readable at page width

T = 600
POLES = [0.5, 0.5, 0.5]
print(f"unstable2: open-loop poles {np.round(get_plant('unstable2').poles, 3)}")


def make_env():
    return gym.make(
        "stcgym/ObserverCanonical-v0",
        plant="unstable2",
        noise_std=0.05,
        reference={"kind": "square", "period": 100},
        max_episode_steps=T,
    )


def episode(policy, seed=1):
    """Run one episode; return y_clean, r, u, the policy's theta per step and the
    costs."""
    env = make_env()
    obs, info = env.reset(seed=seed)
    policy.reset()
    y, r, u, theta_hat, cost = [info["y_clean"]], [obs[1]], [], [], []
    for _ in range(T):
        action, _ = policy.predict(obs)
        obs, reward, terminated, truncated, info = env.step(action)
        y.append(info["y_clean"])
        r.append(obs[1])
        u.append(float(action[0]))
        theta_hat.append(
            np.array(getattr(policy, "theta", np.full(4, np.nan)), dtype=float)
        )
        cost.append(-reward)
        if terminated or truncated:
            break
    env.close()
    return (
        np.array(y),
        np.array(r),
        np.array(u),
        np.array(theta_hat),
        np.array(cost),
        info,
    )


env = make_env()
ctl = SelfTuningController(2, poles=POLES, env=env)
y, r, u, theta_hat, cost, info = episode(ctl)
theta_true = info["theta"]
d = ctl.diagnostics
print(f"diverged: {info['diverged']}; loop closed at t = {d['closed_at']}")
print(f"probe samples {d['n_probe']}")
print(f"designs rejected by the safe set {d['n_rejected']}")
print(f"final estimate {np.round(ctl.theta, 3)}, true {theta_true}")

# %%
# The oracle: the same design on the true parameters
# --------------------------------------------------
# ``KnownModelController`` is told ``a`` and ``b``; the ratio of the two costs is what the
# self-tuning controller pays for not knowing them.
oracle = KnownModelController(info["a"], info["b"], poles=POLES, env=env)
y_o, r_o, u_o, _, cost_o, _ = episode(oracle)
print(
    f"mean cost per step: self-tuning {cost.mean():.4f}, oracle {cost_o.mean():.4f}"
)
print(
    f"ratio over the whole episode {cost.sum() / cost_o.sum():.3f}, "
    f"steps 0-100 {cost[:100].sum() / cost_o[:100].sum():.3f}, "
    f"steps 100- {cost[100:].sum() / cost_o[100:].sum():.3f}"
)

# %%
# Traces
# ------
# The noise-free output ``y`` of both controllers, the reference and the inputs. The right
# column zooms on the first 60 samples: the probe, then the first designs on a young
# estimate. Each controller has its colour of every benchmark figure
# (``stcgym.agents.benchmark.style``).
STC, ORACLE = style.color("stc"), style.color("oracle")
fig, axes = plt.subplots(
    2,
    2,
    figsize=(style.WIDTH, 5),
    sharey="row",
    width_ratios=[3, 1],
    layout="constrained",
)
for col, stop in enumerate([T, 60]):
    k = np.arange(stop + 1)
    axes[0, col].plot(k, r[: stop + 1], "k--", lw=1, label="reference r")
    axes[0, col].plot(k, y_o[: stop + 1], color=ORACLE, label="oracle")
    axes[0, col].plot(k, y[: stop + 1], color=STC, label="self-tuning")
    axes[1, col].step(k[:-1], u_o[:stop], where="post", color=ORACLE)
    axes[1, col].step(k[:-1], u[:stop], where="post", color=STC)
    axes[1, col].set_xlabel("step k")
axes[0, 0].set_ylabel("y (noise-free)")
axes[1, 0].set_ylabel("u")
axes[0, 0].set_title("the episode")
axes[0, 1].set_title("first 60 steps")
fig.legend(
    *axes[0, 0].get_legend_handles_labels(), loc="outside lower center", ncol=3
)

# %%
# Estimates against the truth
# ---------------------------
# The default estimator is extended least squares (``"ELS"``), which models the noise and
# stays consistent in closed loop.
labels = ["a1", "a2", "b1", "b2"]
fig, axes = plt.subplots(
    2, 2, figsize=(style.WIDTH, 4.5), sharex=True, layout="constrained"
)
for i, ax in enumerate(axes.flat):
    ax.plot(theta_hat[:, i], color=STC, label="self-tuning estimate")
    ax.axhline(theta_true[i], color="k", ls="--", lw=1, label="true")
    ax.set_title(labels[i])
    ax.set_xscale("symlog", linthresh=10)
for ax in axes[1]:
    ax.set_xlabel("t")
fig.legend(
    *axes[0, 0].get_legend_handles_labels(), loc="outside lower center", ncol=2
)
plt.show()
