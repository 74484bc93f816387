"""Registration with the libraries' registries and conventions: gymnasium ("fedjax_nav/Nav-v0",
checked by gymnasium's and Stable-Baselines3's env checkers; `make_vec` gives the vmap vector
env), brax ("fedjax_nav", trained by brax's own PPO and SAC as they are) and gymnax's
conventions on the JAX env (`make`, `default_params`, `observation_space`, `action_space`)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import warnings

import numpy as np
import pytest


def fresh_python(code: str, timeout: float = 120, **env: str) -> subprocess.CompletedProcess:
    """`code` (dedented) in a fresh interpreter on CPU JAX, its stdout and stderr captured as text;
    `env`: more environment variables. tests/test_brax.py uses it too."""
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        capture_output=True,
        text=True,
        timeout=timeout,
        env={**os.environ, "JAX_PLATFORMS": "cpu", **env},
    )


# ----------------------------------------------------------------------------- gymnasium


@pytest.fixture(scope="module")
def gym():
    gymnasium = pytest.importorskip("gymnasium")
    from fedjax_nav.env import gym_env  # registers fedjax_nav/Nav-v0

    return gymnasium, gym_env


def test_gymnasium_make_passes_keyword_arguments(gym, tmp_path):
    gymnasium, gym_env = gym
    env = gymnasium.make(
        "fedjax_nav/Nav-v0", world="train-2", episode_length=8, random_starts=True, v_max=0.5, num_beams=12
    )
    u = env.unwrapped
    assert isinstance(u, gym_env.NavGymEnv)
    assert env.spec.id == gym_env.ENV_ID == "fedjax_nav/Nav-v0" and env.spec.max_episode_steps is None
    assert u.world_name == "train-2" and u.nav.episode_length == 8 and u.nav.num_beams == 12
    assert float(u.params.v_max) == 0.5
    obs, info = env.reset(seed=0)
    assert obs.shape == (16,) and env.observation_space.contains(obs)
    # truncated by the env's own time limit (no TimeLimit wrapper is registered)
    flags = [env.step(np.zeros(2, np.float32))[2:4] for _ in range(8)]
    assert flags == [(False, False)] * 7 + [(False, True)]

    # a world file by path, and the defaults (train-0, 1024 steps)
    path = tmp_path / "box.json"
    path.write_text(json.dumps({"size": [3.0, 3.0], "starts": [[0.0, 0.0, 0.0]], "goals": [[-1.0, 1.0]]}))
    assert gymnasium.make("fedjax_nav/Nav-v0", world=path).unwrapped.world_name == str(path)
    d = gymnasium.make("fedjax_nav/Nav-v0").unwrapped
    assert d.world_name == "train-0" and d.nav.episode_length == 1024


def test_register_again_is_a_no_op(gym):
    gymnasium, gym_env = gym
    spec = gymnasium.spec(gym_env.ENV_ID)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # gymnasium warns "Overriding environment" on re-registration
        gym_env.register()
    assert gymnasium.spec(gym_env.ENV_ID) is spec


def test_gymnasium_check_env_on_the_made_env(gym):
    gymnasium, _ = gym
    from gymnasium.utils.env_checker import check_env

    env = gymnasium.make("fedjax_nav/Nav-v0", world="train-0", episode_length=8, v_max=2.0)
    check_env(env.unwrapped, skip_render_check=True)


def test_make_without_importing_fedjax_nav_first():
    """gymnasium >= 1.0 has no plugin entry points; "module:id" imports the module that registers."""
    pytest.importorskip("gymnasium")
    code = """
        import sys, gymnasium
        assert "fedjax_nav" not in sys.modules
        env = gymnasium.make("fedjax_nav.env.gym_env:fedjax_nav/Nav-v0", world="train-3", episode_length=4)
        assert type(env.unwrapped).__name__ == "NavGymEnv" and env.unwrapped.world_name == "train-3"
        env.reset(seed=0)
        print("OK")
        """
    out = fresh_python(code, timeout=300)
    assert out.returncode == 0 and out.stdout.strip().endswith("OK"), out.stderr[-3000:]


@pytest.mark.parametrize("order", ["fedjax_nav first", "gymnasium first"])
def test_import_fedjax_nav_registers_the_env_without_importing_gymnasium_or_jax(order):
    """`import fedjax_nav` alone registers "fedjax_nav/Nav-v0" (before: only the submodule
    fedjax_nav.env.gym_env did), in either import order, and `gymnasium.register_envs(fedjax_nav)`
    works; the package import itself loads neither gymnasium nor jax nor numpy (`fedjax-nav
    --help` stays instant), and the registered entry points are strings until an env is made."""
    pytest.importorskip("gymnasium")
    imports = "import fedjax_nav" if order == "fedjax_nav first" else "import gymnasium, fedjax_nav"
    code = f"""
        import sys
        {imports}
        heavy = sorted(m for m in ("gymnasium", "jax", "numpy") if m in sys.modules)
        assert heavy == ({"[]" if order == "fedjax_nav first" else '["gymnasium", "numpy"]'}), heavy
        import gymnasium
        gymnasium.register_envs(fedjax_nav)
        spec = gymnasium.spec("fedjax_nav/Nav-v0")
        assert spec.entry_point == "fedjax_nav.env.gym_env:NavGymEnv", spec
        assert spec.vector_entry_point == "fedjax_nav.env.gym_vector:NavVectorEnv", spec
        assert "jax" not in sys.modules
        env = gymnasium.make("fedjax_nav/Nav-v0", world="train-0", episode_length=4)
        assert type(env.unwrapped).__name__ == "NavGymEnv"
        import fedjax_nav.env.gym_env as ge  # registering again changes nothing
        assert gymnasium.spec(ge.ENV_ID) is spec
        print("OK")
        """
    out = fresh_python(code, timeout=300)
    assert out.returncode == 0 and out.stdout.strip().endswith("OK"), out.stderr[-3000:]


def test_make_vec_builds_the_vmap_vector_env(gym):
    gymnasium, gym_env = gym
    from fedjax_nav.env.gym_vector import NavVectorEnv

    assert gymnasium.spec(gym_env.ENV_ID).vector_entry_point == gym_env.VECTOR_ENTRY_POINT
    envs = gymnasium.make_vec("fedjax_nav/Nav-v0", num_envs=3, world="train-2", episode_length=8, v_max=0.5)
    u = envs.unwrapped
    assert isinstance(u, NavVectorEnv) and u.num_envs == 3
    assert u.world_name == "train-2" and u.task.episode_length == 8 and float(u.params.v_max) == 0.5
    obs, _ = envs.reset(seed=0)
    assert obs.shape == (3, 28) and envs.observation_space.contains(obs)
    sync = gymnasium.make_vec("fedjax_nav/Nav-v0", num_envs=2, vectorization_mode="sync", world="train-2")
    assert type(sync).__name__ == "SyncVectorEnv" and isinstance(sync.envs[0].unwrapped, gym_env.NavGymEnv)


# ----------------------------------------------------------------------------- Stable-Baselines3


def _sb3():
    try:
        import stable_baselines3  # noqa: F401  (needs torch)
    except ImportError as e:
        pytest.skip(
            f"stable_baselines3 cannot be imported ({e}); install torch==2.13.0 (CPU wheel) "
            "first, then stable-baselines3"
        )


def test_sb3_check_env_passes(gym):
    _sb3()
    gymnasium, _ = gym
    from gymnasium.wrappers import RescaleAction
    from stable_baselines3.common.env_checker import check_env

    env = gymnasium.make("fedjax_nav/Nav-v0", world="train-0", episode_length=8, v_max=2.0)
    # As registered: passes; SB3's one remark is that the action box [0, 1] x [-1, 1] (the
    # actor's units) is not symmetric.
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped, warn=True)
        check_env(env, warn=True)
    messages = {str(w.message) for w in caught}
    assert all("symmetric and normalized Box action space" in m for m in messages), messages
    # rescaled to [-1, 1]^2 as docs/gym.md shows: not even a warning
    lo, hi = np.full(2, -1.0, np.float32), np.full(2, 1.0, np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(RescaleAction(env, lo, hi), warn=True)


def test_sb3_ddpg_learns_a_few_steps(gym):
    _sb3()
    gymnasium, _ = gym
    import torch
    from gymnasium.wrappers import RescaleAction
    from stable_baselines3 import DDPG

    torch.set_num_threads(1)
    env = RescaleAction(
        gymnasium.make("fedjax_nav/Nav-v0", world="train-0", episode_length=32),
        np.full(2, -1.0, np.float32),
        np.full(2, 1.0, np.float32),
    )
    model = DDPG(
        "MlpPolicy", env, learning_starts=32, batch_size=16, policy_kwargs=dict(net_arch=[16, 16]), seed=0, device="cpu"
    )
    model.learn(total_timesteps=64)  # two episodes (time limit 32), 32 updates
    obs, _ = env.reset(seed=1)
    action, _ = model.predict(obs, deterministic=True)
    assert action.shape == (2,) and np.all(np.abs(action) <= 1.0)
    assert model.num_timesteps == 64


# ----------------------------------------------------------------------------- brax


def test_brax_get_environment_and_create():
    brax_env = pytest.importorskip("fedjax_nav.env.brax_env")  # imports brax, registers "fedjax_nav"
    import jax
    import jax.numpy as jnp
    from brax import envs

    assert brax_env.ENV_NAME == "fedjax_nav"
    env = envs.get_environment("fedjax_nav", worlds=["train-0", "train-2"], playground=1, v_max=0.5)
    assert isinstance(env, brax_env.BraxNavEnv)
    assert env.num_playgrounds == 2 and env.playground == 1 and env.observation_size == 28
    s = jax.jit(env.reset)(jax.random.PRNGKey(0))
    step = jax.jit(env.step)
    for _ in range(3):
        s = step(s, jnp.array([1.0, 0.0]))
    assert int(s.pipeline_state.playground) == 1 and int(s.pipeline_state.nav.t) == 3
    # full speed (a0 = 1 -> v = v_max = 0.5 m/s) for 3 steps of 0.1 s
    moved = np.asarray(s.pipeline_state.nav.pose[:2]) - np.asarray(
        env.reset(jax.random.PRNGKey(0)).pipeline_state.nav.pose[:2]
    )
    np.testing.assert_allclose(np.linalg.norm(moved), 0.15, atol=1e-5)
    assert np.isfinite(float(s.reward)) and float(s.done) == 0.0

    # brax.envs.create: the training wrappers (EpisodeWrapper, VmapWrapper, AutoResetWrapper)
    wenv = envs.create("fedjax_nav", episode_length=5, batch_size=4, worlds="train-0")
    ws = jax.jit(wenv.reset)(jax.random.PRNGKey(1))  # VmapWrapper splits it into batch_size keys
    assert ws.obs.shape == (4, 28)
    wstep = jax.jit(wenv.step)
    for _ in range(5):
        ws = wstep(ws, jnp.tile(jnp.array([-1.0, 0.0]), (4, 1)))  # stand still: the time limit
    np.testing.assert_array_equal(ws.done, np.ones(4))
    np.testing.assert_array_equal(ws.info["truncation"], np.ones(4))


_BRAX_TRAIN = """
import functools, json, math
import jax, jax.numpy as jnp, numpy as np

native = hasattr(jax, "device_put_replicated")
import fedjax_nav.env.brax_env  # noqa: F401  (registers "fedjax_nav"; the test calls nothing else of ours)
from brax import envs
from brax.training.agents.ppo import networks as ppo_networks, train as ppo
from brax.training.agents.sac import networks as sac_networks, train as sac

env = envs.get_environment("fedjax_nav", worlds=["train-0", "train-2"])
common = dict(num_timesteps=256, episode_length=32, num_envs=4, num_evals=1, num_eval_envs=2, seed=0)
ppo_steps, sac_steps = [], []
ppo_net = functools.partial(
    ppo_networks.make_ppo_networks, policy_hidden_layer_sizes=(8,), value_hidden_layer_sizes=(8,))
make_policy, params, ppo_m = ppo.train(
    env, batch_size=4, num_minibatches=4, unroll_length=8, num_updates_per_batch=1, run_evals=False,
    network_factory=ppo_net, progress_fn=lambda s, m: ppo_steps.append(int(s)), **common)
action, _ = make_policy(params, deterministic=True)(jnp.zeros((3, env.observation_size)), jax.random.PRNGKey(0))
_, _, sac_m = sac.train(
    env, batch_size=16, min_replay_size=64, max_replay_size=512, grad_updates_per_step=1,
    network_factory=functools.partial(sac_networks.make_sac_networks, hidden_layer_sizes=(8,)),
    progress_fn=lambda s, m: sac_steps.append(int(s)), **common)
finite = lambda m: all(math.isfinite(float(v)) for v in m.values() if np.ndim(v) == 0)
print(json.dumps(dict(
    native=native, shim=jax.device_put_replicated.__module__, ppo_steps=ppo_steps, sac_steps=sac_steps,
    ppo_keys=sorted(ppo_m), sac_keys=sorted(sac_m), finite=finite(ppo_m) and finite(sac_m),
    action_shape=list(action.shape), action_max=float(jnp.max(jnp.abs(action))))))
"""


@pytest.mark.slow
def test_brax_ppo_and_sac_train_the_registered_env_as_they_are():
    """brax 0.14.2's own ppo.train and sac.train, a few hundred env steps each, on
    `envs.get_environment("fedjax_nav")` in a clean interpreter that calls no shim: importing
    the adapter (to register it) is all. Its stdout is the one JSON line (no warp noise)."""
    pytest.importorskip("brax")
    out = fresh_python(_BRAX_TRAIN, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    lines = out.stdout.strip().splitlines()
    assert len(lines) == 1, out.stdout
    r = json.loads(lines[0])
    if not r["native"]:  # jax >= 0.10: the adapter's import installed the shim
        assert r["shim"] == "fedjax_nav.env.brax_compat"
    assert r["ppo_steps"] == [256] and r["sac_steps"] == [256]
    assert {"training/policy_loss", "training/v_loss"} <= set(r["ppo_keys"])
    assert {"training/critic_loss", "training/actor_loss", "eval/episode_goal"} <= set(r["sac_keys"])
    assert r["finite"] and r["action_shape"] == [3, 2] and r["action_max"] <= 1.0


# ----------------------------------------------------------------------------- gymnax conventions


@pytest.fixture(scope="module")
def nav():
    import jax

    from fedjax_nav import env as nav  # the package: make, NavEnv, EnvParams

    env, params = nav.make("Nav-v0", world="train-2", episode_length=16, v_max=0.5)
    return jax, nav, env, params


def test_make_splits_env_and_params_arguments(nav):
    jax, navm, env, params = nav
    from fedjax_nav import worlds

    assert isinstance(env, navm.NavEnv) and isinstance(params, navm.EnvParams)
    assert env.episode_length == 16 and env.mode == "learn" and float(params.v_max) == 0.5
    np.testing.assert_array_equal(params.world.segments, worlds.load("train-2").segments)
    env2, p2 = navm.make("fedjax_nav/Nav-v0", world=["train-0", "train-3"], num_beams=12, goal_index=1)
    assert env2.num_beams == 12 and p2.v_max.shape == (2,) and np.all(np.asarray(p2.goal_index) == 1)
    d = navm.NavEnv().default_params
    np.testing.assert_array_equal(d.world.segments, worlds.load("train-0").segments)
    assert float(d.v_max) == float(navm.EnvParams(world=d.world).v_max)
    with pytest.raises(ValueError, match="unknown environment 'CartPole-v1'"):
        navm.make("CartPole-v1")
    with pytest.raises(TypeError, match="bogus"):
        navm.make(bogus=1)


def test_spaces_hold_what_the_env_gives(nav):
    jax, _, env, params = nav
    import jax.numpy as jnp

    obs_space, act_space = env.observation_space(params), env.action_space(params)
    assert obs_space.shape == (28,) and act_space.shape == (2,) and obs_space.dtype == jnp.float32
    np.testing.assert_array_equal(act_space.low, [0.0, -1.0])
    np.testing.assert_array_equal(act_space.high, [1.0, 1.0])

    @jax.jit
    def rollout(key):  # gymnax-style: actions from the space, everything in one scan
        obs, state = env.reset(key, params)

        def body(carry, k):
            state, ok = carry
            k_act, k_step = jax.random.split(k)
            a = act_space.sample(k_act)
            obs, state, *_ = env.step(k_step, state, a, params)
            return (state, ok & obs_space.contains(obs) & act_space.contains(a)), None

        (_, ok), _ = jax.lax.scan(body, (state, obs_space.contains(obs)), jax.random.split(key, 64))
        return ok, obs_space.sample(key)

    ok, sample = rollout(jax.random.key(0))
    assert bool(ok) and sample.shape == (28,) and bool(obs_space.contains(sample))
    assert not bool(obs_space.contains(jnp.full(28, -1.0)))
    # the gymnasium adapter's spaces are these, converted
    pytest.importorskip("gymnasium")
    from fedjax_nav.env.gym_env import NavGymEnv

    g = NavGymEnv("train-2", episode_length=16, v_max=0.5)
    assert g.observation_space == obs_space.to_gymnasium() and g.action_space == act_space.to_gymnasium()
