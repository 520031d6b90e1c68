"""The test plant of the recursive-estimator tests, simulated by python-control, with its true
states and regressors (the independent side of the comparisons)."""

from __future__ import annotations

import control
import numpy as np

from stcgym.envs.canonical import canonical_matrices

FORMS = ("observer", "observability")
# A well-damped stable plant (poles 0.3 +- 0.33i) used for the convergence checks.
A_TRUE = np.array([-0.6, 0.2])
B_TRUE = np.array([0.5, 1.0])
THETA_TRUE = np.r_[A_TRUE, B_TRUE]


def simulate(a, b, form, u, noise_std=0.0, seed=0):
    """States ``X[:, k] = x(k+1)`` (k = 0..T) and outputs ``y[k] = y(k+1)`` (k < T).

    ``x(1) = 0`` (everything before t = 1 is zero); python-control does the simulation.
    """
    A, B, C, D = canonical_matrices(a, b, form)
    sys = control.ss(A, B, C, D, dt=1)
    T = len(u)
    res = control.forced_response(
        sys, T=np.arange(T + 1), U=np.r_[u, 0.0], X0=np.zeros(len(a)), return_x=True
    )
    rng = np.random.default_rng(seed + 1000)
    y = np.asarray(res.outputs)[:T] + noise_std * rng.standard_normal(T)
    return np.asarray(res.states), y


def true_regressors(X, u, n, form):
    """Rows ``phi(t)^T``, t = 1..T, of (8) (observer form) or (153) (observability form)."""
    T = len(u)

    def x(s):  # x(s), zero for s <= 0
        return X[:, s - 1] if s >= 1 else np.zeros(n)

    def uu(s):
        return u[s - 1] if s >= 1 else 0.0

    H = np.zeros((T, 2 * n))
    for t in range(1, T + 1):
        if form == "observer":
            H[t - 1, :n] = [-x(t - i)[0] for i in range(1, n + 1)]
        else:
            H[t - 1, :n] = -x(t - n)[::-1]
        H[t - 1, n:] = [uu(t - i) for i in range(1, n + 1)]
    return H


def true_state_data(seed, T, form):
    """White input, true states, outputs (noise std 0.2) and true regressors of the test plant."""
    u = np.random.default_rng(seed).standard_normal(T)
    X, y = simulate(A_TRUE, B_TRUE, form, u, noise_std=0.2, seed=seed)
    return u, X, y, true_regressors(X, u, 2, form)


def run_with_true_state(est, X, u, y):
    """Feed the true ``x(t+1)`` through ``predict(..., x_next=...)``; return theta(t) rows."""
    out = []
    for k in range(len(u)):
        out.append(est.update(y[k]))
        est.predict(u[k], x_next=X[:, k + 1])
    return np.array(out)


def rel_err(theta_hat, theta=THETA_TRUE):
    return float(np.linalg.norm(theta_hat - theta) / np.linalg.norm(theta))
