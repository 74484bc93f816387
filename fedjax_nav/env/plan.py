"""A global plan on the known map (docs/planning.md): the next waypoint of a shortest safe path.

Pure JAX, for one robot in one room (vmap outside); every shape is fixed by the static number of
cells per side, `cells`, so that rooms of any size share one program.

    res, xs, ys = grid(size, cells)                      the square cells covering the room
    free = free_cells(world, clearance, cells)           bool[cells, cells]: centres >= D_c from everything
    field = distance_field(free, seeds, res)             f32[cells, cells]: m to the goal, 8-connected
    field = goal_field(world, goal, D_c, D_g, cells)     the three above for one goal
    wp = waypoint(field, size, goal, xy, lookahead)      f32[2]: about `lookahead` m down the field
    p = make(params, goal, D_c, cells)                   Plan: the field and the waypoint at each start row
    names = layout(plan)                                 the observation's entries after the ranges
    wp = at(p, params, goal, xy)                         the waypoint with the params' lookahead

The grid: `cells` x `cells` square cells of side res = max(W, H) / cells from the room's corner
(-W/2, -H/2); a cell is free when its centre lies inside the room and keeps at least the
collision distance from every segment and circle (`geometry.nearest_distance`, the env's own
exact distance). Rows are y, columns x: `field[iy, ix]`.

The field: the shortest 8-connected path length (edges res and res sqrt 2 between free cells,
as `evaluation.paths`' Dijkstra) from each free cell into the goal's cells (the free cells
whose centres lie inside the goal disk, and the goal's own cell when free), +inf where no path
exists or the cell is not free. It is the fixed point of Bellman's equations, found by
Gauss-Seidel sweeps (rows upwards, then downwards; each row also closed along itself) in a
`lax.while_loop` until a pass changes nothing: Dijkstra's distances up to float32 rounding.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from flax import struct
from jax import lax

from fedjax_nav.env.geometry import nearest_distance

SQRT2 = math.sqrt(2.0)
INF = float("inf")
# The 8 neighbours (dy, dx) and the length of the edge to each, in cells.
_DY = (-1, -1, -1, 0, 0, 1, 1, 1)
_DX = (-1, 0, 1, -1, 1, -1, 0, 1)
_STEP = tuple(SQRT2 if dy and dx else 1.0 for dy, dx in zip(_DY, _DX))
SIGHT = 16  # points tested on the straight way from the robot to each next cell of the walk
# The observation's entries after the ranges, by name (`NavEnv.observe` builds them in this order;
# `fedjax-nav export` writes them to meta.json, where the exported policy reads them: docs/export.md).
MAPLESS = ("goal_distance", "goal_bearing", "previous_v", "previous_omega")
PLANNED = ("waypoint_distance", "waypoint_bearing", "previous_v", "previous_omega", "goal_distance")


def layout(plan: bool) -> tuple[str, ...]:
    """The names of the observation's entries after the ranges: the waypoint's in place of the
    goal's with the plan, the goal's distance last (docs/planning.md, "the observation")."""
    return PLANNED if plan else MAPLESS


def grid(size: jax.Array, cells: int) -> tuple[jax.Array, jax.Array, jax.Array]:
    """(res, xs f32[cells], ys f32[cells]): the cell side and the centres' coordinates."""
    size = jnp.asarray(size, jnp.float32)
    res = jnp.max(size) / cells
    centres = res * (jnp.arange(cells, dtype=jnp.float32) + 0.5)
    return res, centres - size[0] / 2, centres - size[1] / 2


def cell_of(xy: jax.Array, size: jax.Array, cells: int) -> tuple[jax.Array, jax.Array]:
    """(iy, ix) i32: the cell holding the point `xy` (clipped onto the grid)."""
    res = jnp.max(size) / cells
    i = jnp.floor((xy + size / 2) / res).astype(jnp.int32)
    i = jnp.clip(i, 0, cells - 1)
    return i[1], i[0]


def free_cells(world, clearance: jax.Array, cells: int) -> jax.Array:
    """bool[cells, cells]: the cells whose centre is inside the room and keeps >= `clearance`
    from every segment and circle of `world` (one room)."""
    _, xs, ys = grid(world.size, cells)
    pts = jnp.stack(jnp.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    d = jax.vmap(lambda p: nearest_distance(world.segments, p, world.circles))(pts).reshape(cells, cells)
    half = world.size / 2
    inside = (jnp.abs(xs)[None, :] < half[0]) & (jnp.abs(ys)[:, None] < half[1])
    return inside & (d >= clearance)


def goal_cells(free: jax.Array, size: jax.Array, goal: jax.Array, goal_radius: jax.Array) -> jax.Array:
    """bool[cells, cells]: the field's zeros, the free cells whose centre lies inside the goal
    disk and the goal's own cell when it is free."""
    cells = free.shape[0]
    _, xs, ys = grid(size, cells)
    inside = jnp.hypot(xs[None, :] - goal[0], ys[:, None] - goal[1]) <= goal_radius
    iy, ix = cell_of(goal, size, cells)
    own = jnp.zeros_like(free).at[iy, ix].set(True)
    return free & (inside | own)


def _run_min(v: jax.Array, w: jax.Array) -> jax.Array:
    """out[j] = min(v[j], out[j - 1] + w[j]) along the last axis: a min-plus linear recurrence,
    as one associative scan (element j is the map x -> min(x + w[j], v[j]))."""

    def compose(a, b):
        return a[0] + b[0], jnp.minimum(a[1] + b[0], b[1])

    return lax.associative_scan(compose, (w, v), axis=-1)[1]


def _sweep(d: jax.Array, free: jax.Array, res: jax.Array) -> jax.Array:
    """One Gauss-Seidel pass over the rows in order: each row takes its three neighbours of the
    row before (already updated), then is closed along itself (left to right, right to left)."""
    w = jnp.where(free, res, INF)  # the edge into a cell from its neighbour in the row
    diag = res * SQRT2

    def row_step(prev, xs):
        row, fr, wr = xs
        left = jnp.concatenate([jnp.full((1,), INF), prev[:-1]])
        right = jnp.concatenate([prev[1:], jnp.full((1,), INF)])
        row = jnp.minimum(row, jnp.minimum(prev + res, jnp.minimum(left, right) + diag))
        row = jnp.where(fr, row, INF)
        row = _run_min(row, wr)
        row = _run_min(row[::-1], wr[::-1])[::-1]
        return row, row

    return lax.scan(row_step, jnp.full(d.shape[1:], INF, d.dtype), (d, free, w))[1]


def distance_field(free: jax.Array, seeds: jax.Array, res: jax.Array) -> tuple[jax.Array, jax.Array]:
    """(field f32[cells, cells], passes i32[]): m from every free cell to the nearest seed cell
    along 8-connected free cells; +inf when not free or cut off. Passes (up and down) until one
    changes nothing; at most cells^2 (a path visits each cell once)."""
    d0 = jnp.where(seeds & free, 0.0, INF).astype(jnp.float32)
    res = jnp.asarray(res, jnp.float32)

    def one_pass(d):
        d = _sweep(d, free, res)
        return _sweep(d[::-1], free[::-1], res)[::-1]

    def cond(c):
        _, changed, n = c
        return changed & (n < free.size)

    def body(c):
        d, _, n = c
        new = one_pass(d)
        return new, jnp.any(new != d), n + 1

    d, _, n = lax.while_loop(cond, body, (d0, jnp.bool_(True), jnp.int32(0)))
    return d, n


def goal_field(world, goal: jax.Array, clearance: jax.Array, goal_radius: jax.Array, cells: int) -> jax.Array:
    """f32[cells, cells]: the distance field to `goal` in `world` (one room) on the grid
    inflated by `clearance` (D_c)."""
    free = free_cells(world, clearance, cells)
    res, _, _ = grid(world.size, cells)
    return distance_field(free, goal_cells(free, world.size, goal, goal_radius), res)[0]


def _neighbours(field: jax.Array, iy: jax.Array, ix: jax.Array):
    """(values f32[8], iy i32[8], ix i32[8], steps f32[8] in cells) of the 8 neighbours; off the
    grid reads +inf."""
    n = field.shape[0]
    ny, nx = iy + jnp.array(_DY), ix + jnp.array(_DX)
    on = (ny >= 0) & (ny < n) & (nx >= 0) & (nx < n)
    ny, nx = jnp.clip(ny, 0, n - 1), jnp.clip(nx, 0, n - 1)
    return jnp.where(on, field[ny, nx], INF), ny, nx, jnp.array(_STEP, jnp.float32)


def waypoint(field: jax.Array, size: jax.Array, goal: jax.Array, xy: jax.Array, lookahead: jax.Array) -> jax.Array:
    """f32[2]: the point about `lookahead` m down the field from the robot at `xy`, in its sight.

    From the robot's cell (not free: its best free neighbour) the walk steps to the neighbour
    that the shortest path takes (least value + edge) while it has walked less than `lookahead`,
    is not in the goal's cells and the next cell's centre stays in sight: every one of `SIGHT`
    points on the straight way from `xy` to it lies in a free cell (the robot's own cell aside),
    so that the way to the waypoint keeps D_c up to half a cell's diagonal. The waypoint is the
    last cell's centre; the goal itself when the robot's path to the goal is at most `lookahead`,
    or when there is no path (the walk never fails: a robot cut off from its goal sees the goal,
    as without the plan)."""
    cells = field.shape[0]
    res, xs, ys = grid(size, cells)
    y0, x0 = cell_of(xy, size, cells)
    vals, ny, nx, _ = _neighbours(field, y0, x0)
    k = jnp.argmin(vals)
    here = jnp.isfinite(field[y0, x0])
    iy, ix = jnp.where(here, y0, ny[k]), jnp.where(here, x0, nx[k])
    start = field[iy, ix]
    t = (jnp.arange(SIGHT, dtype=jnp.float32) + 1.0) / SIGHT

    def in_sight(cy, cx):
        pts = xy[None, :] + t[:, None] * (jnp.stack([xs[cx], ys[cy]]) - xy)[None, :]
        py, px = jax.vmap(lambda p: cell_of(p, size, cells))(pts)
        return jnp.all(jnp.isfinite(field[py, px]) | ((py == y0) & (px == x0)))

    def cond(c):
        cy, cx, walked, moving = c
        return moving & (walked < lookahead) & (field[cy, cx] > 0)

    def body(c):
        cy, cx, walked, _ = c
        v, vy, vx, steps = _neighbours(field, cy, cx)
        j = jnp.argmin(v + steps * res)
        go = (v[j] < field[cy, cx]) & in_sight(vy[j], vx[j])
        return jnp.where(go, vy[j], cy), jnp.where(go, vx[j], cx), walked + steps[j] * res, go

    cy, cx, _, _ = lax.while_loop(cond, body, (iy, ix, jnp.float32(0.0), jnp.bool_(True)))
    point = jnp.stack([xs[cx], ys[cy]])
    use_goal = ~jnp.isfinite(start) | (start <= lookahead)
    return jnp.where(use_goal, goal, point)


def reachable(world, goal: jax.Array, clearance: jax.Array, goal_radius: jax.Array, cells: int) -> jax.Array:
    """bool[starts]: which start rows of `world` (one room) have a path to `goal` on the plan's
    grid (their cell, or a free neighbour of it, has a finite field value)."""
    field = goal_field(world, goal, clearance, goal_radius, cells)

    def one(xy):
        iy, ix = cell_of(xy, world.size, cells)
        vals = _neighbours(field, iy, ix)[0]
        return jnp.isfinite(field[iy, ix]) | jnp.any(jnp.isfinite(vals))

    return jax.vmap(one)(world.starts[:, :2])


@struct.dataclass
class Plan:
    """What an episode keeps of its plan (`EnvState.plan`): the field, and the waypoint at each
    start row, where a respawn puts the robot (so that a step computes one waypoint, not two;
    as `EnvState.start_ranges` keeps the scans at the starts)."""

    field: jax.Array  # f32[cells, cells] m to the goal
    starts: jax.Array  # f32[starts, 2] the waypoint at each start row


def make(params, goal: jax.Array, clearance: jax.Array, cells: int) -> Plan:
    """An episode's `Plan` towards `goal` in the room of `params` (EnvParams: its world, goal
    radius and plan_lookahead), inflated by `clearance`."""
    world = params.world
    field = goal_field(world, goal, clearance, params.goal_radius, cells)
    starts = jax.vmap(lambda xy: waypoint(field, world.size, goal, xy, params.plan_lookahead))(world.starts[:, :2])
    return Plan(field, starts)


def at(plan: Plan, params, goal: jax.Array, xy: jax.Array) -> jax.Array:
    """f32[2]: the waypoint of `plan` for a robot at `xy` (`waypoint` with the params' lookahead)."""
    return waypoint(plan.field, params.world.size, goal, xy, params.plan_lookahead)
