"""Self-tuning regulator, oracles and the policy protocol (stcgym.adaptive.controller et al.)."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest

import stcgym.envs  # noqa: F401  (registers the envs)
from stcgym.adaptive.controller import SelfTuningController, TrackingLaw
from stcgym.adaptive.oracles import KnownModelController, LQGController
from stcgym.adaptive.policy import Policy, StatefulPolicy
from stcgym.adaptive.recursive import make_estimator
from stcgym.envs import PLANTS
from stcgym.envs.canonical import companion_A

STEPS = 2000
A_S2, B_S2 = (-1.5, 0.7), (1.0, 0.5)  # stable2


def _env(plant: str = "stable2", steps: int = STEPS, **kw: object) -> gym.Env:
    return gym.make(
        "stcgym/ObserverCanonical-v0",
        plant=plant,
        noise_std=0.05,
        max_episode_steps=steps,
        **kw,
    )


def _episode(policy: object, env: gym.Env, seed: int, sync_oracle: bool = False) -> dict:
    """Run one episode; cost of step k is -reward (noise-free (y - r)^2 + rho u^2)."""
    obs, info = env.reset(seed=seed)
    policy.reset()
    steps = env.spec.max_episode_steps
    cost = np.full(steps, np.nan)
    y = np.full(steps, np.nan)
    r = np.full(steps, np.nan)
    for k in range(steps):
        if sync_oracle and not np.allclose(info["theta"], np.r_[policy.a, policy.b]):
            policy.set_model(info["a"], info["b"])  # the oracle knows parameter jumps
        action, _ = policy.predict(obs)
        obs, reward, terminated, _, info = env.step(action)
        cost[k], y[k], r[k] = -reward, info["y_clean"], obs[1]
        if terminated:
            return {"bounded": False, "cost": cost, "y": y, "r": r}
    return {"bounded": True, "cost": cost, "y": y, "r": r}


def _ratio(plant: str, seed: int, window: slice, **kw: object) -> tuple[float, dict]:
    spec = PLANTS[plant]
    env = _env(plant)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        res = _episode(SelfTuningController(spec.n, env=env, seed=seed, **kw), env, seed)
    assert res["bounded"], f"{plant} seed {seed} diverged"
    oracle = KnownModelController(spec.a, spec.b, action_bound=10.0)
    ref = _episode(oracle, env, seed, sync_oracle=True)
    return float(res["cost"][window].mean() / ref["cost"][window].mean()), res


# ----------------------------------------------------------------------------- closed loop
def test_stable2_closed_loop_bounded_and_tracks() -> None:
    ratio, res = _ratio("stable2", 0, slice(1000, 2000))
    assert ratio < 1.1
    # Offset-free: at the end of every half period (49 steps after an edge) y sits on r.
    ends = np.arange(1049, 2000, 50)
    err = np.abs(res["y"][ends - 1] - res["r"][ends - 1])
    assert err.max() < 0.05


@pytest.mark.parametrize(
    ("plant", "seed", "bound"),
    [
        ("stable2", 3, 1.25),
        ("lightly_damped2", 1, 1.25),
        ("unstable2", 2, 1.5),
        ("nonminphase2", 4, 1.5),
        ("integrator2", 5, 1.5),
    ],
)
def test_steady_window_cost_ratio_against_known_model(plant: str, seed: int, bound: float) -> None:
    ratio, _ = _ratio(plant, seed, slice(1000, 2000))
    assert ratio <= bound


def test_parameter_jump_is_tracked() -> None:
    ratio, _ = _ratio("timevarying2", 0, slice(1300, 1600), record=False)
    assert ratio <= 1.5


def test_jump_triggers_covariance_reset_and_new_estimates() -> None:
    env = _env("timevarying2")
    ctl = SelfTuningController(2, env=env, record=True)
    res = _episode(ctl, env, 1)
    assert res["bounded"] and ctl.n_covariance_resets >= 1
    resets = np.flatnonzero(ctl.history["reset"])
    assert 1000 <= resets[0] < 1050  # detected right after the jump, no false alarm before
    a_after = np.array([-1.2, 0.52])
    theta = ctl.history["theta"]
    assert np.abs(theta[-1, :2] - a_after).max() < np.abs(theta[999, :2] - a_after).max() / 2


def test_observability_form_env() -> None:
    env = gym.make(
        "stcgym/ObservabilityCanonical-v0", plant="stable2", noise_std=0.05, max_episode_steps=800
    )
    ctl = SelfTuningController(2, env=env)
    assert ctl.form == "observability"
    res = _episode(ctl, env, 0)
    assert res["bounded"] and np.nanmean(res["cost"][400:]) < 0.2


def test_integral_action_removes_offset_of_a_biased_model() -> None:
    """A frozen estimator 20 % off in b: no steady-state error with integral action, a clear one
    without it."""
    env = _env("stable2", steps=600, reference=1.0)
    finals = {}
    for integral in (True, False):
        est = make_estimator(
            "KF-RLS", 2, theta0=[-1.5, 0.7, 1.2, 0.6], enabled=False, process_noise=1e-4
        )
        ctl = SelfTuningController(2, estimator=est, integral=integral, excitation_steps=0, env=env)
        res = _episode(ctl, env, 0)
        finals[integral] = abs(np.mean(res["y"][-100:]) - 1.0)
    assert finals[True] < 0.01
    assert finals[False] > 0.05


def test_estimated_closed_loop_poles_are_the_designed_ones() -> None:
    est = make_estimator("KF-RLS", 2, theta0=[*A_S2, *B_S2], enabled=False, process_noise=1e-4)
    ctl = SelfTuningController(2, estimator=est, poles=[0.4, 0.5, 0.6], record=True)
    env = _env(steps=300)
    _episode(ctl, env, 0)
    h = ctl.history
    closed = ~h["open_loop"]
    assert closed.sum() > 100
    np.testing.assert_allclose(h["poles"][closed][-1], [0.4, 0.5, 0.6], atol=1e-6)
    assert h["theta"].shape == (300, 4) and h["K"].shape == (300, 3) and h["u"].shape == (300,)


# ----------------------------------------------------------------------------- safeguards
class _FakeEstimator:
    """Minimal estimator protocol with a settable model (for safe-set tests)."""

    def __init__(self, theta: list[float]) -> None:
        self.theta = np.array(theta, dtype=float)
        self.x_hat = np.zeros(2)
        self.e = 0.0

    def reset(self) -> None:
        self.x_hat = np.zeros(2)

    def update(self, y: float) -> np.ndarray:
        return self.theta.copy()

    def predict(self, u: float) -> np.ndarray:
        return self.x_hat


def test_safe_set_keeps_last_good_gain() -> None:
    est = _FakeEstimator([*A_S2, *B_S2])
    ctl = SelfTuningController(2, estimator=est, excitation_steps=0)
    ctl.predict(np.array([0.0, 1.0]))
    good = ctl.K
    assert ctl.law.has_gain and np.any(good != 0)
    for bad, reason in (
        ([*A_S2, 0.0, 0.0], "b_small"),  # no input gain
        ([-1.3, 0.4, 1.0, -0.5], "uncontrollable"),  # z^2-1.3z+0.4 = (z-0.5)(z-0.8); B = z-0.5
        # Zero at z = 1: the integral-augmented model loses controllability.
        ([-1.5, 0.7, 1.0, -1.0], "uncontrollable"),
    ):
        est.theta = np.array(bad)
        ctl.predict(np.array([0.0, 1.0]))
        assert not ctl.design_ok and ctl.last_rejection == reason
        np.testing.assert_array_equal(ctl.K, good)
    assert ctl.n_rejected == 3 and ctl.rejections == {"b_small": 1, "uncontrollable": 2}
    # Without integral action the same model is controllable but has no steady state for r.
    est_p = _FakeEstimator([-1.5, 0.7, 1.0, -1.0])
    ctl_p = SelfTuningController(2, estimator=est_p, excitation_steps=0, integral=False)
    ctl_p.predict(np.array([0.0, 1.0]))
    assert ctl_p.last_rejection == "dc_singular" and not ctl_p.law.has_gain


def test_excitation_phase_is_prbs_and_aborts_on_large_output() -> None:
    ctl = SelfTuningController(2, excitation_steps=30, excitation_amplitude=2.0)
    us = [ctl.predict(np.array([0.0, 1.0]))[0][0] for _ in range(20)]
    assert set(np.round(us, 12)) == {-2.0, 2.0} and ctl.open_loop
    ctl.predict(np.array([6.0, 1.0]))  # |y| > excitation_limit = 5: phase ends now
    assert ctl.diagnostics["excitation_end"] == 20 and ctl.n_excitation_aborts == 1
    assert ctl.n_handovers == 1


def test_anti_windup_freezes_integrator() -> None:
    A = companion_A(np.array(A_S2), "observer")
    laws = {
        aw: TrackingLaw(2, action_bound=0.05, anti_windup=aw, poles=0.5) for aw in (True, False)
    }
    for law in laws.values():
        assert law.design(A, np.array(B_S2))[0]
        for _ in range(200):
            law.control(np.zeros(2), y=0.0, r=1.0)  # plant "stuck": error never closes
        assert law.saturated
    assert laws[True].xi == 0.0  # saturated from the first step on: never integrated
    assert laws[False].xi == pytest.approx(200.0)


def test_start_window_with_and_without_excitation_phase_bounded() -> None:
    for steps in (0, 100):
        env = _env("unstable2", steps=400)
        res = _episode(SelfTuningController(2, env=env, excitation_steps=steps), env, 3)
        assert res["bounded"]


# ----------------------------------------------------------------------------- protocol
def test_policy_protocol_single_and_batch() -> None:
    ctl = SelfTuningController(2)
    assert isinstance(ctl, Policy) and isinstance(ctl, StatefulPolicy)
    action, state = ctl.predict(np.array([0.1, 1.0]))
    assert action.shape == (1,) and state is None
    # A batch: each row has its own copy of the controller; rows with equal inputs agree with a
    # fresh single controller fed the same sequence.
    batch = SelfTuningController(2)
    single = SelfTuningController(2)
    rng = np.random.default_rng(0)
    for _ in range(150):
        y = rng.normal()
        acts, _ = batch.predict(np.array([[y, 1.0], [y, 1.0], [0.0, 0.0]]))
        ref, _ = single.predict(np.array([y, 1.0]))
        assert acts.shape == (3, 1)
        assert acts[0, 0] == acts[1, 0] == ref[0]
    # episode_start resets that lane only.
    acts, _ = batch.predict(np.zeros((3, 2)), episode_start=np.array([True, False, False]))
    assert batch._lanes[0].t == 1 and batch._lanes[1].t == 151


def test_episode_start_resets_single() -> None:
    ctl = SelfTuningController(2)
    first = [ctl.predict(np.array([0.0, 1.0]))[0][0] for _ in range(5)]
    again = [ctl.predict(np.array([0.0, 1.0]), episode_start=(k == 0))[0][0] for k in range(5)]
    assert first == again and ctl.t == 5


def test_sb3_evaluate_policy_runs_the_controllers() -> None:
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.evaluation import evaluate_policy

    venv = make_vec_env(
        "stcgym/ObserverCanonical-v0",
        n_envs=2,
        seed=0,
        env_kwargs={"plant": "stable2", "noise_std": 0.05, "max_episode_steps": 300},
    )
    for policy in (
        SelfTuningController(2),
        KnownModelController(A_S2, B_S2),
        LQGController(A_S2, B_S2),
    ):
        mean, _ = evaluate_policy(policy, venv, n_eval_episodes=2, warn=False)
        assert np.isfinite(mean)


def test_oracles_track_without_offset_and_lqg_is_cheaper() -> None:
    env = _env(steps=1000)
    costs = {}
    for name, pol in (
        ("pp", KnownModelController(A_S2, B_S2, action_bound=10.0)),
        ("lqg", LQGController(A_S2, B_S2, control_cost=0.01, action_bound=10.0)),
    ):
        res = _episode(pol, env, 0)
        assert res["bounded"]
        # Offset-free: the last 20 samples of a half period average to r.
        assert abs(np.mean(res["y"][929:949] - res["r"][929:949])) < 0.02
        costs[name] = res["cost"][500:].mean()
    assert costs["lqg"] < costs["pp"]


def test_known_model_oracle_poles() -> None:
    orc = KnownModelController(A_S2, B_S2, poles=[0.3, 0.4, 0.5])
    Aa = np.block([[companion_A(np.array(A_S2)), np.zeros((2, 1))], [np.array([[-1.0, 0.0, 1.0]])]])
    ba = np.array([*B_S2, 0.0])
    eig = np.linalg.eigvals(Aa - np.outer(ba, orc.K))
    np.testing.assert_allclose(np.sort(eig.real), [0.3, 0.4, 0.5], atol=1e-8)


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"poles": 1.1}, "unit circle"),
        ({"poles": [0.5, 0.5]}, "exactly 3"),
        ({"poles": [0.5, 0.5], "integral": False, "feedforward": True}, None),
        ({"estimator": "KF-FOO"}, "unknown algorithm"),
        ({"estimator": "RLS"}, "unknown algorithm"),
        ({"excitation_steps": -1}, "excitation_steps"),
        ({"dither": -0.1}, "dither"),
        ({"action_bound": -1.0}, "action_bound"),
        ({"process_noise": "big"}, "process_noise"),
    ],
)
def test_bad_construction(kwargs: dict, match: str | None) -> None:
    if match is None:
        SelfTuningController(2, **kwargs)  # n poles without integral action is fine
        return
    with pytest.raises(ValueError, match=match):
        SelfTuningController(2, **kwargs)


def test_env_mismatch_is_rejected() -> None:
    env = _env("stable4", steps=10)
    with pytest.raises(ValueError, match="n=2 does not match the env's plant order n=4"):
        SelfTuningController(2, env=env)
    with pytest.raises(ValueError, match="exceeds the env's action_bound"):
        SelfTuningController(4, env=env, action_bound=20.0)
    with pytest.raises(ValueError, match="form"):
        SelfTuningController(4, env=env, form="observability")
    assert SelfTuningController(4, env=env).law.action_bound == 10.0
    with pytest.raises(ValueError):
        SelfTuningController(0)


def _snapshot(ctl: SelfTuningController) -> tuple:
    est = ctl.estimator
    return (
        ctl.t,
        ctl.law.xi,
        ctl.K.tobytes(),
        est.theta.tobytes(),
        est.x_hat.tobytes(),
        est.P.tobytes(),
        ctl._prbs.state,
        ctl._boot.theta.tobytes(),
        repr(ctl.diagnostics),
    )


@pytest.mark.parametrize(
    "bad", [[np.nan, 1.0], [0.0, np.inf], [[0.0, 1.0], [np.nan, 0.0]], [0.0, 1.0, 2.0], [[1.0]]]
)
def test_bad_observation_raises_and_leaves_state(bad: list) -> None:
    env = _env(steps=150)
    ctl = SelfTuningController(2, env=env, excitation_steps=20)
    obs, _ = env.reset(seed=0)
    for _ in range(120):  # past the excitation phase: estimator, gains and integrator live
        obs = env.step(ctl.predict(obs)[0])[0]
    before = _snapshot(ctl)
    with pytest.raises(ValueError, match="observation"):
        ctl.predict(np.array(bad, dtype=object).astype(float) if np.ndim(bad) else bad)
    assert _snapshot(ctl) == before
    ctl.predict(obs)  # still usable


def test_oracle_bad_input() -> None:
    with pytest.raises(ValueError, match="unit circle"):
        KnownModelController(A_S2, B_S2, poles=[0.5, 0.5, 1.0])
    with pytest.raises(ValueError, match="same length"):
        KnownModelController([-1.5, 0.7], [1.0])
    with pytest.raises(ValueError, match="control_cost"):
        LQGController(A_S2, B_S2, control_cost=0.0)
    orc = KnownModelController(A_S2, B_S2)
    with pytest.raises(ValueError, match="finite"):
        orc.predict(np.array([np.nan, 0.0]))
    assert orc.t == 0
