"""Batched estimators and self-tuning controller: equal to B independent single runs.

``mode="exact"`` repeats the single implementation's numpy/BLAS/LAPACK calls on stacked arrays.
OpenBLAS picks its kernels by CPU (and a stacked ``(B, n, n)`` product may take another kernel
than a single ``(n, n)`` one), so the claim is "equal to rounding", not bit for bit: a last-bit
difference in a product, amplified by the conditioning of ``P`` (the paper's ``p0 = 1e6`` cancels
about 6 of the 16 digits in the first updates), stays below ``ROUNDING_RTOL`` relative.
"""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest

import stcgym.envs  # noqa: F401 - registers the single envs
from stcgym.adaptive.batched_controller import BatchedSelfTuningController
from stcgym.adaptive.batched_estimators import make_batched_estimator
from stcgym.adaptive.batched_fast import FastLoop
from stcgym.adaptive.controller import SelfTuningController
from stcgym.adaptive.recursive import make_estimator
from stcgym.envs.vector import ObservabilityCanonicalVectorEnv, ObserverCanonicalVectorEnv

#: Tolerance of "equal to rounding" between stacked and single BLAS/LAPACK calls (see above).
ROUNDING_RTOL = 1e-9

pytestmark = pytest.mark.equality

ENV_IDS = {
    "observer": "stcgym/ObserverCanonical-v0",
    "observability": "stcgym/ObservabilityCanonical-v0",
}


def _data(B: int, T: int, form: str, n: int = 2, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Recorded PRBS input / noisy output of B plants, shape (B, T)."""
    venv_cls = ObserverCanonicalVectorEnv if form == "observer" else ObservabilityCanonicalVectorEnv
    venv = venv_cls(num_envs=B, plant="stable2" if n == 2 else "stable4", noise_std=0.1)
    obs, _ = venv.reset(seed=seed)
    rng = np.random.default_rng(seed)
    U = rng.choice([-1.0, 1.0], size=(B, T))
    Y = np.empty((B, T))
    for k in range(T):
        Y[:, k] = obs[:, 0]
        obs, *_ = venv.step(U[:, k : k + 1])
    return U, Y


def _compare_estimators(
    mode: str,
    name: str,
    n: int,
    p: int,
    form: str,
    rtol: float,
    factory=make_batched_estimator,
    **kw,
):
    B, T = 3, 150
    U, Y = _data(B, T, form, n)
    batched = factory(name, n, num_envs=B, mode=mode, p=p, form=form, **kw)
    singles = [make_estimator(name, n, p=p, form=form, **kw) for _ in range(B)]
    for k in range(T):
        th = batched.update(Y[:, k])
        ths = np.array([s.update(Y[i, k]) for i, s in enumerate(singles)])
        x = batched.predict(U[:, k])
        xs = np.array([s.predict(U[i, k]) for i, s in enumerate(singles)])
        for got, want in (
            (th, ths),
            (x, xs),
            (batched.innovation, [s.innovation for s in singles]),
        ):
            want = np.asarray(want)
            scale = np.maximum(np.abs(want).max(axis=1, keepdims=True), 1e-300)
            assert np.all(np.abs(got - want) <= rtol * scale), (k, got, want)
    if batched.P is not None:
        P_ref = np.array([s.P for s in singles])
        scale = np.abs(P_ref).max(axis=(1, 2), keepdims=True)
        assert np.all(np.abs(batched.P - P_ref) <= max(rtol, 1e-300) * scale)
    assert batched.n_resets.tolist() == [s.n_resets for s in singles]


NAMES = [
    ("O-RLS", 1),
    ("KF-RLS", 1),
    ("O-MILS", 5),
    ("KF-MILS", 5),
    ("O-D-RLS", 1),
    ("KF-D-MILS", 3),
    ("O-SG", 1),
    ("KF-MISG", 3),
]


@pytest.mark.parametrize("form", ["observer", "observability"])
@pytest.mark.parametrize(("name", "p"), NAMES)
def test_exact_estimators_equal_to_rounding(name, p, form):
    """mode="exact" repeats the reference's BLAS/LAPACK calls on stacked arrays."""
    _compare_estimators("exact", name, 2, p, form, rtol=ROUNDING_RTOL)


def test_make_estimator_num_envs_routes_to_the_batched_lanes():
    """``make_estimator(..., num_envs=B)`` passes every setting through (here forgetting and
    the Kalman noise settings, which change the result) to B lanes equal to B single ones."""
    kw = dict(forgetting=0.98, process_noise=0.01 * np.eye(2), measurement_noise=0.5)
    _compare_estimators(
        "exact", "KF-MILS", 2, 3, "observer", ROUNDING_RTOL, factory=make_estimator, **kw
    )
    _compare_estimators(
        "fast", "O-RLS", 2, 1, "observer", 1e-12, factory=make_estimator, forgetting=0.98
    )
    with pytest.raises(ValueError, match="num_envs"):
        make_estimator("O-RLS", 2, mode="fast")


def test_self_tuning_controller_num_envs_builds_the_batched_controller():
    ctl = SelfTuningController(2, num_envs=4, estimator="O-RLS")
    assert isinstance(ctl, BatchedSelfTuningController) and ctl.num_envs == 4
    assert type(SelfTuningController(2, num_envs=2, mode="fast")).__name__.startswith("Fast")
    with pytest.raises(ValueError, match="num_envs"):
        SelfTuningController(2, mode="fast")
    single = SelfTuningController(2)
    assert type(single) is SelfTuningController


@pytest.mark.parametrize(("name", "p"), NAMES)
def test_fast_estimators_within_1e12(name, p):
    """mode="fast" evaluates the same equations in another order: 1e-12 relative with a
    moderate P(0) (the paper's p0 = 1e6 cancels ~6 digits in the first updates)."""
    _compare_estimators("fast", name, 2, p, "observer", rtol=1e-12, p0=100.0)


def test_fast_estimator_n4_and_forgetting():
    _compare_estimators("fast", "KF-MILS", 4, 3, "observer", rtol=1e-12, p0=100.0)
    _compare_estimators("exact", "KF-MILS", 2, 5, "observer", ROUNDING_RTOL, forgetting=0.98)


def test_health_recovery_matches_reference():
    """Overflowing data trigger the same covariance / state resets lane by lane."""
    B = 3
    kw = dict(p=3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for mode in ("exact", "fast"):
            be = make_batched_estimator("KF-MILS", 2, num_envs=B, mode=mode, **kw)
            ss = [make_estimator("KF-MILS", 2, **kw) for _ in range(B)]
            for k in range(25):
                y = np.array([0.1, 1e200 if k == 10 else 0.2, 1e300 if k > 15 else 0.1])
                u = np.array([1.0, 1e150 if k == 12 else -1.0, 1.0])
                be.update(y)
                be.predict(u)
                for i, s in enumerate(ss):
                    s.update(y[i])
                    s.predict(u[i])
            for key in ("n_resets", "n_state_resets", "n_kf_resets"):
                assert be.health[key].tolist() == [s.health[key] for s in ss], (mode, key)
            if mode == "exact":
                np.testing.assert_array_equal(be.theta, [s.theta for s in ss])


def test_scalar_kernels_equal_numpy_kernels():
    """The generated scalar code is bit-for-bit a numpy lane."""
    be = make_batched_estimator("KF-MILS", 2, num_envs=2, p=5, mode="fast")
    U, Y = _data(2, 120, "observer")
    lanes = [be.state.lane(i) for i in range(2)]
    for k in range(120):
        be.update(Y[:, k])
        be.predict(U[:, k])
        for i in range(2):
            S, K = lanes[i]
            S, _ = be._update.scalar(S, K, (Y[i, k],))
            S, _ = be._predict.scalar(S, K, (U[i, k],))
            lanes[i] = (S, K)
    for i in range(2):
        np.testing.assert_array_equal(np.array(lanes[i][0]), be.state.S[:, i])


def test_batched_estimator_errors():
    with pytest.raises(NotImplementedError):
        make_batched_estimator("KF-RLS", 2, num_envs=2, window=10)
    with pytest.raises(ValueError):
        make_batched_estimator("KF-RLS", 2, num_envs=0)
    be = make_batched_estimator("O-RLS", 2, num_envs=2)
    with pytest.raises(ValueError):
        be.update([0.0, np.nan])
    with pytest.raises(RuntimeError):
        be.predict([0.0, 0.0])


# ------------------------------------------------------------------------------ controller
def _closed_loop(mode, kw, plants, T, B=3, mes=250, seed=100):
    """Vector env (exact) + batched controller vs gym.make envs + single controllers.

    SAME_STEP autoreset on both sides; ``episode_start`` resets the controllers.
    Returns the largest relative difference of the actions and of theta.
    """
    form = kw.get("form", "observer")
    venv_cls = ObserverCanonicalVectorEnv if form == "observer" else ObservabilityCanonicalVectorEnv
    env_kw = dict(plant=list(plants), noise_std=0.05)
    seeds = [seed + i for i in range(B)]
    venv = venv_cls(
        num_envs=B, max_episode_steps=mes, autoreset_mode="SameStep", exact=True, **env_kw
    )
    ctl = BatchedSelfTuningController(2, num_envs=B, mode=mode, **kw)
    envs = [gym.make(ENV_IDS[form], max_episode_steps=mes, **env_kw) for _ in range(B)]
    singles = [SelfTuningController(2, **kw) for _ in range(B)]
    obs, _ = venv.reset(seed=seeds)
    sobs = np.array([e.reset(seed=s)[0] for e, s in zip(envs, seeds, strict=True)])
    start = np.ones(B, dtype=bool)
    du = dth = 0.0
    for _ in range(T):
        a, _ = ctl.predict(obs, episode_start=start)
        us = np.array(
            [s.predict(sobs[i], episode_start=start[i])[0][0] for i, s in enumerate(singles)]
        )
        du = max(du, float(np.max(np.abs(a[:, 0] - us) / np.maximum(1.0, np.abs(us)))))
        th = np.array([s.theta for s in singles])
        dth = max(dth, float(np.max(np.abs(ctl.theta - th) / np.maximum(1.0, np.abs(th)))))
        obs, _, term, trunc, _ = venv.step(a)
        start = term | trunc
        for i, e in enumerate(envs):
            o, _, te, tr, _ = e.step(a[i])
            if te or tr:
                o, _ = e.reset()
            sobs[i] = o
        if mode == "exact":
            np.testing.assert_allclose(obs, sobs, rtol=ROUNDING_RTOL, atol=1e-12)
    return du, dth, ctl, singles


CONTROLLER_CASES = [
    dict(),
    dict(estimator="O-RLS"),
    dict(estimator="KF-D-MILS", p=3, form="observability"),
    dict(estimator="KF-MISG", p=2, dither=0.1),
    dict(estimator="KF-RLS", integral=False, feedforward=False, filtered=False),
]


@pytest.mark.parametrize("kw", CONTROLLER_CASES)
def test_exact_controller_equals_single_runs(kw):
    """Vector env + exact batched controller = B single (env, controller) runs to rounding,
    over several episodes (hand-over, rejections, saturation, episode_start resets), with
    every discrete decision (rejections) the same."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        du, dth, ctl, singles = _closed_loop(
            "exact", kw, ("stable2", "unstable2", "nonminphase2"), T=420
        )
    assert du < 1e-8 and dth < 1e-8, (du, dth)
    assert ctl.n_rejected.tolist() == [s.n_rejected for s in singles]


def test_exact_controller_covariance_reset():
    """The change detector fires on timevarying2's jump; the restart replays the window."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        du, dth, ctl, singles = _closed_loop("exact", {}, ("timevarying2",), T=1150, B=2, mes=2000)
    assert du < 1e-8 and dth < 1e-8, (du, dth)
    assert ctl.n_covariance_resets.tolist() == [s.n_covariance_resets for s in singles]
    assert all(s.n_covariance_resets >= 1 for s in singles)


@pytest.mark.parametrize("kw", CONTROLLER_CASES[:3])
def test_fast_controller_close_to_single_runs(kw):
    """Same equations, another evaluation order: actions agree to ~1e-11 (the bootstrap
    estimator with p0 = 1e6 amplifies rounding); all discrete decisions agree."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        du, dth, ctl, singles = _closed_loop(
            "fast", kw, ("stable2", "unstable2", "nonminphase2"), T=420
        )
    assert du < 1e-8, du
    assert ctl.n_rejected.tolist() == [s.n_rejected for s in singles]
    assert ctl.n_handovers.tolist() == [s.n_handovers for s in singles]


def test_fast_loop_single_plant():
    """FastLoop is a lane of the fast batched controller bit for bit, and follows the single
    env + single controller to rounding."""
    loop = FastLoop(plant="stable2", noise_std=0.1, controller=dict(n=2, p=5), seed=3)
    ys, rs, us = loop.run(400)
    ctl = BatchedSelfTuningController(2, num_envs=1, mode="fast", p=5)
    ub = [ctl.predict(np.array([[y, r]]))[0][0, 0] for y, r in zip(ys, rs, strict=True)]
    np.testing.assert_array_equal(ub, us)
    env = gym.make("stcgym/ObserverCanonical-v0", plant="stable2", noise_std=0.1)
    single = SelfTuningController(2, p=5)
    obs, _ = env.reset(seed=3)
    uref = []
    for _ in range(400):
        u = single.predict(obs)[0]
        uref.append(u[0])
        obs, *_ = env.step(u)
    np.testing.assert_allclose(us, uref, rtol=1e-8, atol=1e-8)


def test_controller_api():
    ctl = BatchedSelfTuningController(2, num_envs=4, seed=[0, 1, 2, 3])
    a, state = ctl.predict(np.zeros((4, 2)), episode_start=np.ones(4, dtype=bool))
    assert a.shape == (4, 1) and state is None
    seq = np.hstack([ctl.predict(np.zeros((4, 2)))[0] for _ in range(12)])
    assert len({tuple(row) for row in seq}) == 4  # one PRBS seed per lane
    single = SelfTuningController(2, seed=2)
    single.predict(np.zeros(2))
    np.testing.assert_array_equal(seq[2], [single.predict(np.zeros(2))[0][0] for _ in range(12)])
    with pytest.raises(ValueError):
        ctl.predict(np.zeros((3, 2)))
    with pytest.raises(ValueError):
        ctl.predict(np.full((4, 2), np.nan))
    with pytest.raises(ValueError):
        BatchedSelfTuningController(2, num_envs=2, mode="gpu")
    fast = BatchedSelfTuningController(2, num_envs=4, mode="fast")
    assert fast.predict(np.zeros((4, 2)))[0].shape == (4, 1)
