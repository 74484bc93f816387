"""A run of a learner other than DDPG end to end: `train` writes what the learner shares, resumes
from its checkpoints (zero-size leaves included: a feed-forward PPO's empty GRU state), both
evaluations drive its greedy policy (a recurrent PPO's with its GRU state carried through each
episode, checked against a step loop written out here), and its export acts as its greedy policy."""

from __future__ import annotations

import numpy as np
import pytest

from fedjax_nav import rundir
from fedjax_nav.config import load_config

TINY = [
    "env.episode_length=16",
    "env.envs_per_robot=2",
    "run.episodes=2",
    "run.chunk_episodes=1",
    "run.checkpoint_every=1",
    "fed.period=1",
    "offpolicy.batch_size=8",
    "offpolicy.buffer_size=64",
    "offpolicy.hidden=16",
    "ppo.rollout=8",
    "ppo.minibatches=2",
    "ppo.epochs=1",
    "ppo.hidden=16",
    # 5 robots in the smallest shipped room: compile time grows with the rooms' obstacles
    "env.worlds=[train-0,train-0,train-0,train-0,train-0]",
]


# the case's name -> its overrides (a GRU's minibatches split env.envs_per_robot = 2)
CASES = {
    "ppo": ["learner=ppo"],
    "td3": ["learner=td3"],
    "ppo-gru": ["learner=ppo", "ppo.recurrent=gru", "ppo.gru_hidden=8"],
}


@pytest.fixture(scope="module", params=list(CASES))
def learner_run(request, tmp_path_factory):
    from fedjax_nav.training.run import train

    cfg = load_config("thesis/flddpg", TINY + CASES[request.param])
    out = tmp_path_factory.mktemp(request.param) / "run"
    train(cfg, out, progress=False)
    return cfg.learner, cfg, out


def test_params_hold_what_the_learner_shares(learner_run):
    from fedjax_nav.agents import learners

    name, cfg, out = learner_run
    with np.load(out / rundir.PARAMS) as z:
        tops = {k.split("/")[0] for k in z.files}
        leaves = [z[k] for k in z.files]
    assert tops == set(learners.get(name).shared_fields)
    assert all(x.shape[:2] == (1, cfg.num_robots) and np.isfinite(x).all() for x in leaves)


def test_resume_from_the_learners_checkpoint_equals_the_uninterrupted_run(learner_run, tmp_path):
    """The uninterrupted run resumed from its episode-1 checkpoint (the one of episode 2 removed and
    saved again, the results written again) ends with the same parameters, bit for bit."""
    import json
    import shutil

    from fedjax_nav.training.run import train

    name, cfg, out = learner_run
    if name != "ppo":  # off-policy state resumes as DDPG's does (tests/test_checkpoint.py); PPO's has empty leaves
        pytest.skip("resume of a replay-buffer learner: tests/test_checkpoint.py")
    resumed = tmp_path / "r"
    shutil.copytree(out, resumed)
    for f in (rundir.PARAMS, rundir.METRICS, rundir.SUMMARY):  # what the resumed run must write itself
        (resumed / f).unlink()
    train(cfg, resumed, progress=False, resume=True, from_checkpoint=1)
    assert json.loads((resumed / rundir.SUMMARY).read_text())["resumed_from_episode"] == 1
    with np.load(out / rundir.PARAMS) as a, np.load(resumed / rundir.PARAMS) as b:
        assert sorted(a.files) == sorted(b.files)
        for k in a.files:
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_both_evaluations_drive_the_learners_greedy_policy(learner_run):
    from fedjax_nav.evaluation import evaluate_run
    from fedjax_nav.evaluation.suite import evaluate_suite

    name, cfg, out = learner_run
    # in the smallest shipped room, not the thesis arena (57 obstacles, unrolled in the compiled
    # program): what is checked is the learner's policy in the protocol, not the room
    ev = evaluate_run(out, "train-0", attempts=1, max_steps=16)
    assert ev.summary["episodes"] == len(ev.frame) > 0 and ev.frame["success"].isin([0, 1]).all()
    suite = evaluate_suite(out, "probe", attempts=1, max_steps=8)
    assert len(suite["episodes"]) > 0


def _greedy_steps(cfg, actor, obs_seq, first_seq):
    """The learner's greedy actions along one sequence of observations (`first`: the memory resets)."""
    import jax
    import jax.numpy as jnp

    from fedjax_nav.agents import learners
    from fedjax_nav.config import values

    learner = learners.get(cfg.learner)
    nets = learner.make_nets(values(cfg))
    memory, out = learner.memory(nets), []
    for obs, first in zip(obs_seq, first_seq):
        if first:
            memory = learner.memory(nets)
        first_flag = None if memory is None else jnp.bool_(first)
        action, memory = learner.greedy(nets, actor, jnp.asarray(obs), memory, first_flag)
        out.append(np.asarray(jax.device_get(action)))
    return np.stack(out)


@pytest.fixture(scope="module")
def gru_run(learner_run):
    """The recurrent case with its actors perturbed (a tiny run's policy head starts at ~0, so
    that its actions barely depend on anything): the hidden state then moves the actions."""
    import dataclasses

    import jax

    from fedjax_nav.evaluation import load_run

    name, cfg, out = learner_run
    if cfg.ppo.recurrent != "gru" or name != "ppo":
        pytest.skip("the recurrent PPO case")
    run = load_run(out)
    leaves, tree = jax.tree.flatten(run.actor_params)
    keys = jax.random.split(jax.random.key(7), len(leaves))
    leaves = [x + 0.7 * jax.random.normal(k, x.shape) for x, k in zip(leaves, keys)]
    return dataclasses.replace(run, actor_params=jax.tree.unflatten(tree, leaves))


def _hand_protocol(run, T: int):
    """What the hand-written episodes below share: the eval world, the protocol's env with its
    noise, its params, and the env step and the learner's greedy policy each jitted once (eager,
    every step dispatches the lidar's ops over the arena's 57 obstacles one by one: most of the
    test's time)."""
    import jax

    from fedjax_nav import worlds
    from fedjax_nav.agents import learners
    from fedjax_nav.config import envs, values
    from fedjax_nav.env.nav import NavEnv, make_params
    from fedjax_nav.evaluation import ACTION_NOISE, RANGE_NOISE

    cfg = run.cfg
    w = worlds.load("eval")
    env = NavEnv(**{**envs.env_settings(cfg, "eval", noise=True, episode_length=T), "mode": "eval", "noise": True})
    params = make_params(w, **envs.eval_values(cfg, RANGE_NOISE, ACTION_NOISE))
    learner = learners.get(cfg.learner)
    nets = learner.make_nets(values(cfg))
    greedy = jax.jit(lambda actor, obs, memory, first: learner.greedy(nets, actor, obs, memory, first))
    return {
        "world": w,
        "env": env,
        "params": params,
        "learner": learner,
        "nets": nets,
        "step": jax.jit(env.step),
        "greedy": greedy,
    }


def _hand_episode(run, protocol: dict, agent: int, T: int, reset_every_step: bool):
    """Episode 0 (goal 0, attempt 0) of agent `agent` in evaluate_run(run, "eval", attempts=1,
    max_steps=T), written out step by step: the protocol's keys, noise and env, the learner's
    greedy policy with its memory from `memory(nets)`, `first` at step 0 (or at every step)."""
    import jax
    import jax.numpy as jnp

    w, env, params = protocol["world"], protocol["env"], protocol["params"]
    G = int(w.num_goals)
    keys = jax.random.split(jax.random.key(0), run.num_agents * G).reshape(run.num_agents, G)
    k_reset, key = jax.random.split(keys[agent, 0])
    obs, state = env.reset(k_reset, params.replace(goal_index=0))
    actor = jax.tree.map(lambda x: x[agent], run.actor_params)
    memory, poses = protocol["learner"].memory(protocol["nets"]), [np.asarray(state.pose)]
    for t in range(T):
        key, k_step = jax.random.split(key)
        first = jnp.bool_(t == 0 or reset_every_step)
        action, memory = protocol["greedy"](actor, obs, memory, first)
        obs, state, _, term, trunc, _ = protocol["step"](k_step, state, action, params)
        poses.append(np.asarray(state.pose))
        if bool(term | trunc):
            break
    return np.stack(poses)


def test_recurrent_evaluation_carries_the_hidden_state_through_the_episode(gru_run):
    from fedjax_nav.evaluation import evaluate_run

    T = 16
    ev = evaluate_run(gru_run, "eval", attempts=1, max_steps=T)
    protocol = _hand_protocol(gru_run, T)
    for agent in (0, 1):
        got = ev.result.poses[agent, 0, 0]
        want = _hand_episode(gru_run, protocol, agent, T, reset_every_step=False)
        np.testing.assert_allclose(got[: len(want)], want, atol=1e-4)
        assert int(ev.result.steps[agent, 0, 0]) == len(want) - 1
        # zeroing the GRU state at every step drives elsewhere: the carried state is what acts
        forgetful = _hand_episode(gru_run, protocol, agent, T, reset_every_step=True)
        n = min(len(forgetful), len(want))
        assert np.abs(forgetful[:n] - want[:n]).max() > 1e-3


def test_export_acts_as_the_learners_greedy_policy(learner_run, tmp_path):
    """Every learner exports (numpy here; ONNX and every activation: tests/test_export_learners.py);
    the exported policy.py's actions along a sequence with a reset equal the learner's greedy ones."""
    import importlib.util

    import jax

    from fedjax_nav.deploy.export import export_run
    from fedjax_nav.evaluation import load_run

    name, cfg, out = learner_run
    written = export_run(out, tmp_path / "x", "numpy", None, None)
    assert any(p.name == "policy.py" for p in written)
    spec = importlib.util.spec_from_file_location(f"exported_{name}_{cfg.ppo.recurrent}", tmp_path / "x" / "policy.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    policy = mod.Policy(str(tmp_path / "x"))
    rng = np.random.default_rng(0)
    obs = rng.normal(0.0, 2.0, (10, cfg.env.num_beams + 4)).astype(np.float32)
    first = [True] + [False] * 4 + [True] + [False] * 4
    got = []
    for o, f in zip(obs, first):
        if f:
            policy.reset()
        got.append(policy(o))
    actor = jax.tree.map(lambda x: x[0], load_run(out).actor_params)
    np.testing.assert_allclose(np.stack(got), _greedy_steps(cfg, actor, obs, first), atol=1e-5)
