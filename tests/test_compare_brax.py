"""scripts/compare_brax.py's pure pieces: the same numbers go into brax's train() and the project's
config, the brax env is the trainer's env, the SAC target entropy and PPO's initial std are brax's
in this project's units, brax actions reach the env's box as the adapter maps them, and the common
evaluator stops an episode at its first termination."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("brax")

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "compare_brax.py"


@pytest.fixture(scope="module")
def cb():
    spec = importlib.util.spec_from_file_location("compare_brax", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # its dataclasses look their module up while they are built
    spec.loader.exec_module(mod)
    return mod


def test_ppo_settings_are_the_same_numbers_on_both_sides(cb):
    task, s = cb.Task(chunk=2, evals=3), cb.PPOSettings()
    b = cb.brax_train_kwargs(task, "ppo", s, seed=5)
    cfg = cb.project_config(task, "ppo", s, seeds=4)
    p = cfg.ppo
    assert (cfg.method, cfg.learner, cfg.num_robots, cfg.run.seeds) == ("iddpg", "ppo", 1, 4)
    assert b["num_envs"] == cfg.env.envs_per_robot and b["episode_length"] == cfg.env.episode_length
    assert (b["learning_rate"], b["discounting"], b["gae_lambda"]) == (p.lr, p.gamma, p.gae_lambda)
    assert (b["clipping_epsilon"], b["entropy_cost"], b["vf_loss_coefficient"]) == (p.clip_eps, p.ent_coef, p.vf_coef)
    assert b["max_grad_norm"] == p.max_grad_norm and p.value_clip == 0.0
    assert (b["unroll_length"], b["num_minibatches"], b["num_updates_per_batch"]) == (
        p.rollout,
        p.minibatches,
        p.epochs,
    )
    # one brax training step = one project update: the same rows, cut into the same number of minibatches
    assert b["batch_size"] * b["num_minibatches"] * b["unroll_length"] == p.rollout * cfg.env.envs_per_robot
    # a brax epoch (one evaluation) is one chunk of the project's run, and the totals agree
    per_eval = cb.env_steps_per_eval(task, s)
    assert per_eval == cfg.run.chunk_episodes * cfg.env.episode_length * cfg.env.envs_per_robot
    assert b["num_timesteps"] == cfg.run.episodes * cfg.env.episode_length * cfg.env.envs_per_robot == 3 * per_eval
    assert b["num_evals"] == task.evals + 1 and b["seed"] == 5
    n = b["network_factory"].keywords
    assert n["policy_hidden_layer_sizes"] == n["value_hidden_layer_sizes"] == (p.hidden,) * p.depth
    assert p.activation == n["activation"].__name__ == "tanh"
    assert (b["reward_scaling"], b["normalize_observations"]) == (1.0, False)
    assert math.isclose(math.exp(p.init_log_std), cb.brax_initial_std(), rel_tol=1e-6)


def test_sac_settings_are_the_same_numbers_on_both_sides(cb):
    task, s = cb.Task(chunk=1, evals=4), cb.SACSettings()
    b = cb.brax_train_kwargs(task, "sac", s, seed=0)
    cfg = cb.project_config(task, "sac", s, seeds=2)
    d, sc = cfg.offpolicy, cfg.sac
    assert (cfg.method, cfg.learner) == ("iddpg", "sac")
    assert b["num_envs"] == cfg.env.envs_per_robot and b["episode_length"] == cfg.env.episode_length
    assert b["learning_rate"] == d.lr == sc.alpha_lr and b["discounting"] == d.gamma and b["tau"] == sc.tau
    assert b["batch_size"] == d.batch_size == b["min_replay_size"] and b["max_replay_size"] == d.buffer_size
    assert b["grad_updates_per_step"] == d.gradient_steps and d.train_every == 1
    assert b["network_factory"].keywords["hidden_layer_sizes"] == (d.hidden,) * d.depth
    assert d.activation == b["network_factory"].keywords["activation"].__name__ == "relu"
    assert sc.init_alpha == 1.0 and math.isclose(sc.target_entropy, cb.brax_sac_target_entropy_box(), rel_tol=1e-6)
    # brax counts its prefill (ceil(batch / envs) steps of every env) in num_timesteps
    prefill = -(-d.batch_size // s.num_envs) * s.num_envs
    assert b["num_timesteps"] - prefill == cfg.run.episodes * cfg.env.episode_length * cfg.env.envs_per_robot


def test_the_brax_env_is_the_trainers_env(cb):
    import jax

    from fedjax_nav import worlds
    from fedjax_nav.config import envs
    from fedjax_nav.env.brax_env import BraxNavEnv
    from fedjax_nav.training.hparams import hparams_from_config

    cfg = cb.project_config(cb.Task(), "ppo", cb.PPOSettings(), seeds=1)
    benv = BraxNavEnv(**cb.brax_env_kwargs(cfg))
    ours = envs.make_env(cfg, "learn")
    assert (benv.nav.num_beams, benv.nav.max_range, benv.nav.collision_test, benv.nav.noise) == (
        ours.num_beams,
        ours.max_range,
        ours.collision_test,
        ours.noise,
    )
    world = jax.tree.map(lambda x: x[0], worlds.load_many(list(cfg.env.worlds)))
    want = envs.env_params(world, hparams_from_config(cfg))
    got = benv.params_at(0)
    for (path, a), b in zip(jax.tree_util.tree_leaves_with_path(want), jax.tree.leaves(got)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=jax.tree_util.keystr(path))


def test_target_entropy_and_initial_std_are_braxs_in_box_units(cb):
    import jax
    import jax.numpy as jnp
    from brax.training.distribution import NormalTanhDistribution

    from fedjax_nav.agents import distributions as dist

    d = NormalTanhDistribution(event_size=2)
    # brax's std at a raw scale output of 0 is the project's initial PPO std
    np.testing.assert_allclose(d.create_dist(jnp.zeros(4)).scale, cb.brax_initial_std(), rtol=1e-6)
    # the same raw actions: brax's log-density ([-1, 1]^2) minus the box one is sum_i log scale_i,
    # so brax's target entropy -1 is the project's target in box units
    k1, k2, k3 = jax.random.split(jax.random.PRNGKey(0), 3)
    loc, raw_scale = jax.random.normal(k1, (64, 2)), jax.random.normal(k2, (64, 2))
    std = jax.nn.softplus(raw_scale) + 1e-3
    u = loc + std * jax.random.normal(k3, (64, 2)) * 3.0

    @jax.jit
    def gap(loc, raw_scale, std, u):
        return d.log_prob(jnp.concatenate([loc, raw_scale], -1), u) - dist.log_prob_raw(loc, jnp.log(std), u)

    np.testing.assert_allclose(gap(loc, raw_scale, std, u), math.log(0.5), atol=2e-4)
    assert math.isclose(cb.brax_sac_target_entropy_box(), -0.5 * 2 + math.log(0.5), rel_tol=1e-6)
    # the deterministic actions agree too: brax's tanh(loc) mapped to the box is the squashed mean
    np.testing.assert_allclose(cb.brax_to_box(jnp.tanh(loc)), dist.mode(loc), atol=1e-6)


def test_brax_actions_reach_the_box_as_the_adapter_maps_them(cb):
    import jax
    import jax.numpy as jnp

    from fedjax_nav.env.brax_env import BraxNavEnv

    env = BraxNavEnv("train-0")
    s0 = env.reset(jax.random.PRNGKey(0))
    actions = jnp.array([[0.3, -0.7], [-1.0, 1.0], [2.0, -3.0]])

    def via_brax(a):
        return env.step(s0, a).pipeline_state.nav.pose

    def direct(a):
        return env.nav.step(jax.random.PRNGKey(1), s0.pipeline_state.nav, cb.brax_to_box(a), env.params_at(0))[1].pose

    poses = jax.jit(jax.vmap(via_brax))(actions)
    np.testing.assert_allclose(poses, jax.jit(jax.vmap(direct))(actions), atol=1e-6)
    assert np.ptp(poses[:, 0]) > 1e-3  # the three actions move the robot differently


def test_the_evaluator_ends_an_episode_at_its_first_termination(cb):
    """Full speed straight ahead from train-0's start (2, 2.15) facing -x: the robot hits the wall
    x = -3 (collision at 0.25 m) after ~190 of 512 steps; the return is the progress to there and
    one collision penalty, never what the stopped env would add after it."""
    import jax.numpy as jnp

    cfg = cb.project_config(cb.Task(), "ppo", cb.PPOSettings(), seeds=1)

    def policy_fn(p, obs):
        return jnp.array([p, 0.0])  # p: the speed (v / v_max); 0 = stand still

    ret, success = cb.evaluate(policy_fn, jnp.array([1.0, 0.0]), cfg, episodes=3)
    assert ret.shape == success.shape == (2, 3) and not success.any()
    goal, start, crash = np.array([-2.0, -1.85]), np.array([2.0, 2.15]), np.array([-2.75, 2.15])
    want = 40.0 * (np.linalg.norm(start - goal) - np.linalg.norm(crash - goal)) - 10.0
    np.testing.assert_allclose(ret[0], want, atol=1.5)
    # standing still, only the evaluation's action noise moves it: v = max(0, N(0, 0.01)) v_max, about
    # 0.05 m towards the goal over 512 steps, 2 reward units; it never ends the episode
    assert np.all(np.abs(ret[1]) < 3.0)


def test_a_rerun_of_some_learners_keeps_the_others_rows(cb, tmp_path):
    import pandas as pd

    path = tmp_path / "t.csv"
    old = pd.DataFrame({"framework": ["brax", "fedjax_nav", "brax"], "learner": ["ppo", "ppo", "sac"], "x": [1, 2, 3]})
    old.to_csv(path, index=False)
    new = pd.DataFrame({"framework": ["brax"], "learner": ["ppo"], "x": [9]})
    merged = cb.keep_others(path, new).sort_values(["framework", "learner"]).reset_index(drop=True)
    assert list(zip(merged.framework, merged.learner, merged.x)) == [
        ("brax", "ppo", 9),
        ("brax", "sac", 3),
        ("fedjax_nav", "ppo", 2),
    ]
    assert cb.keep_others(tmp_path / "none.csv", new).equals(new)
