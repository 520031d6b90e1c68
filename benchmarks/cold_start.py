"""Cold start: what a new user waits for before the first answer, from an empty numba cache.

Run from the repository root::

    python benchmarks/cold_start.py            # every scenario, cold then warm
    python benchmarks/cold_start.py --top 25   # more rows of the per-function table

Every measurement runs in a fresh Python process. ``cold``: numba's cache directory
(``NUMBA_CACHE_DIR``) is a new empty temporary directory, so every kernel compiles, as in a new
virtualenv, after an upgrade or on CI. ``warm``: the same process again on the cache the cold
run filled, the baseline measured in the same run (the machine is shared: compare ratios).

Scenarios:

* ``api``: a newcomer's sequence in one process, each step timed on its own: import
  ``stcgym.envs`` and ``stcgym.adaptive``; ``gym.make`` + ``reset`` + the first plant step;
  the first ``SelfTuningController(2).predict``; then the first predict of a second estimator
  (``KF-MILS``), of ``design="lq"``, of a batch of 4 lanes and of the compiled rollout;
* ``README example 1-3``: the ``python`` blocks under the README's :data:`README_SECTION`
  heading (a plant as an environment; an estimator of the paper online; the self-tuning
  controller against PPO and the known-model oracle), each run as a script (wall time of the
  whole process, interpreter start included).

The per-function table comes from numba's ``numba:compile`` events in the cold ``api``
process (``numba.core.event``): for each compiled function (and signature) the time spent in
its own compilation, without the compilation of the separately compiled functions it calls
(``self``), and with them (``total``); inlined helpers are part of their caller's time.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MARK = "COLD_START_JSON "


def _steps() -> list[tuple[str, object]]:
    """The newcomer's sequence: (label, step) pairs, each step timed on its own."""
    state: dict = {}

    def imports() -> None:
        import stcgym.adaptive  # noqa: F401
        import stcgym.envs  # noqa: F401

    def plant() -> None:
        import gymnasium as gym
        import numpy as np

        env = gym.make("stcgym/ObserverCanonical-v0", plant="unstable2")
        state["obs"], _ = env.reset(seed=0)
        env.step(np.array([0.0]))

    def predict(**kw: object):
        def step() -> None:
            import numpy as np

            from stcgym.adaptive import SelfTuningController

            B = kw.get("num_envs")
            obs = state["obs"] if B is None else np.tile(state["obs"], (B, 1))
            SelfTuningController(2, **kw).predict(obs)

        return step

    def rollout() -> None:
        import numpy as np

        from stcgym.adaptive import SelfTuningController
        from stcgym.adaptive.control.rollout import rollout
        from stcgym.envs import PLANTS

        ctl = SelfTuningController(2, num_envs=4)
        rollout(ctl, PLANTS["unstable2"].theta, 10, reference=np.ones(11))

    return [
        ("import stcgym.envs + stcgym.adaptive", imports),
        ("first plant step (gym.make, reset, step)", plant),
        ("first SelfTuningController(2).predict", predict()),
        ("then estimator='KF-MILS': first predict", predict(estimator="KF-MILS")),
        ("then design='lq': first predict", predict(design="lq")),
        ("then num_envs=4: first predict", predict(num_envs=4)),
        ("then rollout(num_envs=4, 10 steps)", rollout),
    ]


# ------------------------------------------------------------------------- child process
def _compile_events(buffer: list) -> list[dict]:
    """Per compile (function, signature): inclusive and self time from the event records."""
    out: list[dict] = []
    stack: list[dict] = []
    for stamp, ev in buffer:
        if ev.is_start:
            disp = ev.data["dispatcher"]
            fn = disp.py_func
            name = f"{fn.__module__.removeprefix('stcgym.')}.{fn.__qualname__}"
            sig = ", ".join(str(a) for a in ev.data["args"])
            stack.append({"name": name, "sig": sig, "start": stamp, "children": 0.0})
        else:
            item = stack.pop()
            total = stamp - item.pop("start")
            item["total"] = total
            item["self"] = total - item.pop("children")
            if stack:
                stack[-1]["children"] += total
            out.append(item)
    return out


def child_api() -> dict:
    """Run the newcomer's sequence in this process; time each and record numba's compile events."""
    from numba.core import event

    t0 = time.perf_counter()
    recorder = event.RecordingListener()
    event.register("numba:compile", recorder)
    times = []
    for label, step in _steps():
        t = time.perf_counter()
        step()
        times.append((label, time.perf_counter() - t))
    event.unregister("numba:compile", recorder)
    return {
        "steps": times,
        "total": time.perf_counter() - t0,
        "compiles": _compile_events(recorder.buffer),
    }


# ------------------------------------------------------------------------ parent process
#: The README section whose ``python`` blocks are timed as scripts.
README_SECTION = "## Quick start: three examples"


def readme_blocks(heading: str) -> list[str]:
    """The ``python`` code blocks of the README section under ``heading``."""
    text = (ROOT / "README.md").read_text()
    start = text.index(f"\n{heading}\n")
    end = text.find("\n## ", start + len(heading) + 2)
    blocks = re.findall(r"```python\n(.*?)```", text[start : end if end >= 0 else None], re.S)
    if not blocks:
        raise ValueError(f"no python block under {heading!r} in README.md")
    return blocks


def _process(args: list[str], cache: str, stdin: str | None = None) -> tuple[float, str]:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache, MPLBACKEND="Agg")
    t = time.perf_counter()
    done = subprocess.run(
        [sys.executable, *args],
        input=stdin,
        capture_output=True,
        text=True,
        env=env,
        cwd=ROOT,
    )
    wall = time.perf_counter() - t
    if done.returncode != 0:
        raise RuntimeError(f"{args} failed:\n{done.stdout}\n{done.stderr}")
    return wall, done.stdout


def api_run(cache: str) -> tuple[float, dict]:
    wall, out = _process([__file__, "--child", "api"], cache)
    line = next(ln for ln in out.splitlines() if ln.startswith(MARK))
    return wall, json.loads(line[len(MARK) :])


def script_run(code: str, cache: str) -> float:
    return _process(["-"], cache, stdin=code)[0]


def per_function_table(compiles: list[dict], top: int) -> None:
    by_name: dict[str, list[float]] = {}
    for c in compiles:
        agg = by_name.setdefault(c["name"], [0.0, 0.0, 0])
        agg[0] += c["self"]
        agg[2] += 1
    total_self = sum(c["self"] for c in compiles)
    print(f"\nwhere the cold compile time goes ({len(compiles)} compiles, {total_self:.1f} s):")
    print(f"{'compiled function':58s} {'signatures':>10s} {'self s':>8s} {'share':>6s}")
    rows = sorted(by_name.items(), key=lambda kv: -kv[1][0])
    for name, (self_s, _, count) in rows[:top]:
        print(f"{name:58s} {count:10d} {self_s:8.2f} {self_s / total_self:6.1%}")
    rest = rows[top:]
    if rest:
        s = sum(v[0] for _, v in rest)
        print(f"{f'... {len(rest)} more functions':58s} {'':10s} {s:8.2f} {s / total_self:6.1%}")
    print("\nslowest single compiles, total time including the functions they compile:")
    for c in sorted(compiles, key=lambda c: -c["total"])[: min(top, 8)]:
        print(f"  {c['total']:6.2f} s  {c['name']}({c['sig'][:70]})")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description="cold-start compile times from an empty cache")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--top", type=int, default=15, help="rows of the per-function table")
    args = ap.parse_args(argv)
    if args.child == "api":
        print(MARK + json.dumps(child_api()))
        return
    head = f"{'measurement (fresh process each)':46s} {'cold s':>8s} {'warm s':>8s}"
    print(f"{head} {'cold/warm':>9s}")

    def row(label: str, cold: float, warm: float) -> None:
        print(f"{label:46s} {cold:8.2f} {warm:8.2f} {cold / warm:8.1f}x", flush=True)

    with tempfile.TemporaryDirectory() as cache:
        cold_wall, cold = api_run(cache)
        warm_wall, warm = api_run(cache)
    for (label, c), (_, w) in zip(cold["steps"], warm["steps"], strict=True):
        row(label, c, w)
    row("api sequence, whole process", cold_wall, warm_wall)
    for k, code in enumerate(readme_blocks(README_SECTION), start=1):
        with tempfile.TemporaryDirectory() as cache:
            c = script_run(code, cache)
            w = script_run(code, cache)
        row(f"README example {k}, whole process", c, w)
    per_function_table(cold["compiles"], args.top)


if __name__ == "__main__":
    main()
