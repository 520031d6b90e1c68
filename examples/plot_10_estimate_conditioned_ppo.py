"""
Estimate-conditioned PPO against the self-tuning controller
===========================================================

Does an RL agent do better on plants it has not seen when it is given what an
online estimator knows? ``theta_ppo`` is PPO whose observation is its window of past
signals followed by the online estimate of the paper's O-RLS estimator running on
the same data (``theta_hat``, ``log10 diag P``, the innovation). Here it trains on a
small family of three catalogue plants, one drawn per episode, and meets the
self-tuning controller on those plants and on two it never saw.

The training budget is tiny, so that the example runs in about a minute: **it does
not train the agent to convergence**, and the numbers say nothing about what it
reaches with a real budget. The benchmark (``stcgym bench``, see :doc:`the RL
baselines page </rl_baselines>`) trains it to a plateau with several seeds, beside
PPO without the estimate and residual RL on the controller, and answers from those
numbers whether the controller's advantage is its identification or its design.
"""

# %%
# A small family and a short budget
# ---------------------------------
# ``default_config("theta_ppo")`` is PPO's recipe with the estimate among the
# inputs. The estimator is told the plant order (2), as the self-tuning controller
# is.
import matplotlib.pyplot as plt
import numpy as np

from stcgym.adaptive import SelfTuningController
from stcgym.agents import CurveOptions, EnvSpec, default_config, train_agent
from stcgym.agents.benchmark import style
from stcgym.agents.controllers import controller_seeds
from stcgym.agents.evaluation.episodes import EpisodeSet, run_episodes

plt.rcParams.update(style.RC)  # the project's figure style: readable at page width

seen = ("stable2", "unstable2", "integrator2")
unseen = ("lightly_damped2", "nonminphase2")
reference = {"kind": "random_steps", "amplitude": 1.0, "hold": [50, 150]}
settings = dict(steps=400, noise_std=0.05, action_bound=5.0, reference=reference)
train = EnvSpec(plants=seen, **settings)
config = default_config("theta_ppo")
config.hyperparams.update(n_steps=512)
agent = train_agent(
    "theta_ppo",
    config,
    train,
    steps=8192,
    seed=0,
    curve=CurveOptions(
        episodes=EpisodeSet(seen, (10_000, 10_001, 10_002)), points=3
    ),
    progress=False,
)
print(f"theta_ppo: {agent.steps} steps in {agent.wall_s:.0f} s, kept the "
      f"checkpoint of step {agent.best_step}")  # fmt: skip

# %%
# The same episodes for both
# --------------------------
# Two episodes on each plant, the seen and the unseen ones. The controller's probe
# is seeded per episode as the benchmark seeds it.
test = EnvSpec(plants=seen + unseen, **settings)
plants = tuple(p for p in seen + unseen for _ in range(2))
episodes = EpisodeSet(plants, tuple(range(100, 100 + len(plants))))


def self_tuning(lanes, seeds):
    return SelfTuningController(
        2, num_envs=len(lanes), action_bound=5.0, seed=controller_seeds(seeds, 0)
    )


rl = run_episodes(lambda p, s: agent.policy.with_lanes(len(p), s), test, episodes)
stc = run_episodes(self_tuning, test, episodes)
for name in seen + unseen:
    lanes = [i for i, p in enumerate(plants) if p == name]
    a, b = rl.cost[lanes].mean(), stc.cost[lanes].mean()
    tag = "seen" if name in seen else "unseen"
    print(f"{name:16s} ({tag:6s}) cost per step: theta_ppo {a:9.4g}, stc {b:.4g}")

# %%
# What the agent is given
# -----------------------
# Left: both on the first episode of an unseen plant. Right: the estimate among the
# agent's inputs on that episode (``policy.lanes.theta_hat``) against the true
# parameters. The estimator learns only from what the inputs excite: an agent whose
# input barely moves the plant gives it little to go on, where the controller's
# probe and steps give its own estimator a clear response.
policy = agent.policy.with_lanes(None)
policy.reset()
env = test.make()
obs, info = env.reset(seed=episodes.seeds[6], options={"plant": unseen[0]})
estimates = []
for _ in range(test.steps):
    action, _ = policy.predict(obs)
    estimates.append(policy.lanes.theta_hat[0].copy())
    obs, *_ = env.step(action)
estimates = np.array(estimates)

fig, axes = plt.subplots(1, 2, figsize=(style.WIDTH, 4.2), layout="constrained")
ax = axes[0]
ax.plot(rl.r[6], "k--", lw=1, label="reference r")
ax.plot(rl.y[6], color=style.color("theta_ppo"), lw=1.2, label="theta_ppo")
ax.plot(stc.y[6], color=style.color("stc"), lw=1.2, label="self-tuning")
ax.set(xlabel="step k", ylabel="y (noise-free)", title=f"{unseen[0]} (unseen)")
ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.18), ncol=2)
ax = axes[1]
labels = ["a1", "a2", "b1", "b2"]
# colours unlike the controllers' of the left panel
for j, (label, color) in enumerate(
    zip(labels, ["C4", "C5", "C2", "C3"], strict=True)
):
    ax.plot(estimates[:, j], color=color, lw=1.2, label=label)
    ax.axhline(info["theta"][j], color=color, ls="--", lw=1)
ax.set(xlabel="step k", ylabel="O-RLS estimate", title="estimates (dashed: true)")
ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.18), ncol=4)
plt.show()
