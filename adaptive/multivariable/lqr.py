"""Known-model oracle of the multivariable self-tuning controller: LQR on the true ``(A, B)``.

:class:`LQRController` applies ``u = sat(-K x + F r)`` with the LQ gain ``K`` of the true model
(the stabilising solution of the discrete algebraic Riccati equation, solved by the same
compiled doubling routine as the self-tuning controller's fresh-model design:
:func:`stcgym.adaptive.multivariable.mimo_lq.dare_solve`) and the same feed-forward ``F`` to the
cheapest equilibrium (:func:`~stcgym.adaptive.multivariable.mimo_lq.steady_state_feedforward`), with
the same weights (default the env's cost) and the same ``predict``/``reset`` protocol.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.control.safe_set import NOT_STABILISABLE, STATUS_NAMES, UNIT_CIRCLE_MODE
from stcgym.adaptive.multivariable import mimo_lq as lq
from stcgym.adaptive.multivariable.controller import plant_and_weights
from stcgym.adaptive.policy import OBSERVATION_LIMIT, LanePolicy
from stcgym.envs.env_settings import split_observation
from stcgym.lanes.validation import matrix

__all__ = ["LQRController", "lqr_design"]


def _pbh_modes(M: NDArray, E: NDArray, unit_circle: bool) -> str:
    """The eigenvalues ``lambda`` of ``M`` on the unit circle (``unit_circle``), or on or
    outside it, where the PBH matrix ``[M - lambda I, E]`` loses rank, as text ("" if none)."""
    n = M.shape[0]
    lam = np.linalg.eigvals(M)
    mag = np.abs(lam)
    tol = 1e-8 * max(1.0, float(np.max(mag, initial=0.0)))
    near = np.abs(mag - 1.0) <= tol if unit_circle else mag >= 1.0 - tol
    found = []
    for mode in lam[near]:
        s = np.linalg.svd(np.hstack((M - mode * np.eye(n), E)), compute_uv=False)
        if s[-1] <= 1e-9 * max(1.0, float(s[0])):
            found.append(f"{mode:.4g}")
    return ", ".join(found)


def lq_failure_reason(
    A: NDArray, B: NDArray, Q: NDArray, R: NDArray, N: NDArray, status: int
) -> str:
    """The real cause of a failed solve, by the PBH tests: ``[A - lambda I, B]`` for a mode on
    or outside the unit circle (reachability), ``[A_N^T - lambda I, Q_N]`` for one on it
    (observability through ``Q_N``)."""
    stuck = _pbh_modes(A, B, unit_circle=False)
    if status == NOT_STABILISABLE or stuck:
        return (
            f"(A, B) is not stabilisable: no input reaches the mode(s) {stuck or '?'} on or "
            "outside the unit circle, so no gain stabilises the loop"
        )
    RNt = np.linalg.solve(R, N.T)
    AN, QN = A - B @ RNt, Q - N @ RNt
    hidden = _pbh_modes(AN.T, QN, unit_circle=True)
    if status == UNIT_CIRCLE_MODE or hidden:
        a, q = ("A - B R^-1 N^T", "Q - N R^-1 N^T") if np.any(N) else ("A", "Q")
        return (
            f"the mode(s) {hidden or '?'} of {a} on the unit circle are unobservable through "
            f"the state weight {q}: the optimal loop leaves them on the unit circle, so no "
            "stabilising LQ solution exists (weight them in Q)"
        )
    return f"the Riccati solve failed ({STATUS_NAMES[status]})"


def lqr_design(
    A: ArrayLike, B: ArrayLike, Q: ArrayLike, R: ArrayLike, N: ArrayLike | None = None
) -> tuple[NDArray, NDArray]:
    """``(K, F)`` of the infinite-horizon LQ problem on ``(A, B)`` with the stage cost
    ``x^T Q x + u^T R u + 2 x^T N u`` (``N`` default zero; python-control's ``dlqr``).

    Raises ``ValueError`` naming the cause when no stabilising solution exists (``(A, B)`` not
    stabilisable, or a mode on the unit circle unobservable through ``Q - N R^-1 N^T``) or when
    there is no equilibrium for some reference (an uncontrollable mode at ``z = 1``).
    """
    A, B, Q, R = (np.ascontiguousarray(M, dtype=float) for M in (A, B, Q, R))
    n, m = B.shape
    N = np.zeros((n, m)) if N is None else np.ascontiguousarray(N, dtype=float)
    work = lq.mimo_design_work(n, m)
    P = np.zeros((n, n))
    K = np.zeros((m, n))
    problem = lq.LQProblem(Q, R, N, 1e-12, 64)
    status = lq.dare_solve(A, B, problem, P, K, work, 0)
    if status != 0:
        raise ValueError(
            "no stabilising LQ gain for these weights: " + lq_failure_reason(A, B, Q, R, N, status)
        )
    F = np.zeros((m, n))
    if not lq.steady_state_feedforward(A, B, problem, K, F, work, 0):
        raise ValueError("(A, B) has no equilibrium for some reference (a mode at z = 1)")
    return K, F


class LQRController(LanePolicy):
    """LQR with feed-forward tracking on the true model (module docstring).

    Parameters
    ----------
    A, B
        True matrices, ``(n, n)`` and ``(n, m)``, or one per lane ``(B, n, n)``, ``(B, n, m)``.
    env, num_envs, Q, R, N, action_bound
        As for :class:`~stcgym.adaptive.MultivariableSelfTuningController` (``Q`` positive
        semidefinite: any weight for which the stabilising Riccati solution exists).

    Raises
    ------
    ValueError
        ``A`` and ``B`` not finite or of inconsistent shapes, settings that do not match
        ``env``, malformed ``Q``/``R``/``N`` or ``action_bound``, or a model with no stabilising
        LQ gain for these weights (the message names the cause: ``(A, B)`` not stabilisable, or
        a mode on the unit circle unobservable through the state weight).

    Attributes
    ----------
    K, F : ndarray -- ``(m, n)`` (``(B, m, n)`` for lanes).

    Examples
    --------
    A double integrator sampled at 0.1 s, observed as ``[x, x_ref]``; the gain is
    python-control's ``dlqr``:

    >>> import control
    >>> import numpy as np
    >>> from stcgym.adaptive import LQRController
    >>> A = np.array([[1.0, 0.1], [0.0, 1.0]])
    >>> B = np.array([[0.005], [0.1]])
    >>> oracle = LQRController(A, B, Q=1.0, R=0.01)
    >>> np.round(oracle.K, 4)
    array([[5.8939, 6.8209]])
    >>> np.allclose(oracle.K, control.dlqr(A, B, np.eye(2), 0.01 * np.eye(1))[0])
    True
    >>> action, _ = oracle.predict(np.array([1.0, 0.0, 0.0, 0.0]))
    >>> np.round(action, 4)
    array([-5.8939])
    """

    observation_limit = OBSERVATION_LIMIT

    def __init__(
        self,
        A: ArrayLike,
        B: ArrayLike,
        *,
        env: Any = None,
        num_envs: int | None = None,
        Q: ArrayLike | float | None = None,
        R: ArrayLike | float | None = None,
        N: ArrayLike | None = None,
        action_bound: float | None = None,
    ) -> None:
        A_arr = np.asarray(A, dtype=float)
        B_arr = np.asarray(B, dtype=float)
        if A_arr.ndim not in (2, 3) or B_arr.ndim != A_arr.ndim:
            raise ValueError(
                f"A and B must be (n, n) and (n, m), or (lanes, n, n) and (lanes, n, m), got "
                f"shapes {A_arr.shape} and {B_arr.shape}"
            )
        n, m = B_arr.shape[-2:]
        n, m = plant_and_weights(self, n, m, num_envs, action_bound, env, Q, R, N)
        lanes = self.num_lanes
        if A_arr.ndim == 2:
            A_arr = np.broadcast_to(matrix(A_arr, "A", (n, n)), (lanes, n, n))
            B_arr = np.broadcast_to(matrix(B_arr, "B", (n, m)), (lanes, n, m))
        elif A_arr.shape != (lanes, n, n) or B_arr.shape != (lanes, n, m):
            raise ValueError(
                f"per-lane A and B must have shapes ({lanes}, {n}, {n}) and ({lanes}, {n}, "
                f"{m}), got {A_arr.shape} and {B_arr.shape}"
            )
        if not (np.all(np.isfinite(A_arr)) and np.all(np.isfinite(B_arr))):
            raise ValueError("A and B must be finite")
        self._K = np.zeros((lanes, m, n))
        self._F = np.zeros((lanes, m, n))
        for i in range(lanes):
            self._K[i], self._F[i] = lqr_design(A_arr[i], B_arr[i], self.Q, self.R, self.N)
        self._u = np.zeros((lanes, m))

    def _reset_lanes(self, idx: NDArray) -> None:
        """The oracle has no state."""

    def _act(self, obs: NDArray, starts: NDArray | None, deterministic: bool) -> NDArray:
        X, Rr = split_observation(obs, self.n_states)
        lq.feedback_laws(self._K, self._F, X, Rr, float(self.action_bound), self._u)
        return self._lanes_out(self._u)

    @property
    def K(self) -> NDArray:
        """LQ gain, ``(m, n)`` (``(B, m, n)`` for lanes)."""
        return self._lanes_out(self._K)

    @property
    def F(self) -> NDArray:
        """Reference feed-forward, shapes as :attr:`K`."""
        return self._lanes_out(self._F)

    def __repr__(self) -> str:
        return self._repr(f"n_states={self.n_states}, n_inputs={self.n_inputs}")
