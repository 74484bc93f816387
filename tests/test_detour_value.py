"""The learned value along replayed episodes (fedjax_nav.evaluation.values, docs/clutter.md, "Why
detours fail"): each learner's `value` through the learner table against its network applied by
hand on the same parameters (PPO's value net, DDPG's critic, the twins' min of TD3 and SAC at the
greedy action), read from a run directory's params.npz, carried along a recurrent PPO's sequence;
a learner without one refused in one line; the evaluation program's recorded observations are
those at its poses, the episodes unchanged; the per-episode readings of `detours.value_columns`."""

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fedjax_nav import learner_table, rundir
from fedjax_nav.agents import learners, ppo
from fedjax_nav.config import load_config, values
from fedjax_nav.evaluation import EvalError, detours
from fedjax_nav.evaluation import values as vals
from fedjax_nav.evaluation.run_data import RunAgents

OBS = 28
PPO_TINY = ["learner=ppo", "method=iddpg", "env.worlds=[train-0,train-0]", "ppo.hidden=8", "run.seeds=2"]


def _nets(args):
    cfg = load_config(None, args)
    return cfg, learners.get(cfg.learner), learners.get(cfg.learner).make_nets(values(cfg))


def _bare(cfg) -> RunAgents:
    """A RunAgents of `cfg` holding no parameters (values_along reads the config only)."""
    return RunAgents(Path("."), cfg, {}, np.zeros(1, int), np.zeros(1, int), 1, 1)


def _dense(p: dict, x: np.ndarray) -> np.ndarray:
    return x @ np.asarray(p["kernel"], np.float64) + np.asarray(p["bias"], np.float64)


def _value_by_hand(value: dict, x: np.ndarray) -> np.ndarray:
    """PPO's ValueNet of depth 2 in numpy: Dense_0 is its output layer (made before the trunk)."""
    p = value["params"]
    h = np.tanh(_dense(p["Dense_2"], np.tanh(_dense(p["Dense_1"], x))))
    return _dense(p["Dense_0"], h)[..., 0]


@pytest.fixture(scope="module")
def ppo_run(tmp_path_factory):
    """A PPO run directory of 2 seeds x 2 networks (iddpg's per-robot networks), its own initial
    parameters: config.yaml and params.npz as training writes them."""
    cfg, learner, nets = _nets(PPO_TINY)
    run = tmp_path_factory.mktemp("value") / "run"
    run.mkdir()
    rundir.write_config(run, cfg)
    keys = jax.random.split(jax.random.key(3), 4).reshape(2, 2)
    state = jax.vmap(jax.vmap(lambda k: ppo.init(nets.ppo, k, OBS)))(keys)
    rundir.write_params(run, {"actor": state.actor, "log_std": state.log_std, "value": state.value})
    return run


def test_ppo_value_from_a_run_directory_is_its_value_net_by_hand(ppo_run):
    from fedjax_nav.evaluation.runs import load_run

    run = load_run(ppo_run)
    params = vals.value_params(run)
    assert set(params) == {"actor", "value"} and run.num_agents == 4
    obs = np.asarray(jax.random.normal(jax.random.key(1), (4, 3, 5, OBS)))  # [A, E, T, obs]
    got = vals.values_along(run, params, obs)
    assert got.shape == (4, 3, 5)
    value = rundir.read_params(ppo_run, "value")  # [seed, net, ...]
    for a in range(4):
        mine = jax.tree.map(lambda x, a=a: x[a // 2, a % 2], value)
        np.testing.assert_allclose(got[a], _value_by_hand(mine, obs[a].astype(np.float64)), rtol=1e-5, atol=1e-5)
    assert np.ptp(got) > 1e-3  # the agents and observations differ: a constant would not pass


def test_ppo_value_normalises_with_the_actors_statistics():
    cfg, learner, nets = _nets([*PPO_TINY, "ppo.normalize_obs=true"])
    state = ppo.init(nets.ppo, jax.random.key(0), OBS)
    rows = 3.0 + 2.0 * jax.random.normal(jax.random.key(1), (64, OBS))
    from fedjax_nav.agents import normalize

    actor = {**state.actor, ppo.NORM: normalize.moments(normalize.update(normalize.init(OBS), rows))}
    obs = np.asarray(jax.random.normal(jax.random.key(2), (OBS,))) + 3.0
    v, memory = learner.value(nets, {"actor": actor, "value": state.value}, obs, learner.memory(nets), True)
    m = jax.tree.map(lambda x: np.asarray(x, np.float64), actor[ppo.NORM])
    x = np.clip((obs - m["mean"]) / np.sqrt(m["mean_sq"] - m["mean"] ** 2 + 1e-8), -10, 10)
    assert float(v) == pytest.approx(float(_value_by_hand(state.value, x)), abs=1e-4)
    assert memory.value.shape == (0,)  # no GRU: the memory passes through


def test_a_recurrent_ppo_value_carries_its_gru_along_the_sequence():
    cfg, learner, nets = _nets([*PPO_TINY, "ppo.recurrent=gru", "ppo.gru_hidden=4", "ppo.minibatches=1"])
    state = ppo.init(nets.ppo, jax.random.key(0), OBS)
    params = {"actor": state.actor, "value": state.value}
    obs = jax.random.normal(jax.random.key(1), (1, 2, 6, OBS))
    got = vals.values_along(_bare(cfg), jax.tree.map(lambda x: x[None], params), obs)
    reset = jnp.arange(6) == 0
    for e in range(2):
        _, want, _ = nets.ppo.value.apply(state.value, jnp.zeros(4), obs[0, e], reset)
        np.testing.assert_allclose(got[0, e], np.asarray(want[:, 0]), rtol=1e-5, atol=1e-6)
    # a memory that started again at every step would read otherwise
    alone = [learner.value(nets, params, o, learner.memory(nets), True)[0] for o in obs[0, 0]]
    assert not np.allclose(got[0, 0, 1:], np.asarray(alone)[1:], atol=1e-4)


@pytest.mark.parametrize("name", ["ddpg", "td3", "sac"])
def test_an_off_policy_value_is_the_critic_at_the_greedy_action(name):
    cfg, learner, nets = _nets([f"learner={name}", "offpolicy.hidden=8", "offpolicy.depth=1"])
    obs = jax.random.normal(jax.random.key(1), (OBS,))
    actor = nets.actor.init(jax.random.key(2), obs)
    action = np.asarray(learner.greedy(nets, actor, obs, None, None)[0], np.float64)
    x = np.concatenate([np.asarray(obs, np.float64), action])
    keys = jax.random.split(jax.random.key(3), 2)
    critics = [nets.critic.init(k, obs, jnp.asarray(action, jnp.float32)) for k in keys]
    by_hand = [_dense(c["params"]["Dense_1"], np.maximum(_dense(c["params"]["Dense_0"], x), 0))[0] for c in critics]
    (critic,) = [n for n in learner_table.get(name).value_networks if n != "actor"]
    twin = critic == "critics"
    q = jax.tree.map(lambda *t: jnp.stack(t), *critics) if twin else critics[0]
    v, memory = learner.value(nets, {"actor": actor, critic: q}, obs, None, None)
    assert float(v) == pytest.approx(min(by_hand) if twin else by_hand[0], abs=1e-5) and memory is None
    assert twin == (name != "ddpg") and abs(by_hand[0] - by_hand[1]) > 1e-4  # the min is a choice


def test_a_learner_without_a_value_is_refused_in_one_line(ppo_run, tmp_path):
    import toy_learner

    from fedjax_nav.evaluation.runs import load_run

    learner_table.register(toy_learner.ROW)
    try:
        cfg = load_config(None, ["learner=toy"])
        with pytest.raises(EvalError, match="learner 'toy': the learner table gives it no value function") as e:
            vals.value_params(_bare(cfg))
        assert "\n" not in str(e.value)
    finally:
        learner_table.unregister("toy")
    # a params.npz without the value net: one line naming the file and what the learner reads
    run = tmp_path / "run"
    run.mkdir()
    (run / rundir.CONFIG).write_bytes((ppo_run / rundir.CONFIG).read_bytes())
    with np.load(ppo_run / rundir.PARAMS) as z:
        np.savez(run / rundir.PARAMS, **{k: z[k] for k in z.files if not k.startswith("value/")})
    with pytest.raises(EvalError, match=r"params.npz: no 'value/...' arrays \(learner 'ppo' reads its value from"):
        vals.value_params(load_run(run))


def test_the_recorded_observations_are_those_at_the_poses_and_change_no_episode():
    from test_evaluation import CORRIDOR, DRIVE, scripted

    from fedjax_nav.env.nav import make_params
    from fedjax_nav.evaluation.rollout import eval_program, observed_program

    T = 100
    settings = dict(num_beams=24, max_range=3.5, collision_test="exact", episode_length=T, mode="eval", noise=True)
    env = make_params(CORRIDOR, range_noise=0.01, action_noise=0.01, v_max=1.0, dt=0.1)
    goals, keys = jnp.arange(3, dtype=jnp.int32), jax.random.split(jax.random.key(0), 4 * 6).reshape(4, 6)
    plain = jax.device_get(eval_program(settings, scripted, 64)(DRIVE, env, goals, keys))
    seen = jax.device_get(observed_program(settings, scripted, 64)(DRIVE, env, goals, keys))
    for k in plain:
        np.testing.assert_array_equal(plain[k], seen[k])
    obs, poses, steps = seen["obs"], seen["poses"], seen["steps"]  # [A, G, K, T + 1, ...]
    assert obs.shape == (*poses.shape[:-1], OBS) and (steps < T).any()
    goal_xy = np.asarray(CORRIDOR.goals)[:3][None, :, None, None, :]
    np.testing.assert_allclose(obs[..., 24], np.linalg.norm(goal_xy - poses[..., :2], axis=-1), atol=1e-4)
    last = np.take_along_axis(obs, steps[..., None, None], axis=3)
    t = np.arange(T + 1)[None, None, None, :, None]
    assert (np.where(t >= steps[..., None, None], obs == last, True)).all()  # frozen after the end


def test_the_value_readings_of_an_episode():
    v = np.array([[5.0, 4.0, 3.0, 2.0, 9.0], [1.0, 2.0, 3.0, 4.0, 4.0]])  # [E, T + 1]
    steps, closest = np.array([3, 4]), np.array([3, 1])  # the first's closest approach: its last pose
    c = detours.value_columns(v, steps, closest)
    assert list(c["v_start"]) == [5.0, 1.0] and list(c["v_end"]) == [3.0, 4.0]
    assert list(c["v_closest"]) == [3.0, 2.0]  # at most the last step the policy acted on
    assert list(c["v_last_100"]) == [4.0, 2.5] and list(c["v_fell"]) == [True, False]
