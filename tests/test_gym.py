"""The gymnasium adapters (optional extra): `NavGymEnv` passes gymnasium's checker (render
included), keeps `terminated` (goal / collision) apart from `truncated` (time limit), draws
rgb_array frames, changes episodes with the seed when asked to, pickles, refuses to hang in a
forked child; the vmap `NavVectorEnv` equals gymnasium's SyncVectorEnv over NavGymEnvs."""

import copy
import json
import os
import pickle
import subprocess
import sys
import textwrap
import time

import jax
import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

from gymnasium.vector import AutoresetMode, SyncVectorEnv  # noqa: E402

from fedjax_nav import worlds  # noqa: E402
from fedjax_nav.env import gym_env, gym_task  # noqa: E402
from fedjax_nav.env.gym_env import NavGymEnv  # noqa: E402
from fedjax_nav.env.gym_vector import NavVectorEnv  # noqa: E402

SIZE = 64  # render_size of the tests (one compiled frame)


@pytest.fixture(scope="module")
def env():
    # a fast robot and a short episode: collisions and truncation within a few steps
    return NavGymEnv("train-0", episode_length=8, v_max=2.0, render_mode="rgb_array", render_size=SIZE)


def test_check_env_passes_render_included():
    from gymnasium.utils.env_checker import check_env

    # through make: the env has a spec, so the checker also tries the other render modes
    made = gymnasium.make(gym_env.ENV_ID, world="train-0", episode_length=8, v_max=2.0, render_mode="rgb_array")
    check_env(made.unwrapped)


def test_spaces_and_shapes(env):
    assert env.observation_space.shape == (28,) and env.observation_space.dtype == np.float32
    assert env.action_space.shape == (2,)
    np.testing.assert_array_equal(env.action_space.low, [0.0, -1.0])
    np.testing.assert_array_equal(env.action_space.high, [1.0, 1.0])
    obs, info = env.reset(seed=0)
    assert obs.shape == (28,) and obs.dtype == np.float32 and info == {}
    obs, r, term, trunc, info = env.step(env.action_space.sample())
    assert obs.shape == (28,) and isinstance(r, float) and isinstance(term, bool) and isinstance(trunc, bool)
    assert set(info) == {"goal", "collision", "pose", "clearance"}
    assert NavGymEnv("train-0").render() is None  # render_mode None draws nothing
    with pytest.raises(ValueError, match="render_mode"):
        NavGymEnv("train-0", render_mode="human")


def test_truncated_at_the_time_limit(env):
    env.reset(seed=0)
    flags = [env.step(np.array([0.0, 0.0], np.float32))[2:4] for _ in range(8)]  # stand still
    assert flags[:-1] == [(False, False)] * 7
    assert flags[-1] == (False, True)


def test_terminated_on_collision_not_truncated(tmp_path):
    # a world given by path: facing the wall 1.5 m ahead (collision at 1.25 m), 0.5 m per step
    path = tmp_path / "box.json"
    path.write_text(json.dumps({"size": [3.0, 3.0], "starts": [[0.0, 0.0, 0.0]], "goals": [[-1.0, 1.0]]}))
    env = NavGymEnv(path, episode_length=8, v_max=5.0)
    env.reset(seed=0)
    flags = [env.step(np.array([1.0, 0.0], np.float32)) for _ in range(3)]
    assert [f[2:4] for f in flags] == [(False, False), (False, False), (True, False)]
    assert flags[-1][4]["collision"] and not flags[-1][4]["goal"]
    assert flags[-1][1] < 0  # the collision penalty
    # the episode is over for the caller: reset starts a new one at the start pose
    obs, _ = env.reset()
    assert obs[-2:].tolist() == [0.0, 0.0]  # no previous action yet


# ----------------------------------------------------------------------------- render


def _scale(size_m, px=SIZE):
    """(metres across the frame, metres per pixel): gym_task.frame's scale, the room + 10 % + 0.2 m."""
    extent = max(size_m) * 1.1 + 0.2
    return extent, extent / px


def _pixel(xy, size_m):
    """(row, col) of the pixel holding the point xy."""
    extent, m_px = _scale(size_m)
    return int((extent / 2 - xy[1]) / m_px), int((xy[0] + extent / 2) / m_px)


def _centroid(img, rgb, size_m):
    """The mean position (m) of the pixels of colour rgb."""
    extent, m_px = _scale(size_m)
    rows, cols = np.nonzero((img == rgb).all(-1))
    assert len(rows), f"no pixel of colour {rgb}"
    return np.array([(cols.mean() + 0.5) * m_px - extent / 2, extent / 2 - (rows.mean() + 0.5) * m_px]), m_px


def test_render_rgb_array_draws_the_robot_goal_and_room(env):
    env.reset(seed=0)
    img = env.render()
    assert img.shape == (SIZE, SIZE, 3) and img.dtype == np.uint8
    w = worlds.load("train-0")
    robot = (31, 119, 180)
    xy, m_px = _centroid(img, robot, w.size)
    np.testing.assert_allclose(xy, np.asarray(w.starts[0, :2]), atol=1.5 * m_px)  # the robot at its start
    assert tuple(img[_pixel(np.asarray(w.goals[0]), w.size)]) == (40, 160, 40)  # the goal's centre
    assert tuple(img[0, 0]) == (200, 200, 200)  # outside the walls
    assert (img == (60, 60, 60)).all(-1).sum() > SIZE  # walls and obstacles
    # the picture follows the robot: 3 steps at full speed (0.2 m each) along its heading
    for _ in range(3):
        *_, info = env.step(np.array([1.0, 0.0], np.float32))
    xy2, _ = _centroid(env.render(), robot, w.size)
    np.testing.assert_allclose(xy2, info["pose"][:2], atol=1.5 * m_px)
    assert np.linalg.norm(xy2 - xy) > 0.5


# ----------------------------------------------------------------------------- seeds


def test_default_episode_is_the_worlds_and_seeded_resets_are_deterministic():
    a, b = NavGymEnv("train-0", random_starts=True), NavGymEnv("train-0", random_starts=True)
    for s in (0, 1, 2):
        np.testing.assert_array_equal(a.reset(seed=s)[0], b.reset(seed=s)[0])
    fixed = NavGymEnv("train-0")  # the world's start 0 and goal 0, no noise: one episode
    first = fixed.reset(seed=0)[0]
    assert all(np.array_equal(fixed.reset(seed=s)[0], first) for s in (1, 2, 3))


@pytest.mark.parametrize(
    "options",
    [
        dict(world="train-2", placement="random"),
        dict(rooms="procedural", room_family="cylinders", room_spec={"cylinders_max": 3, "width_max": 6.0}),
    ],
    ids=["random-placement", "procedural-rooms"],
)
def test_seeds_change_the_episode(options):
    env, twin = NavGymEnv(**options), NavGymEnv(**options)
    obs = [env.reset(seed=s)[0] for s in range(4)]
    for i in range(4):
        for j in range(i):
            assert not np.array_equal(obs[i], obs[j]), (i, j)
    np.testing.assert_array_equal(twin.reset(seed=2)[0], obs[2])  # a seed gives one episode
    # an unseeded reset goes on with the stream: yet another episode
    assert not any(np.array_equal(env.reset()[0], o) for o in obs)
    # the drawn start keeps the collision distance (and the placement's margin) from every obstacle
    _, _, term, _, info = env.step(np.zeros(2, np.float32))
    assert not term and info["clearance"] > worlds.CLEARANCE
    if options.get("rooms") == "procedural":  # a new room, not only a new start
        params = [env._state[1]]
        env.reset(seed=7)
        params.append(env._state[1])
        assert not np.array_equal(np.asarray(params[0].world.segments), np.asarray(params[1].world.segments))


def test_random_placement_is_the_trainings():
    from fedjax_nav.training import rooms

    w = worlds.load("train-3")
    keys = jax.random.split(jax.random.key(0), 4)
    ours = jax.jit(jax.vmap(gym_task.place, in_axes=(None, 0)))(w, keys)
    theirs = jax.jit(jax.vmap(rooms.place, in_axes=(None, 0)))(w, keys)
    for a, b in zip(jax.tree.leaves(ours), jax.tree.leaves(theirs)):
        np.testing.assert_array_equal(a, b)
    assert len(np.unique(np.asarray(ours.starts[:, 0]), axis=0)) == 4  # four keys, four starts


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(placement="anywhere"), "placement"),
        (dict(rooms="maze"), "rooms"),
        (dict(world="train-0", rooms="procedural"), "world"),
        (dict(room_spec={"cylinders_max": 2}), "room_spec"),
        (dict(rooms="procedural", room_spec={"wings": 2}), "wings"),
        (dict(collision_test="fuzzy"), "collision_test"),
    ],
)
def test_bad_options_name_the_field(kwargs, match):
    with pytest.raises(ValueError, match=match):
        NavGymEnv(**kwargs)


# ----------------------------------------------------------------------------- pickling


def test_pickle_and_deepcopy_keep_the_episode_and_stream():
    env = gymnasium.make(gym_env.ENV_ID, world="train-2", placement="random", episode_length=16)
    env.reset(seed=5)
    for _ in range(3):
        env.step(np.array([0.5, 0.2], np.float32))
    clones = [pickle.loads(pickle.dumps(env)), copy.deepcopy(env)]
    a = np.array([0.7, -0.3], np.float32)
    ref = env.step(a)
    for c in clones:
        out = c.step(a)
        np.testing.assert_array_equal(out[0], ref[0])
        assert out[1:4] == ref[1:4]
    ref_reset = env.reset()[0]  # the random stream goes on identically
    for c in clones:
        np.testing.assert_array_equal(c.reset()[0], ref_reset)
    fresh = pickle.loads(pickle.dumps(NavGymEnv("train-0")))  # never reset: still usable
    assert fresh.reset(seed=0)[0].shape == (28,)


# ----------------------------------------------------------------------------- the vmap vector env

VEC = dict(world="train-0", random_starts=True, episode_length=6, v_max=2.0)


def _sync(n, mode):
    return SyncVectorEnv([lambda: NavGymEnv(**VEC) for _ in range(n)], autoreset_mode=mode)


def _same_infos(a: dict, b: dict):
    assert set(a) == set(b), (sorted(a), sorted(b))
    for k in a:
        if k == "final_obs":
            for x, y in zip(a[k], b[k]):
                assert (x is None and y is None) or np.allclose(x, y, atol=1e-6)
        elif isinstance(a[k], dict):
            _same_infos(a[k], b[k])
        elif k.startswith("_"):
            np.testing.assert_array_equal(a[k], b[k])
        else:
            mask = a[f"_{k}"]
            np.testing.assert_allclose(np.asarray(a[k], float)[mask], np.asarray(b[k], float)[mask], atol=1e-6)


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_vector_env_equals_sync_vector_env(mode):
    n, steps = 3, 16
    vec = gymnasium.make_vec(gym_env.ENV_ID, num_envs=n, autoreset_mode=mode, **VEC)
    assert isinstance(vec.unwrapped, NavVectorEnv) and vec.metadata["autoreset_mode"] == mode
    sync = _sync(n, mode)
    assert vec.single_observation_space == sync.single_observation_space
    assert vec.observation_space.shape == (n, 28) and vec.action_space.shape == (n, 2)
    a, _ = vec.reset(seed=11)
    b, _ = sync.reset(seed=11)
    np.testing.assert_allclose(a, b, atol=1e-6)
    rng = np.random.default_rng(0)
    ended = 0
    for _ in range(steps):
        act = rng.uniform([0.5, -1.0], [1.0, 1.0], size=(n, 2)).astype(np.float32)
        va, sa = vec.step(act), sync.step(act)
        for x, y in zip(va[:4], sa[:4]):
            assert np.asarray(x).dtype == np.asarray(y).dtype
            np.testing.assert_allclose(np.asarray(x, float), np.asarray(y, float), atol=1e-5)
        _same_infos(va[4], sa[4])
        ended += int((va[2] | va[3]).sum())
    assert ended >= n  # collisions and time limits: every sub-env was reset at least once


def test_vector_env_disabled_autoreset_and_reset_mask():
    n = 3
    vec = NavVectorEnv(n, autoreset_mode="disabled", **VEC)  # a mode by name, as by AutoresetMode
    obs0, _ = vec.reset(seed=0)
    stand = np.zeros((n, 2), np.float32)
    for _ in range(6):  # standing still: the time limit ends every episode at step 6
        obs, _, term, trunc, _ = vec.step(stand)
    assert trunc.all() and not term.any()
    with pytest.raises(RuntimeError, match="reset_mask"):
        vec.step(stand)
    mask = np.array([True, False, True])
    new, _ = vec.reset(seed=[0, None, 5], options={"reset_mask": mask})
    np.testing.assert_array_equal(new[0], obs0[0])  # seed 0 again: the same episode
    np.testing.assert_array_equal(new[1], obs[1])  # not reset
    np.testing.assert_array_equal(new[2], NavGymEnv(**VEC).reset(seed=5)[0])
    with pytest.raises(RuntimeError, match="reset_mask"):  # sub-env 1 still waits for its reset
        vec.step(stand)
    vec.reset(options={"reset_mask": ~mask})
    vec.step(stand)


def test_vector_env_render_and_pickle():
    vec = NavVectorEnv(2, render_mode="rgb_array", render_size=SIZE, **VEC)
    single = [NavGymEnv(**VEC, render_mode="rgb_array", render_size=SIZE) for _ in range(2)]
    vec.reset(seed=3)
    for i, e in enumerate(single):
        e.reset(seed=3 + i)
    frames = vec.render()
    assert isinstance(frames, tuple) and len(frames) == 2
    for f, e in zip(frames, single):
        assert f.shape == (SIZE, SIZE, 3) and f.dtype == np.uint8
        np.testing.assert_array_equal(f, e.render())
    clone = pickle.loads(pickle.dumps(vec))
    act = np.full((2, 2), 0.5, np.float32)
    np.testing.assert_array_equal(clone.step(act)[0], vec.step(act)[0])


def test_vector_env_with_gymnasiums_episode_statistics():
    from gymnasium.wrappers.vector import RecordEpisodeStatistics

    vec = RecordEpisodeStatistics(gymnasium.make_vec(gym_env.ENV_ID, num_envs=2, **VEC))
    vec.reset(seed=0)
    lengths = []
    for _ in range(8):
        *_, info = vec.step(np.zeros((2, 2), np.float32))
        if "episode" in info:
            lengths += list(info["episode"]["l"][info["_episode"]])
    assert lengths == [6, 6]  # both stood still to the time limit


# ----------------------------------------------------------------------------- async vectorization

_ASYNC = """
import sys, time
import gymnasium
import fedjax_nav.env.gym_env as ge
def main():
    t = time.time()
    try:
        envs = gymnasium.make_vec(ge.ENV_ID, num_envs={n}, vectorization_mode="async", {extra} episode_length=4)
        obs, _ = envs.reset(seed=0)
        envs.step(envs.action_space.sample())
        envs.close()
        print("OK", obs.shape)
    except Exception as e:
        print("FAILED", type(e).__name__, round(time.time() - t, 1))
if __name__ == "__main__":
    main()
"""


def _run(code: str, timeout: float):
    env = {**os.environ, "JAX_PLATFORMS": "cpu"}
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout, env=env)


def test_async_with_fork_fails_fast_instead_of_hanging():
    """Under fork (the default start method here) the worker refuses to build the env: an error
    in seconds, not a hang (the old adapter hung here until killed)."""
    t0 = time.monotonic()
    out = _run(textwrap.dedent(_ASYNC.format(n=2, extra="")), timeout=120)
    assert out.stdout.startswith("FAILED"), out.stdout + out.stderr[-2000:]
    assert "forked after JAX had started" in out.stderr and "'context': 'spawn'" in out.stderr
    assert time.monotonic() - t0 < 110


def test_refuse_forked_child(monkeypatch):
    monkeypatch.setattr(gym_env, "_forked_after_jax", True)
    with pytest.raises(RuntimeError, match="spawn"):
        NavGymEnv("train-0")
    with pytest.raises(RuntimeError, match="spawn"):
        NavVectorEnv(2)


@pytest.mark.slow
def test_async_with_spawn_works():
    out = _run(textwrap.dedent(_ASYNC.format(n=1, extra="vector_kwargs={'context': 'spawn'},")), timeout=300)
    assert out.stdout.startswith("OK (1, 28)"), out.stdout + out.stderr[-2000:]
