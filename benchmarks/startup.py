"""Start-up and estimator benchmark of the self-tuning controller: every estimator name in the
closed loop, on the catalogue and on a random family of plants.

Usage::

    python benchmarks/startup.py [--seeds 20] [--plants 1000] [--steps 1000] [--names ...]
                                 [--out FILE.json]

Setting: ``stcgym/ObserverCanonical-v0``, square-wave reference of period 100, output noise std
0.05, ``action_bound`` 10, ``control_cost`` 0.01. Cost of step ``k`` is the env's ``-reward``;
episode cost is the sum over the episode, start included; a diverged episode (``|y| > 100``)
is flagged and charged its last per-step cost for every step it did not live (the divergence
rule of :func:`stcgym.adaptive.control.rollout.charge_divergence`, the same as ``stcgym bench`` and
``stcgym sweep``). Every episode and every lane gets its own controller seed.

Costs come from the compiled rollout (:func:`stcgym.adaptive.control.rollout.rollout`, the env's own
plant step) for the controller and from the oracles stepped on the same plant and noise.

Sections
--------
* **estimators on the random family** (one row per name: ``"ELS"`` and the 16 paper names, each
  with the controller's default settings for it, and O-RLS and KF-MILS once more with the
  paper's regressor ``x_hat(t|t-1)``, ``estimator_options={"regressor": "predicted"}``):
  ``--plants`` second-order plants, poles up to magnitude 1.15 (real or complex), ``|b_i|`` in
  ``[0.1, 4]``, no zero within 0.1 of a pole;
  the plants lost among those ``KnownModelController`` holds (and how many of them are
  open-loop unstable), the bounded fraction, median and 90th percentile of the episode ratio
  over the oracle. For the default estimator also the plants lost and the change detector's
  false alarms (alarms on these time-invariant plants).
* **estimators on the catalogue** (one row per name): geometric mean and worst plant of the
  seed-averaged episode ratio over the catalogue, seeds of ``unstable2`` bounded, and the
  ``timevarying2`` post-jump window (1000-1500 of a 1500-step episode) against the oracle
  that switches to the new parameters.
* **catalogue details** for the default estimator: start window (steps 0-100), steps 100-,
  steps to settle (first ``k`` from which the 100-step window cost is within 1.2x the
  oracle's), and ``design="lq"`` against :class:`LQGController`.

Targets: every estimator name bounded on >= 99.5 % of the plants the oracle holds; for the
default and the paper's O-RLS and KF-MILS median <= 1.15, p90 <= 1.5, catalogue geometric mean
<= 1.3 and every plant <= 1.5, ``unstable2`` bounded on every seed, within 1.2x of the
informed oracle after the jump; LQ <= 1.3x LQG.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import warnings
from typing import Any

import gymnasium as gym
import numpy as np

import stcgym.envs  # noqa: F401  (registers the envs)
from stcgym.adaptive import (
    ALGORITHMS,
    KnownModelController,
    LawOptions,
    LQGController,
    SelfTuningController,
)
from stcgym.adaptive.control.rollout import charge_divergence, rollout
from stcgym.envs import PLANTS
from stcgym.envs.canonical import companion_A

NOISE = 0.05
#: LQG without integral action, the optimal linear controller for the envs' cost on the known
#: model (the README's ``design="lq"`` / LQG column is measured against it)
LQG_LAW = LawOptions(integral=False)
BOUND = 10.0
CATALOGUE = ("stable2", "lightly_damped2", "unstable2", "nonminphase2", "integrator2", "stable4")
#: The controller's default estimator, then the paper's 16 names, then the mission's two with
#: the paper's own regressor (``x_hat(t|t-1)``) for comparison.
DEFAULT = "ELS"
NAMES = (DEFAULT, *ALGORITHMS, "O-RLS:predicted", "KF-MILS:predicted")


NDArray = np.ndarray
SQUARE = np.array([1.0 if (k % 100) < 50 else -1.0 for k in range(100_001)])


def oracle_costs(
    oracles: list[Any],
    thetas: NDArray,
    z: NDArray,
    steps: int,
    jump: tuple[int, NDArray] | None = None,
) -> tuple[NDArray, NDArray]:
    """Per-step costs ``(B, steps)`` of one known-model oracle per lane on the env's plant step
    (numpy), output noise ``NOISE * z``, and the lanes that diverged (charged by the divergence
    rule). With ``jump`` the plant and the oracles switch to the new parameters at that step."""
    B, n = thetas.shape[0], thetas.shape[1] // 2
    A = np.array([companion_A(th[:n]) for th in thetas])
    b = thetas[:, n:].copy()
    for o in oracles:
        o.reset()
    x = np.zeros((B, n))
    cost = np.zeros((B, steps))
    alive = np.ones(B, dtype=bool)
    steps_run = np.full(B, steps)
    for k in range(steps):
        if jump is not None and k == jump[0]:
            th2 = np.broadcast_to(jump[1], thetas.shape)
            A = np.array([companion_A(th[:n]) for th in th2])
            b = th2[:, n:].copy()
            for o, th in zip(oracles, th2, strict=True):
                o.set_model(th[:n], th[n:])
        y = x[:, 0] + NOISE * z[:, k]
        u = np.array([o.predict(np.array([yi, SQUARE[k]]))[0][0] if ok else 0.0
                      for o, yi, ok in zip(oracles, y, alive, strict=True)])  # fmt: skip
        u = np.clip(u, -BOUND, BOUND)
        x = np.einsum("bij,bj->bi", A, x) + b * u[:, None]
        x[~alive] = 0.0
        cost[alive, k] = ((x[:, 0] - SQUARE[k + 1]) ** 2 + 0.01 * u**2)[alive]
        died = alive & (np.abs(x[:, 0] + NOISE * z[:, k + 1]) > 100.0)
        steps_run[died] = k + 1
        alive &= ~died
    return charge_divergence(cost, steps_run), ~alive


def stc_costs(thetas: NDArray, z: NDArray, steps: int, seed0: int, jump=None, **kw: Any) -> tuple:
    """Per-step costs of ``SelfTuningController`` (compiled rollout, one lane per plant), the
    lanes that diverged, and the controller."""
    B, n = thetas.shape[0], thetas.shape[1] // 2
    ctl = SelfTuningController(n, num_envs=B, seed=seed0 + np.arange(B), action_bound=BOUND, **kw)
    res = rollout(
        ctl, thetas, steps, reference=SQUARE[: steps + 1], noise_std=NOISE, z=z, window=1,
        jump=jump,
    )  # fmt: skip
    return res.step_cost, res.diverged, ctl


def settle_step(c: NDArray, o: NDArray, window: int = 100, tol: float = 1.2) -> int:
    """First ``k`` (step 10) from which every ``window``-step cost is within ``tol`` x oracle."""
    ks = list(range(0, len(c) - window + 1, 10))
    ok = [c[k : k + window].sum() <= tol * o[k : k + window].sum() for k in ks]
    for i in range(len(ks)):
        if all(ok[i:]):
            return ks[i]
    return len(c)


def _ratio(c: NDArray, o: NDArray, held: NDArray) -> float:
    """Ratio of seed-averaged episode costs over the lanes the oracle ``held``."""
    return float(c[held].sum(1).mean() / o[held].sum(1).mean())


def _estimator_kw(name: str) -> dict[str, Any]:
    """Controller keywords of a row: ``"ELS"`` (the default), a paper name, or
    ``"NAME:predicted"`` (the paper's name with the paper's own regressor)."""
    if name == DEFAULT:
        return {}
    est, _, regressor = name.partition(":")
    kw: dict[str, Any] = {"estimator": est}
    if regressor:
        kw["estimator_options"] = {"regressor": regressor}
    return kw


def _label(name: str) -> str:
    est, _, regressor = name.partition(":")
    return f"`{est}`" + (f", {regressor} regressor (the paper's)" if regressor else "")


def catalogue(seeds: int, steps: int, names: tuple[str, ...]) -> dict[str, Any]:
    """Per plant and estimator name: seed-averaged episode ratio and bounded fraction; for the
    default estimator also the start/steady windows, settling and ``design="lq"``."""
    rows: dict[str, Any] = {}
    for j, plant in enumerate(CATALOGUE):
        spec = PLANTS[plant]
        th = np.tile(spec.theta, (seeds, 1))
        z = np.random.default_rng(100 + j).standard_normal((seeds, steps + 1))
        orc = oracle_costs(
            [KnownModelController(spec.a, spec.b) for _ in range(seeds)], th, z, steps
        )
        lqg = oracle_costs(
            [LQGController(spec.a, spec.b, law=LQG_LAW, noise_std=NOISE) for _ in range(seeds)],
            th,
            z,
            steps,
        )
        row: dict[str, Any] = {}
        for name, kw, ref in (
            ("default", {}, orc),
            ("lq", {"design": "lq"}, lqg),
            *[(est, _estimator_kw(est), orc) for est in names if est != DEFAULT],
        ):
            c, diverged, _ = stc_costs(th, z, steps, 1000 * j, **kw)
            ref, held = ref[0], ~ref[1]
            entry = {"ratio": _ratio(c, ref, held), "bounded": float(1 - diverged.mean())}
            if name in ("default", "lq"):
                entry["start_ratio"] = float(c[:, :100].sum(1).mean() / ref[:, :100].sum(1).mean())
                entry["steady_ratio"] = _ratio(c[:, 100:], ref[:, 100:], held)
                entry["settle"] = settle_step(c.mean(0), ref.mean(0))
            row[name] = entry
        row[DEFAULT] = row["default"]
        rows[plant] = row
        d = row["default"]
        print(
            f"{plant:16s} ratio {d['ratio']:6.2f} start(0-100) {d['start_ratio']:6.2f} "
            f"after(100-) {d['steady_ratio']:5.2f} settle {d['settle']:4d}  "
            f"lq/LQG {row['lq']['ratio']:5.2f} (start {row['lq']['start_ratio']:.2f}, "
            f"after {row['lq']['steady_ratio']:.2f})",
            flush=True,
        )
    summary = {}
    for name in names:
        r = np.array([rows[p][name]["ratio"] for p in CATALOGUE])
        worst = int(np.argmax(r))
        summary[name] = {
            "geometric_mean": float(np.exp(np.mean(np.log(r)))),
            "max": float(r[worst]),
            "worst_plant": CATALOGUE[worst],
            "unstable2_bounded": rows["unstable2"][name]["bounded"],
        }
    rows["by_estimator"] = summary
    d = summary[DEFAULT]
    rows["geometric_mean"], rows["max"] = d["geometric_mean"], d["max"]
    print(f"catalogue ({DEFAULT}): max {d['max']:.3f}  geometric mean {d['geometric_mean']:.3f}")
    return rows


def jump(seeds: int, names: tuple[str, ...]) -> dict[str, Any]:
    """``timevarying2`` (jump at 1000): window 1000-1500 against the oracle that knows it."""
    spec = PLANTS["timevarying2"]
    th = np.tile(spec.theta, (seeds, 1))
    env = gym.make("stcgym/ObserverCanonical-v0", plant="timevarying2", max_episode_steps=1002)
    env.reset(seed=0)
    for _ in range(1001):
        *_, info = env.step(np.zeros(1))
    after = np.asarray(info["theta"], dtype=float)
    z = np.random.default_rng(7).standard_normal((seeds, 1501))
    o, _ = oracle_costs(
        [KnownModelController(spec.a, spec.b) for _ in range(seeds)], th, z, 1500, (1000, after)
    )
    w = slice(1000, 1500)
    out: dict[str, Any] = {}
    for name in names:
        c, _, ctl = stc_costs(th, z, 1500, 0, jump=(1000, after), **_estimator_kw(name))
        out[name] = {
            "post_jump_ratio": float(c[:, w].sum(1).mean() / o[:, w].sum(1).mean()),
            "alarms_per_lane": float(np.mean(ctl.diagnostics["n_alarms"])),
        }
    d = out[DEFAULT]
    print(
        f"timevarying2 ({DEFAULT}) post-jump ratio {d['post_jump_ratio']:.3f} "
        f"(alarms per lane {d['alarms_per_lane']:.2f})",
        flush=True,
    )
    return out


def random_plants(count: int, rng: np.random.Generator) -> list[tuple[NDArray, NDArray]]:
    plants = []
    while len(plants) < count:
        if rng.random() < 0.5:
            poles = rng.uniform(-1.15, 1.15, 2)
        else:
            rad, ang = rng.uniform(0.0, 1.15), rng.uniform(0.0, np.pi)
            poles = np.array([rad * np.exp(1j * ang), rad * np.exp(-1j * ang)])
        a = np.real(np.poly(poles))[1:]
        b = rng.uniform(0.1, 4.0, 2) * rng.choice([-1.0, 1.0], 2)
        zero = -b[1] / b[0]
        if np.min(np.abs(poles - zero)) < 0.1:
            continue
        plants.append((a, b))
    return plants


def family(count: int, steps: int, names: tuple[str, ...], seed: int = 0) -> dict[str, Any]:
    """Every estimator name on ``count`` random second-order plants (same plants and noise)."""
    rng = np.random.default_rng(seed)
    plants = random_plants(count, rng)
    th = np.array([np.r_[a, b] for a, b in plants])
    z = rng.standard_normal((count, steps + 1))
    c_orc, orc_diverged = oracle_costs(
        [KnownModelController(a, b) for a, b in plants], th, z, steps
    )
    held = ~orc_diverged
    unstable = np.array([np.max(np.abs(np.roots(np.r_[1.0, a]))) >= 1.0 for a, _ in plants])
    out: dict[str, Any] = {"plants": count, "oracle_held": int(held.sum()),
                           "oracle_held_unstable": int((held & unstable).sum())}  # fmt: skip
    for name in names:
        c_stc, diverged, ctl = stc_costs(th, z, steps, 10_000, **_estimator_kw(name))
        ok = ~diverged
        ratio = c_stc.sum(1)[held & ok] / c_orc.sum(1)[held & ok]
        after = c_stc[:, 100:].sum(1)[held & ok] / c_orc[:, 100:].sum(1)[held & ok]
        lost = held & ~ok
        row: dict[str, Any] = {
            "lost": int(lost.sum()),
            "lost_unstable": int((lost & unstable).sum()),
            "bounded_fraction_of_held": float((held & ok).sum() / max(held.sum(), 1)),
            "median_ratio": float(np.median(ratio)) if ratio.size else float("inf"),
            "p90_ratio": float(np.percentile(ratio, 90)) if ratio.size else float("inf"),
            "p90_ratio_after_100": float(np.percentile(after, 90)) if ratio.size else float("inf"),
            "lanes_with_alarm": int((ctl.diagnostics["n_alarms"] > 0).sum()),
        }
        if name == DEFAULT:
            row["diverged_after_alarm"] = int(((ctl.diagnostics["n_alarms"] > 0) & lost).sum())
            row["lost_plants"] = [_describe(*plants[i]) for i in np.flatnonzero(lost)]
        out[name] = row
        print(
            f"{name:10s} lost {row['lost']:4d} ({row['lost_unstable']} open-loop unstable), "
            f"bounded {100 * row['bounded_fraction_of_held']:6.2f} %, median "
            f"{row['median_ratio']:.3f}, p90 {row['p90_ratio']:.3f} (steps 100-: "
            f"{row['p90_ratio_after_100']:.3f}), lanes with an alarm {row['lanes_with_alarm']}",
            flush=True,
        )
    d = out[DEFAULT]
    print(
        f"random family: {count} plants, oracle holds {out['oracle_held']} "
        f"({out['oracle_held_unstable']} open-loop unstable); {DEFAULT}: false alarms on "
        f"{d['lanes_with_alarm']} lanes ({d['diverged_after_alarm']} of them lost)"
    )
    for row in d["lost_plants"]:
        print("  lost:", row)
    return out


def _describe(a: NDArray, b: NDArray) -> dict[str, Any]:
    den = 1.0 + a.sum()
    return {
        "poles": np.roots(np.r_[1.0, a]).round(3).astype(str).tolist(),
        "zero": round(float(-b[1] / b[0]), 3),
        "dc_gain": float(b.sum() / den) if abs(den) > 1e-12 else float("inf"),
    }


def _fmt(v: float) -> str:
    return "inf" if not np.isfinite(v) else f"{v:.2f}"


def table(result: dict[str, Any], names: tuple[str, ...]) -> str:
    """The markdown table of every estimator name (the README shows it)."""
    fam, cat, jmp = result.get("family"), result.get("catalogue"), result.get("jump")
    head = ["estimator"]
    if fam:
        head += ["family: lost (unstable)", "bounded %", "median", "p90"]
    if cat:
        head += ["catalogue: geo. mean", "worst plant", "unstable2 bounded"]
    if jmp:
        head += ["after the jump"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name in names:
        cells = [_label(name)]
        if fam:
            f = fam[name]
            cells += [
                f"{f['lost']} ({f['lost_unstable']})",
                f"{100 * f['bounded_fraction_of_held']:.1f}",
                _fmt(f["median_ratio"]),
                _fmt(f["p90_ratio"]),
            ]
        if cat:
            c = cat["by_estimator"][name]
            cells += [
                _fmt(c["geometric_mean"]),
                f"{_fmt(c['max'])} ({c['worst_plant']})",
                f"{100 * c['unstable2_bounded']:.0f} %",
            ]
        if jmp:
            cells += [_fmt(jmp[name]["post_jump_ratio"])]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--plants", type=int, default=1000)
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument(
        "--names",
        nargs="+",
        default=list(NAMES),
        help="estimator names (NAME:predicted: with the paper's regressor)",
    )
    ap.add_argument("--skip-catalogue", action="store_true")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    names = tuple(dict.fromkeys([DEFAULT, *args.names]))  # the default first, once
    # this benchmark is where that warning's figures come from
    warnings.filterwarnings("ignore", message="estimator .* does not hold the loop")
    for name in names:
        SelfTuningController(2, **_estimator_kw(name))  # an unknown name fails here, at once
    warnings.simplefilter("ignore", RuntimeWarning)
    result: dict[str, Any] = {}
    if args.plants:
        result["family"] = family(args.plants, args.steps, names)
    if not args.skip_catalogue:
        result["jump"] = jump(args.seeds, names)
        result["catalogue"] = catalogue(args.seeds, args.steps, names)
    print()
    print(table(result, names))
    if args.out:
        d = os.path.dirname(os.path.abspath(args.out))
        with tempfile.NamedTemporaryFile("w", dir=d, delete=False, suffix=".tmp") as fh:
            json.dump(result, fh, indent=1)
        os.replace(fh.name, args.out)


if __name__ == "__main__":
    main()
