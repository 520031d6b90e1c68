"""
A parameter jump and re-convergence
===================================

A ``Jumps`` schedule changes the plant's parameters during an episode: here ``stable2``
becomes ``unstable2`` (a pole at 1.1) at step 1000. The catalogue plant ``timevarying2`` is
another such jump, built in. The self-tuning controller notices the jump through its change
detector (the short-term innovation power rises above the long-term one), inflates the
estimator's covariance and re-converges. It is compared with the same controller without
change detection and with the *informed oracle*: the known-model controller told the new
parameters at the very step they change.
"""

# %%
# The plant and its jump
# ----------------------
# The true parameters in force are in ``info["theta"]`` at every step, which is how the
# oracle below learns of the jump (a real controller cannot see them).
import gymnasium as gym
import matplotlib.pyplot as plt
import numpy as np

import stcgym.envs  # noqa: F401
from stcgym.adaptive import (
    ChangeDetection,
    KnownModelController,
    SelfTuningController,
)
from stcgym.agents.benchmark import style
from stcgym.envs import Jumps, get_plant

plt.rcParams.update(style.RC)  # the project's figure style: readable at page width

T, JUMP = 1500, 1000
POLES = [0.5, 0.5, 0.5]
AFTER = get_plant("unstable2").theta  # [a1, a2, b1, b2] from step 1000 on


def make_env():
    return gym.make(
        "stcgym/ObserverCanonical-v0",
        plant="stable2",
        schedule=Jumps({JUMP: AFTER}),
        noise_std=0.05,
        reference={"kind": "square", "period": 100},
        max_episode_steps=T,
    )


def episode(policy, informed=False, seed=3):
    """One episode: noise-free y, r, u, the policy's theta and the true theta, the
    costs.

    With ``informed`` the policy (a known-model controller) is switched to the true
    parameters whenever they change.
    """
    env = make_env()
    obs, info = env.reset(seed=seed)
    policy.reset()
    y, r, u, theta_hat, theta, cost = (
        [info["y_clean"]],
        [obs[1]],
        [],
        [],
        [info["theta"]],
        [],
    )
    known = info["theta"]
    for k in range(T):
        if informed and not np.array_equal(info["theta"], known):
            known = info["theta"]
            policy.set_model(info["a"], info["b"])
            print(f"the oracle is told the new parameters before choosing u({k})")
        action, _ = policy.predict(obs)
        obs, reward, terminated, truncated, info = env.step(action)
        y.append(info["y_clean"])
        r.append(obs[1])
        u.append(float(action[0]))
        theta.append(info["theta"])
        theta_hat.append(
            np.array(getattr(policy, "theta", np.full(4, np.nan)), dtype=float)
        )
        cost.append(-reward)
        if terminated or truncated:
            break
    env.close()
    traces = [np.array(v) for v in (y, r, u, theta_hat, theta, cost)]
    return dict(
        zip(["y", "r", "u", "theta_hat", "theta", "cost"], traces, strict=True)
    )


env = make_env()
_, info = env.reset(seed=3)
print(f"before the jump: a = {info['a']}, b = {info['b']}")

# %%
# Three controllers on the same noise and reference
# -------------------------------------------------
runs = {
    "self-tuning": episode(SelfTuningController(2, poles=POLES, env=env)),
    "no change detection": episode(
        SelfTuningController(
            2, poles=POLES, env=env, change_detection=ChangeDetection(enabled=False)
        )
    ),
    "informed oracle": episode(
        KnownModelController(info["a"], info["b"], poles=POLES, env=env),
        informed=True,
    ),
}
after = runs["informed oracle"]["theta"][-1]
print(f"after the jump:  a = {after[:2]}, b = {after[2:]}")
poles_before, poles_after = get_plant("stable2").poles, np.roots([1.0, *after[:2]])
print(f"open-loop poles before {np.round(poles_before, 3)}")
print(f"open-loop poles after {np.round(poles_after, 3)}")
oracle_cost = runs["informed oracle"]["cost"]


def ratio(cost, lo, hi):
    return cost[lo:hi].sum() / oracle_cost[lo:hi].sum()


for name in ("self-tuning", "no change detection"):
    c = runs[name]["cost"]
    print(
        f"{name:20s} cost / informed oracle: "
        f"steps 500-1000 {ratio(c, 500, JUMP):.3f}, "
        f"1000-1100 {ratio(c, JUMP, JUMP + 100):.3f}, "
        f"1100-1500 {ratio(c, JUMP + 100, T):.3f}"
    )


# %%
# Re-convergence
# --------------
# The cost per reference period (100 steps) over the oracle's: a controller has
# re-converged when it is back within 1.2x for good. Without change detection the
# estimator's covariance has shrunk over the first 1000 steps, so it adapts to the new plant
# slowly, and the loop, designed for the old plant, runs badly meanwhile.
def per_period(cost):
    return cost[: len(cost) // 100 * 100].reshape(-1, 100).sum(axis=1)


periods = np.arange(0, T, 100)
for name in ("self-tuning", "no change detection"):
    rel = per_period(runs[name]["cost"]) / per_period(oracle_cost)
    outside = np.flatnonzero(rel[JUMP // 100 :] > 1.2)
    first_good = JUMP + 100 * (outside[-1] + 1 if outside.size else 0)
    when = (
        f"from step {first_good} on"
        if first_good < T
        else "not again in this episode"
    )
    print(f"{name:20s} within 1.2x of the informed oracle per period: {when}")

# Each controller has its colour of the benchmark figures
# (``stcgym.agents.benchmark.style``).
COLORS = {
    name: style.color(key)
    for name, key in zip(runs, ["stc", "stc_nocd", "oracle"], strict=True)
}
fig, axes = plt.subplots(
    2, 1, figsize=(style.WIDTH, 5.5), sharex=True, layout="constrained"
)
ax = axes[0]
ax.plot(runs["self-tuning"]["r"], "k--", lw=1, label="reference r")
for name in runs:
    ax.plot(runs[name]["y"], color=COLORS[name], lw=1, label=name)
ax.axvline(JUMP, color="k", lw=3, alpha=0.25, label="jump")
ax.set_xlim(800, T)
ax.set_ylabel("y (noise-free)")
ax = axes[1]
for name in ("self-tuning", "no change detection"):
    rel = per_period(runs[name]["cost"]) / per_period(oracle_cost)
    ax.step(periods + 100, rel, where="pre", color=COLORS[name], label=name)
ax.axhline(1.2, color="k", ls=":", lw=1, label="1.2x the oracle")
ax.axvline(JUMP, color="k", lw=3, alpha=0.25)
ax.set_yscale("log")
ax.set_ylabel("cost per period / oracle")
ax.set_xlabel("step k")
handles = {}
for ax in axes:
    handles.update(zip(*reversed(ax.get_legend_handles_labels()), strict=True))
fig.legend(handles.values(), handles.keys(), loc="outside lower center", ncol=3)

# %%
# The estimates follow the new parameters
# ---------------------------------------
# The self-tuning controller's and the one without change detection, the truth dashed.
labels = ["a1", "a2", "b1", "b2"]
fig, axes = plt.subplots(
    2, 2, figsize=(style.WIDTH, 4.5), sharex=True, layout="constrained"
)
for i, ax in enumerate(axes.flat):
    for name in ("self-tuning", "no change detection"):
        ax.plot(runs[name]["theta_hat"][:, i], color=COLORS[name], lw=1, label=name)
    truth = runs["self-tuning"]["theta"][:, i]
    ax.plot(truth, "k--", lw=1, label="true")
    ax.set_ylim(truth.min() - 0.4, truth.max() + 0.4)
    ax.set_title(labels[i])
    ax.set_xlim(800, T)
for ax in axes[1]:
    ax.set_xlabel("t")
fig.legend(
    *axes[0, 0].get_legend_handles_labels(), loc="outside lower center", ncol=3
)
plt.show()
