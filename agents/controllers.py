"""The classical controllers of ``stcgym bench``, behind one registry.

``CONTROLLERS[name].build(cfg, scenario)`` gives a lane builder ``builder(plants, seeds)``
returning one policy for ``len(plants)`` lanes (:func:`stcgym.agents.evaluation.episodes.
run_episodes`): lane ``i`` runs on the plant spec ``plants[i]`` (only the known-model
controllers look at it) with the controller seed ``seeds[i]``.

* ``stc``: the self-tuning controller with its defaults (pole placement, extended least
  squares); ``stc_lq``: the same with the self-tuning LQ design (``design="lq"``) weighted by
  the bench's cost ``(y - r)^2 + control_cost u^2``; ``stc_kfmils``: ``stc`` on the paper's
  KF-MILS estimator; ``stc_tuned``: ``stc`` with options tuned on the validation split with
  the RL agents' Optuna budget (the full tier, :mod:`stcgym.agents.benchmark.tuning`). Each is
  told the plant order of the scenario's training distribution (also on a held-out
  distribution of another order) and nothing else; the others' options are the library's
  defaults, fixed before any test plant was drawn.
* ``lqg``: the yardstick, LQG on the true model for the bench's own cost (the steady-state
  LQ gain and Kalman filter, the reference fed forward through the steady state), told the new
  parameters at a jump; on a measured-state MIMO plant the LQR on the true ``(A, B)``
  (:class:`~stcgym.agents.evaluation.mimo.InformedLQR`) with the weights of the scenario's
  performance-output cost, told the new model at a valve switch.
* ``oracle``: pole placement on the true model with the self-tuning controller's poles and
  integral action (:class:`~stcgym.adaptive.KnownModelController`), told the new parameters
  at a jump: the self-tuning controller's design with the identification problem removed.
* ``zero``: zero input, the reference of the normalised score.
* ``fixed_pi``: the best fixed PI law for the scenario's training split, tuned on it
  (:mod:`stcgym.agents.fixed_pi`): what one robust controller without adaptation reaches.
* ``stc_mimo``: the multivariable self-tuning LQ controller
  (:class:`~stcgym.adaptive.MultivariableSelfTuningController`) weighted by the scenario's
  cost ``||C_z x + D_z u - r||^2 + control_cost ||u||^2`` (``Q = C_z' C_z``,
  ``R = D_z' D_z + control_cost I``, ``N = C_z' D_z``).

Each declares the plants it runs on (``ControllerInfo.plants``): a scenario evaluates only the
controllers that declare its kind (``EnvSpec.plant_kind``: ``"siso"`` or ``"mimo"``), and what
it knows (:attr:`ControllerInfo.knows`, the report's knowledge table). Tests may register more.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "CONTROLLERS",
    "YARDSTICK",
    "ControllerInfo",
    "ZeroController",
    "controller_seeds",
    "controllers_for",
    "self_tuning",
]

#: The controller every ratio is taken to.
YARDSTICK = "lqg"


class ZeroController:
    """Zero input on every lane (SB3's ``predict``/``reset`` protocol): the reference of the
    normalised score ``(C_zero - C) / (C_zero - C_LQG)``.

    Parameters
    ----------
    num_envs : int or None
        ``None``: one env (``predict`` on ``(2 p,)`` gives ``(m,)``); else that many lanes.
    n_inputs : int, default 1
        Inputs ``m``.

    Examples
    --------
    >>> import numpy as np
    >>> from stcgym.agents.controllers import ZeroController
    >>> ZeroController(num_envs=2).predict(np.ones((2, 2)))[0]
    array([[0.],
           [0.]])
    """

    def __init__(self, num_envs: int | None = None, n_inputs: int = 1) -> None:
        self.num_envs, self.n_inputs = num_envs, int(n_inputs)

    def reset(self) -> None:
        """Nothing to forget."""

    def predict(
        self, observation: Any, state: Any = None, episode_start: Any = None, deterministic=True
    ) -> tuple[NDArray, None]:
        shape = (self.n_inputs,) if self.num_envs is None else (self.num_envs, self.n_inputs)
        return np.zeros(shape), None


@dataclass(frozen=True)
class ControllerInfo:
    """A classical controller of the bench.

    ``build(cfg, scenario) -> builder(plants, seeds) -> policy``; ``online`` marks a
    controller that learns from the episode (its data use is the episode's steps); ``plants``
    the kinds of plant it runs on (``"siso"``, ``"mimo"``); ``informed`` a known-model
    controller told the true parameters whenever they change; ``seeded`` a controller with
    random parts (its runs are controller seeds); ``knows`` what it is given, for the report;
    ``tuned`` the tuning study it reads.
    """

    kind: str
    build: Callable[[Any, Any], Callable[[list[Any], list[int]], Any]]
    online: bool = False
    description: str = ""
    plants: tuple[str, ...] = ("siso",)
    informed: bool = False
    seeded: bool = False
    knows: dict[str, str] = field(default_factory=dict)
    #: the tuning study (a key of ``BenchConfig.tuned``) it is built from, if any
    tuned: str | None = None

    def runs_on(self, spec: Any) -> bool:
        """Whether the controller runs on the plants of the env spec ``spec``."""
        return spec.plant_kind in self.plants


def controller_seeds(seeds: Sequence[int], run: int) -> list[int]:
    """Controller seeds of run ``run`` on the episodes ``seeds``: every episode and run its own
    stream (a pure function of both). The bench seeds the self-tuning controllers' probes with
    them, and the residual RL agent the controller inside it, so that a run of each meets the
    same probe on the same episode.

    Examples
    --------
    >>> from stcgym.agents.controllers import controller_seeds
    >>> a, b = controller_seeds([1000, 1001], run=0), controller_seeds([1000], run=1)
    >>> a[0] != a[1] and a[0] != b[0], a == controller_seeds([1000, 1001], run=0)
    (True, True)
    """
    return [int(np.random.SeedSequence([int(s), int(run)]).generate_state(1)[0]) for s in seeds]


def _lanes(plants: Sequence[Any]) -> tuple[NDArray, NDArray]:
    """Per-lane true ``a``, ``b`` of catalogue or family plant specs, ``(B, n)`` each."""
    return np.array([p.a for p in plants], dtype=float), np.array([p.b for p in plants])


def self_tuning(cfg: Any, sc: Any, **options: Any) -> Callable[[list[Any], list[int]], Any]:
    """The self-tuning controller with its defaults and ``options``, told the order of the
    scenario's training distribution (``sc.controller_order``)."""
    from stcgym.adaptive import SelfTuningController

    def builder(plants: list[Any], seeds: list[int]) -> Any:
        return SelfTuningController(
            sc.controller_order,
            num_envs=len(plants),
            action_bound=sc.env.action_bound,
            seed=[int(s) for s in seeds],
            **options,
        )

    return builder


def _stc(cfg: Any, sc: Any) -> Callable[[list[Any], list[int]], Any]:
    return self_tuning(cfg, sc)


def _stc_kfmils(cfg: Any, sc: Any) -> Callable[[list[Any], list[int]], Any]:
    # no estimator options: the controller picks its closed-loop settings for KF-MILS itself
    return self_tuning(cfg, sc, estimator="KF-MILS")


def _stc_tuned(cfg: Any, sc: Any) -> Callable[[list[Any], list[int]], Any]:
    from stcgym.agents.benchmark.tuning import stc_options

    tuned = cfg.tuned.get("stc")
    if tuned is None:
        raise ValueError("stc_tuned needs the tuning of the full tier (--tune-trials N)")
    return self_tuning(cfg, sc, **stc_options(tuned["params"]))


def _stc_lq(cfg: Any, sc: Any) -> Callable[[list[Any], list[int]], Any]:
    from stcgym.adaptive import LawOptions
    from stcgym.adaptive.control.options import cost_weights

    # the LQ weights are the bench's own cost, as LQG's (q_i keeps the integrator)
    law = LawOptions(lq_weights=cost_weights(sc.env.control_cost))
    return self_tuning(cfg, sc, design="lq", law=law)


def _oracle(cfg: Any, sc: Any) -> Callable[[list[Any], list[int]], Any]:
    from stcgym.adaptive import KnownModelController

    def builder(plants: list[Any], seeds: list[int]) -> Any:
        a, b = _lanes(plants)
        return KnownModelController(a, b, num_envs=len(plants), action_bound=sc.env.action_bound)

    return builder


def _lqg(cfg: Any, sc: Any) -> Callable[[list[Any], list[int]], Any]:
    from stcgym.adaptive import LawOptions, LQGController
    from stcgym.adaptive.control.options import cost_weights

    env = sc.env
    if env.plant_kind == "mimo":  # measured state: the LQR on the true (A, B)
        return _mimo_lqr(env)
    # without integral action: the optimal linear controller for the bench's cost on the
    # known model
    law = LawOptions(integral=False, lq_weights=cost_weights(env.control_cost))

    def builder(plants: list[Any], seeds: list[int]) -> Any:
        a, b = _lanes(plants)
        return LQGController(
            a, b, law=law, noise_std=env.noise_std, action_bound=env.action_bound,
            num_envs=len(plants),
        )  # fmt: skip

    return builder


def _fixed_pi(cfg: Any, sc: Any) -> Callable[[list[Any], list[int]], Any]:
    from stcgym.agents.fixed_pi import FixedPI, training_split, tune_fixed_pi

    gains = tune_fixed_pi(training_split(sc.env))
    bound = sc.env.action_bound
    return lambda plants, seeds: FixedPI(gains.kp, gains.ki, bound, len(plants))


def _zero(cfg: Any, sc: Any) -> Callable[[list[Any], list[int]], Any]:
    m = sc.env.channels[1]
    return lambda plants, seeds: ZeroController(len(plants), m)


def _mimo_weights(env: Any) -> dict[str, Any]:
    """The LQ weights of a ``mimo`` scenario's cost: ``Q``, ``R`` and, where the performance
    output has a feed-through, the cross weight ``N``."""
    Q, R, N = env.plant.lq_weights(env.control_cost)
    return dict(Q=Q, R=R) if not np.any(N) else dict(Q=Q, R=R, N=N)


def _mimo_lqr(env: Any) -> Callable[[list[Any], list[int]], Any]:
    from stcgym.agents.evaluation.mimo import InformedLQR

    def lqr(plants: list[Any], seeds: list[int]) -> Any:
        A, B = (np.array(m) for m in zip(*(p.discrete() for p in plants), strict=True))
        return InformedLQR(A, B, action_bound=env.action_bound, **_mimo_weights(env))

    return lqr


def _stc_mimo(cfg: Any, sc: Any) -> Callable[[list[Any], list[int]], Any]:
    from stcgym.adaptive import MultivariableSelfTuningController

    env = sc.env
    n, m = env.order, env.channels[1]

    def builder(plants: list[Any], seeds: list[int]) -> Any:
        return MultivariableSelfTuningController(
            n, m, num_envs=len(plants), action_bound=env.action_bound,
            input_range=env.plant.input_range, seed=[int(s) for s in seeds],
            **_mimo_weights(env),
        )  # fmt: skip

    return builder


_ADAPTIVE = {
    "order": "the training distribution's order n",
    "integral": "yes, with anti-windup",
    "model": "none: identified online",
    "data": "the episode so far",
}
_KNOWN = {"order": "true", "model": "true (a, b), told the jump", "data": "none"}


def _adaptive(
    build: Any, description: str, knows: dict[str, str] = _ADAPTIVE, tuned: str | None = None
) -> ControllerInfo:
    """A self-tuning controller's entry: online, seeded, SISO."""
    return ControllerInfo(
        "adaptive", build, True, description, seeded=True, knows=knows, tuned=tuned
    )


def _known_model(
    build: Any, description: str, integral: str, plants: tuple[str, ...] = ("siso",)
) -> ControllerInfo:
    """A known-model oracle's entry: offline, told the true parameters whenever they change;
    ``integral`` says whether its law has integral action, for the report."""
    return ControllerInfo(
        "oracle",
        build,
        False,
        description,
        plants,
        informed=True,
        knows={**_KNOWN, "integral": integral},
    )


#: Classical controllers by name (tests may register more).
CONTROLLERS: dict[str, ControllerInfo] = {
    "stc": _adaptive(_stc, "self-tuning controller (defaults)"),
    "stc_lq": _adaptive(_stc_lq, "self-tuning LQ (design='lq')"),
    "stc_tuned": _adaptive(
        _stc_tuned,
        "the self-tuning controller with options tuned on the validation split",
        {**_ADAPTIVE, "data": "the episode so far; options tuned on validation episodes"},
        tuned="stc",
    ),
    "stc_kfmils": _adaptive(
        _stc_kfmils, "the self-tuning controller on the paper's KF-MILS estimator"
    ),
    "lqg": _known_model(
        _lqg,
        "LQG on the true model, the bench's cost (LQR with measured state on a MIMO plant)",
        "no (reference feed-forward)",
        ("siso", "mimo"),
    ),
    "oracle": _known_model(
        _oracle,
        "pole placement on the true model (the self-tuning controller's poles)",
        "yes, with anti-windup",
    ),
    "zero": ControllerInfo(
        "reference",
        _zero,
        False,
        "zero input",
        ("siso", "mimo"),
        knows={"order": "-", "integral": "-", "model": "-", "data": "-"},
    ),
    "fixed_pi": ControllerInfo(
        "reference",
        _fixed_pi,
        False,
        "the best fixed PI law for the training split (one law for every plant)",
        knows={
            "order": "none",
            "integral": "yes (PI), with anti-windup",
            "model": "none: one PI law, tuned on the training split's plants",
            "data": "200 training-split episodes (tuning: grid and Nelder-Mead)",
        },
    ),
    "stc_mimo": ControllerInfo(
        "adaptive",
        _stc_mimo,
        True,
        "multivariable self-tuning LQ controller",
        ("mimo",),
        seeded=True,
        knows={
            "order": "the number of states and inputs",
            "integral": "no",
            "model": "none: identified online",
            "data": "the episode so far",
        },
    ),
}


def controllers_for(names: Sequence[str], spec: Any) -> list[str]:
    """The controllers of ``names`` (in order) that run on the plants of the env spec ``spec``."""
    return [name for name in names if CONTROLLERS[name].runs_on(spec)]
