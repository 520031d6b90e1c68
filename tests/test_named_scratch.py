"""The named lane state and scratch: every field declared once with its shape, no two fields
sharing memory, and each compiled function reading only the fields it names."""

from __future__ import annotations

from itertools import combinations

import numpy as np
import pytest

from stcgym.adaptive.control import lq, safe_set
from stcgym.adaptive.control import placement as pp
from stcgym.adaptive.control import safe_set as ss
from stcgym.adaptive.control.controller_step import make_controller_state
from stcgym.adaptive.control.extended_ls import make_extended_ls
from stcgym.adaptive.control.known_model import make_oracle_state, oracle_shapes
from stcgym.adaptive.control.options import LawOptions
from stcgym.adaptive.estimation.estimator_spec import EstimatorSpec
from stcgym.adaptive.estimation.least_squares import least_squares_work
from stcgym.adaptive.multivariable import mimo_lq
from stcgym.adaptive.multivariable.controller_step import make_mimo_state
from stcgym.adaptive.multivariable.state_matrix import make_state_matrix
from stcgym.adaptive.regression.rls_step import make_rls_state, rls_shapes
from stcgym.adaptive.variants import DESIGNS
from stcgym.envs.dynamics import OBSERVER
from stcgym.lanes.compiled import make_work


def _arrays(tree: tuple) -> dict[str, np.ndarray]:
    """Every array of a (nested) named tuple by its dotted field name."""
    out = {}
    for name, value in zip(tree._fields, tree, strict=True):
        if isinstance(value, tuple):
            out.update({f"{name}.{k}": v for k, v in _arrays(value).items()})
        else:
            out[name] = value
    return out


def _assert_disjoint(tree: tuple) -> None:
    arrays = _arrays(tree)
    for (a, x), (b, y) in combinations(arrays.items(), 2):
        assert not np.shares_memory(x, y), f"{a} and {b} share memory"


SCRATCH = {
    "DesignWork": lambda: ss.design_work(3, True, 4),
    "LQWork": lambda: lq.lq_work(2, False, 3),
    "LQSolveWork": lambda: lq.lq_work(4, True, 2, solve=True),
    "DareWork": lambda: lq.dare_work(3, 2),
    "MimoDesignWork": lambda: mimo_lq.mimo_design_work(4, 2, 3),
    "ControllerState+Work": lambda: make_controller_state(
        2, 3, LawOptions(), DESIGNS["lq"].compiled_design
    ),
    "MimoState+Work": lambda: make_mimo_state(3, 2, 2),
    "OracleState+Proposal": lambda: make_oracle_state(3, 2),
    "RLSState+Work": lambda: make_rls_state(3, 2, 4, 2),
    "WindowedLeastSquaresWork": lambda: least_squares_work(4, 2, 3, window=True),
    "ExtendedLSState+Work": lambda: make_extended_ls(2, 3, 10.0),
    "StateMatrixState+Work": lambda: make_state_matrix(3, 2, 2),
    "EstimatorState+Work": lambda: (
        EstimatorSpec.build("KF-MILS", 2, p=3).make_state(2),
        EstimatorSpec.build("KF-MILS", 2, p=3).make_work(2),
    ),
}


@pytest.mark.parametrize("kind", list(SCRATCH))
def test_no_two_fields_share_memory(kind: str) -> None:
    built = SCRATCH[kind]()
    if type(built) is tuple:  # a state and its scratch
        for part in built:
            _assert_disjoint(part)
        for x in _arrays(built[0]).values():
            for y in _arrays(built[1]).values():
                assert not np.shares_memory(x, y)
    else:
        _assert_disjoint(built)


@pytest.mark.parametrize(("n", "integral"), [(1, False), (2, True), (5, True)])
def test_design_scratch_has_the_declared_shapes(n: int, integral: bool) -> None:
    m = n + int(integral)
    work = lq.lq_work(n, integral, 3, solve=True)
    shapes = lq.lq_shapes(n, integral)
    assert set(shapes) == set(lq.LQSolveWork._fields)
    for name, field in zip(work._fields, work, strict=True):
        assert field.shape == (3, *shapes[name]) and field.dtype == np.float64
    # the model is n x n, every design on the augmented model m x m, the steady state n + 1
    assert shapes["A"] == (n, n) and shapes["A_aug"] == shapes["Cinv"] == (m, m)
    assert shapes["M"] == (n + 1, n + 1) and shapes["K"] == (m,) and shapes["A_k"] == (m, m)
    # each composite scratch is exactly the fields of its parts, each declared once
    parts = (safe_set.ModelWork, safe_set.ControllabilityWork, safe_set.SteadyStateWork)
    assert safe_set.DesignWork._fields == sum((p._fields for p in parts), ())
    assert lq.LQWork._fields == safe_set.DesignWork._fields + lq.RiccatiStepWork._fields
    assert lq.DareWork._fields == mimo_lq.DoublingWork._fields + lq.SolveWork._fields
    assert lq.LQSolveWork._fields == lq.LQWork._fields + lq.DareWork._fields


@pytest.mark.parametrize(("n", "m"), [(1, 1), (4, 2), (3, 5)])
def test_mimo_design_scratch_has_the_declared_shapes(n: int, m: int) -> None:
    shapes = mimo_lq.mimo_design_shapes(n, m)
    assert set(shapes) == set(mimo_lq.MimoDesignWork._fields)
    work = mimo_lq.mimo_design_work(n, m, 2)
    for name, field in zip(work._fields, work, strict=True):
        assert field.shape == (2, *shapes[name])
    assert shapes["KKT"] == (2 * n + m, 2 * n + m)
    assert shapes["K_sol"] == (m, n) and shapes["S_inv"] == (m, m) and shapes["PB"] == (n, m)


def test_state_shapes_declare_every_field() -> None:
    state, proposal = oracle_shapes(3)
    s, p = make_oracle_state(3, 2)
    # the gain is a lane state of its own (safe_set.gain_shapes)
    assert set(state) | {"gain"} == set(s._fields) and set(proposal) == set(p._fields)
    assert s.t.dtype == np.int64 and s.saturated.dtype == np.bool_
    assert type(s.gain) is ss.Gain and s.gain.K_x.shape == (2, 3) and s.gain.N.shape == (2,)
    state, work = rls_shapes(3, 2, 4)
    s, w = make_rls_state(3, 2, 4, 5)
    assert set(state) == set(s._fields) and set(work) == set(w._fields)
    assert s.hist_Phi.shape == (5, 4, 2, 3) and s.count.dtype == np.int64


def test_make_work_builds_only_the_fields_of_its_type() -> None:
    shapes = lq.lq_shapes(2, True)  # declares more fields than DesignWork has
    work = make_work(safe_set.DesignWork, shapes, 2)
    assert type(work) is safe_set.DesignWork
    assert work.Cinv.shape == (2, 3, 3) and not np.any(work.Cinv)


def test_a_design_reads_only_its_own_lane() -> None:
    """Lane 1 of a batched scratch gives the same design as a scratch of one lane, and lanes 0
    and 2 are never written."""
    theta = np.array([-1.5, 0.7, 1.0, 0.5])
    alpha = np.array([-1.5, 0.75, -0.125])  # (z - 0.5)^3
    cfg = ss.DesignConfig(OBSERVER, True, True, ss.safe_set(), alpha)
    gain_one = ss.make_gain(2, 1)
    assert pp.place_design(theta, cfg, gain_one, ss.design_work(2, True), 0) == ss.OK
    work = ss.design_work(2, True, 3)
    gain = ss.make_gain(2, 3)
    for field in (*work, *gain):
        field[0] = np.nan
        field[2] = np.nan
    status = pp.place_design(theta, cfg, gain, work, 1)
    assert status == ss.OK
    for one, field in zip(gain_one, gain, strict=True):
        np.testing.assert_array_equal(field[1], one[0])
    for field in (*work, *gain):
        assert np.isnan(field[0]).all() and np.isnan(field[2]).all()
