"""The recursive estimators of Ding & Ma (2014) as the paper prints them, in dense numpy.

A statement to read beside the paper: one method a half-step, ``P`` held explicitly (no
square-root factor, no structure exploited, no health checks, no speed). The compiled lane
functions of :mod:`stcgym.adaptive.estimation` never import it; the tests compare them against it
to a stated tolerance (``tests/test_estimator_kernels.py``), so it is an independent check.

* innovation ``E(p, t) = Y(p, t) - Phi(p, t)^T theta(t-1)`` (17), (38);
* SG/MISG (12)-(22): ``r(t) = lambda r(t-1) + ||phi_hat(t)||^2`` (or ``||Phi||^2``, remark 1),
  ``theta(t) = theta(t-1) + Phi E / r(t)``;
* RLS (32)-(36): ``L = P phi / (lambda + phi^T P phi)``, ``P = (P - L phi^T P) / lambda``;
* MILS (37)-(44): ``L = P Phi (lambda I + Phi^T P Phi)^{-1}``, ``P = (P - L Phi^T P) / lambda``;
* NG, the normalised-gradient (projection) algorithm (Astrom & Wittenmark, not in the paper):
  ``theta(t) = theta(t-1) + mu phi e / (bias + phi^T phi)``;
* D- rules (96)-(145): the same on ``a`` (rows ``0..n-1``) and ``b`` (rows ``n..2n-1``), both
  with the innovation computed from ``theta(t-1)``;
* open-loop observer (46), closed-loop observer (50), Kalman filter (66)-(68) with ``Q``, ``R``;
* ``filtered=True``: the regressor from ``x_hat(t|t) = x_hat(t) + g (y(t) - x1_hat(t))``,
  ``g = P1 c^T / (R + c P1 c^T)`` (KF) or ``A^{n-1} e_n`` (O, which then propagates
  ``x_hat(t|t)``), times ``injection`` after the first ``injection_warmup`` steps (O);
* regressors (9)/(57) (observer form) and (153) (observability form), zero before ``t = 1``.
"""

from __future__ import annotations

import numpy as np

from stcgym.adaptive.estimation.estimator_spec import EstimatorSpec
from stcgym.envs.canonical import companion_A

__all__ = ["ReferenceEstimator"]


class ReferenceEstimator:
    """One plant's estimator as ``spec`` configures it (:meth:`EstimatorSpec.build
    <stcgym.adaptive.estimation.estimator_spec.EstimatorSpec.build>`, the keywords of
    :func:`stcgym.adaptive.make_estimator`; a finite ``window`` and a callable
    ``observer_gain`` are not covered). The spec gives the settings and initial values only;
    the update is this class's own. :meth:`update` and :meth:`predict` are the two
    half-steps, :meth:`run` a pass over recorded data.
    """

    def __init__(self, spec: EstimatorSpec) -> None:
        v = spec.variant  # registry entries: the names only, none of the kernels' math
        self.state, self.rule, self.decomposed = v.state, v.rule, v.decomposed
        n, p = spec.n, spec.p
        self.n, self.p, self.form, self.lam = n, p, spec.form, spec.forgetting
        d = 2 * n
        self.theta = np.array(spec.theta0, float)
        self.P = None if spec.P0 is None else np.array(spec.P0, float)
        self.r = np.array([spec.r0, spec.r0])
        self.stacked_r = spec.stacked_r
        self.x = np.array(spec.x_init, float)
        self.P1 = np.eye(n) if spec.P1_init is None else np.array(spec.P1_init, float)
        self.Q = np.zeros((n, n)) if spec.Q is None else np.array(spec.Q, float)
        self.R = spec.R
        self.K = None if spec.observer_gain is None else np.array(spec.observer_gain, float)
        self.filtered = spec.regressor == "filtered"
        # the normalised gradient's mu and bias (the rule's own parameters, in order)
        self.mu, self.bias = spec.rule_parameters if v.rule.name == "NG" else (None, None)
        self.injection, self.injection_warmup = spec.injection, spec.injection_warmup
        self.t = 0
        self.Phi = np.zeros((d, p))  # column j = phi_hat(t - j)
        self.Y = np.zeros(p)
        self.xs = [np.zeros(n) for _ in range(n)]  # x_hat(t), x_hat(t-1), ..., zero before 1
        self.phi = np.zeros(d)
        self.y = 0.0

    def blocks(self):
        """The parameter blocks a rule updates: ``theta`` whole, or ``a`` and ``b`` (D-)."""
        n, d = self.n, 2 * self.n
        return [slice(0, n), slice(n, d)] if self.decomposed else [slice(0, d)]

    def update(self, y: float) -> np.ndarray:
        """Measurement step with ``y(t)``: ``Phi(p, t)``, ``Y(p, t)``, ``E(p, t)`` and the rule;
        returns ``theta_hat(t)``."""
        self.Phi = np.column_stack([self.phi, self.Phi[:, :-1]])
        self.Y = np.r_[y, self.Y[:-1]]
        self.y = y
        self.t += 1
        E = self.Y - self.Phi.T @ self.theta
        delta = np.zeros_like(self.theta)
        lam = self.lam
        for k, blk in enumerate(self.blocks()):
            Phi = self.Phi[blk]
            if self.rule.normaliser:  # SG, MISG
                inc = np.sum(Phi**2) if self.stacked_r else np.sum(Phi[:, 0] ** 2)
                self.r[k] = lam * self.r[k] + inc
                delta[blk] = Phi @ E / self.r[k]
                continue
            if not self.rule.covariance:  # NG
                phi = Phi[:, 0]
                delta[blk] = self.mu * phi * E[0] / (self.bias + phi @ phi)
                continue
            P = self.P[blk, blk]
            if not self.rule.multi_innovation:  # RLS
                phi = Phi[:, 0]
                L = P @ phi / (lam + phi @ P @ phi)
                self.P[blk, blk] = (P - np.outer(L, phi @ P)) / lam
                delta[blk] = L * E[0]
            else:
                L = P @ Phi @ np.linalg.inv(lam * np.eye(self.p) + Phi.T @ P @ Phi)
                self.P[blk, blk] = (P - L @ Phi.T @ P) / lam
                delta[blk] = L @ E
        self.theta = self.theta + delta
        self.E = E
        return self.theta.copy()

    def predict(self, u: float) -> np.ndarray:
        """State step with ``u(t)``: ``x_hat(t+1)`` by the state estimator on ``A_hat(t)``,
        ``b_hat(t)``, and the regressor ``phi_hat(t+1)``; returns ``x_hat(t+1)``."""
        n = self.n
        A = companion_A(self.theta[:n], self.form)
        b = self.theta[n:]
        x = self.x
        c = np.eye(n)[0]
        x_reg = x  # the state estimate the regressor is built from
        if self.filtered:  # x_hat(t|t) = x_hat(t) + g (y(t) - c x_hat(t))
            if self.state.kalman:
                g = self.P1 @ c / (self.R + c @ self.P1 @ c)
            else:  # deadbeat: c g = 1 and A (I - g c) nilpotent
                g = np.linalg.matrix_power(A, n - 1) @ np.eye(n)[n - 1]
                if self.t > self.injection_warmup:  # then a fraction of it
                    g = self.injection * g
            x_reg = x + g * (self.y - x[0])
        if self.state.kalman:
            s = self.R + c @ self.P1 @ c
            L1 = A @ self.P1 @ c / s
            x_next = A @ x + b * u + L1 * (self.y - x[0])
            self.P1 = A @ self.P1 @ A.T - np.outer(L1, c @ self.P1 @ A.T) + self.Q
            self.L1 = L1
        elif self.K is not None:
            x_next = A @ x + b * u + self.K * (self.y - x[0])
        elif self.filtered:  # output injection: propagate the corrected estimate
            x_next = A @ x_reg + b * u
        else:
            x_next = A @ x + b * u
        # regressor phi_hat(t+1)
        self.xs = [x_reg.copy(), *self.xs[:-1]]
        if self.form == "observer":
            phi_a = np.r_[-x_reg[0], self.phi[: n - 1]]
        else:
            phi_a = -self.xs[n - 1][::-1]
        self.phi = np.r_[phi_a, u, self.phi[n : 2 * n - 1]]
        self.x = x_next
        return x_next.copy()

    def run(self, u, y) -> np.ndarray:
        """``update(y[k])``, ``predict(u[k])`` for every ``k``; the ``theta_hat`` of each step."""
        out = []
        for uk, yk in zip(u, y, strict=True):
            out.append(self.update(yk))
            self.predict(uk)
        return np.array(out)
