"""Shared rooms (docs/shared_rooms.md): the robots of a fleet drive in one room together.

Environment j of every robot is one room. Per robot the env code stays what it is (`NavEnv`,
unbatched); what a shared room adds is data:

- `others`: the other robots of a room as circles f32[K, 3] (x, y, r), gathered once per step
  from the poses every robot reached (`fleet_others`); a robot's own row and absent robots
  (the padding clients of a mesh) have r = 0, which the lidar and the distance never see.
- each robot's own start and goal in the room: every start / goal row of its World row is its
  own (`fixed_fleet`: robot i takes the room's start i and goal i; `place_fleet`: drawn in the
  free space, apart from the other robots' starts and goals).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fedjax_nav import worlds
from fedjax_nav.env.geometry import nearest_distance
from fedjax_nav.env.gym_task import MIN_START_GOAL, PLACEMENT_MARGIN
from fedjax_nav.env.robot import unicycle
from fedjax_nav.worlds import World

FLEET_TRIES = 256  # candidates per room, shared by its robots' starts and goals
# m between any two of a room's starts and goals: two robot discs (D_c = worlds.CLEARANCE) and
# the placement margin each, so that no robot starts in contact with another or on its goal
SEPARATION = 2.0 * (worlds.CLEARANCE + PLACEMENT_MARGIN)


def others(xy: jax.Array, radius: jax.Array, present: jax.Array) -> jax.Array:
    """One room's K robots at `xy` f32[K, 2] with radii f32[K]: f32[K, K, 3], row i robot i's
    others as circles (its own row and the absent robots, `present` False, with r = 0; an absent
    robot sees none: a mesh's padding client drives alone)."""
    k = xy.shape[0]
    r = jnp.where(present[:, None] & present[None, :] & ~jnp.eye(k, dtype=bool), radius[None, :], 0.0)
    return jnp.concatenate([jnp.broadcast_to(xy[None], (k, k, 2)), r[..., None]], axis=-1)


def fleet_others(poses: jax.Array, radius: jax.Array, present: jax.Array, per: int) -> jax.Array:
    """Every environment's others: poses f32[R * per, 3] and radius f32[R * per] robot-major
    (environment j of robot i is row i * per + j, in room j), present bool[R] ->
    f32[R * per, R, 3]."""
    n = poses.shape[0] // per
    xy = poses[:, :2].reshape(n, per, 2).swapaxes(0, 1)  # [per rooms, R, 2]
    rad = radius.reshape(n, per).T
    out = jax.vmap(others, in_axes=(0, 0, None))(xy, rad, present)  # [per, R, R, 3]
    return out.swapaxes(0, 1).reshape(n * per, n, 3)


def give_way(pose: jax.Array, action: jax.Array, others: jax.Array, radius: jax.Array, params) -> jax.Array:
    """`action` (v / v_max, omega / omega_max), or (0, -1) when the step it commands (the
    unicycle at the nominal speeds) would bring the robot's disc nearer than `params.give_way`
    to another robot's and nearer than it is now (docs/shared_rooms.md, "Giving way"): the
    robot stops and turns right in place, as the traffic rule of `plan.keep_right` has it, and
    drives on once its step no longer closes on the other. Unchanged, bitwise, when give_way is
    0 or no robot is that near. `others`: f32[K, 3], the other robots as circles where they are
    before this step (r = 0: none)."""
    a = jnp.clip(action, jnp.array([0.0, -1.0]), 1.0)
    ahead = unicycle(pose, a[0] * params.v_max, a[1] * params.omega_max, params.dt)
    gap = lambda p: jnp.linalg.norm(others[:, :2] - p[:2], axis=-1) - others[:, 2] - radius  # noqa: E731
    now, then = gap(pose), gap(ahead)
    nearer = (others[:, 2] > 0) & (then < params.give_way) & (then < now)
    return jnp.where((params.give_way > 0) & jnp.any(nearer), jnp.array([0.0, -1.0], action.dtype), action)


def fleet_move(env, keys, states, actions, params, present, per: int):
    """`jax.vmap(env.move)` in shared rooms (robot-major, `per` rooms): each robot gives way
    (`give_way`) to the others where they are before the move. `present`: bool[robots]."""
    radius = jax.vmap(env.radius)(params)
    before = fleet_others(states.pose, radius, present, per)
    actions = jax.vmap(give_way)(states.pose, actions, before, radius, params)
    return jax.vmap(env.move)(keys, states, actions, params)


def own(world: World, start: jax.Array, goal: jax.Array) -> World:
    """`world` with every start row `start` (x, y, theta) and every goal row `goal` (x, y)."""
    return world.replace(
        starts=jnp.broadcast_to(start, world.starts.shape),
        num_starts=jnp.int32(1),
        goals=jnp.broadcast_to(goal, world.goals.shape),
        num_goals=jnp.int32(1),
    )


def fixed_fleet(world: World, robots: int) -> World:
    """One room's World rows of `robots` robots [robots]: robot i starts at the room's start row
    i and drives to its goal row i (the caller checks that the room has that many)."""
    return jax.vmap(lambda i: own(world, world.starts[i], world.goals[i]))(jnp.arange(robots))


def place_fleet(world: World, key: jax.Array, robots: int, keep_first: bool = False) -> World:
    """One room's World rows of `robots` robots [robots], drawn: FLEET_TRIES uniform candidates
    keeping D_c + PLACEMENT_MARGIN from every obstacle; the starts, then the goals, each the
    first candidate SEPARATION from every point taken before (a goal also MIN_START_GOAL from
    its own start); best effort in that order when none qualifies, the room's own start 0 /
    goal 0 when no candidate clears the obstacles. Start yaws are uniform. `keep_first`: robot 0
    takes the room's own start 0 and goal 0 (a generated room's, solvable by construction), the
    others are drawn apart from them; a fleet of one is then the room as it is."""
    c = worlds.CLEARANCE + PLACEMENT_MARGIN
    k_p, k_yaw = jax.random.split(key)
    half = jnp.maximum(world.size / 2 - c, 0.0)
    pts = jax.random.uniform(k_p, (FLEET_TRIES, 2), minval=-1.0, maxval=1.0) * half
    ok = jax.vmap(lambda q: nearest_distance(world.segments, q, world.circles))(pts) > c
    taken = jnp.zeros((2 * robots, 2), jnp.float32)
    if keep_first:
        taken = taken.at[0].set(world.starts[0, :2]).at[robots].set(world.goals[0])
    for p in range(2 * robots):  # robots is small and static: unrolled
        if keep_first and p in (0, robots):
            continue
        d = jnp.linalg.norm(pts[:, None] - taken[None, :p], axis=-1)  # [tries, p]
        apart = jnp.all(d >= SEPARATION, axis=1)
        score = 1 + 2 * apart.astype(jnp.int32)
        if p >= robots:  # a goal: away from its own start, the least of the three wishes
            far = jnp.linalg.norm(pts - taken[p - robots], axis=-1) >= MIN_START_GOAL
            score = 1 + 4 * apart.astype(jnp.int32) + 2 * far.astype(jnp.int32)
        score = jnp.where(ok, score, 0)
        fallback = world.starts[0, :2] if p < robots else world.goals[0]
        taken = taken.at[p].set(jnp.where(jnp.any(ok), pts[jnp.argmax(score)], fallback))
    yaw = jax.random.uniform(k_yaw, (robots,), minval=-jnp.pi, maxval=jnp.pi)
    starts = jnp.concatenate([taken[:robots], yaw[:, None]], axis=1)
    starts = jnp.where(jnp.any(ok), starts, world.starts[0])
    if keep_first:
        starts = starts.at[0].set(world.starts[0])
    return jax.vmap(lambda s, g: own(world, s, g))(starts, taken[robots:])


def fleet_step(env, present, per: int):
    """`jax.vmap(env.step)` for shared rooms: (keys, states, actions, params) of every
    environment, robot-major -> every environment's step. Each robot moves (giving way,
    `fleet_move`), the reached poses are gathered once (`fleet_others`), each settles seeing the
    others where they are now.
    `present`: bool[robots], False for a mesh's padding clients (alone: they see no robot, none sees them)."""
    present = jnp.asarray(present)

    def step(keys, states, actions, params):
        moved = fleet_move(env, keys, states, actions, params, present, per)
        around = fleet_others(moved.pose, jax.vmap(env.radius)(params), present, per)
        return jax.vmap(env.settle)(keys, states, moved, params, around)

    return step
