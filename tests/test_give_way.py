"""Giving way in shared rooms (docs/shared_rooms.md, "Giving way"; env/shared.py `give_way`).

Checked against a float64 numpy reference of the rule (the unicycle arc in closed form, the
gaps between discs), bitwise off, and on two robots driving head-on: without the rule they
touch, with it they pass.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fedjax_nav import worlds
from fedjax_nav.env import shared
from fedjax_nav.env.nav import NavEnv, make_params

R = 0.25  # D_c, the robots' disc radius


def _reference(pose, action, others, gap, v_max, omega_max, dt):
    """float64: True when the commanded step ends nearer than `gap` to a present disc and nearer than now."""
    x, y, th = (float(c) for c in pose)
    v = min(max(float(action[0]), 0.0), 1.0) * v_max
    w = min(max(float(action[1]), -1.0), 1.0) * omega_max
    if abs(w) > 1e-9:  # the arc in closed form
        x2, y2 = x + v / w * (np.sin(th + w * dt) - np.sin(th)), y + v / w * (np.cos(th) - np.cos(th + w * dt))
    else:
        x2, y2 = x + v * dt * np.cos(th), y + v * dt * np.sin(th)
    present = others[:, 2] > 0
    now = np.hypot(others[:, 0] - x, others[:, 1] - y) - others[:, 2] - R
    then = np.hypot(others[:, 0] - x2, others[:, 1] - y2) - others[:, 2] - R
    return bool(np.any(present & (then < gap) & (then < now))), np.abs(np.where(present, then - gap, 1.0)).min()


def test_a_robot_stops_and_turns_right_exactly_when_its_step_closes_within_the_gap_as_float64():
    params = make_params(worlds.load("eval"), give_way=0.05)
    gw = jax.jit(lambda p, a, o: shared.give_way(p, a, o, jnp.float32(R), params))
    rng = np.random.default_rng(0)
    blocked = checked = 0
    for _ in range(400):
        pose = np.array([*rng.uniform(-1, 1, 2), rng.uniform(-np.pi, np.pi)], np.float32)
        action = rng.uniform([-0.2, -1.2], [1.2, 1.2]).astype(np.float32)
        # two others near the gap's edge (within 0.2 m of touching), one absent
        ang = rng.uniform(-np.pi, np.pi, 3)
        dist = 2 * R + rng.uniform(0.0, 0.2, 3)
        others = np.stack([pose[0] + dist * np.cos(ang), pose[1] + dist * np.sin(ang), [R, R, 0.0]], 1)
        others = others.astype(np.float32)
        want, margin = _reference(pose, action, others.astype(np.float64), 0.05, 0.25, 1.0, 0.1)
        if margin < 1e-5:
            continue  # on the edge of the gap: float32 may fall either side
        got = np.asarray(gw(jnp.asarray(pose), jnp.asarray(action), jnp.asarray(others)))
        expected = np.array([0.0, -1.0], np.float32) if want else action
        assert np.array_equal(got, expected), (pose, action, others)
        blocked += want
        checked += 1
    assert checked > 350 and 50 < blocked < checked - 50  # both outcomes were met


def test_giving_way_off_is_the_move_bitwise():
    robots = 4
    env = NavEnv()
    params = jax.vmap(lambda _: make_params(worlds.load("eval")))(jnp.arange(robots))
    keys = jax.random.split(jax.random.key(3), robots)
    _, states = jax.vmap(env.reset)(keys, params)
    rng = np.random.default_rng(1)
    xy = rng.uniform(-0.4, 0.4, (robots, 2))  # crowded: every robot within the gap of another
    pose = np.concatenate([xy, rng.uniform(-np.pi, np.pi, (robots, 1))], 1).astype(np.float32)
    states = states.replace(pose=jnp.asarray(pose))
    actions = jnp.asarray(rng.uniform(0, 1, (robots, 2)).astype(np.float32))
    present = jnp.ones(robots, bool)
    plain = jax.jit(jax.vmap(env.move))(keys, states, actions, params)
    off = jax.jit(lambda *a: shared.fleet_move(env, *a, present, 1))(keys, states, actions, params)
    assert jax.tree.all(jax.tree.map(lambda a, b: np.array_equal(a, b), plain, off))
    on = jax.jit(lambda *a: shared.fleet_move(env, *a, present, 1))(
        keys, states, actions, params.replace(give_way=jnp.full(robots, 0.05))
    )
    assert not np.array_equal(np.asarray(on.pose), np.asarray(plain.pose))  # and on, it did act here


@pytest.mark.parametrize("gap, touch", [(0.0, True), (0.05, False)])
def test_two_robots_driving_head_on_touch_unless_they_give_way(gap, touch):
    """Both steer at full speed for the other's start (a proportional heading controller), from
    2 m apart on one line: without the rule they meet in about 30 steps; with it each stops,
    turns right, and drives on past the other to its goal."""
    env = NavEnv(episode_length=400)
    params = jax.vmap(lambda _: make_params(worlds.load("eval"), give_way=gap))(jnp.arange(2))
    keys = jax.random.split(jax.random.key(0), 2)
    _, states = jax.vmap(env.reset)(keys, params)
    states = states.replace(pose=jnp.array([[-1.0, 0.0, 0.0], [1.0, 0.0, np.pi]], jnp.float32))
    step = shared.fleet_step(env, jnp.ones(2, bool), 1)
    goals = jnp.array([[1.0, 0.0], [-1.0, 0.0]])

    def body(s, k):
        to = goals - s.pose[:, :2]
        turn = jnp.angle(jnp.exp(1j * (jnp.arctan2(to[:, 1], to[:, 0]) - s.pose[:, 2])))
        steer = jnp.stack([jnp.ones(2), jnp.clip(2.0 * turn, -1.0, 1.0)], 1)
        _, s2, _, _, _, info = step(jax.random.split(k, 2), s, steer, params)
        return s2, (info["robot_collision"], info["pose"])

    _, (contact, poses) = jax.jit(lambda s: jax.lax.scan(body, s, jax.random.split(keys[0], 110)))(states)
    assert bool(np.asarray(contact).any()) == touch
    if not touch:  # (the world's own goals are elsewhere: the controller's points end nothing)
        to_goal = np.linalg.norm(np.asarray(poses[..., :2]) - np.asarray(goals), axis=-1).min(0)
        assert (to_goal < 0.15).all(), to_goal  # each came past the other to its point
