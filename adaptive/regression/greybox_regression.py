"""The regression of a grey-box structure: ``z(k) = phi(k) theta`` built from measured data.

:class:`GreyBoxRegression` holds the coefficients that :meth:`AffineStateSpace.regression
<stcgym.adaptive.regression.greybox.AffineStateSpace.regression>` derives (by the state route or the
input-output route, see :mod:`stcgym.adaptive.regression.greybox`) and applies them to measured
``u``,
``y``; :meth:`GreyBoxRegression.equations` writes the regression out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from stcgym.lanes.validation import finite_array

__all__ = ["GreyBoxRegression"]


def _samples(value: ArrayLike, name: str, width: int) -> NDArray:
    """``value`` as ``T`` finite samples of ``width`` signals, shape ``(T, width)`` (a single
    signal may be given as ``(T,)``)."""
    arr = finite_array(value, name)
    if arr.ndim == 1 and width == 1:
        arr = arr[:, None]
    if arr.ndim != 2 or arr.shape[1] != width:
        want = "(T,) or (T, 1)" if width == 1 else f"(T, {width})"
        raise ValueError(f"{name} must have shape {want}, got {np.shape(value)}")
    return arr


@dataclass(frozen=True)
class GreyBoxRegression:
    """A linear regression ``z(k) = phi(k) theta`` built from measured ``u``, ``y``.

    Produced by :meth:`AffineStateSpace.regression`; :meth:`build` applies it to data. The
    fields are set by that method; they are listed as the constructor's parameters.

    Parameters
    ----------
    method : {"state", "output"}
    order : int
        Samples of ``y`` ahead that one row needs (``1`` for ``"state"``, ``n`` for
        ``"output"``): row ``k`` uses ``y(k .. k + order)`` and ``u(k .. k + order - 1)``.
    y_coef0, y_coef : ndarray, shapes ``(order + 1, p, p)`` and ``(q, order + 1, p, p)``
        ``z(k) = sum_i y_coef0[i] y(k+i) - sum_l u_coef0[l] u(k+l)`` and
        ``phi_j(k) = -sum_i y_coef[j, i] y(k+i) + sum_l u_coef[j, l] u(k+l)``.
    u_coef0, u_coef : ndarray, shapes ``(order, p, m)`` and ``(q, order, p, m)``
    names : tuple of str
        Parameter names (for messages and :meth:`equations`).
    H_inv : ndarray or None
        ``"state"`` only: the equations are written in ``x(k) = H_inv y(k)``.

    Examples
    --------
    The object of Voevoda & Troshina (2016), eq. (5)-(8), simulated with ``theta = 0.8``;
    least squares on the regression recovers it:

    >>> import numpy as np
    >>> from stcgym.adaptive import AffineStateSpace
    >>> obj = AffineStateSpace(
    ...     Phi0=[[0, 1], [-0.3, 0]], Gamma0=[0, 1], H=[1, 0], Phi_terms=[[[0, 0], [0, 1]]]
    ... )
    >>> reg = obj.regression()
    >>> reg.method, reg.order, reg.num_params
    ('output', 2, 1)
    >>> Phi, Gamma = obj.matrices([0.8])
    >>> u = np.random.default_rng(0).standard_normal(30)
    >>> x, y = np.zeros(2), np.empty(30)
    >>> for k in range(30):
    ...     y[k] = x[0]
    ...     x = Phi @ x + Gamma[:, 0] * u[k]
    >>> phi, z = reg.build(u, y)
    >>> phi.shape, z.shape
    ((28, 1), (28,))
    >>> np.round(np.linalg.lstsq(phi, z, rcond=None)[0], 6)
    array([0.8])
    """

    method: str
    order: int
    y_coef0: NDArray
    y_coef: NDArray
    u_coef0: NDArray
    u_coef: NDArray
    names: tuple[str, ...]
    H_inv: NDArray | None = None

    @property
    def num_params(self) -> int:
        """Number of unknown parameters ``d`` (the length of ``theta``)."""
        return self.y_coef.shape[0]

    @property
    def num_outputs(self) -> int:
        """Equations per row: ``p`` outputs (``"output"``) or ``n`` states (``"state"``)."""
        return self.y_coef0.shape[1]

    @property
    def num_inputs(self) -> int:
        """Number of plant inputs ``m``."""
        return self.u_coef0.shape[2]

    def build(self, u: ArrayLike, y: ArrayLike) -> tuple[NDArray, NDArray]:
        """Regressors and targets from measured ``u(0..T-1)``, ``y(0..T-1)``.

        Parameters
        ----------
        u : array_like, shape (T,) or (T, m)
            Input applied at step ``k`` (the env's action after observing ``y(k)``).
        y : array_like, shape (T,) or (T, p_measured)
            Measured output at step ``k``.

        Returns
        -------
        phi : ndarray, shape (T - order, q) for one equation per row, else (T - order, p, q)
            ``phi[k]`` is ``phi(k)``; with ``p`` equations its row ``r`` is the regressor of
            equation ``r``: ``z(k) = phi(k) theta``, the layout
            :class:`~stcgym.adaptive.regression.rls.RecursiveLeastSquares` takes.
        z : ndarray, shape (T - order,) or (T - order, p)
        """
        u_arr = _samples(u, "u", self.num_inputs)
        y_arr = _samples(y, "y", self._measured_outputs)
        if u_arr.shape[0] != y_arr.shape[0]:
            raise ValueError(
                f"u and y must have the same number of samples T, got {u_arr.shape[0]} and "
                f"{y_arr.shape[0]}"
            )
        T = y_arr.shape[0]
        if T <= self.order:
            raise ValueError(f"y needs more than {self.order} samples for one row, got {T}")
        signals = self._equation_signals(y_arr)  # (T, p) signals the equations are written in
        win = self.order + 1
        Yw = np.lib.stride_tricks.sliding_window_view(signals, win, axis=0)  # (N, p, win)
        Uw = np.lib.stride_tricks.sliding_window_view(u_arr[: T - 1], self.order, axis=0)
        N = T - self.order
        Uw = Uw[:N]
        z = np.einsum("irs,ksi->kr", self.y_coef0, Yw) - np.einsum("lrs,ksl->kr", self.u_coef0, Uw)
        phi = -np.einsum("jirs,ksi->krj", self.y_coef, Yw) + np.einsum(
            "jlrs,ksl->krj", self.u_coef, Uw
        )
        if self.num_outputs == 1:
            return phi[:, 0, :], z[:, 0]
        return phi, z

    @property
    def _measured_outputs(self) -> int:
        return self.num_outputs if self.H_inv is None else self.H_inv.shape[1]

    def _equation_signals(self, y: NDArray) -> NDArray:
        return y if self.H_inv is None else y @ self.H_inv.T

    def equations(self, digits: int = 4) -> str:
        """The regression written out, one line per equation and parameter.

        E.g. ``z(k) = y(k+2) + 0.3 y(k) - u(k)`` and ``phi[theta](k) = y(k+1)`` for the paper's
        object (subscripts ``_r`` number outputs / states / inputs when there are several).

        Parameters
        ----------
        digits : int, default 4
            Significant digits of the coefficients.

        Returns
        -------
        str
            The equations, one per line.
        """
        p, m = self.num_outputs, self.num_inputs
        sig = "x" if self.method == "state" else "y"

        def symbol(name: str, idx: int, count: int, lag: int) -> str:
            sub = f"_{idx + 1}" if count > 1 else ""
            return f"{name}{sub}(k{f'+{lag}' if lag else ''})"

        def combination(y_coef: NDArray, u_coef: NDArray, r: int) -> str:
            """``sum_i y_coef[i, r] y(k+i) + sum_l u_coef[l, r] u(k+l)``, highest lag first."""
            terms = [
                (y_coef[i, r, s], symbol(sig, s, p, i))
                for i in range(self.order, -1, -1)
                for s in range(p)
            ]
            terms += [
                (u_coef[lag, r, s], symbol("u", s, m, lag))
                for lag in range(self.order - 1, -1, -1)
                for s in range(m)
            ]
            text = ""
            for coef, sym in terms:
                if abs(coef) < 10.0 ** (-digits - 2):
                    continue
                body = sym if abs(abs(coef) - 1.0) < 1e-12 else f"{abs(coef):.{digits}g} {sym}"
                sign = ("-" if coef < 0 else "") if not text else (" - " if coef < 0 else " + ")
                text += sign + body
            return text or "0"

        lines = []
        for r in range(p):
            eq = f"_{r + 1}" if p > 1 else ""
            lines.append(f"z{eq}(k) = {combination(self.y_coef0, -self.u_coef0, r)}")
            for j, name in enumerate(self.names):
                rhs = combination(-self.y_coef[j], self.u_coef[j], r)
                lines.append(f"phi{eq}[{name}](k) = {rhs}")
        return "\n".join(lines)
