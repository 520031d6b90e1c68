"""
A first environment and a hand-written controller
=================================================

Build a catalogue plant as a Gymnasium environment, close the loop with a few lines of
discrete PI control written by hand, and plot the output ``y``, the reference ``r`` and the
input ``u``. Nothing here is adaptive: the gains are chosen for this one plant.
"""

# %%
# The environment
# ---------------
# ``import stcgym.envs`` registers the ``stcgym/`` ids. ``stable2`` is a well-damped
# second-order plant; the output is measured with noise of standard deviation 0.05 and the
# reference is a square wave of period 100 samples. At step ``k`` the agent sees
# ``obs = [y(k), r(k)]`` and applies ``u(k)``.
import gymnasium as gym
import matplotlib.pyplot as plt
import numpy as np

import stcgym.envs  # noqa: F401  (registers the stcgym/ environments)
from stcgym.agents.benchmark import style
from stcgym.envs import get_plant

plt.rcParams.update(style.RC)  # the project's figure style: readable at page width

T = 300
env = gym.make(
    "stcgym/ObserverCanonical-v0",
    plant="stable2",
    noise_std=0.05,
    reference={"kind": "square", "period": 100},
    max_episode_steps=T,
)
plant = get_plant("stable2")
print(f"stable2: a = {plant.a}, b = {plant.b}, poles {np.round(plant.poles, 3)}")
print(f"DC gain {plant.dc_gain:.2f}, observation space {env.observation_space}")

# %%
# A hand-written PI controller
# ----------------------------
# The velocity form ``u(k) = u(k-1) + kp (e(k) - e(k-1)) + ki e(k)`` with ``e = r - y``.
# The plant's DC gain is large, so the gains are small; the integral term removes the
# steady-state offset.
kp, ki = 0.1, 0.035

obs, info = env.reset(seed=0)
y, y_clean, r, u = [obs[0]], [info["y_clean"]], [obs[1]], []
u_prev, e_prev, total_reward = 0.0, 0.0, 0.0
for _ in range(T):
    e = obs[1] - obs[0]
    u_k = u_prev + kp * (e - e_prev) + ki * e
    obs, reward, terminated, truncated, info = env.step(np.array([u_k]))
    total_reward += reward
    y.append(obs[0])
    y_clean.append(info["y_clean"])
    r.append(obs[1])
    u.append(u_k)
    u_prev, e_prev = u_k, e
    if terminated or truncated:
        break
env.close()

y, y_clean, r, u = np.array(y), np.array(y_clean), np.array(r), np.array(u)
mean_cost = -total_reward / len(u)
print(f"steps run {len(u)}, diverged {info['diverged']}")
print(f"mean cost per step {mean_cost:.4f}")
error = np.mean(np.abs(y_clean[-20:] - r[-20:]))
print(f"mean |y_clean - r| over the last 20 steps: {error:.3f}")
print(f"true parameters at the end (info['theta']): {info['theta']}")

# %%
# The closed loop
# ---------------
# The output follows each reference step after a short transient. The measurement noise
# enters ``u`` through the controller, and the plant's large gain turns it back into ripple
# on the noise-free output ``y_clean`` (``info["y_clean"]``, the signal the reward scores):
# gains fixed by hand trade tracking speed against that ripple.
fig, (ax_y, ax_u) = plt.subplots(
    2, 1, sharex=True, figsize=(style.WIDTH, 5), layout="constrained"
)
ax_y.plot(y, color="0.7", lw=0.8, label="y (measured)")
ax_y.plot(y_clean, label="y_clean")
ax_y.plot(r, "k--", label="reference r")
ax_y.set_ylabel("output")
ax_u.step(np.arange(len(u)), u, where="post", color="C2")
ax_u.set_ylabel("u")
ax_u.set_xlabel("step k")
fig.suptitle("stable2 under a hand-written PI controller")
fig.legend(loc="outside lower center", ncol=3)
plt.show()
