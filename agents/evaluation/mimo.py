"""The MIMO plants' environments and known-model controllers of the evaluation: what running a
controller on a multi-input plant needs, shared by the bench and RL training.

:class:`MimoEnvSpec` is an :class:`~stcgym.agents.evaluation.env_spec.EnvSpec` whose plant is a
MIMO catalogue name (or a split of the quadruple-tank family), so the evaluation loop, RL
training and JSON tasks take it as they take a SISO spec. Two formulations
(:func:`formulation`):

``process`` (``quadruple_tank``, ``quadruple_tank_nmp``)
    Johansson's quadruple tank at ``P-`` or ``P+``: references on the two lower levels,
    independent random steps per channel (:data:`TANK_REFERENCE`, each channel its own levels
    and hold times, so the steps are staggered), the bench's output noise and control cost,
    pump voltages within ``[0, 10]`` V around the operating point.
``controlgym`` (``he1``, ``ac1``)
    controlgym 1.0.0's linear-control task: regulation (``r = 0``) from
    ``x(0) ~ N(0, 0.1 I)``, process noise ``B1 w`` with ``w ~ N(0, 0.1 I)``, no output noise,
    cost ``||C1 x + D12 u||^2`` (``control_cost = 0``), :data:`CONTROLGYM_STEPS` steps
    (:data:`CONTROLGYM_SETTINGS`).

The cost weighs the plant's performance output ``z = C_z x + D_z u``
(``||z(k) - r(k)||^2 + control_cost ||u(k)||^2``), the state is measured and the reference
observed as a target state (``reference_in="state"``: the observation is
``[x(k) + v(k), r_x(k)]`` with ``r_x = C_z^+ r``). The yardsticks: :class:`InformedLQR`, the
LQR on the true ``(A, B)`` told every model change, and :class:`OutputLQG` for a measured
output; :func:`channel_metrics` gives the per-channel tracking figures. The bench's MIMO
scenarios are built from these in :mod:`stcgym.agents.benchmark.mimo`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from stcgym.agents.evaluation.env_spec import EnvSpec, thaw
from stcgym.envs.mimo_plants import MimoPlantSpec, get_mimo_plant

__all__ = [
    "CONTROLGYM_SETTINGS",
    "CONTROLGYM_STEPS",
    "MIMO_ENV_ID",
    "SWITCH",
    "TANK_FAMILY_ENV_ID",
    "TANK_REFERENCE",
    "InformedLQR",
    "MimoEnvSpec",
    "OutputLQG",
    "channel_metrics",
    "formulation",
]

MIMO_ENV_ID = "stcgym/StateSpace-v0"
TANK_FAMILY_ENV_ID = "stcgym/QuadrupleTankFamily-v0"
#: The quadruple tank's references: each lower level its own random steps of up to 2 cm, held
#: 50-150 samples (4-12.5 minutes at 5 s, a few of the slowest time constants), drawn
#: independently per channel.
TANK_REFERENCE = {"kind": "random_steps", "amplitude": 2.0, "hold": [50, 150]}
#: controlgym 1.0.0's linear-control defaults: ``noise_cov = random_init_state_cov = 0.1``.
CONTROLGYM_STEPS = 1000
CONTROLGYM_SETTINGS = {
    "steps": CONTROLGYM_STEPS,
    "noise_std": 0.0,
    "process_noise_std": math.sqrt(0.1),
    "initial_state_std": math.sqrt(0.1),
    "control_cost": 0.0,
    "reference": {"kind": "zero"},
}
#: The valve switch of ``mimo_switch``: from ``P-`` to ``P+`` half-way through the episode.
SWITCH = ("quadruple_tank", "quadruple_tank_nmp")


def formulation(plant: str) -> str:
    """``"controlgym"`` for a plant with a measured output and a noise input in its source
    (``he1``, ``ac1``), else ``"process"``.

    Examples
    --------
    >>> from stcgym.agents.evaluation.mimo import formulation
    >>> formulation("he1"), formulation("quadruple_tank_nmp")
    ('controlgym', 'process')
    """
    spec = get_mimo_plant(plant)
    return "controlgym" if spec.B1_c is not None else "process"


@dataclass(frozen=True)
class MimoEnvSpec(EnvSpec):
    """The environment of a ``mimo`` scenario: one MIMO catalogue plant, or a split of the
    quadruple-tank family (:data:`~stcgym.envs.tank_family.TANK_FAMILY`), measured state, the
    cost of its performance output.

    The fields are :class:`~stcgym.agents.evaluation.evaluate.EnvSpec`'s (``reference`` a spec
    for every channel of ``z``; ``family`` only the tank family's key, with its ``split``), and
    ``process_noise_std`` (the env's), ``switch_to`` (a MIMO catalogue plant the model jumps to
    at ``jump_step``).

    Raises
    ------
    ValueError
        On construction: not exactly one plant (or both a plant and a family), an unknown
        MIMO plant (the message lists the catalogue), an unknown family or split, ``steps``
        not a positive integer, a switch outside the episode, to a plant of other dimensions
        or in a family, ``jump_to``.

    Examples
    --------
    >>> from stcgym.agents.evaluation.mimo import MimoEnvSpec, TANK_REFERENCE
    >>> spec = MimoEnvSpec("quadruple_tank", steps=200, reference=TANK_REFERENCE)
    >>> spec.channels, spec.order
    ((4, 2), 4)
    >>> obs, info = spec.make().reset(seed=0)
    >>> obs.shape  # [x(0) + v(0), r_x(0)]: four levels and the target of each
    (8,)
    >>> EnvSpec.from_dict(spec.to_dict()) == spec
    True

    The test split of the quadruple-tank family, a member drawn per episode:

    >>> test = MimoEnvSpec(family="quadruple_tank-v1", split="test", steps=200,
    ...                    reference=TANK_REFERENCE)
    >>> len(test.plant_names()), test.plant_names()[0], test.channels
    (100, 'quadruple_tank-v1/test/250', (4, 2))
    """

    process_noise_std: float = 0.0
    switch_to: str | None = None
    plant_kind: ClassVar[str] = "mimo"

    def __post_init__(self) -> None:
        from stcgym.agents.evaluation.env_spec import freeze

        plants = (self.plants,) if isinstance(self.plants, str) else tuple(self.plants)
        object.__setattr__(self, "reference", freeze(self.reference))
        if int(self.steps) != self.steps or self.steps < 1:
            raise ValueError(f"episode steps must be a positive integer, got {self.steps!r}")
        if self.family is not None:
            self._check_tank_family(plants)
            return
        if len(plants) != 1:
            raise ValueError(f"a MIMO scenario runs on one MIMO plant, got {list(plants)}")
        object.__setattr__(self, "plants", (get_mimo_plant(plants[0]).name,))
        if self.jump_to is not None:
            raise ValueError("a MIMO scenario has one plant; its switch is switch_to, jump_step")
        if (self.jump_step is None) != (self.switch_to is None):
            raise ValueError("switch_to and jump_step go together")
        if self.switch_to is not None:
            other = get_mimo_plant(self.switch_to)
            if (other.n_states, other.n_inputs) != (self.plant.n_states, self.plant.n_inputs):
                raise ValueError(f"switch_to {self.switch_to!r} has other dimensions")
            object.__setattr__(self, "switch_to", other.name)
            if not 0 < self.jump_step < self.steps:
                raise ValueError(
                    f"jump_step must lie inside the episode (0, {self.steps}), got {self.jump_step}"
                )

    def _check_tank_family(self, plants: tuple[str, ...]) -> None:
        from stcgym.envs.tank_family import TANK_FAMILY

        if self.family != TANK_FAMILY.key:
            raise ValueError(f"a MIMO family must be {TANK_FAMILY.key!r}, got {self.family!r}")
        if plants:
            raise ValueError("give plants or a family, not both")
        if self.split not in TANK_FAMILY.split_names:
            raise ValueError(
                f"split must be one of {TANK_FAMILY.split_names} of family {self.family!r}, "
                f"got {self.split!r}"
            )
        if self.jump_to is not None or self.jump_step is not None or self.switch_to is not None:
            raise ValueError("a MIMO family has no switch (jump_step, jump_to, switch_to)")
        if self.jump_probability not in (None, 0.0):
            raise ValueError(f"a MIMO family has no jumps, got {self.jump_probability!r}")

    def _members(self) -> list[MimoPlantSpec]:
        from stcgym.envs.tank_family import TANK_FAMILY

        return TANK_FAMILY.members(self.split)

    @property
    def plant(self) -> MimoPlantSpec:
        """The catalogue entry of the plant (a family: its first member; the members share
        the performance output, input range and dimensions, so the cost's weights)."""
        if self.family is not None:
            return self._members()[0]
        return get_mimo_plant(self.plants[0])

    @property
    def order(self) -> int:
        """Number of states ``n``."""
        return self.plant.n_states

    @property
    def channels(self) -> tuple[int, int]:
        """``(outputs, inputs)``: the ``n`` measured states (the observation ``[x, r_x]``)
        and the ``m`` inputs."""
        return self.plant.n_states, self.plant.n_inputs

    def plant_names(self) -> list[str]:
        if self.family is not None:
            return [p.name for p in self._members()]
        return list(self.plants)

    def reference_spec(self) -> dict[str, Any]:
        """The reference of every channel of ``z`` (zero when the spec has none)."""
        return {"kind": "zero"} if self.reference is None else thaw(self.reference)

    def _kwargs(self) -> tuple[str, dict[str, Any]]:
        kwargs: dict[str, Any] = dict(
            self._common_kwargs(),
            reference_in="state",
            process_noise_std=float(self.process_noise_std),
        )
        if self.switch_to is not None:
            from stcgym.envs.signals import Jumps

            A, B = get_mimo_plant(self.switch_to).discrete()
            kwargs["schedule"] = Jumps({int(self.jump_step): np.hstack((A, B))})
        if self.family is not None:
            return TANK_FAMILY_ENV_ID, {**kwargs, "split": self.split}
        return MIMO_ENV_ID, {**kwargs, "plant": self.plants[0], "cost": "performance"}

    def reset_episode(self, env: gym.Env, seed: int, plant: str | None) -> tuple[Any, Any, Any]:
        """``(obs, info, plant_spec)`` of ``env.reset(seed=seed)``; ``plant`` may only name the
        spec's own plant (a family: one of the split's members; default the env's draw)."""
        if self.family is not None:
            options = None if plant is None else {"plant": plant}
            obs, info = env.reset(seed=int(seed), options=options)
            return obs, info, env.unwrapped.mimo_plant
        if plant is not None and plant.lower() != self.plants[0]:
            raise ValueError(f"plant must be {self.plants[0]!r} (the spec's), got {plant!r}")
        obs, info = env.reset(seed=int(seed))
        return obs, info, env.unwrapped.mimo_plant

    def reset_lanes(
        self, env: Any, seeds: list[int], plants: list[str] | None
    ) -> tuple[np.ndarray, list[Any]]:
        if self.family is not None:
            options = None if plants is None else {"plant": list(plants)}
            obs, _ = env.reset(seed=[int(s) for s in seeds], options=options)
            return obs, list(env.plants)
        obs, _ = env.reset(seed=[int(s) for s in seeds])
        return obs, [self.plant] * len(seeds)

    def to_dict(self) -> dict[str, Any]:
        """The spec as JSON data, marked ``kind: "mimo"`` (``EnvSpec.from_dict`` reads it)."""
        return {**super().to_dict(), "kind": "mimo"}


class InformedLQR:
    """The yardstick of a ``mimo`` scenario: the LQR on the true ``(A, B)`` of each lane
    (:class:`~stcgym.adaptive.LQRController`) with the scenario's weights, told the new model
    whenever it changes (:meth:`set_model`, the valve switch). ``predict`` and ``reset`` are
    the LQR's.

    Parameters
    ----------
    A, B : array_like
        Per-lane true matrices ``(lanes, n, n)``, ``(lanes, n, m)``.
    Q, R, N : array_like
        LQ weights (``N``, the cross weight, only where the cost has one).
    action_bound : float
        The bench's action bound.
    """

    def __init__(
        self, A: Any, B: Any, *, Q: Any, R: Any, N: Any = None, action_bound: float
    ) -> None:
        self._A = np.array(A, dtype=float)
        self._B = np.array(B, dtype=float)
        self._weights = {"Q": Q, "R": R} if N is None else {"Q": Q, "R": R, "N": N}
        self._bound = float(action_bound)
        self.policy = self._design()

    def predict(
        self, observation: Any, state: Any = None, episode_start: Any = None, deterministic=True
    ) -> tuple[NDArray, Any]:
        return self.policy.predict(observation, state, episode_start, deterministic)

    def reset(self) -> None:
        """The LQR has no state."""
        self.policy.reset()

    def _design(self) -> Any:
        from stcgym.adaptive import LQRController

        return LQRController(
            self._A, self._B, num_envs=len(self._A), action_bound=self._bound, **self._weights
        )

    def set_model(self, A: Any, B: Any, lanes: Any = None) -> None:
        """The lanes ``lanes`` (a mask; default all) now run on ``(A, B)``, one per such lane."""
        mask = np.ones(len(self._A), dtype=bool) if lanes is None else np.asarray(lanes, bool)
        self._A[mask], self._B[mask] = A, B
        self.policy = self._design()


class OutputLQG:
    """LQG on the true model from the measured output: the LQ gain of the cost
    ``x' Q x + u' R u + 2 x' N u`` (:func:`stcgym.adaptive.multivariable.lqr.lqr_design`) on the
    current
    estimate of the steady-state Kalman filter for process noise ``W`` and output noise ``V``
    (the Riccati solution of python-control's ``dlqe``), starting from ``x_hat = 0``.

    At step ``k`` the env observes ``[y(k), r(k)]`` (the reference is ignored: regulation);
    the filter corrects its prediction with ``y(k)``,
    ``x_hat(k|k) = x_hat(k|k-1) + M (y(k) - C x_hat(k|k-1))``, ``M = S C' (C S C' + V)^-1``,
    applies ``u(k) = -K x_hat(k|k)`` (clipped to ``action_bound``) and predicts
    ``x_hat(k+1|k) = A x_hat(k|k) + B u(k)``.

    Parameters
    ----------
    A, B, C : array_like
        The true model (``(n, n)``, ``(n, m)``, ``(p, n)``).
    Q, R, N : array_like
        LQ weights (``N`` default zero).
    W, V : array_like
        Process and output noise covariances (``(n, n)``, ``(p, p)``; ``V`` positive definite).
    num_envs : int or None
        ``None``: one env (``predict`` on ``(p + p_r,)``); else that many lanes.
    action_bound : float
        Inputs are clipped to ``[-action_bound, action_bound]``.

    Examples
    --------
    he1 in controlgym's formulation, measuring only its second state:

    >>> import gymnasium as gym
    >>> import numpy as np
    >>> from stcgym.agents.evaluation.mimo import OutputLQG
    >>> from stcgym.envs import get_mimo_plant
    >>> plant = get_mimo_plant("he1")
    >>> (A, B), G = plant.discrete(), plant.noise_input()
    >>> Q, R, N = plant.lq_weights()
    >>> lqg = OutputLQG(A, B, np.array(plant.C_y), Q, R, N, W=0.1 * G @ G.T, V=0.1 * np.eye(1))
    >>> env = gym.make("stcgym/StateSpace-v0", plant="he1", cost="performance",
    ...                measured="output", control_cost=0.0, reference="zero")
    >>> obs, _ = env.reset(seed=0, options={"initial_state": [1.0, 0.0, 0.0, 0.0]})
    >>> lqg.predict(obs)[0].shape
    (2,)
    """

    def __init__(
        self,
        A: Any,
        B: Any,
        C: Any,
        Q: Any,
        R: Any,
        N: Any = None,
        *,
        W: Any,
        V: Any,
        num_envs: int | None = None,
        action_bound: float = 1e9,
    ) -> None:
        import control

        from stcgym.adaptive.multivariable.lqr import lqr_design

        self.A, self.B, self.C = (np.array(M, dtype=float) for M in (A, B, C))
        n, m = self.B.shape
        self.K = lqr_design(self.A, self.B, Q, R, N)[0]
        S = np.asarray(control.dlqe(self.A, np.eye(n), self.C, W, V)[1], dtype=float)
        V = np.asarray(V, dtype=float)
        self.M = S @ self.C.T @ np.linalg.inv(self.C @ S @ self.C.T + V)
        self.num_envs, self.action_bound = num_envs, float(action_bound)
        self._x_pred = np.zeros((1 if num_envs is None else int(num_envs), n))

    def reset(self) -> None:
        """``x_hat = 0`` on every lane."""
        self._x_pred[:] = 0.0

    def predict(
        self, observation: Any, state: Any = None, episode_start: Any = None, deterministic=True
    ) -> tuple[NDArray, None]:
        obs = np.atleast_2d(np.asarray(observation, dtype=float))
        y = obs[:, : self.C.shape[0]]
        x_hat = self._x_pred + (y - self._x_pred @ self.C.T) @ self.M.T
        u = np.clip(-x_hat @ self.K.T, -self.action_bound, self.action_bound)
        self._x_pred = x_hat @ self.A.T + u @ self.B.T
        return (u[0] if self.num_envs is None else u), None


def channel_metrics(z: NDArray, r: NDArray, span: int) -> dict[str, NDArray]:
    """Per-episode tracking figures of a multi-channel run.

    ``track_rms_<i>`` (``i = 1, 2``): the RMS tracking error ``e_i = z_i - r_i`` of channel
    ``i`` over the steps lived; ``cross_peak``: the cross-channel disturbance, how far a
    channel's error moves, ``max |e_i(t) - e_i(k)|`` over the ``span`` steps after a reference
    step of another channel ``j`` between ``k`` and ``k + 1`` while ``r_i`` holds, averaged
    over such steps (``nan`` without one).

    Parameters
    ----------
    z, r : ndarray, shape (B, T + 1, p)
        Performance outputs and references (``nan`` after a divergence).
    span : int
        Steps after a reference step that belong to it.

    Examples
    --------
    Channel 2 follows its reference exactly; channel 1 sits 0.2 off its reference and is
    knocked a further 0.5 off when channel 2's reference steps after ``k = 2``:

    >>> import numpy as np
    >>> from stcgym.agents.evaluation.mimo import channel_metrics
    >>> r = np.zeros((1, 8, 2)); r[0, 3:, 1] = 1.0
    >>> z = r.copy(); z[0, :, 0] = 0.2; z[0, 4, 0] = 0.7
    >>> m = channel_metrics(z, r, span=3)
    >>> [round(float(m[key][0]), 4) for key in ("track_rms_1", "track_rms_2", "cross_peak")]
    [0.3102, 0.0, 0.5]
    """
    B, T1, p = z.shape
    e = z - r
    out = {f"track_rms_{i + 1}": np.full(B, math.nan) for i in range(2)}
    out["cross_peak"] = np.full(B, math.nan)
    with np.errstate(invalid="ignore"):
        for i in range(min(p, 2)):
            out[f"track_rms_{i + 1}"] = np.sqrt(np.nanmean(e[:, :, i] ** 2, axis=1))
    for b in range(B):
        peaks = []
        steps = np.diff(r[b], axis=0) != 0  # (T, p): r steps between k and k + 1
        for k, j in zip(*np.nonzero(steps), strict=True):
            stop = min(T1, k + 1 + span)
            for i in range(p):
                if i == j or steps[k : stop - 1, i].any():
                    continue
                moved = np.abs(e[b, k + 1 : stop, i] - e[b, k, i])
                if moved.size and np.isfinite(moved).all():
                    peaks.append(float(moved.max()))
        if peaks:
            out["cross_peak"][b] = float(np.mean(peaks))
    return out
