"""RL agents that know what a classical part knows: the estimate-conditioned agents (an
estimator's estimate among their inputs) and residual RL on the self-tuning controller, in
training (the vector wrapper) and evaluation (the policy adapter), saved and reloaded, in the
bench, and the report's answer to "identification or design?"."""

from __future__ import annotations

import contextlib
import csv
import io
import json
from types import SimpleNamespace

import numpy as np
import pytest

import stcgym.envs  # noqa: F401  (registers the ids)
from stcgym.adaptive import make_estimator
from stcgym.agents.controllers import CONTROLLERS, controller_seeds
from stcgym.agents.evaluation.env_spec import EnvSpec
from stcgym.agents.evaluation.episodes import EpisodeSet, run_episodes
from stcgym.agents.rl.interfaces import InterfaceSpec
from stcgym.agents.rl.wrappers import WindowConfig

SB3 = pytest.importorskip("stable_baselines3")

REFERENCE = {"kind": "random_steps", "amplitude": 1.0, "hold": [20, 40]}
FAMILY = dict(family="siso2-v1", action_bound=3.0, reference=REFERENCE, initial_state_std=0.5)
WINDOW = WindowConfig(window=3)


def _o_rls_alone():
    """O-RLS as the self-tuning controller runs it in closed loop, written out by hand: the
    measurement-corrected regressor, P(0) = 300 I, theta(0) = 0, the deadbeat injection for
    50 steps and 0.4 of it after (EstimatorOptions' defaults)."""
    return make_estimator(
        "O-RLS", 2, p0=300.0, theta0=np.zeros(4), regressor="filtered", injection=0.4,
        injection_warmup=50,
    )  # fmt: skip


def _alone(ys, us, estimator="O-RLS"):
    """theta_hat(t), log10 diag P(t) and e(t) of the estimator run alone on one episode:
    ``update(y(t))``, then ``predict(u(t))`` while there is an input; ``"ELS"``: a
    self-tuning controller's ``propose([y(t), 0])`` and ``commit(u(t))``."""
    if estimator == "ELS":
        return _els_alone(ys, us)
    est = _o_rls_alone()
    out = []
    for k, y in enumerate(ys):
        est.update(y)
        out.append(np.concatenate([est.theta, np.log10(np.diag(est.P)), [est.e]]))
        if k < len(us) and us[k] is not None:
            est.predict(us[k])
    return np.array(out)


def _els_alone(ys, us):
    """The self-tuning controller's extended least squares on one episode, one plant: told
    another reference and seed than the interface's controller, which change its proposals
    only (never applied), not its estimate."""
    from stcgym.adaptive import SelfTuningController

    ctl = SelfTuningController(2, seed=12345)
    out = []
    for k, y in enumerate(ys):
        ctl.propose(np.array([y, 0.0]))
        S = ctl.compiled_args.est.S[0]
        diag_p = np.diag(S @ S.T)[:4]  # theta over [a; b; c]: the variances of a and b
        out.append(np.concatenate([ctl.theta, np.log10(diag_p), [ctl.compiled_args.s.e[0]]]))
        if k < len(us) and us[k] is not None:
            ctl.commit(us[k])
    return np.array(out)


def _check(got, expected):
    """The estimate and the innovation bit for bit (the same compiled estimator on both
    sides), log10 diag P to float32 rounding (numpy forms the diagonal in another order)."""
    expected = np.clip(expected, -10, 10).astype(np.float32)
    exact = [0, 1, 2, 3, 8]
    np.testing.assert_array_equal(got[..., exact], expected[..., exact])
    np.testing.assert_allclose(got[..., 4:8], expected[..., 4:8], rtol=1e-6)


class _Recorder:
    """A stand-in model: random actions, and every feature batch it was asked about."""

    def __init__(self, seed: int = 0) -> None:
        self.rng, self.seen = np.random.default_rng(seed), []

    def predict(self, features, deterministic=True, **kwargs):
        self.seen.append(np.array(features))
        return self.rng.uniform(-0.1, 0.1, (len(features), 1)), None


@pytest.mark.equality
@pytest.mark.parametrize("estimator", ["O-RLS", "ELS"])
def test_estimate_features_are_the_estimator_run_alone_in_evaluation(estimator):
    from stcgym.agents.rl.policy import SB3Policy

    spec = EnvSpec(split="test", jump_probability=1.0, steps=80, **FAMILY)
    episodes = EpisodeSet.of(spec, 1, 500, 3)
    model = _Recorder()
    interface = InterfaceSpec("estimate", order=2, estimator=estimator)
    policy = SB3Policy(model, WINDOW, spec.action_bound, interface=interface)
    batch = run_episodes(lambda p, s: policy.with_lanes(len(p), s), spec, episodes)
    assert not batch.diverged.any() and (batch.jump_step > 0).all()
    # the measured outputs (the adapter's input) from the env itself, the inputs applied
    env = spec.make_vec(3, info_keys=())
    obs, _ = spec.reset_lanes(env, list(episodes.seeds), list(episodes.plants))
    ys = [obs[:, 0]]
    for k in range(spec.steps - 1):
        obs, *_ = env.step(batch.u[:, k : k + 1])
        ys.append(obs[:, 0])
    ys = np.array(ys)
    features = np.array(model.seen)  # (steps, lanes, features)
    n_window = WINDOW.n_features
    assert features.shape == (spec.steps, 3, n_window + 9)
    for lane in range(3):
        expected = _alone(ys[:, lane], list(batch.u[lane]), estimator)
        _check(features[:, lane, n_window:], expected)


@pytest.mark.equality
@pytest.mark.parametrize("estimator", ["O-RLS", "ELS"])
def test_estimate_features_are_the_estimator_run_alone_in_training_across_restarts(estimator):
    from stable_baselines3.common.vec_env import VecEnvWrapper

    from stcgym.agents.rl.vec_env import SB3VecEnv, VecHistoryWindow

    class Raw(VecEnvWrapper):  # what the lanes observe and are given, before the window
        def reset(self):
            self.obs = [self.venv.reset().copy()]
            self.actions, self.dones, self.last = [], [], []
            return self.obs[0]

        def step_async(self, actions):
            self.actions.append(np.array(actions)[:, 0])
            self.venv.step_async(actions)

        def step_wait(self):
            obs, rewards, dones, infos = self.venv.step_wait()
            self.obs.append(obs.copy())
            self.dones.append(dones.copy())
            self.last.append({i: info["terminal_observation"] for i, info in enumerate(infos)
                              if "terminal_observation" in info})  # fmt: skip
            return obs, rewards, dones, infos

    spec = EnvSpec(split="train", steps=30, **FAMILY)  # 30-step episodes: two restarts
    raw = Raw(SB3VecEnv(spec.make_vec(2, info_keys=())))
    interface = InterfaceSpec("estimate", order=2, estimator=estimator)
    vec = VecHistoryWindow(raw, WINDOW, spec.steps, interface=interface)
    assert vec.observation_space.shape == (WINDOW.n_features + 9,)
    vec.seed(4)
    features = [vec.reset()]
    terminal = []
    rng = np.random.default_rng(2)
    for _ in range(75):
        vec.step_async(rng.uniform(-0.1, 0.1, (2, 1)))
        f, _, dones, infos = vec.step_wait()
        features.append(f)
        terminal.append({i: info["terminal_observation"] for i, info in enumerate(infos)
                         if "terminal_observation" in info})  # fmt: skip
    features = np.array(features)[:, :, WINDOW.n_features :]
    u = np.array(raw.actions)  # the inputs applied (steps, lanes)
    y = np.array(raw.obs)[:, :, 0]
    for lane in range(2):
        ends = [k + 1 for k, d in enumerate(raw.dones) if d[lane]]
        assert len(ends) == 2
        for start, end in zip([0, *ends], [*ends, len(y)], strict=True):
            ys = list(y[start:end, lane])
            us = list(u[start:end, lane])
            if end in ends:  # the final observation of the episode
                ys.append(raw.last[end - 1][lane][0])
            expected = _alone(ys, us, estimator)
            _check(features[start:end, lane], expected[: end - start])
            if end in ends:
                _check(terminal[end - 1][lane][WINDOW.n_features :], expected[-1])


def _stc_costs(spec, episodes, run):
    """The bench's ``stc`` on ``episodes``, run ``run``: its own builder and seeds."""
    sc = SimpleNamespace(env=spec, controller_order=spec.order)
    builder = CONTROLLERS["stc"].build(SimpleNamespace(), sc)
    seeds = dict(zip(episodes.seeds, controller_seeds(episodes.seeds, run), strict=True))
    return run_episodes(lambda p, s: builder(p, [seeds[x] for x in s]), spec, episodes)


@pytest.mark.equality
def test_a_zero_residual_is_the_self_tuning_controller_on_the_same_seeds(tmp_path):
    import torch

    from stcgym.agents import default_config
    from stcgym.agents.rl.configs import with_action_unit
    from stcgym.agents.rl.sb3 import (
        SB3Policy,
        _training_env,
        build_model,
        interface_of,
        load_agent,
        save_agent,
    )

    spec = EnvSpec(split="test", jump_probability=0.5, steps=200, **FAMILY)
    episodes = EpisodeSet.of(spec, 2, 700, 4)
    config = with_action_unit(default_config("residual_ppo"), 0.3)
    vec = _training_env(config, spec, 5, None)
    model = build_model("residual_ppo", config, vec, 5)
    # the policy's mean action is exactly zero at initialisation, whatever it observes
    obs = torch.as_tensor(
        np.random.default_rng(0).normal(0, 3, (16, vec.observation_space.shape[0]))
    )
    mean = model.policy.get_distribution(obs.float()).distribution.mean
    assert torch.count_nonzero(mean) == 0
    policy = SB3Policy(model, WindowConfig(**config.window), spec.action_bound,
                       interface=interface_of(config, spec, 5))  # fmt: skip
    ours = run_episodes(lambda p, s: policy.with_lanes(len(p), s), spec, episodes)
    stc = _stc_costs(spec, episodes, run=5)
    assert np.array_equal(ours.cost, stc.cost) and np.array_equal(ours.u, stc.u)
    assert not np.array_equal(stc.cost, _stc_costs(spec, episodes, run=4).cost)  # seeds matter
    # the same after a save and reload
    from stcgym.agents.rl.sb3 import TrainedAgent

    agent = TrainedAgent("residual_ppo", policy, config, 5, spec, 0, 0.0)
    save_agent(agent, tmp_path / "agent")
    again = load_agent(tmp_path / "agent")
    assert again.policy.interface == policy.interface
    reloaded = run_episodes(lambda p, s: again.policy.with_lanes(len(p), s), spec, episodes)
    assert np.array_equal(reloaded.cost, stc.cost)


def test_residual_corrects_the_controller_within_its_bound():
    from stcgym.adaptive import SelfTuningController

    spec = InterfaceSpec("residual", order=2, fraction=0.25)
    lanes = spec.build(WINDOW, 2.0, 3, seeds=[1, 2, 3])
    alone = SelfTuningController(2, num_envs=3, action_bound=2.0, seed=[1, 2, 3])
    alone.reset()
    rng = np.random.default_rng(0)
    obs = rng.normal(0, 0.3, (3, 2))
    for k in range(40):
        starts = np.ones(3, bool) if k == 0 else None
        lanes.observe(obs, starts)
        u_stc = alone.propose(obs)
        assert np.array_equal(lanes.features()[:, -1], (u_stc[:, 0] / 2.0).astype(np.float32))
        a = rng.uniform(-2, 2, (3, 1))  # out of range: clipped to [-1, 1]
        u = lanes.to_input(a)
        np.testing.assert_array_equal(u, np.clip(u_stc + 0.5 * np.clip(a, -1, 1), -2, 2))
        # the controller inside is told the applied input, correction included
        alone.commit(u)
        assert np.array_equal(lanes.controller.theta, alone.theta)
        obs = rng.normal(0, 0.3, (3, 2))
    # a controller told only its own inputs would hold another estimate
    assert not np.array_equal(lanes.controller.theta, _own_inputs_only(rng_seed=0))
    assert lanes.n_features == WINDOW.n_features + 1


def _own_inputs_only(rng_seed: int) -> np.ndarray:
    """theta of the controller above when each step is ``predict`` (its own input assumed)."""
    from stcgym.adaptive import SelfTuningController

    alone = SelfTuningController(2, num_envs=3, action_bound=2.0, seed=[1, 2, 3])
    rng = np.random.default_rng(rng_seed)
    obs = rng.normal(0, 0.3, (3, 2))
    for _ in range(40):
        alone.predict(obs)
        rng.uniform(-2, 2, (3, 1))
        obs = rng.normal(0, 0.3, (3, 2))
    return alone.theta


@pytest.mark.parametrize("kind", ["window", "estimate", "residual"])
def test_the_action_unit_scales_the_action_and_keeps_the_whole_bound(kind):
    rng = np.random.default_rng(1)
    bound, unit, fraction = 27.0, 3.0, 0.25
    span = bound if kind != "residual" else fraction * bound
    plain = InterfaceSpec(kind, order=2, fraction=fraction).build(WINDOW, bound, 4, seeds=range(4))
    scaled = InterfaceSpec(kind, order=2, fraction=fraction, action_unit=unit).build(
        WINDOW, bound, 4, seeds=range(4)
    )
    assert plain.action_limit == 1.0 and plain.action_unit == span
    assert scaled.action_limit == pytest.approx(span / unit) and scaled.action_unit == unit
    obs = rng.normal(0, 0.3, (4, 2))
    for lanes in (plain, scaled):
        lanes.observe(obs, np.ones(4, bool))
    base = plain.u_base if kind == "residual" else np.zeros((4, 1))
    a = np.array([[0.5], [-0.02], [50.0], [-50.0]])
    # one unit of action is `unit` of input; beyond the box, the correction's or bound's edge
    expected = np.clip(base + np.clip(a * unit, -span, span), -bound, bound)
    np.testing.assert_allclose(scaled.to_input(a), expected, rtol=0, atol=1e-12)
    # without a unit the box is [-1, 1] and one unit of action is the whole range, as before
    expected = np.clip(base + span * np.clip(a, -1, 1), -bound, bound)
    np.testing.assert_array_equal(plain.to_input(a), expected)


def test_a_measured_unit_must_be_measured_before_an_interface_is_built():
    spec = InterfaceSpec("window", action_unit="lqg")
    with pytest.raises(ValueError, match="measured by the bench"):
        spec.build(WINDOW, 5.0)
    for bad in (0.0, -1.0, float("nan"), "typical", True):
        with pytest.raises(ValueError, match="interface.action_unit"):
            InterfaceSpec("window", action_unit=bad)


def test_interface_values_are_checked():
    with pytest.raises(ValueError, match="interface.kind"):
        InterfaceSpec("oracle")
    with pytest.raises(ValueError, match="interface.estimator"):
        InterfaceSpec("estimate", estimator="RLS")
    with pytest.raises(ValueError, match="interface.fraction"):
        InterfaceSpec("residual", fraction=-0.1)
    with pytest.raises(ValueError, match="plant order"):
        InterfaceSpec("estimate").build(WINDOW, 1.0)
    with pytest.raises(ValueError, match="SISO"):
        InterfaceSpec("residual", order=2).build(WINDOW, 1.0, channels=(2, 2))
    assert InterfaceSpec("estimate", estimator="kf-mils").estimator == "KF-MILS"
    assert InterfaceSpec("estimate", estimator="els").estimator == "ELS"


def test_informed_agents_are_their_base_agent_with_an_interface():
    from stcgym.agents import apply_overrides, default_config
    from stcgym.agents.rl.configs import (
        ALGORITHMS,
        FAMILY_ALGORITHMS,
        INFORMED,
        agent_knowledge,
        base_algorithm,
        validate_config,
    )
    from stcgym.agents.rl.zoo_departures import ZOO_DEPARTURES

    for agent, (base, what) in INFORMED.items():
        cfg, ref = default_config(agent), default_config(base)
        assert ALGORITHMS[agent] == ALGORITHMS[base] and base_algorithm(agent) == base
        assert agent in FAMILY_ALGORITHMS and what
        kinds = ("estimate", "residual", "true")
        assert cfg.window == ref.window and cfg.interface["kind"] in kinds
        assert (cfg.standard_family_steps, cfg.eval_interval) == (
            ref.standard_family_steps,
            ref.eval_interval,
        )
        # every departure of the base agent, but the residual agent's own exploration
        own = {e[0] for e in ZOO_DEPARTURES[agent]} - {e[0] for e in ZOO_DEPARTURES[base]}
        assert not own or own == {"action_net init"}
        kept = {
            e for e in ZOO_DEPARTURES[base] if agent != "residual_ppo" or e[0] != "log_std_init"
        }
        assert kept <= set(ZOO_DEPARTURES[agent])
        knows = agent_knowledge(agent, cfg.to_dict())
        told = "true (a, b)" if agent == "oracle_ppo" else "none:"  # the privileged one
        assert "n" in knows["order"] and knows["model"].startswith(told)
    residual = default_config("residual_ppo")
    assert residual.hyperparams["policy_kwargs"]["log_std_init"] == -2.0
    assert [e[2] for e in ZOO_DEPARTURES["residual_ppo"] if e[0] == "log_std_init"] == ["-2"]
    for agent in ("ppo", "theta_ppo", "rppo"):  # exploration in the range of useful inputs
        assert default_config(agent).hyperparams["policy_kwargs"]["log_std_init"] == -5.0
    assert (
        "self-tuning controller inside"
        in agent_knowledge("residual_ppo", residual.to_dict())["model"]
    )
    for name in ("KF-MILS", "ELS"):
        configs = apply_overrides({}, [f"theta_ppo.interface.estimator={name}"])
        assert configs["theta_ppo"].interface == {
            "action_unit": "lqg",
            "kind": "estimate",
            "estimator": name,
        }
    for bad, message in [
        ("theta_ppo.interface.estimator=RLS", "interface.estimator"),
        ("residual_ppo.interface.fraction=2", "interface.fraction"),
        ("theta_ppo.interface.order=3", "set by the bench"),
        ("theta_ppo.interface.colour=1", "interface"),
    ]:
        with pytest.raises(ValueError, match=message):
            apply_overrides({}, [bad])
    cfg = default_config("theta_sac")
    cfg.interface = {"kind": "estimate", "log_p": "yes"}
    with pytest.raises(ValueError, match="log_p"):
        validate_config(cfg)


def test_the_tiers_list_the_informed_agents():
    from stcgym.agents.benchmark.style import COLORS, color
    from stcgym.agents.benchmark.tiers import FULL, QUICK, STANDARD
    from stcgym.agents.benchmark.tuning import sample_rl

    assert {"theta_ppo", "theta_sac", "residual_ppo"} <= set(FULL["agents"])
    # the standard tier's time goes to the PPO-based ones (SAC's is in the full tier)
    assert {"theta_ppo", "residual_ppo"} <= set(STANDARD["agents"])
    assert set(QUICK["agents"]) <= set(STANDARD["agents"])
    names = list(dict.fromkeys([*QUICK["agents"], "theta_ppo", "theta_sac", "residual_ppo"]))
    assert len({color(n) for n in names if n != "stc_mimo"}) == len(names) - 1
    assert all(color(n) == COLORS[n] for n in names)

    class Trial:  # what sample_rl asks of an Optuna trial
        def suggest_float(self, name, low, high, log=False):
            return low

        def suggest_categorical(self, name, choices):
            return choices[0]

    assert "batch_size" in sample_rl(Trial(), "theta_sac")["hyperparams"]  # SAC's space
    assert "n_steps" in sample_rl(Trial(), "residual_ppo")["hyperparams"]


# ------------------------------------------------------------------------------ the bench
TINY = [
    "bench",
    "--scenarios", "family,ood,jump",
    "--ood", "ood_order3",
    "--train-steps", "256",
    "--eval-interval", "128",
    "--train-seeds", "2",
    "--test-plants", "3",
    "--curve-episodes", "2",
    "--bound-plants", "8",
    "--episode-steps", "100",
    "--curve-points", "2",
    "--bootstrap-reps", "100",
    "--jobs", "1",
    "--no-progress",
    "--agents", "ppo,theta_ppo,residual_ppo,stc,lqg",
    *[f"--hp={a}.{k}" for a in ("ppo", "theta_ppo", "residual_ppo")
      for k in ("n_steps=64", "n_envs=2", "batch_size=64", "n_epochs=1")],
    # no room for a correction: residual_ppo is the controller, whatever it learnt
    "--hp", "residual_ppo.interface.fraction=0.0",
]  # fmt: skip


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    from stcgym.agents.cli import main

    out = tmp_path_factory.mktemp("bench")
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = main([*TINY, "--out", str(out), "--run", "tiny"])
    assert rc == 0, err.getvalue()
    return out / "tiny"


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.equality
def test_bench_runs_the_informed_agents_and_a_zero_residual_is_stc(tiny_run):
    rows = _rows(tiny_run / "metrics.csv")
    per: dict[tuple[str, str], dict] = {}
    for r in rows:
        per.setdefault((r["scenario"], r["controller"]), {})[(r["run"], r["seed"])] = r
    scenarios = {"family:test", "family:ood_order3", "jump:test"}
    assert {s for s, _ in per} == scenarios
    for s in scenarios:
        for agent in ("ppo", "theta_ppo", "residual_ppo"):
            assert (
                len(per[(s, agent)]) == 2 * 3 and per[(s, agent)].keys() == per[(s, "stc")].keys()
            )
            assert all(r["family"] == "rl" and r["train_stop"] in ("cap", "plateau")
                       for r in per[(s, agent)].values())  # fmt: skip
        # run r of the residual agent meets the controller of run r of stc: the same costs
        for key, r in per[(s, "stc")].items():
            assert per[(s, "residual_ppo")][key]["cost"] == r["cost"], (s, key)
    curves = {(r["algo"]) for r in _rows(tiny_run / "learning_curves.csv")}
    assert curves == {"ppo", "theta_ppo", "residual_ppo"}
    report = (tiny_run / "report.md").read_text()
    knows = report.split("## What each controller knows")[1].split("## Headline")[0]
    assert "| theta_ppo | the training distribution's n (its estimator's)" in knows
    assert "online estimate of the self-tuning controller's extended least squares" in knows
    assert "self-tuning controller inside" in knows
    answer = report.split("## Identification or design?")[1].split("## ")[0]
    assert "`theta_ppo` is given the controller's own estimate" in answer
    assert "`family:test`" in answer and "`jump:test`" in answer
    assert "Residual RL on the controller lowers its cost in 0 of 3" in answer
    # the same costs on every episode: a ratio of 1 (its interval pairs runs of each at random)
    assert answer.count("`: residual_ppo / stc 1 [") == 3
    for algo in ("theta_ppo", "residual_ppo"):
        assert f"| family | {algo} | 0 |" in report  # its training runs, plateau or cap


def test_bench_saves_informed_agents_that_stcgym_eval_reloads(tiny_run, capsys):
    from stcgym.agents.cli import main

    rows = _rows(tiny_run / "metrics.csv")
    for algo in ("theta_ppo", "residual_ppo"):
        model = tiny_run / "models" / f"family_{algo}_s1"
        meta = json.loads((model / "agent.json").read_text())
        assert meta["interface"]["order"] == 2 and meta["interface"]["run"] == 1
        assert len(meta["obs_norm"]["mean"]) == InterfaceSpec.from_dict(
            meta["interface"]
        ).n_features(WindowConfig(**meta["window"]))
        assert main(["eval", str(model), "--seeds", "3", "--episode-steps", "100"]) == 0
        out = capsys.readouterr().out
        key = ("family:test", algo, "1")
        bench = {r["seed"]: float(r["cost"]) for r in rows
                 if (r["scenario"], r["controller"], r["run"]) == key}  # fmt: skip
        assert len(bench) == 3
        printed = {line.split(" seed ")[1].split(":")[0]: float(line.rsplit(" ", 1)[1])
                   for line in out.splitlines() if ": cost " in line}  # fmt: skip
        # stcgym eval reproduces the bench's numbers (the bench keeps float32 per-step costs,
        # eval prints 4 digits)
        assert printed.keys() == bench.keys()
        for seed, cost in bench.items():
            assert printed[seed] == pytest.approx(cost, rel=1e-3)


@pytest.mark.parametrize(
    "agents, message",
    [
        ("theta_dqn,stc", "unknown agent(s) ['theta_dqn']"),
        ("residual_sac,stc", "unknown agent(s) ['residual_sac']"),
    ],
)
def test_bad_agent_names_are_refused(tmp_path, capsys, agents, message):
    from stcgym.agents.cli import main

    assert main(["bench", "--agents", agents, "--out", str(tmp_path), "--run", "bad"]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_informed_agents_need_the_plant_family(tmp_path, capsys):
    from stcgym.agents.cli import main

    args = ["bench", "--agents", "theta_ppo,stc", "--scenarios", "nominal"]
    assert main([*args, "--out", str(tmp_path), "--run", "bad"]) == 2
    assert "train on the plant family" in capsys.readouterr().err


# ------------------------------------------------------------------------------ the answer
def _tables(costs: dict[str, float], rng, runs=3, plants=20):
    """Scenario tables with log-normal costs around the given medians."""
    out = {}
    base = rng.lognormal(0, 0.3, (1, plants, 1))
    for name, median in costs.items():
        noise = rng.lognormal(0, 0.05, (runs, plants, 1))
        out[name] = {"cost": median * base * noise}
    return out


@pytest.mark.parametrize(
    "costs, expected",
    [
        ({"stc": 1.0, "ppo": 2.0, "theta_ppo": 1.0}, "in 1, for part of it in 0, and for none"),
        ({"stc": 1.0, "ppo": 2.0, "theta_ppo": 1.41}, "in 0, for part of it in 1, and for none"),
        ({"stc": 1.0, "ppo": 2.0, "theta_ppo": 2.0}, "in 0, for part of it in 0, and for none of "
         "it in 1"),
        ({"stc": 2.0, "ppo": 1.0, "theta_ppo": 1.0}, "lower cost than PPO in 0"),
    ],
)  # fmt: skip
def test_identification_or_design_follows_the_numbers(costs, expected):
    from stcgym.agents.benchmark.attribution import identification_or_design

    rng = np.random.default_rng(1)
    lines = identification_or_design([("family:test", _tables(costs, rng))], reps=200)
    text = " ".join(lines)
    assert expected in text and "residual_ppo" not in text  # not in this run
    if costs["theta_ppo"] == 1.41:
        assert "closes 50 % of the log-cost gap" in text
    assert identification_or_design([("family:test", _tables({"stc": 1.0}, rng))], reps=50) == []


def test_a_single_env_adapter_returns_one_action_of_the_input_shape():
    from stcgym.agents.rl.policy import SB3Policy

    for kind in ("window", "estimate", "residual"):
        policy = SB3Policy(_Recorder(), WINDOW, 2.0, interface=InterfaceSpec(kind, order=2))
        obs = np.array([0.1, 1.0])
        assert policy.predict(obs)[0].shape == (1,)  # the fast path of one env
        assert policy.predict(obs, episode_start=True)[0].shape == (1,)
        batch = policy.with_lanes(3, [1, 2, 3])
        assert batch.predict(np.tile(obs, (3, 1)))[0].shape == (3, 1)


def test_the_estimate_conditioned_agents_observe_the_controllers_estimate_and_records_keep_theirs():
    from stcgym.agents.benchmark.attribution import _given
    from stcgym.agents.rl.configs import agent_knowledge, default_config

    for agent in ("theta_ppo", "theta_sac"):
        interface = default_config(agent).interface
        assert interface["kind"] == "estimate" and interface["estimator"] == "ELS"
    # a config recorded without an estimator (an earlier run's) means O-RLS, as it did then
    recorded = default_config("theta_ppo").to_dict()
    recorded["interface"] = {"kind": "estimate", "action_unit": "lqg"}
    assert "online estimate of O-RLS " in agent_knowledge("theta_ppo", recorded)["model"]
    assert "not the controller's own" in _given("O-RLS") and "only the design" in _given("ELS")


def test_both_estimate_interfaces_show_the_estimate_their_features_hold():
    from stcgym.agents import WindowConfig
    from stcgym.agents.rl.interfaces import InterfaceSpec

    for estimator in ("O-RLS", "ELS"):
        lanes = InterfaceSpec("estimate", estimator=estimator, order=2).build(
            WindowConfig(window=4), 2.0, 2
        )
        lanes.observe(np.array([[0.1, 1.0], [0.0, 1.0]]), starts=np.ones(2, bool))
        for k in range(30):
            lanes.to_input(np.array([[0.5], [-0.5]]) * (-1) ** k)
            lanes.observe(np.array([[0.4 * (-1) ** k, 1.0], [-0.3, 1.0]]))
        theta = lanes.theta_hat
        assert theta.shape == (2, 4) and np.abs(theta).sum() > 0, estimator
        # the features after the window: theta_hat first
        np.testing.assert_array_equal(lanes.features()[:, -9:-5], theta.astype(np.float32))
