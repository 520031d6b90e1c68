"""What a controller reads from the env it runs on, checked against its own settings.

The single-input controllers (:class:`~stcgym.adaptive.SelfTuningController` and its
known-model oracles) read an env's plant order, input bound, canonical form and lane count
(:func:`env_settings`, resolved with the controller's arguments by :func:`plant_settings`);
the multivariable ones its state and input dimensions, input bound and range, cost and
observation layout (:func:`mimo_env_settings`, :func:`resolve_dimensions`,
:func:`input_limits`, :func:`split_observation`). Every mismatch is a ``ValueError`` naming
the setting.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from stcgym.envs.canonical import check_form
from stcgym.lanes.validation import integer, real_in

__all__ = [
    "DEFAULT_ACTION_BOUND",
    "env_settings",
    "input_limits",
    "mimo_env_settings",
    "plant_settings",
    "resolve_dimensions",
    "split_observation",
]

#: Saturation of the input when neither ``action_bound`` nor an env gives one (the envs' default).
DEFAULT_ACTION_BOUND = 10.0


def _action_bound(action_bound: Any, env_bound: float | None) -> float:
    """``action_bound`` (default the env's bound, else :data:`DEFAULT_ACTION_BOUND`), ``> 0``
    and not above the env's."""
    if action_bound is None:
        action_bound = DEFAULT_ACTION_BOUND if env_bound is None else env_bound
    bound = real_in(action_bound, "action_bound", lo=0.0, lo_open=True)
    if env_bound is not None and bound > env_bound:
        raise ValueError(f"action_bound={bound} exceeds the env's action_bound={env_bound}")
    return bound


def env_settings(env: Any) -> tuple[int | None, float | None, str | None, int | None]:
    """``(n, action_bound, form, num_envs)`` of an stcgym env, vector env or wrapper."""
    base = getattr(env, "unwrapped", env)
    n_inputs = getattr(base, "n_inputs", 1)
    n_outputs = getattr(base, "n_outputs", 1)
    if n_inputs != 1 or n_outputs != 1:
        raise ValueError(
            f"the controllers are single-input single-output; the env has "
            f"{n_inputs} inputs and {n_outputs} outputs (a plant with measured state takes "
            f"stcgym.adaptive.MultivariableSelfTuningController and LQRController)"
        )
    n = getattr(base, "n_states", None)
    bound = getattr(base, "action_bound", None)
    form = getattr(base, "form", None)
    num = getattr(env, "num_envs", None)
    return (
        None if n is None else int(n),
        None if bound is None else float(np.max(bound)),
        None if form is None else str(form),
        None if num is None else int(num),
    )


def plant_settings(
    n: int,
    *,
    num_envs: Any = None,
    action_bound: Any = None,
    form: Any = None,
    env: Any = None,
) -> tuple[int | None, float, str]:
    """``(num_envs, action_bound, form)`` of a controller of order ``n``, checked against ``env``.

    ``action_bound=None`` takes the env's bound, else :data:`DEFAULT_ACTION_BOUND`;
    ``form=None`` the env's form, else ``"observer"``. With an
    env, ``n``, ``num_envs`` and ``form`` must match it and ``action_bound`` must not exceed it.
    Raises ``ValueError`` naming the setting.
    """
    env_n, env_bound, env_form, env_num = (None,) * 4 if env is None else env_settings(env)
    if env_n is not None and env_n != n:
        raise ValueError(f"n={n} does not match the env's plant order n={env_n}")
    if num_envs is not None:
        num_envs = integer(num_envs, "num_envs", 1)
    if env_num is not None and num_envs != env_num:
        raise ValueError(
            f"num_envs={num_envs} does not match the env's num_envs={env_num}: build the "
            f"controller with num_envs={env_num}"
        )
    bound = _action_bound(action_bound, env_bound)
    form = check_form((env_form or "observer") if form is None else form)
    if env_form is not None and env_form != form:
        raise ValueError(f"form={form!r} does not match the env's form {env_form!r}")
    return num_envs, bound, form


def mimo_env_settings(env: Any, n_states: Any = None) -> dict[str, Any]:
    """``n_states``, ``n_inputs``, ``action_bound``, ``control_cost``, ``num_envs``,
    ``obs_dim`` and ``input_range`` (``(low, high)`` or ``None``) of an env or vector env (or a
    wrapper of one).

    A ``stcgym/StateSpace-v0`` env is read from its plant (observation ``[x, r]``, ``obs_dim =
    2 n``), checking the state is measured. Any other Gymnasium env needs a 1-D ``Box``
    observation that is the state ``x`` (``obs_dim = n``, regulation to ``r = 0``) or ``[x,
    r]`` (``obs_dim = 2 n``; give ``n_states`` to say which, default the state alone) and a 1-D
    ``Box`` action space: ``n_inputs`` is its size, ``action_bound`` the largest symmetric
    bound inside it, ``input_range`` its bounds, ``control_cost`` the default 0.01.

    Raises ``ValueError`` when a StateSpace env's output is not the state (``C != I`` or
    ``D != 0``), or when another env's spaces are not such ``Box`` spaces.
    """
    base = getattr(env, "unwrapped", env)
    C = getattr(base, "C", None)
    D = getattr(base, "D", None)
    n = getattr(base, "n_states", None)
    num = getattr(env, "num_envs", None)
    num = None if num is None else int(num)
    if C is None or n is None:
        return _gymnasium_env_settings(env, n_states, num)
    C = np.asarray(C, dtype=float)
    if C.shape != (n, n) or not np.array_equal(C, np.eye(n)):
        raise ValueError(
            f"the multivariable controllers need the measured state (C = I, {n} x {n}); the "
            f"env's C has shape {C.shape} and is not the identity"
        )
    if D is not None and np.any(np.asarray(D) != 0):
        raise ValueError("the multivariable controllers need D = 0 (the env's D is not zero)")
    return {
        "n_states": int(n),
        "n_inputs": int(base.n_inputs),
        "action_bound": float(np.max(base.action_bound)),
        "control_cost": float(base.control_cost),
        "num_envs": num,
        "obs_dim": 2 * int(n),
        "input_range": getattr(base, "input_range", None),
    }


def _gymnasium_env_settings(env: Any, n_states: Any, num_envs: int | None) -> dict[str, Any]:
    """:func:`mimo_env_settings` of an env that is not stcgym's: read from its spaces."""
    from gymnasium import spaces

    obs_space = getattr(env, "single_observation_space", None) or getattr(
        env, "observation_space", None
    )
    act_space = getattr(env, "single_action_space", None) or getattr(env, "action_space", None)
    if not (isinstance(obs_space, spaces.Box) and len(obs_space.shape) == 1):
        raise ValueError(
            "env must be a stcgym/StateSpace-v0 env or a Gymnasium env whose observation space "
            f"is a 1-D Box holding the state (or [state, reference]), got {obs_space!r}"
        )
    if not (isinstance(act_space, spaces.Box) and len(act_space.shape) == 1):
        raise ValueError(
            "the multivariable controllers need a 1-D Box action space (one entry per input), "
            f"got {act_space!r}"
        )
    p = int(obs_space.shape[0])
    n = p if n_states is None else integer(n_states, "n_states", 1)
    if p not in (n, 2 * n):
        raise ValueError(
            f"the env's observation has {p} entries: with n_states={n} it must be the state "
            f"({n}) or [state, reference] ({2 * n})"
        )
    low = np.asarray(act_space.low, dtype=float)
    high = np.asarray(act_space.high, dtype=float)
    bound = float(min(np.min(-low), np.min(high)))
    if not bound > 0:
        raise ValueError(
            "the env's action space must contain a symmetric box around 0 (the controllers "
            f"saturate every input at +-action_bound), got low={low}, high={high}"
        )
    return {
        "n_states": n,
        "n_inputs": int(act_space.shape[0]),
        "action_bound": bound,
        "control_cost": 0.01,
        "num_envs": num_envs,
        "obs_dim": p,
        "input_range": (low, high),
    }


def resolve_dimensions(
    n_states: Any, n_inputs: Any, num_envs: Any, action_bound: Any, env: Any
) -> tuple[int, int, int | None, float, float, int]:
    """``(n, m, num_envs, action_bound, control_cost, obs_dim)`` from the arguments and the
    env, checked against each other (``ValueError`` naming the mismatch); ``obs_dim`` is
    ``2 n`` (``[x, r]``) without an env (:func:`mimo_env_settings`)."""
    es = None if env is None else mimo_env_settings(env, n_states)
    if es is None and (n_states is None or n_inputs is None):
        raise ValueError("give env=... or both n_states and n_inputs")
    n = es["n_states"] if n_states is None else integer(n_states, "n_states", 1)
    m = es["n_inputs"] if n_inputs is None else integer(n_inputs, "n_inputs", 1)
    cost = 0.01
    if es is not None:
        if n != es["n_states"] or m != es["n_inputs"]:
            raise ValueError(
                f"n_states={n}, n_inputs={m} do not match the env's plant "
                f"({es['n_states']} states, {es['n_inputs']} inputs)"
            )
        if num_envs is None:
            num_envs = es["num_envs"]
        elif es["num_envs"] != num_envs:
            raise ValueError(
                f"num_envs={num_envs} does not match the env's num_envs={es['num_envs']}"
            )
        cost = es["control_cost"]
    if num_envs is not None:
        num_envs = integer(num_envs, "num_envs", 1)
    bound = _action_bound(action_bound, None if es is None else es["action_bound"])
    return n, m, num_envs, bound, cost, 2 * n if es is None else es["obs_dim"]


def input_limits(
    input_range: Any, m: int, bound: float, env_range: Any = None
) -> tuple[NDArray, NDArray]:
    """Every input's range ``(low, high)`` (``m`` values each): ``input_range`` (a pair of
    numbers or of ``m`` values), else the env's, else ``[-bound, bound]``, always inside
    ``[-bound, bound]``. ``ValueError`` naming ``input_range`` unless ``low < 0 < high`` (the
    start-up probe is zero-mean around the operating point ``u = 0``)."""
    given = env_range if input_range is None else input_range
    if given is None:
        return np.full(m, -bound), np.full(m, bound)
    try:
        low, high = (np.broadcast_to(np.asarray(v, dtype=float), (m,)).copy() for v in given)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"input_range must be a pair (low, high) of numbers or of {m} values, got "
            f"{input_range!r}"
        ) from exc
    if not (np.all(low < 0) and np.all(high > 0)):
        raise ValueError(
            f"input_range must hold u = 0 inside every input's range (low < 0 < high), got "
            f"low={low}, high={high}"
        )
    return np.maximum(low, -bound), np.minimum(high, bound)


def split_observation(obs: NDArray, n: int) -> tuple[NDArray, NDArray]:
    """``(X, R)`` of a ``(lanes, obs_dim)`` batch: the states and the references (zero when
    the observation is the state alone), C-contiguous."""
    X = np.ascontiguousarray(obs[:, :n])
    if obs.shape[1] == n:
        return X, np.zeros_like(X)
    return X, np.ascontiguousarray(obs[:, n:])
