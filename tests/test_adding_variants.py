"""The recipes of the contributors' page (docs/development.md, "Adding a variant"), followed
on toy variants: the files each recipe lists are the files it takes, and the variant then runs
through the public API like the registry's own.

* a design with settings of its own on a compiled design: the registry entry alone, here a
  toy design with every pole at 0.8, against the controller with ``poles=0.8`` (the same
  compiled code: bit for bit) and its oracle;
* a compiled design: a new module and the registry entry, here Ackermann's formula on poles
  the design's compiled argument carries (every pole at 0.8), against the controller's pole
  placement with ``poles=0.8`` (the same arithmetic: bit for bit);
* a state estimator: the registry entry, its lane function and its branch in the estimator's
  state step, applied to a copy of the package (``TOY``: the closed-loop observer (50) with the
  gain fixed at ``K = e_1 / 2``), run in a fresh process, against ``CO-`` with that gain.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import stcgym.adaptive
import stcgym.envs
import stcgym.lanes
from stcgym.adaptive import KnownModelController, SelfTuningController
from stcgym.adaptive.variants import DESIGNS, PLACEMENT, Design

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = {
    "lanes": Path(stcgym.lanes.__file__).parent,
    "envs": Path(stcgym.envs.__file__).parent,
    "adaptive": Path(stcgym.adaptive.__file__).parent,
}


def _recipe_files(title: str) -> list[str]:
    """The source files a recipe of docs/development.md lists (its ``- `path`: ...`` items)."""
    text = (ROOT / "docs" / "development.md").read_text()
    section = text.split(f"### {title}\n", 1)[1].split("\n### ", 1)[0].split("\n## ", 1)[0]
    return re.findall(r"^\d+\. `([\w/]+\.py)`", section, flags=re.M)


def _closed_loop(controller: SelfTuningController, other: SelfTuningController) -> None:
    """150 samples of ``controller`` on a second-order plant (every lane), ``other`` seeing the
    same observations: their inputs equal bit for bit."""
    A = np.array([[1.5, 1.0], [-0.56, 0.0]])
    b = np.array([1.0, 0.5])
    x = np.zeros(2)
    rng = np.random.default_rng(0)
    for _ in range(150):
        obs = np.array([x[0] + 0.01 * rng.standard_normal(), 1.0])
        if controller.num_envs is not None:
            obs = np.tile(obs, (controller.num_envs, 1))
        u = controller.predict(obs)[0]
        np.testing.assert_array_equal(u, other.predict(obs)[0])
        x = A @ x + b * np.ravel(u)[0]


# ------------------------------------------------------------------------------ a design
TOY_DESIGN = Design(
    name="toy_slow",
    compiled=PLACEMENT,
    doc="Ackermann's formula with every closed-loop pole at z = 0.8",
    parameters=(),
    oracle="KnownModelController",
    oracle_options={"poles": 0.8},
    poles=0.8,
)


@pytest.mark.equality
def test_a_design_on_a_compiled_design_is_one_registry_entry(monkeypatch) -> None:
    assert _recipe_files("Adding a design") == ["adaptive/variants.py"]
    monkeypatch.setitem(DESIGNS, TOY_DESIGN.name, TOY_DESIGN)
    toy = SelfTuningController(2, design="toy_slow", seed=3)
    _closed_loop(toy, SelfTuningController(2, poles=0.8, seed=3))
    np.testing.assert_array_equal(toy.poles, np.full(3, 0.8))
    oracle = TOY_DESIGN.make_oracle([-1.5, 0.56], [1.0, 0.5])
    assert isinstance(oracle, KnownModelController)
    np.testing.assert_array_equal(oracle.poles, np.full(3, 0.8))


# ------------------------------------------------------------------------ a compiled design
# the recipe's new module: Ackermann's formula on the characteristic polynomial its compiled
# argument carries (the controller's pole placement reads the controller's own)
TOY_MODULE = '''
from typing import NamedTuple

import numpy as np

from stcgym.adaptive.control.placement import characteristic_coefficients
from stcgym.adaptive.control.pole_placement import ackermann_gain
from stcgym.adaptive.control.safe_set import OK, design_start, design_work, finish
from stcgym.adaptive.variants import CompiledDesign
from stcgym.lanes.compiled import lane


class SlowPoles(NamedTuple):
    char_poly: np.ndarray  # every closed-loop pole at 0.8


class NoState(NamedTuple):
    """The design keeps no lane state."""


@lane(inline=True)
def controller_design(design, theta, cfg, state, gain, w, lane_i):
    status, rcond = design_start(theta, cfg, w, lane_i)
    if status != OK:
        return status
    ackermann_gain(w.A_aug[lane_i], w.b_aug[lane_i], design.char_poly, w.K[lane_i], w, lane_i)
    return finish(theta, cfg, rcond, gain, w, lane_i)


def _argument(n, law):
    return SlowPoles(characteristic_coefficients(np.full(n + int(law.integral), 0.8)))


COMPILED_DESIGN = CompiledDesign(
    argument=SlowPoles,
    step=controller_design,
    make_argument=_argument,
    make_state=lambda n, law, num_lanes: NoState(),
    make_work=design_work,
)
'''


@pytest.mark.equality
def test_a_compiled_design_is_a_new_module_and_its_registry_entry(monkeypatch, tmp_path) -> None:
    new_module, registry = _recipe_files("Adding a compiled design")
    assert registry == "adaptive/variants.py"
    name = Path(new_module).stem
    (tmp_path / f"{name}.py").write_text(TOY_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    # the same oracle as the toy design above; the poles are the compiled argument's
    entry = replace(TOY_DESIGN, name="toy_compiled", compiled=name, poles=None)
    monkeypatch.setitem(DESIGNS, entry.name, entry)
    toy = SelfTuningController(2, design="toy_compiled", seed=3, num_envs=2)
    same = SelfTuningController(2, poles=0.8, seed=3, num_envs=2)
    assert toy.compiled_args.design.char_poly.shape == (3,)  # its own argument
    _closed_loop(toy, same)
    np.testing.assert_array_equal(toy.K, same.K)
    assert toy.diagnostics["n_rejected"].tolist() == same.diagnostics["n_rejected"].tolist()


# ----------------------------------------------------------------------- a state estimator
# (file, anchor that occurs once, text inserted before it): the recipe's three steps
TOY_STATE_EDITS = [
    (
        "adaptive/variants.py",
        "\n)  # fmt: skip\n\n#: The 16 algorithms",
        """
    StateEstimator(
        name="TOY", equations="(50) with K = e_1 / 2", fields=lambda n: {},
        flops=lambda n: 4 * n * n + 2, controller_p0=300.0, filtered_regressor=False,
        injection=False, paper=False,
    ),""",
    ),
    (
        "adaptive/estimation/state_estimation.py",
        "\n@lane(inline=True, entry=True)\ndef kalman_step(",
        '''
@lane(inline=True)
def toy_observer_step(A, b, x, u, y, x_next):
    """x_hat(t+1) = A_hat x_hat(t) + b_hat u(t) + e_1 (y(t) - x1_hat(t)) / 2."""
    n = x.shape[0]
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += A[i, j] * x[j]
        x_next[i] = acc + b[i] * u
    x_next[0] += 0.5 * (y - x[0])

''',
    ),
    (
        "adaptive/estimation/estimator.py",
        "    else:  # filtered O: x_hat(t+1) = A_hat x_hat(t|t) + b_hat u(t)",
        """    elif cfg.state == STATE_TOY:
        toy_observer_step(A, b, x, u, y, x_next)
""",
    ),
    (
        "adaptive/estimation/estimator.py",
        "\n# ---- status bits",
        '\nSTATE_TOY = _STATES["TOY"].code\n',
    ),
    (
        "adaptive/estimation/estimator.py",
        "    kalman_step,\n    observer_step,\n)",
        "    toy_observer_step,\n",
    ),
]

TOY_RUN = """
import json, numpy as np
from stcgym.adaptive import make_estimator
rng = np.random.default_rng(1)
u = rng.standard_normal(200)
y = np.zeros(200)
x = np.zeros(2)
for t in range(200):
    y[t] = x[0] + 0.05 * rng.standard_normal()
    x = np.array([[1.2, 1.0], [-0.4, 0.0]]) @ x + np.array([1.0, 0.5]) * u[t]
toy = make_estimator("toy-rls", 2, p0=100.0)
ref = make_estimator("CO-RLS", 2, p0=100.0, observer_gain=[0.5, 0.0])
print(json.dumps({"toy": toy.run(u, y).tolist(), "co": ref.run(u, y).tolist(),
                  "name": toy.name, "flops": toy.flops_state}))
"""


def test_a_state_estimator_takes_the_three_files_of_its_recipe(tmp_path: Path) -> None:
    listed = _recipe_files("Adding a state estimator")
    assert len(listed) <= 3
    pkg = tmp_path / "pkg"
    for name, src in PACKAGES.items():
        shutil.copytree(src, pkg / "stcgym" / name, ignore=shutil.ignore_patterns("__pycache__"))
    touched = set()
    for rel, anchor, text in TOY_STATE_EDITS:
        path = pkg / "stcgym" / rel
        source = path.read_text()
        assert source.count(anchor) == 1, (rel, anchor)
        path.write_text(source.replace(anchor, text + anchor))
        touched.add(rel)
    assert sorted(touched) == sorted(listed)
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CACHE")}
    env.update(PYTHONPATH=str(pkg), PYTHONDONTWRITEBYTECODE="1")
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "cache")
    done = subprocess.run(
        [sys.executable, "-c", TOY_RUN], capture_output=True, text=True, env=env, cwd=pkg
    )
    assert done.returncode == 0, done.stderr
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert out["name"] == "TOY-RLS" and out["flops"] == 4 * 2 * 2 + 2
    toy, co = np.array(out["toy"]), np.array(out["co"])
    assert np.all(np.isfinite(toy)) and np.abs(toy[-1] - toy[0]).max() > 0.1
    np.testing.assert_allclose(toy, co, rtol=1e-9, atol=1e-12)
