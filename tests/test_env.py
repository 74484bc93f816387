"""NavEnv: kinematics, every reward term, collision and goal tests, episodes, observation layout,
batching over padded playgrounds, keys and noise.

Hand-built worlds come from `worlds.from_dict` (validated like a user's file) and are padded to
one common shape (conftest.TINY_SHAPE) so that each env configuration compiles `step` once.
Most use a 10 x 2 m corridor: walls at x = +-5 and y = +-1.
"""

import math
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import EPISODE_LENGTH, ROLLOUT_STEPS, drive, tiny_world

from fedjax_nav import worlds
from fedjax_nav.env import NavEnv, lidar, make_params, unicycle

PI = math.pi


def wrap(a):
    return (a + PI) % (2 * PI) - PI


def run(jenv, world, actions, seed=0, **overrides):
    """Reset, then one jitted `step` per action. Returns params, the reset (obs, state) and a
    list of steps (obs, state, reward, terminated, truncated, info, prev_state) as numpy."""
    params = make_params(world, **overrides)
    key = jax.random.key(seed)
    key, k0 = jax.random.split(key)
    obs, state = jenv.reset(k0, params)
    first = SimpleNamespace(obs=np.asarray(obs), state=state)
    steps = []
    for a in actions:
        key, k = jax.random.split(key)
        obs, new, reward, term, trunc, info = jenv.step(k, state, jnp.asarray(a, jnp.float32), params)
        steps.append(
            SimpleNamespace(
                obs=np.asarray(obs),
                state=new,
                prev=state,
                reward=float(reward),
                terminated=bool(term),
                truncated=bool(trunc),
                goal=bool(info["goal"]),
                collision=bool(info["collision"]),
                pose=np.asarray(info["pose"], np.float64),
                clearance=float(info["clearance"]),
            )
        )
        state = new
    return params, first, steps


# ----------------------------------------------------------------------------- kinematics


@pytest.fixture(scope="module")
def unicycle_jit():
    return jax.jit(unicycle)


def _uni(fn, pose, v, omega, dt=0.1):
    return np.asarray(
        fn(jnp.asarray(pose, jnp.float32), jnp.float32(v), jnp.float32(omega), jnp.float32(dt)), np.float64
    )


def test_unicycle_straight_line(unicycle_jit):
    got = _uni(unicycle_jit, (1.0, 2.0, 0.3), 0.25, 0.0)
    np.testing.assert_allclose(got, [1 + 0.025 * math.cos(0.3), 2 + 0.025 * math.sin(0.3), 0.3], atol=1e-6)
    # Many steps stay on the line through the start with the start's heading.
    pose = np.array([1.0, 2.0, 0.3])
    for _ in range(20):
        pose = _uni(unicycle_jit, pose, 0.25, 0.0)
    np.testing.assert_allclose(pose, [1 + 0.5 * math.cos(0.3), 2 + 0.5 * math.sin(0.3), 0.3], atol=1e-5)
    # Backwards-free: v = 0 stays put.
    np.testing.assert_allclose(_uni(unicycle_jit, (1.0, 2.0, 0.3), 0.0, 0.0), [1.0, 2.0, 0.3], atol=1e-7)


def test_unicycle_pure_rotation(unicycle_jit):
    got = _uni(unicycle_jit, (1.0, -2.0, 0.5), 0.0, 1.0)
    np.testing.assert_allclose(got, [1.0, -2.0, 0.6], atol=1e-6)
    got = _uni(unicycle_jit, (1.0, -2.0, 0.5), 0.0, -0.7, dt=0.5)
    np.testing.assert_allclose(got, [1.0, -2.0, 0.15], atol=1e-6)


def test_unicycle_arc_is_the_closed_form_circle(unicycle_jit):
    x0, y0, th0, v, om, dt = 0.5, -1.0, 0.4, 0.25, 0.8, 0.1
    radius = v / om
    cx, cy = x0 - radius * math.sin(th0), y0 + radius * math.cos(th0)  # centre of the turn (left)
    pose = np.array([x0, y0, th0])
    for k in range(1, 80):  # more than a full turn (2 pi / (0.8 * 0.1) = 78.5 steps)
        pose = _uni(unicycle_jit, pose, v, om, dt)
        th = th0 + om * dt * k
        np.testing.assert_allclose(pose[:2], [cx + radius * math.sin(th), cy - radius * math.cos(th)], atol=2e-5)
        assert pose[2] == pytest.approx(wrap(th), abs=2e-5)
    # One long step: a quarter circle of radius 2/pi, exactly.
    got = _uni(unicycle_jit, (0.0, 0.0, 0.0), 1.0, PI / 2, dt=1.0)
    np.testing.assert_allclose(got, [2 / PI, 2 / PI, PI / 2], atol=1e-6)
    # Turning right (omega < 0) from heading +y: a quarter circle to the right.
    got = _uni(unicycle_jit, (0.0, 0.0, PI / 2), 1.0, -PI / 2, dt=1.0)
    np.testing.assert_allclose(got, [2 / PI, 2 / PI, 0.0], atol=1e-6)
    # Nearly straight: still the exact arc (a v / omega form loses float32 digits here).
    for om in (1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 0.1):
        got = _uni(unicycle_jit, (0.0, 0.0, 0.3), 0.25, om)
        r = 0.25 / om
        th1 = 0.3 + om * 0.1
        want = [r * (math.sin(th1) - math.sin(0.3)), -r * (math.cos(th1) - math.cos(0.3)), th1]
        np.testing.assert_allclose(got, want, atol=1e-6)


def test_unicycle_heading_wrapped(unicycle_jit):
    got = _uni(unicycle_jit, (0.0, 0.0, 3.1), 0.0, 1.0)
    assert got[2] == pytest.approx(3.2 - 2 * PI, abs=1e-5)
    got = _uni(unicycle_jit, (0.0, 0.0, -3.1), 0.0, -1.0)
    assert got[2] == pytest.approx(2 * PI - 3.2, abs=1e-5)
    got = _uni(unicycle_jit, (0.0, 0.0, 0.0), 0.0, 1.0, dt=10.0)
    assert got[2] == pytest.approx(10.0 - 4 * PI, abs=1e-5)
    # An unwrapped input heading comes out wrapped, with the position moved along it.
    got = _uni(unicycle_jit, (0.0, 0.0, 2 * PI + 0.3), 0.25, 0.0)
    np.testing.assert_allclose(got, [0.025 * math.cos(0.3), 0.025 * math.sin(0.3), 0.3], atol=1e-5)
    for th in np.linspace(-10, 10, 21):
        assert -PI <= _uni(unicycle_jit, (0.0, 0.0, th), 0.1, 0.9)[2] <= PI


# ----------------------------------------------------------------------------- reward terms


def test_progress_reward(learn_env):
    world = tiny_world(starts=[[-3.0, 0.0, 0.0]], goals=[[4.0, 0.0]])
    actions = [(1.0, 0.0), (1.0, 0.0), (0.5, 1.0), (0.7, -0.6), (0.0, 0.3)]
    _, first, steps = run(learn_env, world, actions)
    # Straight at the goal at full speed: 0.025 m closer, reward 40 * 0.025 = 1.
    assert steps[0].reward == pytest.approx(1.0, abs=1e-4)
    assert float(first.state.dist) == pytest.approx(7.0)
    goal = np.array([4.0, 0.0])
    prev = np.array([-3.0, 0.0])
    for s in steps:
        assert not (s.terminated or s.goal or s.collision)
        d_prev, d_now = np.linalg.norm(goal - prev), np.linalg.norm(goal - s.pose[:2])
        assert s.reward == pytest.approx(40.0 * (d_prev - d_now), abs=1e-4)
        assert s.reward == pytest.approx(40.0 * (float(s.prev.dist) - float(s.state.dist)), abs=1e-5)
        prev = s.pose[:2]
    # Turning on the spot gives nothing; turning away costs.
    assert steps[4].reward == pytest.approx(0.0, abs=1e-5)
    assert steps[2].reward < 1.0
    # The scale is data: progress_scale=20 halves the progress reward.
    _, _, steps = run(learn_env, world, actions[:1], progress_scale=20.0)
    assert steps[0].reward == pytest.approx(0.5, abs=1e-4)


def test_goal_reward_and_learn_mode_reset(learn_env):
    start = [3.48, 0.0, 0.0]  # 0.52 m from the goal: one full-speed step (0.025 m) reaches it
    world = tiny_world(starts=[start], goals=[[4.0, 0.0]])
    _, first, steps = run(learn_env, world, [(1.0, 0.0), (1.0, 0.0)])
    s = steps[0]
    assert s.goal and s.terminated and not s.collision and not s.truncated
    assert s.reward == pytest.approx(100.0 + 40.0 * 0.025, abs=1e-4)
    np.testing.assert_allclose(s.pose, [3.505, 0.0, 0.0], atol=1e-6)  # info: the pose reached
    # learn mode: put back at the start, the episode goes on (t is not reset).
    np.testing.assert_allclose(np.asarray(s.state.pose), start, atol=1e-7)
    assert int(s.state.t) == 1
    assert float(s.state.dist) == pytest.approx(0.52, abs=1e-6)
    np.testing.assert_array_equal(np.asarray(s.state.prev_action), [0.0, 0.0])
    np.testing.assert_allclose(s.obs, first.obs, atol=1e-6)  # the observation at the start
    # ... and reaches the goal again on the next step.
    assert steps[1].goal and int(steps[1].state.t) == 2


def test_no_goal_outside_goal_radius(learn_env):
    world = tiny_world(starts=[[3.45, 0.0, 0.0]], goals=[[4.0, 0.0]])  # 0.55 -> 0.525 m
    _, _, steps = run(learn_env, world, [(1.0, 0.0)])
    assert not steps[0].goal and not steps[0].terminated
    assert steps[0].reward == pytest.approx(1.0, abs=1e-4)
    # The goal radius is data: 0.53 m makes the same step a success.
    _, _, steps = run(learn_env, world, [(1.0, 0.0)], goal_radius=0.53)
    assert steps[0].goal and steps[0].reward == pytest.approx(101.0, abs=1e-4)


def test_collision_exact_threshold(learn_env):
    goal = np.array([4.0, 0.0])
    # 0.26 m from the wall y = 1, heading into it: one step brings it to 0.235 m < 0.25.
    world = tiny_world(starts=[[0.0, 0.74, PI / 2]], goals=[goal.tolist()])
    _, _, steps = run(learn_env, world, [(1.0, 0.0)])
    s = steps[0]
    assert s.collision and s.terminated and not s.goal
    assert s.clearance == pytest.approx(0.235, abs=1e-6)
    progress = 40.0 * (np.linalg.norm(goal - [0.0, 0.74]) - np.linalg.norm(goal - [0.0, 0.765]))
    assert s.reward == pytest.approx(-10.0 + progress, abs=1e-4)
    # 0.28 m from the wall: after the step 0.255 m, no collision.
    world = tiny_world(starts=[[0.0, 0.72, PI / 2]], goals=[goal.tolist()])
    _, _, steps = run(learn_env, world, [(1.0, 0.0)])
    assert not steps[0].collision and not steps[0].terminated
    assert steps[0].clearance == pytest.approx(0.255, abs=1e-6)
    # The collision distance is data.
    _, _, steps = run(learn_env, world, [(1.0, 0.0)], collision_distance=0.26)
    assert steps[0].collision
    # A cylinder counts as well as a wall.
    world = tiny_world(starts=[[0.0, 0.0, 0.0]], goals=[[-4.0, 0.0]], circles=[[0.76, 0.0, 0.5]])
    _, _, steps = run(learn_env, world, [(1.0, 0.0)])
    assert steps[0].collision and steps[0].clearance == pytest.approx(0.235, abs=1e-6)


def test_collision_and_goal_in_the_same_step_add_up(learn_env):
    # v_max = 1 m/s: one step of 0.1 m takes the robot 0.16 m from the wall and 0.494 m from the goal.
    goal = np.array([0.49, 0.9])
    world = tiny_world(starts=[[0.0, 0.74, PI / 2]], goals=[goal.tolist()])
    _, _, steps = run(learn_env, world, [(1.0, 0.0)], v_max=1.0)
    s = steps[0]
    assert s.goal and s.collision and s.terminated
    progress = 40.0 * (np.linalg.norm(goal - [0.0, 0.74]) - np.linalg.norm(goal - [0.0, 0.84]))
    assert s.reward == pytest.approx(100.0 - 10.0 + progress, abs=1e-4)


# A short segment 0.25 m ahead-left, between beams 0 and 1: the exact test sees it after one
# step (0.23 m), the 24 beams do not.
SLIVER = [[0.2528, 0.0283, 0.2528, 0.0383]]


def test_exact_collision_catches_what_the_beams_miss(learn_env, lidar_env):
    world = tiny_world(starts=[[0.0, 0.0, 0.0]], goals=[[-1.5, -1.5]], size=(4.0, 4.0), segments=SLIVER)
    _, _, steps = run(learn_env, world, [(1.0, 0.0)])
    assert steps[0].collision and steps[0].terminated
    assert steps[0].clearance == pytest.approx(math.hypot(0.2278, 0.0283), abs=1e-5)
    _, _, steps = run(lidar_env, world, [(1.0, 0.0)])
    assert not steps[0].collision and not steps[0].terminated
    assert steps[0].clearance == pytest.approx(1.975, abs=1e-5)  # the shortest beam: a wall


def test_lidar_collision_test(lidar_env, lidar_jit):
    start = [0.0, 0.74, PI / 2]
    world = tiny_world(starts=[start], goals=[[4.0, 0.0]])
    params, first, steps = run(lidar_env, world, [(1.0, 0.0), (0.0, 0.0)])
    s = steps[0]
    assert s.collision and s.terminated
    assert s.clearance == pytest.approx(0.235, abs=1e-6)  # beam 0 straight into the wall
    # learn mode: reset to the start, and the beams are cast again there.
    np.testing.assert_allclose(np.asarray(s.state.pose), start, atol=1e-7)
    want = np.asarray(lidar_jit(world.segments, jnp.asarray(start, jnp.float32), circles=world.circles))
    np.testing.assert_allclose(s.obs[:24], want, atol=1e-6)
    np.testing.assert_allclose(s.obs, first.obs, atol=1e-6)
    assert not steps[1].collision  # 0.26 m from the wall again


def test_learn_mode_continues_after_collision(learn_env):
    start = [0.0, 0.715, PI / 2]  # 0.285 m from the wall: no collision after 1 step, one after 2
    world = tiny_world(starts=[start], goals=[[4.0, 0.0]])
    _, _, steps = run(learn_env, world, [(1.0, 0.0)] * 3)
    assert [s.collision for s in steps] == [False, True, False]
    assert [int(s.state.t) for s in steps] == [1, 2, 3]
    assert not any(s.truncated for s in steps)
    np.testing.assert_allclose(np.asarray(steps[1].state.pose), start, atol=1e-7)
    np.testing.assert_allclose(np.asarray(steps[2].state.pose), [0.0, 0.74, PI / 2], atol=1e-6)
    # After the reset the progress term is measured from the start again.
    goal = np.array([4.0, 0.0])
    d = lambda y: np.linalg.norm(goal - [0.0, y])  # noqa: E731
    assert steps[2].reward == pytest.approx(40.0 * (d(0.715) - d(0.74)), abs=1e-4)


def test_truncated_at_episode_length(learn_env):
    start = [0.0, 0.0, 0.0]
    world = tiny_world(starts=[start], goals=[[4.0, 0.0]])
    _, _, steps = run(learn_env, world, [(0.0, 0.0)] * (EPISODE_LENGTH + 1))
    assert [s.truncated for s in steps] == [False] * (EPISODE_LENGTH - 1) + [True, True]
    assert not any(s.terminated for s in steps)
    assert [int(s.state.t) for s in steps] == list(range(1, EPISODE_LENGTH + 2))
    # Truncation does not reset (the caller does, with the true last observation in hand).
    np.testing.assert_allclose(np.asarray(steps[-1].state.pose), start, atol=1e-7)


def test_eval_mode_does_not_reset(eval_env):
    goal = [4.0, 0.0]
    # Reaches the goal on the last step of the episode: terminated (success), not truncated.
    world = tiny_world(starts=[[3.405, 0.0, 0.0]], goals=[goal])
    _, _, steps = run(eval_env, world, [(1.0, 0.0)] * EPISODE_LENGTH)
    assert [s.goal for s in steps] == [False] * (EPISODE_LENGTH - 1) + [True]
    assert steps[-1].terminated and not steps[-1].truncated
    np.testing.assert_allclose(np.asarray(steps[-1].state.pose), [3.505, 0.0, 0.0], atol=1e-5)
    assert steps[-1].reward == pytest.approx(101.0, abs=1e-4)
    # A collision: terminated, the robot stays where it hit.
    world = tiny_world(starts=[[0.0, 0.74, PI / 2]], goals=[goal])
    _, _, steps = run(eval_env, world, [(1.0, 0.0)])
    assert steps[0].collision and steps[0].terminated
    np.testing.assert_allclose(np.asarray(steps[0].state.pose), [0.0, 0.765, PI / 2], atol=1e-6)
    assert float(steps[0].state.dist) == pytest.approx(math.hypot(4.0, 0.765), abs=1e-5)
    # Time out: truncated at episode_length, not terminated.
    world = tiny_world(starts=[[0.0, 0.0, 0.0]], goals=[goal])
    _, _, steps = run(eval_env, world, [(0.0, 0.0)] * EPISODE_LENGTH)
    assert [s.truncated for s in steps] == [False] * (EPISODE_LENGTH - 1) + [True]
    assert not any(s.terminated for s in steps)


# ----------------------------------------------------------------------------- starts and goals

# Three starts, each 0.26 m from the top wall heading into it: one step from any of them collides.
THREE_STARTS = [[-4.0, 0.74, PI / 2], [0.0, 0.74, PI / 2], [4.0, 0.74, PI / 2]]


def test_random_starts_pick_among_num_starts(learn_env):
    world = tiny_world(starts=THREE_STARTS, goals=[[-2.0, -0.5]])
    assert world.starts.shape[0] == 4 and int(world.num_starts) == 3  # row 3 is padding
    keys = jax.random.split(jax.random.key(3), 300)
    _, states = learn_env.reset_keys(keys, make_params(world, random_starts=True))
    idx = np.asarray(states.start_index)
    assert set(idx.tolist()) == {0, 1, 2}
    assert min(np.bincount(idx)) > 50
    np.testing.assert_array_equal(np.asarray(states.pose), np.asarray(world.starts)[idx])
    # Without random starts: always start 0.
    _, states = learn_env.reset_keys(keys, make_params(world))
    assert np.all(np.asarray(states.start_index) == 0)
    np.testing.assert_array_equal(np.asarray(states.pose), np.tile(THREE_STARTS[0], (300, 1)).astype(np.float32))


def test_reset_after_terminated_picks_a_random_start(learn_env):
    world = tiny_world(starts=THREE_STARTS, goals=[[-2.0, -0.5]])
    params = make_params(world, random_starts=True)
    _, state = learn_env.reset(jax.random.key(0), params)
    seen = []
    for i in range(40):
        _, new, _, term, _, info = learn_env.step(jax.random.key(100 + i), state, jnp.array([1.0, 0.0]), params)
        assert bool(term) and bool(info["collision"])
        k = int(new.start_index)
        np.testing.assert_array_equal(np.asarray(new.pose), np.asarray(THREE_STARTS[k], np.float32))
        seen.append(k)
    assert set(seen) == {0, 1, 2}
    # Fixed start: always back to start 0.
    params = make_params(world)
    for i in range(5):
        _, new, *_ = learn_env.step(jax.random.key(200 + i), state, jnp.array([1.0, 0.0]), params)
        assert int(new.start_index) == 0


def test_goal_index_selects_the_goal(learn_env):
    world = tiny_world(starts=[[0.0, 0.0, 0.0]], goals=[[4.0, 0.5], [-3.0, -0.5]])
    for i, g in enumerate([[4.0, 0.5], [-3.0, -0.5]]):
        _, first, _ = run(learn_env, world, [], goal_index=i)
        np.testing.assert_array_equal(np.asarray(first.state.goal), np.asarray(g, np.float32))
        assert first.obs[24] == pytest.approx(math.hypot(*g), abs=1e-6)


# ----------------------------------------------------------------------------- observation


@pytest.mark.parametrize("heading,goal", [(-3.0, (-1.0, 0.1)), (3.0, (-1.0, -0.1)), (0.4, (2.0, 0.5))])
def test_observation_layout(learn_env, lidar_jit, heading, goal):
    start = (0.0, 0.0, heading)
    world = tiny_world(starts=[list(start)], goals=[list(goal)], circles=[[1.0, -0.6, 0.2]])
    params, first, steps = run(learn_env, world, [(0.5, -0.3), (2.0, -3.0), (-0.5, 0.4)])
    assert learn_env.env.obs_size == 28 and first.obs.shape == (28,) and first.obs.dtype == np.float32

    def check(obs, pose, prev_action):
        pose32 = jnp.asarray(pose, jnp.float32)
        ranges = np.asarray(lidar_jit(world.segments, pose32, circles=world.circles))
        np.testing.assert_allclose(obs[:24], ranges, atol=1e-5)  # 24 ranges, beam 0 ahead
        rel = np.asarray(goal) - np.asarray(pose[:2])
        assert obs[24] == pytest.approx(np.linalg.norm(rel), abs=1e-5)  # goal distance
        bearing = wrap(math.atan2(rel[1], rel[0]) - pose[2])
        assert -PI <= obs[25] <= PI
        assert obs[25] == pytest.approx(bearing, abs=1e-5)  # bearing, wrapped
        np.testing.assert_allclose(obs[26:], prev_action, atol=1e-7)  # previous action

    check(first.obs, start, [0.0, 0.0])
    if heading == -3.0:  # the raw bearing (3.04 + 3.0) is beyond pi: it must come out wrapped
        assert first.obs[25] == pytest.approx(math.atan2(0.1, -1.0) + 3.0 - 2 * PI, abs=1e-5)
    check(steps[0].obs, steps[0].pose, [0.5, -0.3])
    check(steps[1].obs, steps[1].pose, [1.0, -1.0])  # clipped to the action box
    check(steps[2].obs, steps[2].pose, [0.0, 0.4])
    # Clipped actions drive the robot: (2, -3) is full speed, full right turn; v < 0 is v = 0.
    want = np.asarray(unicycle(jnp.asarray(steps[0].pose, jnp.float32), 0.25, -1.0, 0.1))
    np.testing.assert_allclose(steps[1].pose, want, atol=1e-6)
    np.testing.assert_allclose(steps[2].pose[:2], steps[1].pose[:2], atol=1e-7)


def test_step_compiles_once_for_all_worlds_of_one_shape(learn_env):
    w1 = tiny_world(starts=[[0.0, 0.0, 0.0]], goals=[[4.0, 0.0]])
    w2 = tiny_world(
        starts=[[1.0, 0.5, 1.0], [2.0, 0.0, 0.0]],
        goals=[[-4.0, 0.0], [1.0, 0.0]],
        segments=[[-1.0, -0.5, -1.0, 0.5]],
        circles=[[3.0, 0.5, 0.2]],
        size=(12.0, 3.0),
    )
    run(learn_env, w1, [(1.0, 0.0)])
    before = learn_env.traces
    run(learn_env, w2, [(1.0, 0.0), (0.3, 0.2)], v_max=0.7, random_starts=True, goal_index=1, range_noise=0.1)
    assert learn_env.traces == before


def test_bad_env_settings_raise():
    with pytest.raises(ValueError, match="mode"):
        NavEnv(mode="train")
    with pytest.raises(ValueError, match="collision_test"):
        NavEnv(collision_test="dense")
    world = tiny_world(starts=[[0.0, 0.0, 0.0]], goals=[[4.0, 0.0]], pad=False)
    with pytest.raises(TypeError, match="vmax"):
        make_params(world, vmax=1.0)


# ----------------------------------------------------------------------------- batching, keys, noise


def test_vmapped_batch_equals_loop_over_single_robots(batch_setup, batch_env):
    b = batch_setup
    obs0, obs, reward, term, trunc, pose, start_idx, t = drive(
        batch_env, b["keys"], b["params"], b["actions"], batched=True
    )
    n = len(b["names"])
    assert obs.shape == (n, ROLLOUT_STEPS, 28)
    assert b["stacked"].segments.shape[0] == n
    for i, name in enumerate(b["names"]):
        world = worlds.load(name)  # its own, unpadded shapes
        params = make_params(world, **b["overrides"])
        s_obs0, s_obs, s_reward, s_term, s_trunc, s_pose, s_idx, s_t = drive(
            batch_env, b["keys"][i], params, b["actions"][i], batched=False
        )
        np.testing.assert_allclose(obs0[i], s_obs0, atol=1e-5)
        np.testing.assert_array_equal(term[i], s_term)
        np.testing.assert_array_equal(start_idx[i], s_idx)
        np.testing.assert_array_equal(t[i], s_t)
        np.testing.assert_array_equal(trunc[i], s_trunc)
        np.testing.assert_allclose(pose[i], s_pose, atol=1e-5)
        np.testing.assert_allclose(reward[i], s_reward, atol=1e-4)
        np.testing.assert_allclose(obs[i], s_obs, atol=1e-5)
    # Not vacuous: robots collided or arrived, and were put back at random starts.
    assert term.sum() >= 2
    assert np.any(start_idx > 0)
    assert np.all(t[:, -1] == ROLLOUT_STEPS)


def test_same_key_same_trajectory(batch_setup, noisy_env):
    b = batch_setup
    params = make_params(b["stacked"], range_noise=0.05, action_noise=0.1, **b["overrides"])
    out1 = drive(noisy_env, b["keys"], params, b["actions"], batched=True)
    out2 = drive(noisy_env, b["keys"], params, b["actions"], batched=True)
    for x, y in zip(out1, out2):
        np.testing.assert_array_equal(x, y)  # bitwise
    # Another key, another trajectory: with fixed starts, so the noise itself must follow the key.
    fixed = params.replace(random_starts=jnp.zeros_like(params.random_starts))
    other_keys = jax.random.split(jax.random.key(43), len(b["names"]))
    a = drive(noisy_env, b["keys"], fixed, b["actions"], batched=True)
    other = drive(noisy_env, other_keys, fixed, b["actions"], batched=True)
    assert not np.array_equal(a[1], other[1]) and not np.array_equal(a[5], other[5])


def test_noise_off_equals_noise_on_with_zero_std(batch_setup, batch_env, noisy_env):
    b = batch_setup
    # Fixed starts: with random starts the two programs draw the start after a reset from
    # different keys (noise=True splits the step key three ways), so only the noise is compared.
    params = make_params(b["stacked"], v_max=2.0, range_noise=0.0, action_noise=0.0)
    off = drive(batch_env, b["keys"], params, b["actions"], batched=True)
    on = drive(noisy_env, b["keys"], params, b["actions"], batched=True)
    # Equal up to float32 rounding (two programs: XLA may fuse and contract differently).
    for x, y in zip(off, on):
        np.testing.assert_allclose(x, y, atol=1e-5, rtol=0)
    assert off[3].sum() >= 1  # some terminations (and resets) happened along the way


def test_noise_with_positive_std_changes_ranges_and_moves(batch_setup, noisy_env):
    b = batch_setup

    def go(**noise):
        params = make_params(b["stacked"], v_max=2.0, **noise)
        return drive(noisy_env, b["keys"], params, b["actions"], batched=True)

    _, obs_q, _, _, _, pose_q, _, _ = go()
    _, obs_r, _, _, _, pose_r, _, _ = go(range_noise=0.05)
    _, obs_a, _, term_a, _, pose_a, _, _ = go(action_noise=0.2)
    # Range noise changes the ranges (by about its std), nothing else.
    np.testing.assert_allclose(pose_r, pose_q, atol=1e-6)
    np.testing.assert_allclose(obs_r[..., 24:], obs_q[..., 24:], atol=1e-6)
    clean = obs_q[..., :24]
    diff = (obs_r[..., :24] - clean)[(clean > 0.3) & (clean < 3.0)]
    assert diff.size > 500
    assert 0.04 < diff.std() < 0.06 and abs(diff.mean()) < 0.01
    assert np.all(obs_r[..., :24] >= 0.0) and np.all(obs_r[..., :24] <= 3.5)
    noise = obs_r[..., :24] - clean
    assert np.abs(noise[:, 1:] - noise[:, :-1]).max() > 0.05  # fresh noise every step
    # Action noise changes where the robots go; the observed previous action is the commanded one.
    assert np.abs(pose_a - pose_q).max() > 0.01
    commanded = np.clip(np.asarray(b["actions"]), [0, -1], [1, 1])
    kept = ~term_a  # after a terminal step the robot is at a start with no previous action
    np.testing.assert_allclose(obs_a[..., 26:][kept], commanded[kept], atol=1e-7)
    np.testing.assert_array_equal(obs_a[..., 26:][~kept], 0.0)


@pytest.mark.parametrize("env_name", ["learn_env", "lidar_env"])
def test_terminal_step_reports_the_true_final_observation(env_name, request):
    """Driving into a wall: the transition's s' (`info["final_obs"]`) is the observation at the
    pose reached (the wall within D_c ahead), while `obs` is already the next attempt's start."""
    jenv = request.getfixturevalue(env_name)
    world = tiny_world(starts=[[0.0, 0.74, PI / 2]], goals=[[-2.0, -0.5]])  # facing the wall y = 1
    params = make_params(world)
    obs0, state = jenv.reset(jax.random.key(0), params)
    obs, new, _, term, _, info = jenv.step(jax.random.key(1), state, jnp.array([1.0, 0.0]), params)
    assert bool(term) and bool(info["collision"])
    final = np.asarray(info["final_obs"], np.float64)
    pose = np.asarray(info["pose"], np.float64)  # 0.74 + 0.025: 0.235 m from the wall
    ref = np.asarray(lidar(world.segments, jnp.asarray(pose, jnp.float32), 24, 3.5, world.circles))
    np.testing.assert_allclose(final[:24], ref, atol=1e-5)
    assert final[0] == pytest.approx(1.0 - pose[1], abs=1e-5) and final[0] < 0.25  # beam 0 hits the wall
    assert final[24] == pytest.approx(math.hypot(-2.0 - pose[0], -0.5 - pose[1]), abs=1e-5)
    np.testing.assert_allclose(final[26:], [1.0, 0.0])  # the action just taken
    # the policy's next observation is the start's, as at reset
    np.testing.assert_allclose(np.asarray(obs), np.asarray(obs0), atol=1e-6)
    assert not np.allclose(final, np.asarray(obs))


def test_final_obs_equals_obs_on_ordinary_steps(learn_env):
    world = tiny_world(starts=[[0.0, 0.0, 0.0]], goals=[[4.0, 0.5]])
    _, _, steps = run(learn_env, world, [[0.5, 0.2]] * 3)
    params = make_params(world)
    _, state = learn_env.reset(jax.random.key(0), params)
    obs, _, _, term, _, info = learn_env.step(jax.random.key(1), state, jnp.array([0.5, 0.2]), params)
    assert not bool(term)
    np.testing.assert_array_equal(np.asarray(obs), np.asarray(info["final_obs"]))
