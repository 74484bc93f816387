"""The gymnasium wrapper (optional extra): passes gymnasium's checker, shapes, and keeps
`terminated` (goal / collision) apart from `truncated` (time limit)."""

import json

import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")

from fedjax_nav.env.gym_env import NavGymEnv  # noqa: E402


@pytest.fixture(scope="module")
def env():
    # a fast robot and a short episode: collisions and truncation within a few steps
    return NavGymEnv("train-0", episode_length=8, v_max=2.0)


def test_check_env_passes(env):
    from gymnasium.utils.env_checker import check_env

    check_env(env, skip_render_check=True)


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
    assert env.render() is None


def test_seeded_reset_is_deterministic():
    a, b = NavGymEnv("train-0", random_starts=True), NavGymEnv("train-0", random_starts=True)
    for s in (0, 1, 2):
        np.testing.assert_array_equal(a.reset(seed=s)[0], b.reset(seed=s)[0])


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
