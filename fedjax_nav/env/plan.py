"""A global plan on the known map (docs/planning.md): the next waypoint of a shortest safe path.

Pure JAX, for one robot in one room (vmap outside); every shape is fixed by the static number of
cells per side, `cells`, so that rooms of any size share one program.

    res, xs, ys = grid(size, cells)                      the square cells covering the room
    free = free_cells(world, clearance, cells)           bool[cells, cells]: centres >= D_c from everything
    free, cost = cell_costs(world, D_c, margin, cells)   and each cell's length multiplier (>= 1)
    field = distance_field(free, seeds, res, cost)       f32[cells, cells]: m to the goal, 8-connected
    field, cost = goal_field(world, goal, D_c, D_g, cells, margin)   the above for one goal
    wp = waypoint(field, size, goal, xy, lookahead, cost) f32[2]: about `lookahead` m down the field
    p = make(params, goal, D_c, cells)                   Plan: the field, the costs, the starts' waypoints
    names = layout(plan)                                 the observation's entries after the ranges
    wp = at(p, params, goal, xy)                         the waypoint with the params' lookahead
    wp = keep_right(field, size, xy, wp, others, offset, reach)  shared rooms: moved right, a robot ahead
    d = path_distance(field, size, xy)                   m to the goal along the field from any point
    r = path_progress(field, size, before, after, straight)  env.path_progress's progress over one step

The grid: `cells` x `cells` square cells of side res = max(W, H) / cells from the room's corner
(-W/2, -H/2); a cell is free when its centre lies inside the room and keeps at least the
collision distance from every segment and circle (`geometry.nearest_distance`, the env's own
exact distance). Rows are y, columns x: `field[iy, ix]`.

The margin (`env.plan_margin`, m; docs/planning.md, "The margin, and a scripted follower"): a
free cell whose clearance d is under D_c + margin costs more to leave, its edges' lengths times
1 + MARGIN_COST (1 - (d - D_c) / margin), so that the shortest path keeps away from walls where a
short way round allows; margin 0 (the default) makes every multiplier 1.0 exactly, and the
field, bit for bit, the plain length below.

The field: the shortest 8-connected path length (edges res and res sqrt 2 between free cells,
as `evaluation.paths`' Dijkstra; each times the multiplier of the cell it leaves) from each free
cell into the goal's cells (the free cells whose centres lie inside the goal disk, and the
goal's own cell when free), +inf where no path exists or the cell is not free. It is the fixed
point of Bellman's equations, found by Gauss-Seidel sweeps (rows upwards, then downwards; each
row also closed along itself) in a `lax.while_loop` until a pass changes nothing: Dijkstra's
distances up to float32 rounding.
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
MARGIN_COST = 4.0  # a cell at D_c costs 1 + MARGIN_COST times its length; at D_c + margin and beyond, 1
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


def _clearances(world, cells: int) -> tuple[jax.Array, jax.Array]:
    """(d f32[cells, cells], inside bool[cells, cells]): each centre's distance to the nearest
    segment or circle of `world` (one room), and whether it lies inside the room."""
    _, xs, ys = grid(world.size, cells)
    pts = jnp.stack(jnp.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    d = jax.vmap(lambda p: nearest_distance(world.segments, p, world.circles))(pts).reshape(cells, cells)
    half = world.size / 2
    inside = (jnp.abs(xs)[None, :] < half[0]) & (jnp.abs(ys)[:, None] < half[1])
    return d, inside


def free_cells(world, clearance: jax.Array, cells: int) -> jax.Array:
    """bool[cells, cells]: the cells whose centre is inside the room and keeps >= `clearance`
    from every segment and circle of `world` (one room)."""
    d, inside = _clearances(world, cells)
    return inside & (d >= clearance)


def cell_costs(world, clearance: jax.Array, margin: jax.Array, cells: int) -> tuple[jax.Array, jax.Array]:
    """(free bool[cells, cells], cost f32[cells, cells]): `free_cells`, and each cell's length
    multiplier: 1 + MARGIN_COST (1 - (d - clearance) / margin) under clearance + margin, else 1;
    exactly 1.0 everywhere when `margin` is 0."""
    d, inside = _clearances(world, cells)
    on = margin > 0
    near = jnp.clip(1.0 - (d - clearance) / jnp.where(on, margin, 1.0), 0.0, 1.0)
    return inside & (d >= clearance), 1.0 + MARGIN_COST * jnp.where(on, near, 0.0)


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


def _sweep(d: jax.Array, free: jax.Array, edge: jax.Array) -> jax.Array:
    """One Gauss-Seidel pass over the rows in order: each row takes its three neighbours of the
    row before (already updated), then is closed along itself (left to right, right to left).
    `edge` f32[cells, cells]: the length of a straight edge out of each cell (res x its cost)."""
    w = jnp.where(free, edge, INF)  # the edge out of a cell to its neighbour in the row

    def row_step(prev, xs):
        row, fr, wr = xs
        left = jnp.concatenate([jnp.full((1,), INF), prev[:-1]])
        right = jnp.concatenate([prev[1:], jnp.full((1,), INF)])
        row = jnp.minimum(row, jnp.minimum(prev + wr, jnp.minimum(left, right) + wr * SQRT2))
        row = jnp.where(fr, row, INF)
        row = _run_min(row, wr)
        row = _run_min(row[::-1], wr[::-1])[::-1]
        return row, row

    return lax.scan(row_step, jnp.full(d.shape[1:], INF, d.dtype), (d, free, w))[1]


def distance_field(free: jax.Array, seeds: jax.Array, res: jax.Array, cost=None) -> tuple[jax.Array, jax.Array]:
    """(field f32[cells, cells], passes i32[]): m from every free cell to the nearest seed cell
    along 8-connected free cells, each edge's length times the cost (f32[cells, cells], >= 1; None:
    1) of the cell it leaves; +inf when not free or cut off. Passes (up and down) until one
    changes nothing; at most cells^2 (a path visits each cell once)."""
    d0 = jnp.where(seeds & free, 0.0, INF).astype(jnp.float32)
    res = jnp.asarray(res, jnp.float32)
    edge = jnp.broadcast_to(res if cost is None else res * cost, free.shape)

    def one_pass(d):
        d = _sweep(d, free, edge)
        return _sweep(d[::-1], free[::-1], edge[::-1])[::-1]

    def cond(c):
        _, changed, n = c
        return changed & (n < free.size)

    def body(c):
        d, _, n = c
        new = one_pass(d)
        return new, jnp.any(new != d), n + 1

    d, _, n = lax.while_loop(cond, body, (d0, jnp.bool_(True), jnp.int32(0)))
    return d, n


def goal_field(world, goal, clearance, goal_radius, cells: int, margin=0.0) -> tuple[jax.Array, jax.Array]:
    """(field, cost), f32[cells, cells] each: the distance field to `goal` in `world` (one room)
    on the grid inflated by `clearance` (D_c), its cells' costs by `margin` (`cell_costs`)."""
    free, cost = cell_costs(world, clearance, jnp.asarray(margin, jnp.float32), cells)
    res, _, _ = grid(world.size, cells)
    return distance_field(free, goal_cells(free, world.size, goal, goal_radius), res, cost)[0], cost


def _neighbours(field: jax.Array, iy: jax.Array, ix: jax.Array):
    """(values f32[8], iy i32[8], ix i32[8], steps f32[8] in cells) of the 8 neighbours; off the
    grid reads +inf."""
    n = field.shape[0]
    ny, nx = iy + jnp.array(_DY), ix + jnp.array(_DX)
    on = (ny >= 0) & (ny < n) & (nx >= 0) & (nx < n)
    ny, nx = jnp.clip(ny, 0, n - 1), jnp.clip(nx, 0, n - 1)
    return jnp.where(on, field[ny, nx], INF), ny, nx, jnp.array(_STEP, jnp.float32)


def waypoint(
    field: jax.Array, size, goal: jax.Array, xy: jax.Array, lookahead: jax.Array, cost=None, first_step=False
) -> jax.Array:
    """f32[2]: the point about `lookahead` m down the field from the robot at `xy`, in its sight.

    From the robot's cell (not free: its best free neighbour) the walk steps to the neighbour
    that the shortest path takes (least value + edge, the edge times the cell's `cost`; None: 1)
    while it has walked less than `lookahead`, is not in the goal's cells and the next cell's
    centre stays in sight: every one of `SIGHT` points on the straight way from `xy` to it lies
    in a free cell (the robot's own cell aside), so that the way to the waypoint keeps D_c up to
    half a cell's diagonal. The waypoint is the last cell's centre; the goal itself when the
    robot's path to the goal is at most `lookahead`, or when there is no path (the walk never
    fails: a robot cut off from its goal sees the goal, as without the plan). `first_step` (bool,
    traced; `make` and `at` set it where the margin is on): the walk's first step is taken without
    the sight test, so that a robot whose every next cell is hidden behind an inflated corner is
    not sent to its own cell's centre, where it would turn on the spot (docs/planning.md, "The
    margin"); the margin keeps that step's way clear of the walls."""
    cells = field.shape[0]
    res, xs, ys = grid(size, cells)
    y0, x0 = cell_of(xy, size, cells)
    vals, ny, nx, _ = _neighbours(field, y0, x0)
    k = jnp.argmin(vals)
    here = jnp.isfinite(field[y0, x0])
    iy, ix = jnp.where(here, y0, ny[k]), jnp.where(here, x0, nx[k])
    start = field[iy, ix]

    def in_sight(cy, cx):
        return clear_way(field, size, xy, jnp.stack([xs[cx], ys[cy]]))

    def cond(c):
        cy, cx, walked, moving = c
        return moving & (walked < lookahead) & (field[cy, cx] > 0)

    def body(c):
        cy, cx, walked, _ = c
        v, vy, vx, steps = _neighbours(field, cy, cx)
        edge = res if cost is None else res * cost[cy, cx]
        j = jnp.argmin(v + steps * edge)
        go = (v[j] < field[cy, cx]) & (in_sight(vy[j], vx[j]) | (first_step & (walked == 0)))
        return jnp.where(go, vy[j], cy), jnp.where(go, vx[j], cx), walked + steps[j] * res, go

    cy, cx, _, _ = lax.while_loop(cond, body, (iy, ix, jnp.float32(0.0), jnp.bool_(True)))
    point = jnp.stack([xs[cx], ys[cy]])
    use_goal = ~jnp.isfinite(start) | (start <= lookahead)
    return jnp.where(use_goal, goal, point)


def clear_way(field: jax.Array, size, xy: jax.Array, point: jax.Array) -> jax.Array:
    """bool[]: every one of `SIGHT` points on the straight way from `xy` to `point` lies in a free
    cell of `field` (finite), the cell of `xy` itself aside."""
    cells = field.shape[0]
    y0, x0 = cell_of(xy, size, cells)
    t = (jnp.arange(SIGHT, dtype=jnp.float32) + 1.0) / SIGHT
    pts = xy[None, :] + t[:, None] * (point - xy)[None, :]
    py, px = jax.vmap(lambda p: cell_of(p, size, cells))(pts)
    return jnp.all(jnp.isfinite(field[py, px]) | ((py == y0) & (px == x0)))


def keep_right(field: jax.Array, size, xy: jax.Array, wp: jax.Array, others: jax.Array, offset, reach) -> jax.Array:
    """f32[2]: the waypoint `wp` of a robot at `xy` in a shared room, moved `offset` m to the right
    of the robot's way to it (xy -> wp) while another robot of `others` (circles f32[K, 3], r = 0:
    none) has its centre within `reach` m of the robot's and ahead (in front of the line through `xy`
    across that way): the traffic rule that sends two robots meeting head-on to opposite sides
    (docs/shared_rooms.md, "Keeping right"). The moved point when its way from `xy` is clear
    (`clear_way`), else the point half as far, else `wp`; `wp` exactly when `offset` is 0 or no
    robot is near."""
    way = wp - xy
    ahead = way / jnp.maximum(jnp.linalg.norm(way), 1e-6)
    right = jnp.stack([ahead[1], -ahead[0]])
    rel = others[:, :2] - xy[None, :]
    near = (others[:, 2] > 0) & (jnp.linalg.norm(rel, axis=-1) < reach) & (rel @ ahead > 0)
    full, half = wp + offset * right, wp + 0.5 * offset * right
    moved = jnp.where(clear_way(field, size, xy, full), full, jnp.where(clear_way(field, size, xy, half), half, wp))
    return jnp.where(jnp.any(near) & (offset > 0), moved, wp)


def path_distance(field: jax.Array, size, xy: jax.Array) -> jax.Array:
    """f32[]: m from the point `xy` to the goal along `field`: the least, over the cell holding
    `xy` and its 8 neighbours, of the cell's value plus the straight way from `xy` to its centre
    (+inf when all nine are): the field read between its cells' centres, so that a step of 2.5 cm
    is paid about its length along the path, not a cell's side at a time (where the step crosses
    into another cell the nine cells change, and its change may stray from its length by a
    fraction of a cell)."""
    cells = field.shape[0]
    _, xs, ys = grid(size, cells)
    iy, ix = cell_of(xy, size, cells)
    vals, ny, nx, _ = _neighbours(field, iy, ix)
    vals = jnp.append(vals, field[iy, ix])
    ny, nx = jnp.append(ny, iy), jnp.append(nx, ix)
    return jnp.min(vals + jnp.hypot(xs[nx] - xy[0], ys[ny] - xy[1]))


def path_progress(field: jax.Array, size, before: jax.Array, after: jax.Array, straight: jax.Array) -> jax.Array:
    """f32[]: the progress of one step from `before` to `after` (points f32[2]) along the field,
    `path_distance(before) - path_distance(after)` (m), or `straight` (the straight line's
    progress) when either is +inf: a goal cut off on the grid, or a robot whose nine cells are
    all inside the inflated walls, is paid as without the field (docs/clutter.md, "Paid along
    the path")."""
    a, b = path_distance(field, size, before), path_distance(field, size, after)
    return jnp.where(jnp.isfinite(a) & jnp.isfinite(b), a - b, straight)


def reachable(world, goal: jax.Array, clearance: jax.Array, goal_radius: jax.Array, cells: int) -> jax.Array:
    """bool[starts]: which start rows of `world` (one room) have a path to `goal` on the plan's
    grid (their cell, or a free neighbour of it, has a finite field value)."""
    field = goal_field(world, goal, clearance, goal_radius, cells)[0]

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

    field: jax.Array  # f32[cells, cells] m to the goal (each edge times its cell's cost)
    cost: jax.Array  # f32[cells, cells] the cells' length multipliers (`cell_costs`; 1 with no margin)
    starts: jax.Array | None = None  # f32[starts, 2] the waypoint at each start row; None: path_progress alone


def make(params, goal: jax.Array, clearance: jax.Array, cells: int, walk: bool = True) -> Plan:
    """An episode's `Plan` towards `goal` in the room of `params` (EnvParams: its world, goal
    radius, plan_lookahead and plan_margin), inflated by `clearance`; `walk=False`: the field
    only, no waypoints (what `env.path_progress` alone reads)."""
    world = params.world
    field, cost = goal_field(world, goal, clearance, params.goal_radius, cells, params.plan_margin)
    if not walk:
        return Plan(field, cost)
    first = params.plan_margin > 0
    walk = lambda xy: waypoint(field, world.size, goal, xy, params.plan_lookahead, cost, first)  # noqa: E731
    starts = jax.vmap(walk)(world.starts[:, :2])
    return Plan(field, cost, starts)


def at(plan: Plan, params, goal: jax.Array, xy: jax.Array) -> jax.Array:
    """f32[2]: the waypoint of `plan` for a robot at `xy` (`waypoint` with the params' lookahead)."""
    return waypoint(plan.field, params.world.size, goal, xy, params.plan_lookahead, plan.cost, params.plan_margin > 0)
