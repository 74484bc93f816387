"""Waiting at doors in shared rooms (docs/shared_rooms.md, "Waiting at doors"; env/shared.py
`wait_at_door`).

A room 6 m square split by a wall at x = 0 with one door of known width: the width the rule
measures across the door against the analytic width (and, in a procedural room, against a float64
brute force), the rule against its definition (the other robot in the door, ahead, in reach, in
sight; the robot itself not in a door), and off bitwise.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fedjax_nav.env import shared
from fedjax_nav.env.nav import NavEnv, make_params
from fedjax_nav.worlds import procedural, rooms
from fedjax_nav.worlds import world as world_mod

R = 0.25  # D_c, the robots' disc radius


def _room(door: float, centre: float = 0.3, thick: float = 0.1):
    """6 x 6 m, a wall along x = 0 (a box `thick` m thick; 0: a segment, as the procedural rooms'
    walls) with a door of width `door` centred at y = `centre`."""
    lo, hi = centre - door / 2, centre + door / 2
    if thick > 0:
        walls = {"boxes": [[0.0, (lo - 3.0) / 2, thick, lo + 3.0, 0.0], [0.0, (hi + 3.0) / 2, thick, 3.0 - hi, 0.0]]}
    else:
        walls = {"segments": [[0.0, -3.0, 0.0, lo], [0.0, hi, 0.0, 3.0]]}
    spec = {
        "size": [6.0, 6.0],
        **walls,
        "starts": [[-2.0, 0.0, 0.0], [2.0, 0.0, np.pi]],
        "goals": [[2.0, 0.0], [-2.0, 0.0]],
    }
    return world_mod.from_dict(spec)[0]


@pytest.mark.parametrize("door, thick", [(0.6, 0.1), (0.8, 0.0), (1.3, 0.1)])
def test_the_width_across_a_door_is_the_door(door, thick):
    world = _room(door, thick=thick)
    for y in (0.3, 0.1, 0.45):  # anywhere in the door
        got = float(shared._across(world, jnp.array([0.0, y])))
        assert got == pytest.approx(door, abs=1e-5)


def _across_reference(world, xy):
    """float64, brute force: the walls and circles of `world` as points 2 mm apart; the nearest,
    plus the nearest of those behind `xy` as seen from it."""
    seg = np.asarray(world.segments, np.float64)
    seg = seg[np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]) > 0]
    pts = []
    for a, b in zip(seg[:, :2], seg[:, 2:]):
        pts.append(a + np.linspace(0, 1, int(np.hypot(*(b - a)) / 0.002) + 2)[:, None] * (b - a))
    for cx, cy, r in np.asarray(world.circles, np.float64):
        if r > 0:
            ang = np.linspace(0, 2 * np.pi, int(2 * np.pi * r / 0.002) + 2)
            pts.append(np.stack([cx + r * np.cos(ang), cy + r * np.sin(ang)], 1))
    pts = np.concatenate(pts)
    rel = pts - np.asarray(xy, np.float64)
    d = np.hypot(rel[:, 0], rel[:, 1])
    k = np.argmin(d)
    behind = rel @ (rel[k] / d[k]) <= 0
    return d[k] + d[behind].min()


def test_the_width_across_matches_a_float64_brute_force_in_procedural_rooms():
    spec = rooms.RoomSpec(family="walls")
    world = jax.jit(lambda k: procedural.generate(k, spec))(jax.random.key(7))
    across = jax.jit(lambda xy: shared._across(world, xy))
    rng = np.random.default_rng(2)
    half = np.asarray(world.size) / 2 - 0.3
    checked = narrow = 0
    for xy in rng.uniform(-half, half, (60, 2)).astype(np.float32):
        want = _across_reference(world, xy)
        if not np.isfinite(want):
            continue
        assert float(across(jnp.asarray(xy))) == pytest.approx(want, abs=5e-3), xy
        checked += 1
        narrow += want < 1.3
    assert checked >= 50 and narrow >= 3  # doors and corridors among the draws


def _rule(world, pose, other, door=1.0, reach=1.5):
    params = make_params(world, give_way_door=door, give_way_reach=reach)
    others = jnp.array([[*other, R], [0.0, 0.0, 0.0]], jnp.float32)  # one other, one absent row
    action = jnp.array([0.7, 0.3], jnp.float32)
    pose = jnp.asarray(pose, jnp.float32)
    theirs = jax.vmap(lambda xy: shared._across(world, xy))(others[:, :2])
    got = shared.wait_at_door(pose, action, others, theirs, shared._across(world, pose[:2]), params)
    got = np.asarray(got)
    assert np.array_equal(got, [0.0, 0.0]) or np.array_equal(got, action)
    return bool(np.array_equal(got, [0.0, 0.0]))


def test_a_robot_before_a_door_waits_for_the_robot_in_it():
    world = _room(0.8)
    assert _rule(world, [-1.0, 0.3, 0.0], [0.0, 0.3])  # facing the door, the other in it: wait
    assert _rule(world, [-1.0, 0.0, 0.3], [0.0, 0.3])  # off the door's axis, still in sight
    assert not _rule(world, [-1.0, 0.3, np.pi], [0.0, 0.3])  # the door behind it
    assert not _rule(world, [-1.8, 0.3, 0.0], [0.0, 0.3])  # out of reach
    assert _rule(world, [-1.8, 0.3, 0.0], [0.0, 0.3], reach=2.0)
    assert not _rule(world, [-1.0, 0.3, 0.0], [0.0, 0.3], door=0.7)  # a door wider than the rule's
    assert not _rule(world, [-1.0, 0.3, 0.0], [1.0, 0.3])  # the other through it, in the open
    assert not _rule(world, [0.0, 0.3, 0.0], [1.0, 0.3])  # the robot in the door goes on
    assert not _rule(world, [-1.0, 0.3, 0.0], [0.0, 0.3], door=0.0)  # off


def test_a_robot_does_not_wait_for_one_behind_a_wall():
    spec = {
        "size": [6.0, 6.0],
        "segments": [[0.0, -3.0, 0.0, 3.0], [0.8, -3.0, 0.8, 3.0]],  # a corridor 0.8 m wide behind a wall
        "starts": [[-2.0, 0.0, 0.0]],
        "goals": [[2.0, 0.0]],
    }
    corridor = world_mod.from_dict(spec)[0]
    assert not _rule(corridor, [-0.6, 0.0, 0.0], [0.4, 0.0])  # in reach and in a narrow place, out of sight
    assert _rule(corridor, [0.2, 0.0, 0.0], [0.4, 0.0], reach=0.5) is False  # in the corridor too: goes on


def test_waiting_off_is_the_move_bitwise_and_on_it_stops_the_robot():
    env = NavEnv()
    world = _room(0.8)
    params = jax.vmap(lambda _: make_params(world))(jnp.arange(2))
    keys = jax.random.split(jax.random.key(5), 2)
    _, states = jax.vmap(env.reset)(keys, params)
    states = states.replace(pose=jnp.array([[-1.0, 0.3, 0.0], [0.0, 0.3, np.pi]], jnp.float32))
    actions = jnp.array([[1.0, 0.0], [1.0, 0.0]], jnp.float32)
    present = jnp.ones(2, bool)
    move = jax.jit(lambda *a: shared.fleet_move(env, *a, present, 1))
    plain = jax.jit(jax.vmap(env.move))(keys, states, actions, params)
    off = move(keys, states, actions, params)
    assert jax.tree.all(jax.tree.map(lambda a, b: np.array_equal(a, b), plain, off))
    on = move(keys, states, actions, params.replace(give_way_door=jnp.full(2, 1.0)))
    pose = np.asarray(on.pose)
    assert np.allclose(pose[0], [-1.0, 0.3, 0.0], atol=1e-3)  # the robot before the door waited (speed ramps down)
    assert pose[1, 0] < -0.01  # the one in the door came on
