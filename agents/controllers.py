"""The classical controllers of ``stcgym bench``, behind one registry.

``CONTROLLERS[name].build(cfg, scenario)`` gives a policy factory ``factory(plant, seed)``
(the protocol of :func:`stcgym.agents.benchmark.evaluate.evaluate`): ``stc`` (the self-tuning
controller with its defaults and the episode's seed), ``stc_lq`` (the same with the self-tuning
LQ design, ``design="lq"``, weighted by the bench's cost ``(y - r)^2 + control_cost u^2``),
``stc_kfmils`` (the same as ``stc`` on the paper's KF-MILS estimator, ``estimator="KF-MILS"``,
with the closed-loop settings the controller chooses for it), ``oracle`` (the known-model
controller, told the new parameters at a jump; on a MIMO plant the LQR on the true ``(A, B)``,
:class:`~stcgym.adaptive.LQRController`), ``lqg`` (LQG on the true pre-jump parameters) and
``stc_mimo`` (the multivariable self-tuning LQ controller,
:class:`~stcgym.adaptive.MultivariableSelfTuningController`, weighted by the bench's cost
``||x - r||^2 + control_cost ||u||^2``, as its oracle). Each declares the plants it runs on
(``ControllerInfo.plants``): a scenario evaluates only the controllers that declare its kind
(``EnvSpec.plant_kind``: ``"siso"`` or ``"mimo"``). Tests may register more.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["CONTROLLERS", "ControllerInfo", "controllers_for"]


class _SwitchingOracle:
    """Known-model oracle told the true parameters at the jump (policy protocol)."""

    def __init__(self, base: Any, jump_step: int, theta: Sequence[float]) -> None:
        n = len(theta) // 2
        self.base, self.jump_step = base, int(jump_step)
        self.after = (np.asarray(theta[:n]), np.asarray(theta[n:]))
        self._k = 0

    def reset(self) -> None:
        self.base.reset()  # also restores the initial (pre-jump) model
        self._k = 0

    def predict(
        self, observation: Any, state: Any = None, episode_start: Any = None, deterministic=True
    ) -> tuple[Any, Any]:
        if episode_start is not None and np.any(episode_start):
            self.reset()
        # The schedule's value at step J governs the transition J -> J+1, so the model is
        # switched before the input of step J is chosen.
        if self._k == self.jump_step:
            self.base.set_model(*self.after)
        self._k += 1
        return self.base.predict(observation, state, None, deterministic)


@dataclass(frozen=True)
class ControllerInfo:
    """A classical controller of the bench.

    ``build(cfg, scenario) -> factory(plant_spec, seed) -> policy``; ``online`` marks a
    controller that learns from the episode (its data use is the episode's steps); ``plants``
    the kinds of plant it runs on (``"siso"``, ``"mimo"``).
    """

    kind: str
    build: Callable[[Any, Any], Callable[[Any, int], Any]]
    online: bool = False
    description: str = ""
    plants: tuple[str, ...] = ("siso",)

    def runs_on(self, spec: Any) -> bool:
        """Whether the controller runs on the plants of the env spec ``spec``."""
        return spec.plant_kind in self.plants


def _self_tuning(cfg: Any, **options: Any) -> Callable[[Any, int], Any]:
    """The self-tuning controller with its defaults and ``options`` (episode-seeded)."""
    from stcgym.adaptive import SelfTuningController

    def factory(plant: Any, seed: int) -> Any:
        return SelfTuningController(
            plant.n, action_bound=cfg.action_bound, seed=int(seed), **options
        )

    return factory


def _stc(cfg: Any, sc: Any) -> Callable[[Any, int], Any]:
    return _self_tuning(cfg)


def _stc_kfmils(cfg: Any, sc: Any) -> Callable[[Any, int], Any]:
    # no estimator options: the controller picks its closed-loop settings for KF-MILS itself
    return _self_tuning(cfg, estimator="KF-MILS")


def _stc_lq(cfg: Any, sc: Any) -> Callable[[Any, int], Any]:
    from stcgym.adaptive import LawOptions, SelfTuningController
    from stcgym.adaptive.options import cost_weights

    # the LQ weights are the bench's own cost, as LQGController's (q_i keeps the integrator)
    law = LawOptions(lq_weights=cost_weights(cfg.control_cost))

    def factory(plant: Any, seed: int) -> Any:
        return SelfTuningController(
            plant.n, design="lq", law=law, action_bound=cfg.action_bound, seed=int(seed)
        )

    return factory


def _oracle(cfg: Any, sc: Any) -> Callable[[Any, int], Any]:
    from stcgym.adaptive import KnownModelController, LQRController

    if sc.env.plant_kind == "mimo":  # LQR on the true (A, B), the weights of stc_mimo
        return lambda plant, seed: LQRController(
            *plant.discrete(), Q=1.0, R=cfg.control_cost, action_bound=cfg.action_bound
        )

    def factory(plant: Any, seed: int) -> Any:
        base = KnownModelController(plant.a, plant.b, action_bound=cfg.action_bound)
        if sc.env.jump_step is None:
            return base
        return _SwitchingOracle(base, sc.env.jump_step, sc.jump_to)

    return factory


def _lqg(cfg: Any, sc: Any) -> Callable[[Any, int], Any]:
    from stcgym.adaptive import LawOptions, LQGController
    from stcgym.adaptive.options import cost_weights

    # LQG without integral action: the optimal linear controller for the bench's cost on the
    # known model (its published figures are of this design)
    law = LawOptions(integral=False, lq_weights=cost_weights(cfg.control_cost))
    return lambda plant, seed: LQGController(
        plant.a, plant.b, law=law, noise_std=cfg.noise_std, action_bound=cfg.action_bound
    )


def _stc_mimo(cfg: Any, sc: Any) -> Callable[[Any, int], Any]:
    from stcgym.adaptive import MultivariableSelfTuningController

    def factory(plant: Any, seed: int) -> Any:
        return MultivariableSelfTuningController(
            plant.n_states,
            plant.n_inputs,
            Q=1.0,
            R=cfg.control_cost,
            action_bound=cfg.action_bound,
            seed=int(seed),
        )

    return factory


#: Classical controllers by name (tests may register more).
CONTROLLERS: dict[str, ControllerInfo] = {
    "stc": ControllerInfo("adaptive", _stc, True, "self-tuning controller (defaults)"),
    "stc_lq": ControllerInfo("adaptive", _stc_lq, True, "self-tuning LQ (design='lq')"),
    "stc_kfmils": ControllerInfo(
        "adaptive",
        _stc_kfmils,
        True,
        "the self-tuning controller on the paper's KF-MILS estimator",
    ),
    "oracle": ControllerInfo(
        "oracle",
        _oracle,
        False,
        "known-model controller (regulator's design, true parameters; LQR on a MIMO plant)",
        ("siso", "mimo"),
    ),
    "lqg": ControllerInfo("oracle", _lqg, False, "LQG on the true pre-jump parameters"),
    "stc_mimo": ControllerInfo(
        "adaptive", _stc_mimo, True, "multivariable self-tuning LQ controller", ("mimo",)
    ),
}


def controllers_for(names: Sequence[str], spec: Any) -> list[str]:
    """The controllers of ``names`` (in order) that run on the plants of the env spec ``spec``."""
    return [name for name in names if CONTROLLERS[name].runs_on(spec)]
