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
from jax import lax

from fedjax_nav import worlds
from fedjax_nav.env.geometry import lidar, nearest_distance
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


def by_room(x: jax.Array, per: int) -> jax.Array:
    """[R * per, ...] robot-major (environment j of robot i is row i * per + j, in room j) ->
    [per, R, ...]: each room's R robots."""
    return x.reshape(x.shape[0] // per, per, *x.shape[1:]).swapaxes(0, 1)


def fleet_others(poses: jax.Array, radius: jax.Array, present: jax.Array, per: int) -> jax.Array:
    """Every environment's others: poses f32[R * per, 3] and radius f32[R * per] robot-major
    (`by_room`), present bool[R] -> f32[R * per, R, 3]."""
    n = poses.shape[0] // per
    out = jax.vmap(others, in_axes=(0, 0, None))(by_room(poses[:, :2], per), by_room(radius, per), present)
    return out.swapaxes(0, 1).reshape(n * per, n, 3)  # [per, R, R, 3] -> robot-major


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


def _nearest_points(world, xy: jax.Array, side: jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
    """(d f32[M + C], q f32[M + C, 2]): for every segment and circle of `world` the distance from
    `xy` to its nearest point q, inf for padding rows; with `side` (a unit vector) only the part
    behind `xy` as seen along `side` counts (points p with (p - xy) . side <= 0; a circle by its
    centre), inf where none is."""
    a, b = world.segments[:, :2] - xy, world.segments[:, 2:] - xy
    ok = jnp.sum((b - a) ** 2, axis=-1) > 0
    if side is not None:  # clip each segment to the half-plane behind xy
        sa, sb = a @ side, b @ side
        cut = a + (sa / jnp.where(sa == sb, 1.0, sa - sb))[:, None] * (b - a)
        a, b = jnp.where((sa > 0)[:, None], cut, a), jnp.where((sb > 0)[:, None], cut, b)
        ok = ok & ~((sa > 0) & (sb > 0))
    e = b - a
    t = jnp.clip(-jnp.sum(a * e, -1) / jnp.maximum(jnp.sum(e * e, -1), 1e-12), 0.0, 1.0)
    q = a + t[:, None] * e
    c, r = world.circles[:, :2] - xy, world.circles[:, 2]
    dc = jnp.linalg.norm(c, axis=-1)
    qc = c - (r / jnp.maximum(dc, 1e-12))[:, None] * c
    okc = r > 0 if side is None else (r > 0) & (c @ side <= 0)
    d = jnp.concatenate([jnp.where(ok, jnp.linalg.norm(q, axis=-1), jnp.inf), jnp.where(okc, dc - r, jnp.inf)])
    return d, jnp.concatenate([q, qc]) + xy


def _across(world, xy: jax.Array) -> jax.Array:
    """f32[]: m across the room at `xy`: the distance to the nearest wall or obstacle, plus the
    distance to the nearest one on the far side (behind `xy` as seen from the first). In a door or
    a corridor, its width; beside a single wall or in a corner, the room's."""
    d, q = _nearest_points(world, xy)  # not geometry.nearest_distance: the far side needs the point
    k = jnp.argmin(d)
    side = (q[k] - xy) / jnp.maximum(d[k], 1e-12)
    return d[k] + jnp.min(_nearest_points(world, xy, side)[0])


def wait_at_door(pose: jax.Array, action: jax.Array, others: jax.Array, theirs: jax.Array, mine, params) -> jax.Array:
    """`action`, or (0, 0) while another robot of `others` (circles f32[K, 3], r = 0: none) stands in
    a door, and the robot does not, and the other is ahead (in front of the line through the robot
    across its heading), within `params.give_way_reach` of its centre and in its sight (no wall
    between the centres): a place is a door (or a gap, a corridor) where the nearest walls or
    obstacles either side of it are nearer together than `params.give_way_door` (`theirs` f32[K]
    and `mine` f32[]: `_across` at the others' centres and the robot's; docs/shared_rooms.md,
    "Waiting at doors"). The robot waits, facing the door, for the other to come through, instead
    of meeting it there and giving way (`give_way`) beside the door's edge. Unchanged, bitwise,
    when give_way_door is 0 or no robot is in a door near."""
    world = params.world
    rel = others[:, :2] - pose[None, :2]
    dist = jnp.linalg.norm(rel, axis=-1)
    heading = jnp.stack([jnp.cos(pose[2]), jnp.sin(pose[2])])
    door = params.give_way_door
    wait = (others[:, 2] > 0) & (dist < params.give_way_reach) & (rel @ heading > 0)
    wait = wait & (theirs < door) & (mine >= door)
    # in sight: a beam towards the other's centre, as long as the way to it, reaches it
    ray = lambda a, d: lidar(world.segments, jnp.stack([pose[0], pose[1], a]), 1, d, world.circles)[0]  # noqa: E731
    seen = jax.vmap(ray)(jnp.arctan2(rel[:, 1], rel[:, 0]), dist) >= dist
    return jnp.where((door > 0) & jnp.any(wait & seen), jnp.zeros(2, action.dtype), action)


def fleet_move(env, keys, states, actions, params, present, per: int):
    """`jax.vmap(env.move)` in shared rooms (robot-major, `per` rooms): each robot waits at doors
    (`wait_at_door`) and gives way (`give_way`) to the others where they are before the move.
    `present`: bool[robots]. The door check runs only when some robot has env.give_way_door on
    (`lax.cond`: its widths and sight lines about double the step, docs/benchmarks.md; under a
    vmap over that field, as in a sweep that batches it, both branches run)."""
    radius = jax.vmap(env.radius)(params)
    before = fleet_others(states.pose, radius, present, per)

    def doors(actions):
        across = jax.vmap(lambda p, xy: _across(p.world, xy))(params, states.pose[:, :2])
        n = across.shape[0] // per
        theirs = jnp.broadcast_to(by_room(across, per)[None], (n, per, n)).reshape(n * per, n)  # room's widths
        return jax.vmap(wait_at_door)(states.pose, actions, before, theirs, across, params)

    actions = lax.cond(jnp.any(params.give_way_door > 0), doors, lambda a: a, actions)
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
