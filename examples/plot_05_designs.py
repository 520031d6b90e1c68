"""
Pole placement, LQ and LQG on one plant
=======================================

The self-tuning controller designs its gain in one of two ways: pole placement (Ackermann
on the integral-augmented model, every closed-loop pole at a chosen place) or ``design="lq"``
(self-tuning LQ on the environment's cost ``(y - r)^2 + 0.01 u^2``). This example runs both
on the resonant plant ``lightly_damped2`` next to the two oracles that know the plant: the
known-model pole-placement controller and LQG, the optimal linear controller for that cost.
"""

# %%
# The controllers
# ---------------
# ``stcgym.agents.run_episode`` is the benchmark's own evaluation loop: it builds the
# environment of an ``EnvSpec`` afresh, resets it with the seed and runs the policy, so every
# controller meets the same noise and reference. ``run_episode`` takes a policy or a factory
# ``(plant, seed) -> policy``; the self-tuning controllers get the episode's seed for their
# start-up probe.
import matplotlib.pyplot as plt
import numpy as np

from stcgym.adaptive import (
    KnownModelController,
    LawOptions,
    LQGController,
    SelfTuningController,
)
from stcgym.agents import EnvSpec, run_episode
from stcgym.agents.benchmark import style
from stcgym.envs import get_plant

plt.rcParams.update(style.RC)  # the project's figure style: readable at page width

plant = get_plant("lightly_damped2")
radius = abs(plant.poles[0])
print(f"lightly_damped2: poles {np.round(plant.poles, 3)} (radius {radius:.3f})")
spec = EnvSpec(plants=("lightly_damped2",), steps=1000, noise_std=0.05, period=100)
POLES = 0.5  # all three closed-loop poles of the pole-placement designs

controllers = {
    "self-tuning, pole placement": lambda p, seed: SelfTuningController(
        2, poles=POLES, seed=seed
    ),
    "self-tuning LQ": lambda p, seed: SelfTuningController(
        2, design="lq", seed=seed
    ),
    "known model, pole placement": lambda p, seed: KnownModelController(
        p.a, p.b, poles=POLES
    ),
    "LQG (known model)": lambda p, seed: LQGController(
        p.a, p.b, law=LawOptions(integral=False), noise_std=spec.noise_std
    ),
}

# %%
# Five episodes each
# ------------------
# The cost is the mean per-step cost of the episode (start-up included) and of its second
# half (steady state), each divided by LQG's on the same episode.
seeds = range(5)
episodes = {
    name: [run_episode(f, spec, s) for s in seeds]
    for name, f in controllers.items()
}
lqg = episodes["LQG (known model)"]
ratio = {}
for name, eps in episodes.items():
    whole = np.array(
        [e.cost.mean() / q.cost.mean() for e, q in zip(eps, lqg, strict=True)]
    )
    steady = np.array(
        [
            e.cost[500:].mean() / q.cost[500:].mean()
            for e, q in zip(eps, lqg, strict=True)
        ]
    )
    effort = np.mean([np.mean(e.u**2) for e in eps])
    ratio[name] = whole
    print(
        f"{name:28s} episode cost / LQG {whole.mean():.3f} "
        f"(seeds {whole.min():.3f}-{whole.max():.3f}), "
        f"steady {steady.mean():.3f}, mean u^2 {effort:.3f}, "
        f"diverged {sum(e.diverged for e in eps)}"
    )

# %%
# One reference period, and the costs
# ------------------------------------
# Pole placement puts every closed-loop pole at 0.5 whatever the plant; LQ weighs tracking
# against the input, so on this resonant plant it chooses a different compromise. The
# self-tuning designs start from nothing and pay for their start-up in the episode cost.
# Each controller has its colour of the benchmark figures (``stcgym.agents.benchmark.style``).
keys = ["stc", "stc_lq", "oracle", "lqg"]
colors = {
    name: style.color(key) for name, key in zip(controllers, keys, strict=True)
}
fig, axes = plt.subplot_mosaic(
    [["y", "u"], ["cost", "cost"]],
    figsize=(style.WIDTH, 6),
    height_ratios=[3, 2],
    layout="constrained",
)
k = np.arange(400, 501)
ep0 = {name: eps[0] for name, eps in episodes.items()}
axes["y"].plot(k, ep0["LQG (known model)"].r[k], "k--", lw=1, label="reference r")
for i, (name, e) in enumerate(ep0.items()):  # the self-tuning controllers on top
    axes["y"].plot(k, e.y[k], color=colors[name], lw=1.2, label=name, zorder=9 - i)
    axes["u"].step(
        k[:-1], e.u[k[:-1]], where="post", color=colors[name], lw=1.2, zorder=9 - i
    )
axes["y"].set_title("y (noise-free), seed 0")
axes["u"].set_title("u")
for ax in (axes["y"], axes["u"]):
    ax.set_xlabel("step k")
names = list(ratio)
for i, name in enumerate(names):
    axes["cost"].scatter(
        np.full(len(ratio[name]), i), ratio[name], color=colors[name], s=14
    )
    axes["cost"].hlines(ratio[name].mean(), i - 0.3, i + 0.3, color=colors[name])
axes["cost"].set_xticks(range(len(names)), [n.replace(", ", ",\n") for n in names])
axes["cost"].axhline(1.0, color="k", lw=0.8)
axes["cost"].set_ylabel("episode cost / LQG")
fig.legend(
    *axes["y"].get_legend_handles_labels(), loc="outside lower center", ncol=3
)
plt.show()
