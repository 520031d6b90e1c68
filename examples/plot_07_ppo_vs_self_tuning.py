"""
PPO against the self-tuning controller
======================================

Train a PPO agent (stable-baselines3) on ``stable2`` and compare it with the self-tuning
controller and the known-model oracle on the same evaluation episodes. The agent observes a
short window of past outputs, references and inputs, never the plant state; the self-tuning
controller sees only ``[y, r]`` and learns the plant within the episode.

The training budget here is tiny, so that the example runs in seconds: **it does not train
PPO to convergence**, and the numbers below say nothing about what PPO reaches with a real
budget. The benchmark (``stcgym bench``, see :doc:`the benchmark page </benchmark>`)
trains PPO, SAC and RecurrentPPO with several seeds and longer budgets and reports the
comparison with confidence intervals.
"""

# %%
# Training
# --------
# ``train_agent`` takes the algorithm's default configuration (``default_config``: RL Zoo
# Pendulum-style hyperparameters, an observation window with the integral of the tracking
# error, the scored cost as the training reward) and records a learning curve: the cost per
# step of the deterministic policy on validation episodes at log-spaced training steps. Like
# the RL Zoo's best-model callback it keeps the checkpoint with the lowest validation cost,
# which with so few steps may be an early one.
import matplotlib.pyplot as plt
import numpy as np

from stcgym.adaptive import KnownModelController, SelfTuningController
from stcgym.agents import (
    CurveOptions,
    EnvSpec,
    default_config,
    run_episode,
    train_agent,
)
from stcgym.agents.benchmark import style
from stcgym.agents.evaluation.episodes import EpisodeSet

plt.rcParams.update(style.RC)  # the project's figure style: readable at page width

spec = EnvSpec(plants=("stable2",), steps=300, noise_std=0.05, period=100)
config = default_config("ppo")
validation = EpisodeSet(plants=("stable2",), seeds=(10_000,))
agent = train_agent(
    "ppo",
    config,
    spec,
    steps=4096,
    seed=0,
    curve=CurveOptions(episodes=validation, points=3),
    progress=False,
)
print(f"PPO: {agent.steps} environment steps in {agent.wall_s:.1f} s")
for step, cost in agent.curve:
    print(f"  after {step:5d} training steps: validation cost per step {cost:.4f}")
print(f"checkpoint kept (lowest validation cost): after {agent.best_step} steps")

# %%
# Evaluation on the same episodes
# -------------------------------
# ``run_episode`` builds the environment afresh for each seed, so the three controllers meet
# the same noise and reference. The oracle is told the true parameters.
controllers = {
    "PPO (short budget)": lambda p, seed: agent.policy,
    "self-tuning": lambda p, seed: SelfTuningController(p.n, seed=seed),
    "oracle": lambda p, seed: KnownModelController(p.a, p.b),
}
seeds = range(3)
episodes = {
    name: [run_episode(f, spec, s) for s in seeds]
    for name, f in controllers.items()
}
oracle = episodes["oracle"]
for name, eps in episodes.items():
    ratio = [
        e.cost.mean() / o.cost.mean() for e, o in zip(eps, oracle, strict=True)
    ]
    print(
        f"{name:20s} episode cost / oracle: mean {np.mean(ratio):.3f} "
        f"(seeds {min(ratio):.3f}-{max(ratio):.3f}), "
        f"diverged {sum(e.diverged for e in eps)}"
    )

# %%
# Traces and the learning curve
# -----------------------------
# Left: the noise-free output of each controller on seed 0. Right: PPO's validation cost
# against its training steps (step 0 drawn at 1), with the self-tuning controller's and the
# oracle's cost on the same validation episode as dashed lines (the self-tuning controller
# needs no training data). Each controller has the colour it has in every figure of the
# benchmark (``stcgym.agents.benchmark.style``).
colors = {
    "PPO (short budget)": style.color("ppo"),
    "self-tuning": style.color("stc"),
    "oracle": style.color("oracle"),
}
validation_cost = {
    name: run_episode(f, spec, 10_000).cost.mean()
    for name, f in controllers.items()
    if name != "PPO (short budget)"
}
fig, axes = plt.subplots(
    1, 2, figsize=(style.WIDTH, 3.6), width_ratios=[2, 1], layout="constrained"
)
ax = axes[0]
ax.plot(oracle[0].r, "k--", lw=1, label="reference")
for name, eps in episodes.items():
    ax.plot(eps[0].y, color=colors[name], lw=1.2, label=name)
ax.set_xlabel("step k")
ax.set_ylabel("y (noise-free)")
ax = axes[1]
steps, costs = np.array(agent.curve).T
ax.plot(np.maximum(steps, 1), costs, "o-", color=colors["PPO (short budget)"])
for name, cost in validation_cost.items():
    ax.axhline(cost, color=colors[name], ls="--")
ax.set_xscale("log")
ax.set_yscale("log")
ax.set_xlabel("training steps")
ax.set_ylabel("validation cost per step")
fig.legend(*axes[0].get_legend_handles_labels(), loc="outside upper center", ncol=4)
plt.show()
