"""The recipes of the contributors' page (docs/development.md, "Adding a variant"), followed
on toy variants: the files each recipe lists are the files it takes, and the variant then runs
through the public API like the registry's own.

* a design with settings of its own on a compiled design: the registry entry alone, here a
  toy design with every pole at 0.8, against the controller with ``poles=0.8`` (the same
  compiled code: bit for bit) and its oracle;
* a compiled design: a new module and the registry entry, applied to a copy of the package
  and run in a fresh process, here Ackermann's formula on poles the design's compiled argument
  carries (every pole at 0.8), against the controller's pole placement with ``poles=0.8``
  (the same arithmetic: bit for bit);
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


def _run_in_copy(
    tmp_path: Path, edits: list[tuple[str, str, str]], new_files: dict[str, str], script: str
) -> dict:
    """Apply a recipe to a copy of the package -- ``edits``: (file, anchor that occurs once,
    text inserted before it); ``new_files``: path -> text -- and run ``script`` on the copy in
    a fresh process with a numba cache of its own; returns the JSON of its last line."""
    pkg = tmp_path / "pkg"
    for name, src in PACKAGES.items():
        shutil.copytree(src, pkg / "stcgym" / name, ignore=shutil.ignore_patterns("__pycache__"))
    for rel, anchor, text in edits:
        path = pkg / "stcgym" / rel
        source = path.read_text()
        assert source.count(anchor) == 1, (rel, anchor)
        path.write_text(source.replace(anchor, text + anchor))
    for rel, text in new_files.items():
        (pkg / "stcgym" / rel).write_text(text)
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_CACHE")}
    env.update(PYTHONPATH=str(pkg), PYTHONDONTWRITEBYTECODE="1")
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "cache")
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, env=env, cwd=pkg
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


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
from stcgym.adaptive.control.placement import ackermann_gain
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


# its registry entry, inserted at the end of DESIGNS
TOY_DESIGN_ENTRY = (
    "\n    )\n}  # fmt: skip",
    """
        Design(
            name="toy_compiled", compiled="stcgym.adaptive.control.new_design",
            doc="Ackermann's formula with every pole at 0.8, from the design's own argument",
            parameters=(), oracle="KnownModelController", oracle_options={"poles": 0.8},
        ),""",
)

TOY_DESIGN_RUN = """
import json, numpy as np
from stcgym.adaptive import SelfTuningController
toy = SelfTuningController(2, design="toy_compiled", seed=3, num_envs=2)
same = SelfTuningController(2, poles=0.8, seed=3, num_envs=2)
A, b, x = np.array([[1.5, 1.0], [-0.56, 0.0]]), np.array([1.0, 0.5]), np.zeros(2)
rng = np.random.default_rng(0)
u_toy, u_same = [], []
for _ in range(150):
    obs = np.tile([x[0] + 0.01 * rng.standard_normal(), 1.0], (2, 1))
    u_toy.append(toy.predict(obs)[0].ravel().tolist())
    u_same.append(same.predict(obs)[0].ravel().tolist())
    x = A @ x + b * u_toy[-1][0]
print(json.dumps({"toy": u_toy, "same": u_same, "K": [toy.K.tolist(), same.K.tolist()],
                  "char_poly": toy.compiled_args.design.char_poly.tolist()}))
"""


@pytest.mark.equality
def test_a_compiled_design_is_a_new_module_and_its_registry_entry(tmp_path: Path) -> None:
    new_module, registry = _recipe_files("Adding a compiled design")
    assert registry == "adaptive/variants.py"
    assert new_module.endswith("/new_design.py")
    out = _run_in_copy(
        tmp_path, [(registry, *TOY_DESIGN_ENTRY)], {new_module: TOY_MODULE}, TOY_DESIGN_RUN
    )
    assert len(out["char_poly"]) == 3  # its own argument: the augmented model's 3 poles
    assert np.abs(np.array(out["toy"])).max() > 0.1  # the loop ran
    assert out["toy"] == out["same"]  # bit for bit (floats through JSON: repr round-trips)
    assert out["K"][0] == out["K"][1]


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
    out = _run_in_copy(tmp_path, TOY_STATE_EDITS, {}, TOY_RUN)
    assert sorted({rel for rel, _, _ in TOY_STATE_EDITS}) == sorted(listed)
    assert out["name"] == "TOY-RLS" and out["flops"] == 4 * 2 * 2 + 2
    toy, co = np.array(out["toy"]), np.array(out["co"])
    assert np.all(np.isfinite(toy)) and np.abs(toy[-1] - toy[0]).max() > 0.1
    np.testing.assert_allclose(toy, co, rtol=1e-9, atol=1e-12)
