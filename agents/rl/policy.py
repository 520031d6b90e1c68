"""The policy-protocol adapter of a trained Stable-Baselines3 model: :class:`SB3Policy` runs
the model on lanes through the :class:`~stcgym.adaptive.policy.LanePolicy` protocol that the
controllers and oracles share (``predict`` / ``reset``), with the observation window, the
interface's inputs (an estimator's estimate, the true parameters) and the observation
normaliser's statistics of the checkpoint kept (:class:`ObsNorm`); recurrent agents carry
their LSTM state here. :func:`~stcgym.agents.rl.sb3.load_agent` returns one.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from stcgym.adaptive.policy import LanePolicy
from stcgym.agents.rl.interfaces import InterfaceSpec
from stcgym.agents.rl.wrappers import WindowConfig
from stcgym.lanes.validation import integer

__all__ = ["ObsNorm", "SB3Policy"]


@dataclass(frozen=True)
class ObsNorm:
    """A frozen snapshot of SB3's ``VecNormalize`` observation statistics.

    :meth:`apply` is ``VecNormalize.normalize_obs``:
    ``clip((x - mean) / sqrt(var + epsilon), -clip, clip)``.

    Examples
    --------
    >>> import numpy as np
    >>> from stcgym.agents.rl.policy import ObsNorm
    >>> norm = ObsNorm(mean=(1.0, 0.0), var=(4.0, 1.0), clip=10.0, epsilon=0.0)
    >>> norm.apply(np.array([[3.0, 50.0]]))
    array([[ 1., 10.]])
    """

    mean: tuple[float, ...]
    var: tuple[float, ...]
    clip: float = 10.0
    epsilon: float = 1e-8

    @classmethod
    def of(cls, vec_normalize: Any) -> ObsNorm:
        """The current statistics of a ``VecNormalize`` (a copy)."""
        rms = vec_normalize.obs_rms
        return cls(
            tuple(float(v) for v in np.ravel(rms.mean)),
            tuple(float(v) for v in np.ravel(rms.var)),
            float(vec_normalize.clip_obs),
            float(vec_normalize.epsilon),
        )

    def apply(self, features: NDArray) -> NDArray:
        mean, var = np.asarray(self.mean), np.asarray(self.var)
        return np.clip((features - mean) / np.sqrt(var + self.epsilon), -self.clip, self.clip)

    def to_dict(self) -> dict[str, Any]:
        return {"mean": list(self.mean), "var": list(self.var), "clip": self.clip,
                "epsilon": self.epsilon}  # fmt: skip

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> ObsNorm | None:
        if data is None:
            return None
        return cls(tuple(data["mean"]), tuple(data["var"]), data["clip"], data["epsilon"])


class SB3Policy(LanePolicy):
    """An SB3 model behind the shared policy protocol, fed with raw ``[y, r]`` observations.

    The model was trained on :class:`~stcgym.agents.rl.wrappers.HistoryWindow` features (and
    what its :class:`~stcgym.agents.rl.interfaces.InterfaceSpec` adds: an estimator's estimate,
    a self-tuning controller's input); this adapter rebuilds them itself from the raw
    observations it is given and the actions it returned (the interface's lanes: a
    :class:`~stcgym.agents.rl.wrappers.HistoryBuffer` with one window per lane, the estimator
    or controller batched over the lanes), and turns the model's action into the input
    (``a s`` with ``s`` the interface's action unit, or a residual agent's correction of the
    controller's input).
    ``episode_start`` (or :meth:`reset`) starts a new window on those lanes, and a new LSTM
    state for a recurrent model (sb3-contrib ``RecurrentPPO``), which the adapter carries from
    call to call. ``predict`` is :class:`~stcgym.adaptive.policy.LanePolicy`'s.

    Parameters
    ----------
    model
        A trained SB3 model (``predict`` on the window features).
    window
        The :class:`~stcgym.agents.rl.wrappers.WindowConfig` the model was trained with.
    action_bound
        The environment's action bound.
    num_envs
        ``None`` for one env (``predict`` on ``(2,)`` gives ``(1,)``), or ``B`` lanes
        (``predict`` on ``(B, 2)`` gives ``(B, 1)``).
    channels
        ``(outputs, inputs)`` of the plant, ``(p, m)``: observations ``(2 p,)``, actions
        ``(m,)`` (default one of each).
    obs_norm
        The observation normaliser the model was trained behind (``None``: none).
    interface
        What the model observes besides the window and how its action becomes the input
        (:class:`~stcgym.agents.rl.interfaces.InterfaceSpec`; ``None``: the window alone).
    seeds
        The controller seed of each lane of a residual agent (default: from the lane indices
        and the training run, :meth:`InterfaceSpec.build`).

    Raises
    ------
    ValueError
        ``num_envs`` not a positive integer; from ``predict``, an observation of the wrong
        shape or not finite (the adapter is left unchanged).

    Examples
    --------
    An (untrained) PPO model on the window of :class:`~stcgym.agents.HistoryWindow`, asked
    for actions on raw observations of three plants:

    >>> import gymnasium as gym
    >>> import numpy as np
    >>> import stcgym.envs
    >>> from stable_baselines3 import PPO
    >>> from stcgym.agents import HistoryWindow, SB3Policy, WindowConfig
    >>> window = WindowConfig(window=4)
    >>> env = HistoryWindow(gym.make("stcgym/ObserverCanonical-v0", plant="unstable2"), window)
    >>> model = PPO("MlpPolicy", env, seed=0, device="cpu")
    >>> policy = SB3Policy(model, window, action_bound=10.0, num_envs=3)
    >>> actions, state = policy.predict(np.array([[0.0, 1.0], [0.5, 1.0], [2.0, -1.0]]))
    >>> actions.shape, state, bool(np.all(np.abs(actions) <= 10.0))
    ((3, 1), None, True)
    >>> policy.predict(np.array([0.0, 1.0]))
    Traceback (most recent call last):
    ...
    ValueError: observation must have shape (3, 2), one row per lane for num_envs=3, ...
    """

    def __init__(
        self,
        model: Any,
        window: WindowConfig,
        action_bound: float,
        num_envs: int | None = None,
        channels: tuple[int, int] = (1, 1),
        obs_norm: ObsNorm | None = None,
        interface: InterfaceSpec | None = None,
        seeds: Sequence[int] | None = None,
    ) -> None:
        self.model, self.window, self.action_bound = model, window, float(action_bound)
        self.obs_norm = obs_norm
        self.num_envs = None if num_envs is None else integer(num_envs, "num_envs", 1)
        p, m = (integer(c, "channels", 1) for c in channels)
        self.channels, self.obs_dim, self.action_dim = (p, m), 2 * p, m
        self.recurrent = type(model).__name__ == "RecurrentPPO"
        self.interface = InterfaceSpec() if interface is None else interface
        if seeds is not None and len(seeds) != self.num_lanes:
            raise ValueError(f"seeds must hold one seed per lane ({self.num_lanes}), got {seeds}")
        self.seeds = None if seeds is None else [int(s) for s in seeds]
        self._lanes = self._build_lanes()
        self._theta: NDArray | None = None
        self._lstm: Any = None
        # lanes whose next observation starts an episode (every lane before the first call)
        self._fresh = np.ones(self.num_lanes, dtype=bool)

    @property
    def lanes(self) -> Any:
        """What the adapter keeps per lane: the interface's window, and its estimator
        (``lanes.estimator``) or controller (``lanes.controller``); read-only use."""
        return self._lanes

    def _build_lanes(self) -> Any:
        return self.interface.build(
            self.window, self.action_bound, self.num_lanes, self.channels, self.seeds
        )

    def with_lanes(
        self,
        num_envs: int | None,
        seeds: Sequence[int] | None = None,
        plants: Sequence[Any] | None = None,
    ) -> SB3Policy:
        """The same model (shared, not copied) behind a fresh adapter for ``num_envs`` lanes.

        ``seeds``: the episode seeds of the lanes, from which a residual agent's controller
        seeds follow (:func:`~stcgym.agents.controllers.controller_seeds` with the training
        run, as the bench seeds its ``stc`` runs). ``plants``: the plant specs the lanes start
        on (``.a``, ``.b``), told to an agent of the ``"true"`` interface."""
        lanes = None
        if seeds is not None and self.interface.kind == "residual":
            from stcgym.agents.controllers import controller_seeds

            lanes = controller_seeds(seeds, self.interface.run)
        policy = SB3Policy(
            self.model, self.window, self.action_bound, num_envs, self.channels, self.obs_norm,
            self.interface, lanes,
        )  # fmt: skip
        if plants is not None and self.informed:
            policy.set_model([p.a for p in plants], [p.b for p in plants])
        return policy

    @property
    def informed(self) -> bool:
        """Whether the agent observes the true parameters (the ``"true"`` interface): the
        evaluation tells it the plants and every jump (``run_episodes(..., informed=True)``)."""
        return self.interface.kind == "true"

    @property
    def theta(self) -> NDArray | None:
        """The true parameters ``[a | b]`` per lane an informed agent was told (``None`` for
        the other interfaces)."""
        return self._lanes.theta.copy() if self.informed else None

    def set_model(self, a: Any, b: Any, lanes: Any = None) -> None:
        """Tell an agent of the ``"true"`` interface the true parameters of ``lanes``
        (default all), as the known-model oracles are told them.

        Raises
        ------
        ValueError
            The agent does not observe the parameters.
        """
        if not self.informed:
            raise ValueError(f"an agent of the {self.interface.kind!r} interface is told no model")
        self._lanes.set_model(a, b, lanes)
        self._theta = self._lanes.theta.copy()  # kept across a reset of every lane

    def reset(self, lanes: Any = None) -> None:
        """A new episode on every lane (a fresh estimator or controller too), or on ``lanes``
        (indices or a boolean mask)."""
        if lanes is None:
            self._lanes = self._build_lanes()
            if self._theta is not None:
                self._lanes.theta[:] = self._theta
        super().reset(lanes)

    def _reset_lanes(self, idx: NDArray) -> None:
        """The next observation of the lanes ``idx`` starts a new window and LSTM state."""
        self._fresh[idx] = True

    def _act(self, obs: NDArray, starts: NDArray | None, deterministic: bool) -> NDArray:
        starts = self._fresh.copy() if starts is None else starts | self._fresh
        self._lanes.observe(obs, starts)
        self._fresh[:] = False
        features = self._lanes.features()
        if self.obs_norm is not None:
            features = self.obs_norm.apply(features).astype(np.float32)
        if self.recurrent:
            a, self._lstm = self.model.predict(
                features,
                state=self._lstm,
                episode_start=starts,
                deterministic=deterministic,
            )
        else:
            a, _ = self.model.predict(features, deterministic=deterministic)
        u = self._lanes.to_input(a)
        return u[0] if self.num_envs is None else u  # one env: (m,), as LanePolicy's fast path
