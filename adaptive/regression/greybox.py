"""Grey-box structures: state-space objects affine in unknown parameters, turned into a regression.

The object of Voevoda & Troshina (2016), eq. (5)-(6), generalised::

    x(k+1) = Phi(theta) x(k) + Gamma(theta) u(k) + w(k),     y(k) = H x(k) + v(k),
    Phi(theta) = Phi0 + sum_i theta_i Phi_i,     Gamma(theta) = Gamma0 + sum_i theta_i Gamma_i,

with known ``Phi0``, ``Phi_i``, ``Gamma0``, ``Gamma_i`` (``n x n`` and ``n x m``), a known
measurement matrix ``H`` (``p x n``) and ``q`` unknown scalars ``theta``. :class:`AffineStateSpace`
turns measured ``u(k)``, ``y(k)`` into a linear regression ``z(k) = phi(k) theta`` (exact when
``w = v = 0``) for :class:`~stcgym.adaptive.regression.rls.RecursiveLeastSquares` or batch least
squares (:meth:`AffineStateSpace.regression`), in one of two ways:

``method="state"`` (the state is measured: ``H`` square and invertible)
    ``x(k) = H^{-1} y(k)`` and the state equation itself is the regression, linear in ``theta``
    for every affine structure (``p = n`` equations per step)::

        z(k) = x(k+1) - Phi0 x(k) - Gamma0 u(k),      phi_i(k) = Phi_i x(k) + Gamma_i u(k).

``method="output"`` (the paper's way: eliminate the state, eq. (7)-(8))
    By Cayley-Hamilton, ``chi(Phi) = 0`` for ``chi(s) = det(s I - Phi) = s^n + c_{n-1} s^{n-1}
    + ... + c_0``, so every trajectory, whatever its initial state, satisfies
    ``sum_{i=0..n} c_i y(k+i) = sum_{l=0..n-1} beta_l u(k+l)`` (``c_n = 1``), with
    ``beta_l = H M_{n-l} Gamma`` the numerator coefficients of ``H adj(sI - Phi) Gamma``
    (``M_j`` the Faddeev-LeVerrier matrices, :func:`io_coefficients`). When the coefficients are
    affine in ``theta``, ``c = c^0 + sum_i theta_i c^i`` and ``beta = beta^0 + sum_i theta_i
    beta^i``, and::

        z(k)     = sum_i c^0_i y(k+i) - sum_l beta^0_l u(k+l),
        phi_j(k) = -sum_i c^j_i y(k+i) + sum_l beta^j_l u(k+l),

    which for the paper's object is its (7)-(8) (the example of :class:`AffineStateSpace`). A
    coefficient that is not affine (e.g. ``theta`` twice on the diagonal) raises
    :class:`NotLinearInParameters`, naming the coefficient and the product of parameters.

``method="auto"`` (default) takes ``"state"`` when ``H`` is square and well conditioned and
``"output"`` otherwise. With noise the output route is an errors-in-variables problem and its
least squares is biased (the Grey-box models section of the Estimators page of the
documentation); this module builds the paper's plain regression.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.adaptive.regression.greybox_regression import GreyBoxRegression
from stcgym.lanes.validation import finite_array, integer, matrix, one_of

__all__ = [
    "AffineStateSpace",
    "GreyBoxRegression",
    "NotLinearInParameters",
    "io_coefficients",
]

Method = Literal["auto", "state", "output"]

#: Relative tolerance for "this coefficient does not depend on theta" / "this term is zero".
_RTOL = 1e-9
#: ``H`` with a larger condition number is not inverted by ``method="auto"``.
_COND_MAX = 1e8


class NotLinearInParameters(ValueError):
    """The structure gives no regression that is linear in ``theta`` (the message says why).

    A subclass of :class:`ValueError`, raised by :meth:`AffineStateSpace.regression` and
    :meth:`AffineStateSpace.from_functions`.

    Parameters
    ----------
    *args
        The message: the coefficient, the offending product of parameters and the remedies.

    Examples
    --------
    ``theta`` twice on the diagonal: ``chi(s) = (s - theta)^2`` has a ``theta^2`` term, so the
    output route fails, while the measured state still gives a regression:

    >>> import numpy as np
    >>> from stcgym.adaptive import AffineStateSpace, NotLinearInParameters
    >>> obj = AffineStateSpace(Phi0=np.zeros((2, 2)), Gamma0=[1, 0], H=[0, 1],
    ...                        Phi_terms=[np.eye(2)])
    >>> try:
    ...     obj.regression("output")
    ... except NotLinearInParameters as exc:
    ...     print(str(exc)[:45])
    the structure is not linear in the parameters
    >>> measured = AffineStateSpace(Phi0=np.zeros((2, 2)), Gamma0=[1, 0], H=np.eye(2),
    ...                             Phi_terms=[np.eye(2)])
    >>> measured.regression().method
    'state'
    """


# --------------------------------------------------------------------------------------------
# Validation
# --------------------------------------------------------------------------------------------


def _terms(value: ArrayLike | None, name: str, shape: tuple[int, int]) -> NDArray | None:
    """``q`` matrices of ``shape`` stacked as ``(q, *shape)``; ``None`` stays ``None``."""
    if value is None:
        return None
    arr = finite_array(value, name)
    if arr.ndim == 2 and arr.shape == shape and shape[1] != 1:
        raise ValueError(
            f"{name} must be a sequence of matrices (one per parameter), shape (q, {shape[0]}, "
            f"{shape[1]}); for one parameter wrap the matrix in a list"
        )
    if arr.ndim == 2 and shape[1] == 1 and arr.shape[1] == shape[0]:
        arr = arr[:, :, None]  # Gamma_i given as flat vectors
    if arr.ndim != 3 or arr.shape[1:] != shape:
        raise ValueError(f"{name} must have shape (q, {shape[0]}, {shape[1]}), got {arr.shape}")
    return arr


def _scale(*arrays: NDArray) -> float:
    return max([1.0] + [float(np.abs(a).max()) for a in arrays if a.size])


# --------------------------------------------------------------------------------------------
# Input-output coefficients (Cayley-Hamilton, Faddeev-LeVerrier)
# --------------------------------------------------------------------------------------------


def io_coefficients(Phi: ArrayLike, Gamma: ArrayLike, H: ArrayLike) -> tuple[NDArray, NDArray]:
    """Coefficients of the input-output equation of ``(Phi, Gamma, H)``.

    Returns ``c`` (``n + 1``, ``c[n] = 1``) and ``beta`` (``(n, p, m)``) such that every
    trajectory of ``x(k+1) = Phi x(k) + Gamma u(k)``, ``y(k) = H x(k)`` satisfies
    ``sum_i c[i] y(k+i) = sum_l beta[l] u(k+l)``: ``c`` is the characteristic polynomial
    (ascending powers) and ``beta`` the numerator of ``H adj(sI - Phi) Gamma``, computed by the
    Faddeev-LeVerrier recursion ``M_1 = I``, ``c_{n-1} = -tr(Phi)``,
    ``M_j = Phi M_{j-1} + c_{n-j+1} I``, ``c_{n-j} = -tr(Phi M_j) / j``,
    ``adj(sI - Phi) = sum_j M_j s^{n-j}``. Division-free apart from ``1/j``, so structural zeros
    of an affine structure stay (nearly) exact.
    """
    Phi = np.asarray(Phi, dtype=float)
    Gamma = np.asarray(Gamma, dtype=float)
    H = np.asarray(H, dtype=float)
    n = Phi.shape[0]
    c = np.zeros(n + 1)
    c[n] = 1.0
    beta = np.zeros((n, H.shape[0], Gamma.shape[1]))
    M = np.eye(n)
    for j in range(1, n + 1):
        if j > 1:
            M = Phi @ M + c[n - j + 1] * np.eye(n)
        c[n - j] = -np.trace(Phi @ M) / j
        beta[n - j] = H @ M @ Gamma
    return c, beta


# --------------------------------------------------------------------------------------------
# The structure
# --------------------------------------------------------------------------------------------


class AffineStateSpace:
    """``x(k+1) = Phi(theta) x(k) + Gamma(theta) u(k)``, ``y(k) = H x(k)``, affine in ``theta``.

    Parameters
    ----------
    Phi0 : array_like, shape (n, n)
    Gamma0 : array_like, shape (n, m) (a flat vector for one input)
    H : array_like, shape (p, n) (a flat vector for one output)
    Phi_terms : array_like, shape (q, n, n), optional
        ``Phi_i``: ``Phi(theta) = Phi0 + sum_i theta_i Phi_i`` (zeros when omitted).
    Gamma_terms : array_like, shape (q, n, m), optional
        ``Gamma_i`` (zeros when omitted). At least one of the two term arrays is required.
    names : sequence of str, optional
        Parameter names for messages (default ``theta[0]``, ``theta[1]``, ...).

    Raises
    ------
    ValueError
        A matrix that is not finite or not of its shape, neither ``Phi_terms`` nor
        ``Gamma_terms`` given, the two holding different numbers of matrices, a parameter
        whose ``Phi_i`` and ``Gamma_i`` are both zero, ``names`` not one per parameter.

    Examples
    --------
    The object of Voevoda & Troshina (2016), eq. (5)-(6):

    >>> from stcgym.adaptive import AffineStateSpace
    >>> obj = AffineStateSpace(
    ...     Phi0=[[0, 1], [-0.3, 0]], Gamma0=[0, 1], H=[1, 0], Phi_terms=[[[0, 0], [0, 1]]]
    ... )
    >>> print(obj.regression().equations())
    z(k) = y(k+2) + 0.3 y(k) - u(k)
    phi[theta[0]](k) = y(k+1)
    """

    def __init__(
        self,
        Phi0: ArrayLike,
        Gamma0: ArrayLike,
        H: ArrayLike,
        Phi_terms: ArrayLike | None = None,
        Gamma_terms: ArrayLike | None = None,
        *,
        names: Sequence[str] | None = None,
    ) -> None:
        self.Phi0 = matrix(Phi0, "Phi0", (None, None))
        n = self.Phi0.shape[0]
        if self.Phi0.shape != (n, n):
            raise ValueError(f"Phi0 must be square (n x n), got shape {self.Phi0.shape}")
        G0 = finite_array(Gamma0, "Gamma0")
        self.Gamma0 = matrix(G0.reshape(-1, 1) if G0.ndim == 1 else G0, "Gamma0", (n, None))
        H_arr = finite_array(H, "H")
        self.H = matrix(H_arr.reshape(1, -1) if H_arr.ndim == 1 else H_arr, "H", (None, n))
        m = self.Gamma0.shape[1]
        dPhi = _terms(Phi_terms, "Phi_terms", (n, n))
        dGamma = _terms(Gamma_terms, "Gamma_terms", (n, m))
        if dPhi is None and dGamma is None:
            raise ValueError("give Phi_terms or Gamma_terms (the matrices multiplying theta_i)")
        q = (dPhi if dPhi is not None else dGamma).shape[0]  # type: ignore[union-attr]
        if dPhi is not None and dGamma is not None and dGamma.shape[0] != q:
            raise ValueError(
                f"Phi_terms and Gamma_terms must have one matrix per parameter each; got "
                f"{q} and {dGamma.shape[0]}"
            )
        if q < 1:
            raise ValueError("Phi_terms / Gamma_terms must hold at least one matrix")
        self.Phi_terms = np.zeros((q, n, n)) if dPhi is None else dPhi
        self.Gamma_terms = np.zeros((q, n, m)) if dGamma is None else dGamma
        if names is None:
            self.names = tuple(f"theta[{j}]" for j in range(q))
        else:
            self.names = tuple(str(s) for s in names)
            if len(self.names) != q:
                raise ValueError(
                    f"names must hold {q} names (one per parameter), got {len(self.names)}"
                )
        for j in range(q):
            if not (np.any(self.Phi_terms[j]) or np.any(self.Gamma_terms[j])):
                raise ValueError(
                    f"Phi_terms[{j}] and Gamma_terms[{j}] are both zero: {self.names[j]} does "
                    "not enter the model"
                )

    # ---------------------------------------------------------------- alternative constructor
    @classmethod
    def from_functions(
        cls,
        Phi: Callable[[NDArray], ArrayLike] | ArrayLike,
        Gamma: Callable[[NDArray], ArrayLike] | ArrayLike,
        H: ArrayLike,
        num_params: int,
        *,
        names: Sequence[str] | None = None,
        seed: int = 0,
    ) -> AffineStateSpace:
        """Build from functions ``theta -> Phi(theta)``, ``theta -> Gamma(theta)`` (or constants).

        ``Phi0 = Phi(0)`` and ``Phi_i = Phi(e_i) - Phi(0)``; the function is then checked to be
        affine at a few random ``theta`` (and on every pair ``e_i + e_j``), and a
        :class:`NotLinearInParameters` naming ``Phi`` or ``Gamma`` is raised when it is not.
        """
        q = integer(num_params, "num_params")

        def sample(fn: Callable | ArrayLike, name: str, theta: NDArray) -> NDArray:
            value = fn(theta.copy()) if callable(fn) else fn
            arr = finite_array(value, f"{name}(theta)")
            return arr.reshape(-1, 1) if name == "Gamma" and arr.ndim == 1 else arr

        eye = np.eye(q)
        out = {}
        for fn, name in ((Phi, "Phi"), (Gamma, "Gamma")):
            base = sample(fn, name, np.zeros(q))
            terms = np.array([sample(fn, name, eye[j]) - base for j in range(q)])
            rng = np.random.default_rng(seed)
            probes = [
                eye[i] + eye[j] for i, j in itertools.combinations_with_replacement(range(q), 2)
            ]
            probes += list(rng.standard_normal((3, q)))
            for theta in probes:
                value = sample(fn, name, theta)
                if value.shape != base.shape:
                    raise ValueError(f"{name}(theta) changed shape: {base.shape} -> {value.shape}")
                gap = value - (base + np.tensordot(theta, terms, axes=1))
                if np.abs(gap).max() > _RTOL * _scale(base, terms, value):
                    raise NotLinearInParameters(
                        f"{name} is not affine in theta: at theta = {np.round(theta, 4).tolist()} "
                        f"{name}(theta) differs from {name}(0) + sum_i theta_i ({name}(e_i) - "
                        f"{name}(0)) by up to {np.abs(gap).max():.3g}"
                    )
            out[name] = (base, terms)
        return cls(out["Phi"][0], out["Gamma"][0], H, out["Phi"][1], out["Gamma"][1], names=names)

    # ---------------------------------------------------------------- properties
    @property
    def num_params(self) -> int:
        """Number of unknown parameters ``d`` (one ``Phi_terms`` / ``Gamma_terms`` matrix each)."""
        return self.Phi_terms.shape[0]

    @property
    def n(self) -> int:
        """State dimension."""
        return self.Phi0.shape[0]

    def matrices(self, theta: ArrayLike) -> tuple[NDArray, NDArray]:
        """``(Phi(theta), Gamma(theta))``, e.g. for ``stcgym/StateSpace-v0`` (``A``, ``B``).

        Parameters
        ----------
        theta : array_like, shape (q,)
            Finite parameter values.

        Returns
        -------
        Phi : ndarray, shape (n, n)
        Gamma : ndarray, shape (n, m)

        Raises
        ------
        ValueError
            ``theta`` not finite or not of length ``q``.
        """
        th = finite_array(theta, "theta").reshape(-1)
        if th.size != self.num_params:
            raise ValueError(f"theta must hold {self.num_params} values, got {th.size}")
        return (
            self.Phi0 + np.tensordot(th, self.Phi_terms, axes=1),
            self.Gamma0 + np.tensordot(th, self.Gamma_terms, axes=1),
        )

    def __repr__(self) -> str:
        return (
            f"AffineStateSpace(n={self.n}, inputs={self.Gamma0.shape[1]}, "
            f"outputs={self.H.shape[0]}, params={list(self.names)})"
        )

    # ---------------------------------------------------------------- regression
    def regression(self, method: Method = "auto") -> GreyBoxRegression:
        """The linear regression ``z(k) = phi(k) theta`` of this structure.

        Parameters
        ----------
        method : {"auto", "state", "output"}
            ``"state"``: the state equation on ``x(k) = H^{-1} y(k)`` (``H`` square and
            invertible); ``"output"``: the input-output equation of Cayley-Hamilton, Voevoda &
            Troshina (2016), eq. (7)-(8); ``"auto"`` (default): ``"state"`` when ``H`` is square
            and well conditioned, else ``"output"``. The module docstring gives the equations.

        Raises
        ------
        NotLinearInParameters
            ``method="output"`` (or ``"auto"`` without an invertible ``H``) and the input-output
            equation is not affine in ``theta``; the message names the coefficient and the
            product of parameters.
        ValueError
            ``method="state"`` without a square invertible ``H``; parameters that cannot be
            identified from the regression (they do not enter it, or only in fixed
            combinations).
        """
        one_of(method, "method", ("auto", "state", "output"))
        invertible = self.H.shape[0] == self.n and np.linalg.cond(self.H) < _COND_MAX
        if method == "state" and not invertible:
            raise ValueError(
                f"method='state' needs the whole state measured: H must be square ({self.n} x "
                f"{self.n}) and invertible, got shape {self.H.shape}"
                + (
                    f" with condition number {np.linalg.cond(self.H):.3g}"
                    if self.H.shape[0] == self.n
                    else ""
                )
            )
        if method == "state" or (method == "auto" and invertible):
            reg = self._state_regression()
        else:
            reg = self._output_regression()
        self._check_identifiable(reg)
        return reg

    def _state_regression(self) -> GreyBoxRegression:
        n, q = self.n, self.num_params
        y0 = np.zeros((2, n, n))
        y0[1] = np.eye(n)
        y0[0] = -self.Phi0
        yc = np.zeros((q, 2, n, n))
        yc[:, 0] = -self.Phi_terms
        Hi = np.linalg.inv(self.H)
        return GreyBoxRegression(
            "state", 1, y0, yc, self.Gamma0[None], self.Gamma_terms[:, None], self.names, Hi
        )

    def _output_regression(self) -> GreyBoxRegression:
        n, q, p = self.n, self.num_params, self.H.shape[0]
        eye = np.eye(q)
        c0, b0 = io_coefficients(*self.matrices(np.zeros(q)), self.H)
        lin = [io_coefficients(*self.matrices(eye[j]), self.H) for j in range(q)]
        dc = np.array([c - c0 for c, _ in lin])
        db = np.array([b - b0 for _, b in lin])
        self._check_affine(c0, b0, dc, db)
        # a scalar characteristic polynomial acts on every output alike: y_coef[i] = c_i I_p
        y0 = c0[:, None, None] * np.eye(p)
        yc = dc[:, :, None, None] * np.eye(p)
        return GreyBoxRegression("output", n, y0, yc, b0, db, self.names)

    def _check_affine(self, c0: NDArray, b0: NDArray, dc: NDArray, db: NDArray) -> None:
        """Raise unless the map ``theta -> (c, beta)`` is affine.

        Its second differences at ``e_i + e_j`` reveal every quadratic term by name; three random
        probes catch higher-degree terms whose unit-point differences cancel.
        """
        q = self.num_params
        eye = np.eye(q)
        scale = _scale(c0, b0, dc, db)

        def gap_at(theta: NDArray) -> tuple[NDArray, NDArray]:
            c, b = io_coefficients(*self.matrices(theta), self.H)
            return (
                c - c0 - np.tensordot(theta, dc, axes=1),
                b - b0 - np.tensordot(theta, db, axes=1),
            )

        def fail(gc: NDArray, gb: NDArray, what: str) -> None:
            if np.abs(gc).max() >= np.abs(gb).max():
                i = int(np.argmax(np.abs(gc)))
                where = f"c_{i}, the coefficient of y(k{f'+{i}' if i else ''}),"
                size = gc[i]
            else:
                lag, r, s = np.unravel_index(int(np.argmax(np.abs(gb))), gb.shape)
                where = f"beta_{lag}, the coefficient of u(k{f'+{lag}' if lag else ''})" + (
                    f" in output {r}, input {s}," if gb.shape[1] * gb.shape[2] > 1 else ","
                )
                size = gb[lag, r, s]
            raise NotLinearInParameters(
                "the structure is not linear in the parameters: eliminating the state "
                f"(Cayley-Hamilton) writes y(k+{self.n}) in terms of earlier y and u, and "
                f"{where} contains {what} (second difference {size:.3g}), so no regression "
                "z(k) = phi(k) theta exists on the measured output. Measure the state "
                "(H invertible, method='state') or re-parametrise (estimate that product as a "
                "parameter of its own)."
            )

        for i, j in itertools.combinations_with_replacement(range(q), 2):
            gc, gb = gap_at(eye[i] + eye[j])
            if max(np.abs(gc).max(), np.abs(gb).max()) > _RTOL * scale:
                what = (
                    f"a {self.names[i]}^2 term"
                    if i == j
                    else f"a {self.names[i]}*{self.names[j]} term"
                )
                fail(gc, gb, what)
        rng = np.random.default_rng(0)
        for theta in rng.standard_normal((3, q)):
            gc, gb = gap_at(theta)
            if max(np.abs(gc).max(), np.abs(gb).max()) > _RTOL * _scale(c0, b0, dc, db, theta):
                fail(gc, gb, "terms of degree 3 or more in theta")

    def _check_identifiable(self, reg: GreyBoxRegression) -> None:
        """Every parameter must be identifiable from the data the regression uses.

        State route: the pairs ``(Phi_j, Gamma_j)`` must be linearly independent. Output route:
        the transfer function from ``u`` to ``y`` must depend on every parameter, independently;
        checked by the rank of the Jacobian of the Markov parameters
        ``h_k = H Phi^{k-1} Gamma`` (``k = 1 .. 2n``, which fix the transfer function) at a
        random ``theta``. The Cayley-Hamilton equation is not minimal when ``(Phi, H)`` is
        unobservable or ``(Phi, Gamma)`` uncontrollable: a parameter of a cancelled mode then
        enters the equation but not the data (its regressor is zero on noise-free data).
        """
        q = self.num_params
        if reg.method == "state":
            what = "the state equation"
            G = np.concatenate(
                (self.Phi_terms.reshape(q, -1), self.Gamma_terms.reshape(q, -1)), axis=1
            )
        else:
            what = "the transfer function from u to y"
            G = self._markov_jacobian(np.random.default_rng(0).standard_normal(q) / 2).T
        norms = np.linalg.norm(G, axis=1)
        for j in range(q):
            if norms[j] <= _RTOL * max(float(norms.max()), 1e-300):
                raise ValueError(
                    f"{reg.names[j]} does not change {what}, so it cannot be identified from "
                    "the measured data (it acts only on modes that y does not see or that u "
                    "does not excite)"
                )
        Gn = G / norms[:, None]
        _, sv, Vt = np.linalg.svd(Gn.T, full_matrices=False)
        if sv[-1] <= 1e-8:
            combo = " + ".join(
                f"{v:.3g} {reg.names[j]}" for j, v in enumerate(Vt[-1] / norms) if abs(v) > 1e-6
            )
            raise ValueError(
                f"the parameters change {what} only in fixed combinations: moving theta along "
                f"({combo}) leaves it unchanged, so they are not jointly identifiable"
            )

    def _markov_jacobian(self, theta: NDArray) -> NDArray:
        """``d h_k / d theta_j`` for ``h_k = H Phi^{k-1} Gamma``, ``k = 1..2n``: ``(2n p m, q)``.

        ``d(Phi^{k-1}) = sum_a Phi^a Phi_j Phi^{k-2-a}`` (exact for the affine structure).
        """
        n = self.n
        Phi, Gamma = self.matrices(theta)
        powers = [np.eye(n)]
        for _ in range(2 * n):
            powers.append(Phi @ powers[-1])
        cols = []
        for Pj, Gj in zip(self.Phi_terms, self.Gamma_terms, strict=True):
            blocks = []
            for k in range(1, 2 * n + 1):
                dPow = sum(
                    (powers[a] @ Pj @ powers[k - 2 - a] for a in range(k - 1)),
                    np.zeros((n, n)),
                )
                blocks.append(self.H @ (dPow @ Gamma + powers[k - 1] @ Gj))
            cols.append(np.concatenate([b.ravel() for b in blocks]))
        return np.array(cols).T
