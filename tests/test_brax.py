"""The brax adapter (fedjax_nav.env.brax_env) and the jax>=0.10 shim for brax's trainers (installed
when the adapter is imported). brax's own ppo.train / sac.train on the registered env, in a clean
interpreter that calls no shim: tests/test_registration.py."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_registration import fresh_python

from fedjax_nav.env import brax_compat
from fedjax_nav.worlds import World, from_dict, load, stack

brax_env = pytest.importorskip("fedjax_nav.env.brax_env")  # imports brax
from brax.envs.wrappers import training as brax_wrappers  # noqa: E402

BraxNavEnv = brax_env.BraxNavEnv

# A 4 x 4 m room: the robot starts at the origin facing +x; the wall is at x = 2, so with
# v_max = 1 m/s (0.1 m per step at full speed) it collides (clearance < 0.25) at step 18.
# Start 1 faces the goal at (0, 1.45): within the goal radius (0.5 m) at step 10.
ROOM = {
    "size": [4.0, 4.0],
    "starts": [[0.0, 0.0, 0.0], [0.0, 0.0, math.pi / 2]],
    "goals": [[0.0, 1.45]],
}
FORWARD = jnp.array([1.0, 0.0])  # brax units: full speed, no turn
STOP = jnp.array([-1.0, 0.0])  # v = 0


def room() -> World:
    return from_dict(ROOM, "room")[0]


def tree_allclose(a, b) -> bool:
    return all(np.allclose(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))


# ----------------------------------------------------------------------------- compat shim


def test_shim_matches_old_semantics_on_local_devices():
    devices = jax.local_devices()[:1]
    tree = {
        "w": jnp.arange(6, dtype=jnp.float32).reshape(2, 3),
        "n": np.int32(7),
        "flag": jnp.bool_(True),
        "s": 1.5,
    }
    out = brax_compat.device_put_replicated(tree, devices)
    assert jax.tree.structure(out) == jax.tree.structure(tree)
    for key, leaf in tree.items():
        leaf = jnp.asarray(leaf)
        got = out[key]
        assert got.shape == (len(devices), *leaf.shape)
        assert got.dtype == leaf.dtype
        np.testing.assert_array_equal(np.asarray(got), np.stack([np.asarray(leaf)] * len(devices)))
        assert got.sharding.device_set == set(devices)
        # what brax's _unpmap reads back
        np.testing.assert_array_equal(got.addressable_shards[0].data.squeeze(0), leaf)
    # typed keys stack too
    k = jax.random.key(3)
    kk = brax_compat.device_put_replicated(k, devices)
    np.testing.assert_array_equal(jax.random.key_data(kk)[0], jax.random.key_data(k))
    # and jax.pmap consumes the result, one slice per device
    doubled = jax.pmap(lambda t: t["w"] * 2, devices=devices)(out)
    np.testing.assert_array_equal(np.asarray(doubled)[0], np.asarray(tree["w"]) * 2)


@pytest.mark.parametrize("bad", [[], (), "cpu", None])
def test_shim_rejects_bad_devices(bad):
    with pytest.raises(ValueError, match="non-empty sequence"):
        brax_compat.device_put_replicated(jnp.zeros(2), bad)


def test_ensure_installs_only_if_missing(monkeypatch):
    # record jax's state first so that the teardown puts it back exactly as it was
    monkeypatch.setattr(jax, "device_put_replicated", None, raising=False)
    monkeypatch.delattr(jax, "device_put_replicated")
    assert brax_compat.ensure_device_put_replicated() is True
    assert jax.device_put_replicated is brax_compat.device_put_replicated
    assert brax_compat.ensure_device_put_replicated() is True  # idempotent

    def native(x, devices):  # a jax that still has (or has again) the function keeps it
        return "native"

    monkeypatch.setattr(jax, "device_put_replicated", native, raising=False)
    assert brax_compat.ensure_device_put_replicated() is False
    assert jax.device_put_replicated is native


def test_shim_on_two_devices_feeds_pmap():
    """Two forced CPU devices (needs a fresh process): slice i lives on device i."""
    code = """
        import jax, jax.numpy as jnp, numpy as np
        from fedjax_nav.env.brax_compat import device_put_replicated
        devs = jax.local_devices()
        assert len(devs) == 2, devs
        x = {"a": jnp.arange(3.0), "b": jnp.int32(5)}
        out = device_put_replicated(x, devs)
        assert out["a"].shape == (2, 3) and out["b"].shape == (2,)
        for leaf, ref in ((out["a"], x["a"]), (out["b"], x["b"])):
            shards = sorted(leaf.addressable_shards, key=lambda s: s.index[0].start)
            assert [s.device for s in shards] == devs
            for s in shards:
                assert s.data.shape == (1, *ref.shape)
                np.testing.assert_array_equal(s.data[0], ref)
        y = jax.pmap(lambda t: t["a"] + t["b"])(out)
        np.testing.assert_array_equal(np.asarray(y), np.stack([np.arange(3.0) + 5] * 2))
        print("ok")
        """
    res = fresh_python(code, XLA_FLAGS="--xla_force_host_platform_device_count=2")
    assert res.returncode == 0 and "ok" in res.stdout, res.stderr[-2000:]


def test_package_does_not_import_brax():
    code = (
        "import sys, fedjax_nav, fedjax_nav.env, fedjax_nav.worlds, fedjax_nav.env.brax_compat\n"
        "assert not any(m == 'brax' or m.startswith('brax.') for m in sys.modules), 'brax imported'\n"
    )
    res = fresh_python(code)
    assert res.returncode == 0, res.stderr[-2000:]


# ----------------------------------------------------------------------------- the env


@pytest.fixture(scope="module")
def room_env():
    return BraxNavEnv(room(), playground=0, v_max=1.0)


def test_reset_step_shapes_and_types(room_env):
    env = BraxNavEnv(["train-0", "train-2"])
    assert env.observation_size == 28 and env.action_size == 2 and env.backend == "jax"
    assert env.num_playgrounds == 2
    s = jax.jit(env.reset)(jax.random.PRNGKey(0))
    assert s.obs.shape == (28,) and s.obs.dtype == jnp.float32
    assert s.reward.shape == () and s.done.shape == () and s.done.dtype == jnp.float32
    assert set(s.metrics) == {"goal", "collision"}
    assert {"rng", "truncation", "time_out"} <= set(s.info)
    assert isinstance(s.pipeline_state, brax_env.NavPipelineState)
    s2 = jax.jit(env.step)(s, jnp.array([0.3, -0.2]))
    assert s2.obs.shape == (28,) and s2.reward.dtype == jnp.float32
    assert jax.tree.structure(s2) == jax.tree.structure(s)  # scannable
    assert not np.array_equal(s2.info["rng"], s.info["rng"])  # a fresh key every step
    assert np.all(np.isfinite(s2.obs)) and np.isfinite(float(s2.reward))


def test_action_mapping(room_env):
    step = jax.jit(room_env.step)
    s = room_env.reset(jax.random.PRNGKey(1))
    still = step(s, STOP)
    np.testing.assert_allclose(still.pipeline_state.nav.pose, s.pipeline_state.nav.pose, atol=1e-6)
    np.testing.assert_allclose(still.obs[-2:], [0.0, 0.0])  # prev action in NavEnv units
    half = step(s, jnp.array([0.0, 0.5]))
    np.testing.assert_allclose(half.obs[-2:], [0.5, 0.5])
    clipped = step(s, jnp.array([3.0, -7.0]))
    np.testing.assert_allclose(clipped.obs[-2:], [1.0, -1.0])
    fwd = step(s, FORWARD)  # 0.1 m along +x at v_max = 1 m/s, dt = 0.1 s
    np.testing.assert_allclose(fwd.pipeline_state.nav.pose, [0.1, 0.0, 0.0], atol=1e-5)


def test_playground_choice():
    w = stack([load("train-0"), load("train-3")])
    fixed = BraxNavEnv(w, playground=1)
    random = BraxNavEnv(w)
    keys = jax.random.split(jax.random.PRNGKey(2), 32)
    sf = jax.vmap(fixed.reset)(keys)
    sr = jax.vmap(random.reset)(keys)
    assert np.all(sf.pipeline_state.playground == 1)
    pg = np.asarray(sr.pipeline_state.playground)
    assert set(pg.tolist()) == {0, 1}
    # the robot starts at start 0 of the chosen playground
    np.testing.assert_allclose(sr.pipeline_state.nav.pose, np.asarray(w.starts)[pg, 0])
    with pytest.raises(ValueError, match="playground"):
        BraxNavEnv(w, playground=2)


def _run(env, state, action, n):
    def f(s, _):
        s = env.step(s, action)
        return s, (s.done, s.info["truncation"], s.metrics["goal"], s.metrics["collision"])

    return jax.jit(lambda s: jax.lax.scan(f, s, None, length=n))(state)


def test_collision_and_goal_end_the_episode():
    env = BraxNavEnv(room(), playground=0, v_max=1.0)
    _, (done, trunc, goal, coll) = _run(env, env.reset(jax.random.PRNGKey(0)), FORWARD, 18)
    np.testing.assert_array_equal(done, [0] * 17 + [1])
    np.testing.assert_array_equal(coll, [0] * 17 + [1])
    assert not goal.any() and not trunc.any()
    env = BraxNavEnv(room(), playground=0, v_max=1.0, random_starts=True)
    # start 1 faces the goal; find a key that draws it
    for i in range(50):
        s = env.reset(jax.random.PRNGKey(i))
        if int(s.pipeline_state.nav.start_index) == 1:
            break
    assert int(s.pipeline_state.nav.start_index) == 1
    s, (done, trunc, goal, coll) = _run(env, s, FORWARD, 10)
    np.testing.assert_array_equal(goal, [0] * 9 + [1])
    np.testing.assert_array_equal(done, goal)
    assert not coll.any() and not trunc.any()
    assert float(s.reward) > 90.0  # the goal reward


def test_own_time_limit_sets_truncation():
    env = BraxNavEnv(room(), playground=0, episode_length=5)
    _, (done, trunc, goal, coll) = _run(env, env.reset(jax.random.PRNGKey(0)), STOP, 5)
    np.testing.assert_array_equal(done, [0, 0, 0, 0, 1])
    np.testing.assert_array_equal(trunc, [0, 0, 0, 0, 1])
    # a collision at the time limit is a termination, not a truncation (brax's convention)
    env = BraxNavEnv(room(), playground=0, episode_length=18, v_max=1.0)
    _, (done, trunc, _, coll) = _run(env, env.reset(jax.random.PRNGKey(0)), FORWARD, 18)
    assert done[-1] == 1 and coll[-1] == 1 and trunc[-1] == 0


def test_brax_training_wrappers_and_auto_reset():
    w = stack([room(), load("train-0")])  # two playgrounds: the one drawn at reset is kept
    env = brax_wrappers.wrap(BraxNavEnv(w, v_max=1.0), episode_length=10)
    n = 8
    keys = jax.random.split(jax.random.PRNGKey(4), n)
    s0 = jax.jit(env.reset)(keys)
    assert s0.obs.shape == (n, 28) and s0.reward.shape == (n,)
    assert set(s0.info["episode_metrics"]) >= {"goal", "collision", "sum_reward", "length"}

    def f(s, _):
        s = env.step(s, jnp.tile(STOP, (n, 1)))
        return s, (s.done, s.info["truncation"])

    s, (done, trunc) = jax.jit(lambda s: jax.lax.scan(f, s, None, length=10))(s0)
    # standing still: EpisodeWrapper's time limit at step 10, a truncation, then auto-reset
    np.testing.assert_array_equal(done[-1], np.ones(n))
    np.testing.assert_array_equal(trunc[-1], np.ones(n))
    assert not done[:-1].any()
    assert tree_allclose(s.pipeline_state, s0.pipeline_state)
    np.testing.assert_allclose(s.obs, s0.obs)

    # driving forward in the room: the collision at step 18 (before the wrapper's limit of 30)
    # ends the episode as a termination, and the robot is put back at its start.
    env = brax_wrappers.wrap(BraxNavEnv(room(), playground=0, v_max=1.0), episode_length=30)
    s0 = jax.jit(env.reset)(keys)

    def g(s, _):
        s = env.step(s, jnp.tile(FORWARD, (n, 1)))
        return s, (s.done, s.info["truncation"], s.pipeline_state.nav.pose[:, 0], s.metrics["collision"])

    s, (done, trunc, x, coll) = jax.jit(lambda s: jax.lax.scan(g, s, None, length=20))(s0)
    np.testing.assert_array_equal(done[:, 0], [0] * 17 + [1] + [0, 0])
    np.testing.assert_array_equal(coll[:, 0], done[:, 0])
    assert not trunc.any()  # a collision is a termination
    np.testing.assert_allclose(x[17], 0.0, atol=1e-6)  # auto-reset restored pipeline_state
    np.testing.assert_allclose(x[19], 0.2, atol=1e-5)  # and it drives on from the start
    assert float(s.info["episode_metrics"]["collision"][0]) == 0.0  # new episode
    assert int(s.info["steps"][0]) == 2


def test_eval_wrapper_counts_goal_metric():
    env = brax_wrappers.EvalWrapper(brax_wrappers.wrap(BraxNavEnv(room(), playground=0, v_max=1.0), episode_length=30))
    s = env.reset(jax.random.split(jax.random.PRNGKey(0), 2))
    s = jax.jit(lambda s: jax.lax.fori_loop(0, 25, lambda i, s: env.step(s, jnp.tile(FORWARD, (2, 1))), s))(s)
    em = s.info["eval_metrics"]
    np.testing.assert_array_equal(em.episode_metrics["collision"], [1.0, 1.0])
    np.testing.assert_array_equal(em.episode_steps, [18, 18])


# ----------------------------------------------------------------------------- applied on import


def test_register_installs_the_shim(monkeypatch):
    """What makes brax's trainers work on the registered env without a call by the user."""
    monkeypatch.setattr(jax, "device_put_replicated", None, raising=False)
    monkeypatch.delattr(jax, "device_put_replicated")
    brax_env.register()
    assert jax.device_put_replicated is brax_compat.device_put_replicated
    brax_env.register()  # idempotent
    assert jax.device_put_replicated is brax_compat.device_put_replicated


def test_importing_the_adapter_prints_nothing():
    """mjx's two "Failed to import warp" lines are swallowed (in a fresh interpreter, where brax
    is imported for the first time)."""
    code = "import fedjax_nav.env.brax_env, brax.envs\nbrax.envs.get_environment('fedjax_nav')\n"
    res = fresh_python(code)
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout == "", res.stdout


def test_other_output_of_the_brax_import_passes(capsys):
    brax_env._echo_unless_warp_noise(
        "Failed to import warp: No module named 'warp'\nsomething else\nFailed to import mujoco_warp: No module\n"
    )
    assert capsys.readouterr().out == "something else\n"
