"""The plant step, written once: compiled lane functions shared by every stcgym plant.

Every environment of :mod:`stcgym.envs.plants` (one plant) and :mod:`stcgym.envs.vector`
(``B`` plants) advances its plant with the functions of this module, following the convention of
:mod:`stcgym.lanes.compiled`: a *lane function* advances one plant on 1-D (or 2-D matrix) views of
that plant's arrays, and a *batch loop* is ``for i in range(first, last): lane_fn(X[i], ...)``.
A single env therefore equals lane ``i`` of the vector env bit for bit, on any CPU: the same
machine code runs on the same numbers (no BLAS inside; the small loops are written out).

Plants (Ding & Ma 2014): the observer canonical form, eq. (1)-(5) (``form = OBSERVER``), and the
observability canonical form, eq. (146)-(147) (``form = OBSERVABILITY``), both with
``theta = [a1..an, b1..bn]`` and ``c = [1, 0, ..., 0]`` (:func:`shift_transition`); a general
state space ``x(k+1) = A x + B u + w``, ``y = C x + D u + v`` (MIMO); the multichannel static
object ``y^T = u^T Theta + v^T`` of Voevoda & Troshina (2017), without state.

Timing and reward (the environments' contract): at step ``k`` the input ``u(k)`` is clipped to
``[-action_bound, action_bound]``, the state advances with the parameters in force at ``k``, and
the output is ``y(k+1) = C x(k+1) + D u(k) + sigma_v z_v``; the reward is
``-(||clip(y_clean, +-y_bound) - r(k+1)||^2 + rho ||u(k)||^2)`` on the noise-free output
``y_clean``. ``diverged`` is true when an output leaves ``[-y_bound, y_bound]``, the state or
output stops being finite (then ``y`` and ``y_clean`` are replaced by their clipped values, NaN
by 0, so the observation stays finite) or the reward overflows (then the reward is
:data:`REWARD_FLOOR`, the most negative finite float): an episode never returns a non-finite
reward or observation.

Entry points (published signatures, also used by the compiled rollout of :mod:`stcgym.adaptive`;
arrays float64 and C-contiguous; each function's docstring gives its arguments):

* whole env steps, returning ``(reward, clipped, diverged, ...)``: :func:`canonical_plant_step`
  (SISO, floats), :func:`state_space_plant_step`, :func:`static_plant_step`;
* their pieces: clipping, transitions (:func:`shift_transition`, ...), outputs, noise,
  :func:`observe` (divergence test, safe replacement, reward), :func:`performance_reward`;
* batch loops over lanes ``[first, last)``: :func:`canonical_plants_step`,
  :func:`state_space_plants_step`, :func:`performance_rewards`, :func:`noise_inputs`, and at
  reset :func:`canonical_outputs` / :func:`state_outputs`, threaded from
  :data:`PARALLEL_MIN_LANES` lanes a thread on (:class:`stcgym.lanes.compiled.LaneLoop`).

``z_w``, ``z_v`` are standard normals (may be empty when the matching ``sigma`` is 0); those of
a rollout's next steps, with its references and parameters, come from
:meth:`stcgym.envs.vector.LinearPlantVectorEnv.lookahead` and reproduce the env bit for bit.
"""

from __future__ import annotations

import numpy as np

from stcgym.lanes.compiled import lane, lanes
from stcgym.lanes.linalg import all_finite

__all__ = [
    "OBSERVER",
    "OBSERVABILITY",
    "FORM_CODES",
    "REWARD_FLOOR",
    "clip_action",
    "shift_transition",
    "canonical_output",
    "add_noise",
    "state_space_transition",
    "linear_output",
    "matvec",
    "static_output",
    "observe",
    "canonical_plant_step",
    "state_space_plant_step",
    "static_plant_step",
    "canonical_plants_step",
    "state_space_plants_step",
    "canonical_outputs",
    "state_outputs",
    "performance_reward",
    "performance_rewards",
    "noise_inputs",
    "PARALLEL_MIN_LANES",
]

#: Fewest lanes a thread of a plant batch loop gets: smaller batches run on the calling thread.
#: The lane functions take no reference counts (no NRT), so threads do not contend for a
#: counter; what remains is the cost of handing blocks to the pool's threads and waiting for
#: them, which a plant step (about 30 ns per lane) only pays back for huge batches (the
#: measurements: the performance page of the documentation).
PARALLEL_MIN_LANES = 1 << 15


#: ``form`` codes of the canonical lane functions.
OBSERVER = 0
OBSERVABILITY = 1
FORM_CODES = {"observer": OBSERVER, "observability": OBSERVABILITY}

#: Reward reported when ``-(||e||^2 + rho ||u||^2)`` overflows (the step is marked diverged).
REWARD_FLOOR = -float(np.finfo(np.float64).max)


# ----------------------------------------------------------------------------------- pieces
@lane
def clip_input(u_raw, bound):
    """``(clip(u_raw, -bound, bound), clipped)`` for one input value."""
    if u_raw > bound:
        return bound, True
    if u_raw < -bound:
        return -bound, True
    return u_raw, False


@lane
def clip_action(u_raw, bound, u):
    """``u = clip(u_raw, -bound, bound)`` element by element; return whether any was clipped."""
    clipped = False
    for i in range(u.shape[0]):
        u[i], c = clip_input(u_raw[i], bound)
        clipped = clipped or c
    return clipped


@lane(entry=True)
def shift_transition(x, a, a0, b, b0, u, form):
    """``x <- A(a) x + b u`` in place with ``a = a[a0:a0+n]``, ``b = b[b0:b0+n]`` (no views).

    Observer form, eq. (1) (``form == OBSERVER``, ``A(a)`` with ``-a`` in its first column and
    ones on the superdiagonal): ``x_i(t+1) = -a_i x_1(t) + x_{i+1}(t) + b_i u(t)``,
    ``x_{n+1} = 0``. Observability form, eq. (146) (``form == OBSERVABILITY``, ``A(a)`` a shift
    with last row ``[-a_n, ..., -a_1]``, ``b`` the first ``n`` Markov parameters):
    ``x_i(t+1) = x_{i+1}(t) + b_i u(t)`` for ``i < n`` and
    ``x_n(t+1) = -(a_n x_1 + ... + a_1 x_n) + b_n u(t)``. ``u`` is a float.

    ``a`` and ``b`` are read in place at offsets rather than passed as views (each view passed to
    a call is a dozen machine words, a noticeable share of a small plant's step): e.g.
    ``shift_transition(x, theta, 0, theta, n, u, form)`` for ``theta = [a; b]``.
    """
    n = x.shape[0]
    if form == 0:
        x1 = x[0]
        for i in range(n - 1):
            x[i] = (-a[a0 + i] * x1 + x[i + 1]) + b[b0 + i] * u
        x[n - 1] = -a[a0 + n - 1] * x1 + b[b0 + n - 1] * u
    else:
        last = a[a0 + n - 1] * x[0]
        for j in range(1, n):
            last += a[a0 + n - 1 - j] * x[j]
        for i in range(n - 1):
            x[i] = x[i + 1] + b[b0 + i] * u
        x[n - 1] = -last + b[b0 + n - 1] * u


@lane(entry=True)
def add_noise(x, sigma, z):
    """``x <- x + sigma z`` in place (untouched when ``sigma == 0``)."""
    if sigma != 0.0:
        for i in range(x.shape[0]):
            x[i] += sigma * z[i]


@lane(entry=True)
def canonical_output(x):
    """``y = c x = x_1``: the output row of both canonical forms (eq. (2), (147); ``D = 0``)."""
    return x[0]


@lane
def state_space_transition(x, AB, u, tmp):
    """``x <- A x + B u`` in place, ``AB = [A B]`` of shape ``(n, n + m)``; ``tmp``: n floats."""
    n = x.shape[0]
    m = u.shape[0]
    for i in range(n):
        ax = 0.0
        for j in range(n):
            ax += AB[i, j] * x[j]
        bu = 0.0
        for j in range(m):
            bu += AB[i, n + j] * u[j]
        tmp[i] = ax + bu
    for i in range(n):
        x[i] = tmp[i]


@lane(inline=True, entry=True)
def matvec(A, v, out):
    """``out = A @ v`` (``out`` distinct from ``v``): the output ``y = C x`` of a plant without
    feedthrough, and the small products of the estimators' lane functions."""
    for i in range(A.shape[0]):
        acc = 0.0
        for j in range(A.shape[1]):
            acc += A[i, j] * v[j]
        out[i] = acc


@lane
def linear_output(x, C, D, u, y):
    """``y = C x + D u``."""
    for i in range(y.shape[0]):
        cx = 0.0
        for j in range(x.shape[0]):
            cx += C[i, j] * x[j]
        du = 0.0
        for j in range(u.shape[0]):
            du += D[i, j] * u[j]
        y[i] = cx + du


@lane
def static_output(theta, u, y):
    """``y = Theta^T u`` (``y^T = u^T Theta``), ``Theta`` of shape ``(m, p)``."""
    for j in range(y.shape[0]):
        s = 0.0
        for i in range(u.shape[0]):
            s += u[i] * theta[i, j]
        y[j] = s


@lane(entry=True)
def measure(y_clean, sigma_v, z_v):
    """Measured output ``y_clean + sigma_v z_v`` of one channel (``y_clean`` when noise-free)."""
    if sigma_v != 0.0:
        return y_clean + sigma_v * z_v
    return y_clean


@lane
def safe_output(y, y_bound):
    """A non-finite loop's output: ``clip(y, +-y_bound)`` with NaN as 0."""
    if np.isnan(y):
        return 0.0
    if y > y_bound:
        return y_bound
    if y < -y_bound:
        return -y_bound
    return y


@lane
def squared_error(y_clean, r, y_bound):
    """``(clip(y_clean, +-y_bound) - r)^2``: one channel's tracking cost."""
    yc = y_clean
    if yc > y_bound:
        yc = y_bound
    elif yc < -y_bound:
        yc = -y_bound
    e = yc - r
    return e * e


@lane
def reward_of(cost, effort, rho, diverged):
    """``(-(cost + rho effort), diverged)``; an overflow gives ``REWARD_FLOOR`` and diverged."""
    reward = -(cost + rho * effort)
    if not np.isfinite(reward):
        return REWARD_FLOOR, True
    return reward, diverged


@lane
def observe_scalar(x, y_clean, sigma_v, z_v, r, u, rho, y_bound):
    """:func:`observe` for one output and one input: ``(y, y_clean, reward, diverged)``."""
    y = measure(y_clean, sigma_v, z_v)
    finite = all_finite(x) and np.isfinite(y)
    diverged = not finite or abs(y) > y_bound
    if not finite:  # keep observation and reward finite: a diverged loop must end
        y = safe_output(y, y_bound)
        y_clean = y
    reward, diverged = reward_of(squared_error(y_clean, r, y_bound), u * u, rho, diverged)
    return y, y_clean, reward, diverged


@lane
def observe(x, y_clean, sigma_v, z_v, r, u, rho, y_bound, y):
    """Measured output, divergence test and reward of one step; returns ``(reward, diverged)``.

    ``y = y_clean + sigma_v z_v``. Diverged: ``|y_i| > y_bound``, or ``x``/``y`` not finite
    (then ``y`` and ``y_clean`` become ``clip(y, +-y_bound)`` with NaN as 0), or the reward not
    finite (then it is :data:`REWARD_FLOOR`). Reward
    ``-(sum_i (clip(y_clean_i, +-y_bound) - r_i)^2 + rho sum_j u_j^2)``.
    """
    p = y.shape[0]
    for i in range(p):
        y[i] = measure(y_clean[i], sigma_v, z_v[i])
    finite = all_finite(x) and all_finite(y)
    diverged = not finite
    for i in range(p):
        if abs(y[i]) > y_bound:
            diverged = True
    if not finite:  # keep observation and reward finite: a diverged loop must end
        for i in range(p):
            y[i] = safe_output(y[i], y_bound)
            y_clean[i] = y[i]
    cost = 0.0
    for i in range(p):
        cost += squared_error(y_clean[i], r[i], y_bound)
    effort = 0.0
    for j in range(u.shape[0]):
        effort += u[j] * u[j]
    return reward_of(cost, effort, rho, diverged)


@lane(entry=True)
def performance_reward(x, u, r, Cz, Dz, rho):
    """``-(||C_z x + D_z u - r||^2 + rho ||u||^2)``: the reward of a performance output
    ``z = C_z x + D_z u`` at the state ``x`` the input ``u`` acts on (the LQ stage cost with
    ``Q = C_z' C_z``, ``R = D_z' D_z + rho I``, ``N = C_z' D_z``); :data:`REWARD_FLOOR` when it
    overflows."""
    cost = 0.0
    for i in range(Cz.shape[0]):
        z = 0.0
        for j in range(x.shape[0]):
            z += Cz[i, j] * x[j]
        for j in range(u.shape[0]):
            z += Dz[i, j] * u[j]
        e = z - r[i]
        cost += e * e
    effort = 0.0
    for j in range(u.shape[0]):
        effort += u[j] * u[j]
    reward = -(cost + rho * effort)
    if not np.isfinite(reward):
        return REWARD_FLOOR
    return reward


# ----------------------------------------------------------------------------- env steps
@lane(entry=True)
def canonical_plant_step(x, theta, u_raw, bound, sigma_w, z_w, sigma_v, z_v, r, rho, y_bound, form):
    """One step of a canonical plant (``theta = [a; b]``, SISO: scalar input, noise, reference).

    Returns ``(reward, clipped, diverged, u, y_clean, y)`` (``u`` the clipped input). ``u_raw``,
    ``z_v``, ``r`` and the returned ``u``, ``y_clean``, ``y`` are floats; ``z_w`` has ``n``
    standard normals (may be empty when ``sigma_w == 0``).
    """
    n = x.shape[0]
    u, clipped = clip_input(u_raw, bound)
    shift_transition(x, theta, 0, theta, n, u, form)
    add_noise(x, sigma_w, z_w)
    y, y_clean, reward, diverged = observe_scalar(
        x, canonical_output(x), sigma_v, z_v, r, u, rho, y_bound
    )
    return reward, clipped, diverged, u, y_clean, y


@lane(entry=True)
def state_space_plant_step(
    x, AB, C, D, u_raw, bound, sigma_w, z_w, sigma_v, z_v, r, rho, y_bound, u, y_clean, y, tmp
):
    """One step of ``x+ = A x + B u + w``, ``y = C x + D u + v``: ``(reward, clipped, diverged)``.

    ``u``, ``y_clean``, ``y`` receive the clipped input and the outputs.
    """
    clipped = clip_action(u_raw, bound, u)
    state_space_transition(x, AB, u, tmp)
    add_noise(x, sigma_w, z_w)
    linear_output(x, C, D, u, y_clean)
    reward, diverged = observe(x, y_clean, sigma_v, z_v, r, u, rho, y_bound, y)
    return reward, clipped, diverged


@lane(entry=True)
def static_plant_step(theta, u_raw, bound, sigma_v, z_v, r, rho, y_bound, u, y_clean, y, none):
    """One step of the static object ``y = Theta^T u + v``; ``(reward, clipped, diverged)``.

    ``none`` is an empty float array (the object has no state).
    """
    clipped = clip_action(u_raw, bound, u)
    static_output(theta, u, y_clean)
    reward, diverged = observe(none, y_clean, sigma_v, z_v, r, u, rho, y_bound, y)
    return reward, clipped, diverged


# --------------------------------------------------------------------------- batch loops
@lanes(min_lanes=PARALLEL_MIN_LANES)
def canonical_plants_step(
    X,
    Theta,
    U_raw,
    bound,
    sigma_w,
    Z_w,
    sigma_v,
    Z_v,
    R,
    rho,
    y_bound,
    form,
    U,
    Y_clean,
    Y,
    reward,
    clipped,
    diverged,
    first,
    last,
):
    """:func:`canonical_plant_step` for every lane; ``U_raw``, ``Z_v``, ``R``, ``U``,
    ``Y_clean``, ``Y`` of shape ``(B,)``, ``Z_w`` ``(B, n)`` (``(B, 0)`` when unused); outputs
    ``reward`` ``(B,)`` float64, ``clipped`` and ``diverged`` ``(B,)`` bool."""
    for i in range(first, last):
        reward[i], clipped[i], diverged[i], U[i], Y_clean[i], Y[i] = canonical_plant_step(
            X[i],
            Theta[i],
            U_raw[i],
            bound,
            sigma_w,
            Z_w[i],
            sigma_v,
            Z_v[i],
            R[i],
            rho,
            y_bound,
            form,
        )


@lanes(min_lanes=PARALLEL_MIN_LANES)
def state_space_plants_step(
    X,
    AB,
    C,
    D,
    U_raw,
    bound,
    sigma_w,
    Z_w,
    sigma_v,
    Z_v,
    R,
    rho,
    y_bound,
    U,
    Y_clean,
    Y,
    reward,
    clipped,
    diverged,
    TMP,
    first,
    last,
):
    """:func:`state_space_plant_step` for every lane, lane ``i`` with its own ``AB[i]``.

    ``AB`` of shape ``(B, n, n + m)``, the scratch ``TMP`` ``(B, n)``; outputs ``reward``
    ``(B,)`` float64, ``clipped`` and ``diverged`` ``(B,)`` bool.
    """
    for i in range(first, last):
        reward[i], clipped[i], diverged[i] = state_space_plant_step(
            X[i],
            AB[i],
            C,
            D,
            U_raw[i],
            bound,
            sigma_w,
            Z_w[i],
            sigma_v,
            Z_v[i],
            R[i],
            rho,
            y_bound,
            U[i],
            Y_clean[i],
            Y[i],
            TMP[i],
        )


@lanes(min_lanes=PARALLEL_MIN_LANES)
def performance_rewards(X, U, R, Cz, Dz, rho, reward, first, last):
    """:func:`performance_reward` of every lane into ``reward`` (``(B,)``)."""
    for i in range(first, last):
        reward[i] = performance_reward(X[i], U[i], R[i], Cz, Dz, rho)


@lanes(min_lanes=PARALLEL_MIN_LANES)
def noise_inputs(Z, G, out, first, last):
    """``out[i] = G Z[i]``: each lane's process noise through the noise input ``G``."""
    for i in range(first, last):
        matvec(G, Z[i], out[i])


@lanes(min_lanes=PARALLEL_MIN_LANES)
def canonical_outputs(idx, X, Y_clean, first, last):
    """``Y_clean[j, 0] = c x`` of lane ``idx[j]`` (the output at reset, before any input)."""
    for j in range(first, last):
        Y_clean[j, 0] = canonical_output(X[idx[j]])


@lanes(min_lanes=PARALLEL_MIN_LANES)
def state_outputs(idx, X, C, Y_clean, first, last):
    """``Y_clean[j] = C x`` of lane ``idx[j]`` (the output at reset, before any input)."""
    for j in range(first, last):
        matvec(C, X[idx[j]], Y_clean[j])
