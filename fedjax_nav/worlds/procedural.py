"""Procedural rooms: random playgrounds drawn in pure JAX, solvable by construction.

`generate(key, spec)` draws one room as a `World` with fixed padded shapes (from the spec's
maxima), so it jits and vmaps over keys; a training program can draw a fresh room per robot
per episode inside `lax.scan`::

    spec = RoomSpec(family="mixture")
    rooms = jax.jit(jax.vmap(lambda k: generate(k, spec)))(keys)   # a stacked World [n, ...]

Families (`RoomSpec.family`): ``cylinders`` (circles only), ``boxes`` (rotated rectangles
only), ``walls`` (rooms and corridors: interior walls with one doorway each) and ``mixture``
(all three), built here; the dense families ``forest``, ``warehouse``, ``maze`` and ``cave``, and
the indoor ones ``office`` (multi-room floors) and ``corridors``, built in their own modules
(`DENSE_BUILDERS`), each solvable by an argument of its own (their module docstrings). The
spec's ranges of the kinds a family does not use are ignored and take no array space.
Parameters, defaults and allowed ranges: `RoomSpec` and docs/generator.md.

Solvability, by construction (no search, no resampling, no fallback needed)
----------------------------------------------------------------------------
Let ``c = D_c + clearance_margin`` (``D_c`` = `worlds.CLEARANCE` = 0.25 m, margin 0.05 m).

1. Interior walls partition the room by binary space partition: each wall splits one current
   rectangular sub-room into two, spans it from side to side, and has one doorway of width
   ``w > 2 c``. Every sub-room keeps both sides >= ``room_side_min >= door_width_max + 2 c``,
   the doorway lies at least ``c`` from the ends of its wall, and a later wall is only placed
   where it stays at least ``w/2 + c`` from the centre of every existing doorway. Hence the
   doorways form a tree connecting all final sub-rooms, and in every final sub-room ``R``
   the *core* (``R`` shrunk by ``c``) is a convex rectangle whose points are at least ``c``
   from every wall (walls only lie on sub-room boundaries, so any wall point is at least
   ``dist(p, boundary of R)`` from ``p``). For each doorway with centre ``d`` and unit normal
   ``n`` the crossing ``d - c n -> d + c n`` keeps ``>= min(w/2, room_side_min - c) > c``
   from every wall, and its ends lie in the cores of the two sub-rooms it joins.
2. Each sub-room gets a random *hub* in its core. Starts and goals are drawn in cores. The
   *reserved network* is the set of segments start -> hub, goal -> hub (same sub-room) and,
   per doorway, hub -> (d + c n) -> (d - c n) -> hub. Every segment lies in a convex core or
   is a doorway crossing, so it keeps >= ``c`` from every wall, and the network is connected
   (a star in each sub-room, joined along the tree of doorways).
3. Cylinders and boxes are drawn only where they keep >= ``c`` from every segment of the
   reserved network (exact point-segment / segment-segment distances; a candidate that fails
   is redrawn, up to ``tries`` times, then that obstacle is dropped). Overlapping obstacles
   are fine: >= ``c`` from each obstacle is >= ``c`` from their union.

So from every start to every goal the path start -> hub -> (doorways) -> hub -> goal keeps a
clearance >= ``c = D_c + margin > D_c`` from every obstacle: the robot never comes within the
collision distance. This is sound without any grid or search because the guarantee is a
property of the constructed network, checked with exact distances, and it costs one fixed,
branch-free pass (cheap under vmap). The price: obstacles never block the reserved network,
so the network (a random tree, not the straight start-goal line) is always free, and in small
or crowded rooms fewer obstacles or walls than requested may fit (the info dict of
`generate_with_info` reports the counts placed). `tests/test_generate.py` checks thousands of
rooms against an independent float64 grid search.

Held-out test rooms (the disjointness rule)
-------------------------------------------
A *room seed* is an integer in ``[0, 2**32)``; ``room_key(seed) = fold_in(key(ROOM_ROOT),
seed)``. ``fold_in`` encrypts ``[0, seed]`` with threefry-2x32 under the root key, a block
cipher, so distinct seeds give distinct keys. Seeds ``>= TEST_SEED_BASE = 2**31`` are reserved
for the held-out `SUITES` (`is_test_seed`); training must draw rooms from `train_room_key(i)`,
which maps any counter ``i`` into ``[0, 2**31)``. Test and training rooms therefore never share
a key. (Keys made any other way, e.g. ``jax.random.key(s)``, differ from the test keys only with
overwhelming probability.)
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from fedjax_nav.worlds import cave, corridors, forest, maze, office, warehouse
from fedjax_nav.worlds.layout import pad_world
from fedjax_nav.worlds.rooms import _START_TRIES, RoomSpec, check_spec
from fedjax_nav.worlds.sampling import Uniforms, box_corners, first_true, gumbel_argmax, pt_seg, seg_box, take_rows
from fedjax_nav.worlds.shapes import slot_counts
from fedjax_nav.worlds.world import World

# ----------------------------------------------------------------------------- how many draws a spec uses


@functools.lru_cache(maxsize=64)
def _num_uniforms(spec: RoomSpec) -> int:
    counter = Uniforms(None)
    jax.eval_shape(lambda: _build(counter, spec))
    return counter.used


# ----------------------------------------------------------------------------- the generator


def _partition(rng: Uniforms, W, H, n_walls, spec: RoomSpec, c: float, K: int):
    """Binary space partition of the room by up to K walls with one doorway each.

    Returns rooms f32[K+1, 4] (x0, y0, x1, y1), active bool[K+1], wall segments f32[2K, 4]
    (zero rows where no wall), door centres f32[K, 2], door normals f32[K, 2], placed bool[K].
    """
    rmin = spec.room_side_min
    T = spec.tries
    init = (
        jnp.zeros((K + 1, 4), jnp.float32).at[0].set(jnp.stack([-W / 2, -H / 2, W / 2, H / 2])),  # rooms
        jnp.zeros((K + 1,), bool).at[0].set(True),  # active rooms
        jnp.zeros((K, 2), jnp.float32),  # door centres
        jnp.zeros((K, 2), jnp.float32),  # door normals
        jnp.zeros((K,), jnp.float32),  # door widths
        jnp.zeros((K,), bool),  # walls placed
        jnp.zeros((K, 2, 4), jnp.float32),  # the two segments of each wall
    )
    xs = (jnp.arange(K), rng.u((K, K + 1)), rng.u((K, T)), rng.u((K, T)), rng.u((K,)), rng.u((K,)))

    def split(carry, x):  # one wall: a lax.scan step (compiles once, not K times)
        rooms, active, door_pt, door_n, door_w, placed, wall_segs = carry
        j, u_room, u_ax, u_pos, u_w, u_door = x
        ext = rooms[:, 2:] - rooms[:, :2]  # [K+1, 2]: extent along x (split by a vertical wall), y
        can = active[:, None] & (ext >= 2 * rmin)  # [K+1, 2]
        room_ok = can.any(-1)
        area = ext[:, 0] * ext[:, 1]
        r = gumbel_argmax(jnp.where(room_ok, jnp.log(jnp.maximum(area, 1e-6)), -jnp.inf), u_room)
        R, ext_r, can_r = rooms[r], ext[r], can[r]
        # axis 0: a vertical wall x = pos (splits the x extent); 1: a horizontal wall y = pos.
        p0 = jnp.where(can_r[0] & can_r[1], ext_r[0] / (ext_r[0] + ext_r[1]), jnp.where(can_r[0], 1.0, 0.0))
        ax = jnp.where(u_ax < p0, 0, 1)
        lo_ax, hi_ax = R[ax], R[ax + 2]
        pos = lo_ax + rmin + u_pos * jnp.maximum(hi_ax - lo_ax - 2 * rmin, 0.0)
        vert = (ax == 0)[:, None]
        a = jnp.where(
            vert, jnp.stack([pos, jnp.broadcast_to(R[1], (T,))], -1), jnp.stack([jnp.broadcast_to(R[0], (T,)), pos], -1)
        )
        b = jnp.where(
            vert, jnp.stack([pos, jnp.broadcast_to(R[3], (T,))], -1), jnp.stack([jnp.broadcast_to(R[2], (T,)), pos], -1)
        )
        # Keep w/2 + c from the centre of every existing doorway.
        dd = pt_seg(door_pt[None], a[:, None], b[:, None])  # [T, K]
        ok = jnp.all(~placed[None] | (dd >= door_w[None] / 2 + c), axis=1) & can_r[ax]
        t, any_ok = first_true(ok)
        place = (j < n_walls) & room_ok[r] & any_ok
        ax_t, pos_t, a_t, b_t = ax[t], pos[t], a[t], b[t]
        # The doorway: width w, centre at least w/2 + c from both ends of the wall.
        w = spec.door_width_min + u_w * (spec.door_width_max - spec.door_width_min)
        lo_w, hi_w = jnp.where(ax_t == 0, R[1], R[0]), jnp.where(ax_t == 0, R[3], R[2])
        dc = lo_w + w / 2 + c + u_door * jnp.maximum(hi_w - lo_w - w - 2 * c, 0.0)
        along = jnp.where(ax_t == 0, jnp.array([0.0, 1.0]), jnp.array([1.0, 0.0]))
        normal = jnp.where(ax_t == 0, jnp.array([1.0, 0.0]), jnp.array([0.0, 1.0]))
        centre = jnp.where(ax_t == 0, jnp.stack([pos_t, dc]), jnp.stack([dc, pos_t]))
        segs = jnp.stack(
            [jnp.concatenate([a_t, centre - (w / 2) * along]), jnp.concatenate([centre + (w / 2) * along, b_t])]
        )
        child_a = jnp.where(ax_t == 0, jnp.stack([R[0], R[1], pos_t, R[3]]), jnp.stack([R[0], R[1], R[2], pos_t]))
        child_b = jnp.where(ax_t == 0, jnp.stack([pos_t, R[1], R[2], R[3]]), jnp.stack([R[0], pos_t, R[2], R[3]]))
        return (
            jnp.where(place, rooms.at[r].set(child_a).at[j + 1].set(child_b), rooms),
            active.at[j + 1].set(place),
            door_pt.at[j].set(jnp.where(place, centre, 0.0)),
            door_n.at[j].set(normal),
            door_w.at[j].set(jnp.where(place, w, 0.0)),
            placed.at[j].set(place),
            wall_segs.at[j].set(jnp.where(place, segs, 0.0)),
        ), None

    (rooms, active, door_pt, door_n, _, placed, wall_segs), _ = jax.lax.scan(split, init, xs)
    wall_segs = wall_segs.reshape(2 * K, 4)
    return rooms, active, wall_segs, door_pt, door_n, placed


def generate_with_info(key: jax.Array, spec: RoomSpec, density=1.0) -> tuple[World, dict[str, jax.Array]]:
    """`generate`, plus what was drawn: counts requested and placed (walls, boxes, cylinders),
    whether the start-goal distance rule held, the sub-rooms and the reserved network."""
    check_spec(spec)
    rng = Uniforms(jax.random.uniform(key, (_num_uniforms(spec),)))
    return _build(rng, spec, density)


def _thin(n: jax.Array, density) -> jax.Array:
    """floor(density * n), density in [0, 1] (traced): exactly n at density 1."""
    return jnp.clip(jnp.floor(jnp.asarray(density, jnp.float32) * n), 0, n).astype(jnp.int32)


# The dense and indoor families build their rooms in their own modules (one each; shared parts in layout.py).
DENSE_BUILDERS = {"forest": forest.build, "warehouse": warehouse.build, "maze": maze.build, "cave": cave.build}
DENSE_BUILDERS |= {"office": office.build, "corridors": corridors.build}


def _build(rng: Uniforms, spec: RoomSpec, density=1.0) -> tuple[World, dict[str, jax.Array]]:
    if spec.family in DENSE_BUILDERS:
        return DENSE_BUILDERS[spec.family](rng, spec, density)
    c = spec.clearance
    n_cyl_slots, n_box_slots, K = slot_counts(spec)
    W = rng.uniform((), spec.width_min, spec.width_max)
    H = rng.uniform((), spec.height_min, spec.height_max)
    size = jnp.stack([W, H])
    n_starts = rng.randint(spec.starts_min, spec.starts_max)
    n_goals = rng.randint(spec.goals_min, spec.goals_max)
    n_walls_req = rng.randint(spec.walls_min, spec.walls_max) if K else jnp.int32(0)
    n_cyl_req = rng.randint(spec.cylinders_min, spec.cylinders_max) if n_cyl_slots else jnp.int32(0)
    n_box_req = rng.randint(spec.boxes_min, spec.boxes_max) if n_box_slots else jnp.int32(0)
    # a curriculum's density keeps floor(density * n) of each requested count; the uniforms drawn
    # are those of density 1, so thinning changes only how many of the drawn obstacles are kept
    n_walls_req, n_cyl_req, n_box_req = (_thin(n, density) for n in (n_walls_req, n_cyl_req, n_box_req))

    # 1. Sub-rooms (one, the whole room, without walls).
    if K:
        rooms, active, wall_segs, door_pt, door_n, placed = _partition(rng, W, H, n_walls_req, spec, c, K)
    else:
        rooms = jnp.stack([-W / 2, -H / 2, W / 2, H / 2])[None]
        active = jnp.ones((1,), bool)
        wall_segs = jnp.zeros((0, 4), jnp.float32)
        door_pt = door_n = jnp.zeros((0, 2), jnp.float32)
        placed = jnp.zeros((0,), bool)
    core_lo, core_hi = rooms[:, :2] + c, rooms[:, 2:] - c
    core_ext = jnp.maximum(core_hi - core_lo, 0.0)
    room_logits = jnp.where(active, jnp.log(jnp.maximum(core_ext[:, 0] * core_ext[:, 1], 1e-9)), -jnp.inf)
    hubs = core_lo + rng.u((rooms.shape[0], 2)) * (core_hi - core_lo)

    # 2. Goals, then starts (the farthest-first rule), uniformly in the cores by core area.
    g_room, goals, g_active, s_room, starts_xy, s_active, distance_ok, yaw = _starts_and_goals(
        rng, spec, room_logits, core_lo, core_hi, n_starts, n_goals
    )

    # 3. The reserved network: start/goal -> hub of its sub-room; per doorway hub -> crossing -> hub.
    ends = (starts_xy, goals, s_room, g_room, s_active, g_active)
    res_a, res_b, res_on = _reserved(ends, hubs, rooms, active, door_pt, door_n, placed, c, K)

    # 4. Obstacles: `tries` candidates each; the first that keeps c from the network is kept.
    res = (res_a, res_b, res_on)
    circles, cyl_on = _cylinders(rng, spec, size, res, n_cyl_slots, n_cyl_req)
    box_segs, box_on, boxes = _boxes(rng, spec, size, res, n_box_slots, n_box_req)

    # 5. The World, padded to the spec's shapes (extra starts / goals repeat row 0).
    world = pad_world(
        spec,
        W,
        H,
        jnp.concatenate([wall_segs, box_segs]),
        circles,
        starts_xy,
        yaw,
        s_active,
        goals,
        g_active,
        n_starts,
        n_goals,
    )
    info = {
        "walls": jnp.sum(placed).astype(jnp.int32),
        "walls_requested": jnp.asarray(n_walls_req, jnp.int32),
        "boxes": jnp.sum(box_on).astype(jnp.int32),
        "boxes_requested": jnp.asarray(n_box_req, jnp.int32),
        "cylinders": jnp.sum(cyl_on).astype(jnp.int32),
        "cylinders_requested": jnp.asarray(n_cyl_req, jnp.int32),
        "box_rows": boxes,
        "box_on": box_on,
        "distance_ok": distance_ok,
        "rooms": rooms,
        "rooms_active": active,
        "reserved": jnp.concatenate([res_a, res_b], -1),
        "reserved_on": res_on,
    }
    return world, info


def _starts_and_goals(rng: Uniforms, spec: RoomSpec, room_logits, core_lo, core_hi, n_starts, n_goals):
    """Goals, then starts (the farthest-first rule), uniformly in the sub-rooms' cores by core area:
    (goal rooms, goals, goals on, start rooms, starts, starts on, distance rule held, start yaws)."""
    S, G = spec.starts_max, spec.goals_max
    g_room = rng.categorical(room_logits, (G,))
    goals = core_lo[g_room] + rng.u((G, 2)) * (core_hi[g_room] - core_lo[g_room])
    g_active = jnp.arange(G) < n_goals
    s_room_c = rng.categorical(room_logits, (S, _START_TRIES))
    s_cand = core_lo[s_room_c] + rng.u((S, _START_TRIES, 2)) * (core_hi[s_room_c] - core_lo[s_room_c])
    gd = jnp.sqrt(jnp.sum((s_cand[:, :, None] - goals[None, None]) ** 2, -1))  # [S, T, G]
    gd = jnp.min(jnp.where(g_active, gd, jnp.inf), -1)
    first, any_ok = first_true(gd >= spec.min_start_goal_distance)
    pick = jnp.where(any_ok, first, jnp.argmax(gd, -1))
    starts_xy = take_rows(s_cand, pick)
    s_room = take_rows(s_room_c, pick)
    s_active = jnp.arange(S) < n_starts
    distance_ok = jnp.all(~s_active | any_ok)
    yaw = rng.uniform((S,), -jnp.pi, jnp.pi)
    return g_room, goals, g_active, s_room, starts_xy, s_active, distance_ok, yaw


def _reserved(ends, hubs, rooms, active, door_pt, door_n, placed, c: float, K: int):
    """The reserved network (a, b, on): start/goal -> hub of its sub-room; per doorway (of K wall
    slots) hub -> crossing -> hub. `ends`: (starts, goals, their rooms, starts on, goals on)."""
    starts_xy, goals, s_room, g_room, s_active, g_active = ends

    def room_of(p):  # the active sub-room strictly containing p [..., 2]
        inside = (
            active
            & (p[..., None, 0] > rooms[:, 0])
            & (p[..., None, 0] < rooms[:, 2])
            & (p[..., None, 1] > rooms[:, 1])
            & (p[..., None, 1] < rooms[:, 3])
        )
        return jnp.argmax(inside, axis=-1)

    res_a = [starts_xy, goals]
    res_b = [hubs[s_room], hubs[g_room]]
    res_on = [s_active, g_active]
    if K:
        p1, p2 = door_pt + c * door_n, door_pt - c * door_n
        h1, h2 = hubs[room_of(p1)], hubs[room_of(p2)]
        res_a += [h1, p1, p2]
        res_b += [p1, p2, h2]
        res_on += [placed, placed, placed]
    res_a, res_b, res_on = jnp.concatenate(res_a), jnp.concatenate(res_b), jnp.concatenate(res_on)
    return res_a, res_b, res_on


def _cylinders(rng: Uniforms, spec: RoomSpec, size, res, n_cyl_slots: int, n_cyl_req):
    """The cylinders (rows x, y, r; zero rows off) and which are on: `tries` candidates each, the
    first that keeps c from the reserved network `res` (a, b, on)."""
    c, T = spec.clearance, spec.tries
    res_a, res_b, res_on = res
    if not n_cyl_slots:
        return jnp.zeros((0, 3), jnp.float32), jnp.zeros((0,), bool)
    rad = rng.uniform((n_cyl_slots, T), spec.radius_min, spec.radius_max)
    half = jnp.maximum(size / 2 - rad[..., None], 0.0)
    cen = -half + rng.u((n_cyl_slots, T, 2)) * 2 * half
    d = pt_seg(cen[:, :, None], res_a, res_b) - rad[..., None]  # [n, T, R]
    ok = jnp.all(~res_on | (d >= c), -1)
    t, any_ok = first_true(ok)
    cyl_on = any_ok & (jnp.arange(n_cyl_slots) < n_cyl_req)
    circles = jnp.where(cyl_on[:, None], jnp.concatenate([take_rows(cen, t), take_rows(rad, t)[:, None]], -1), 0.0)
    return circles, cyl_on


def _boxes(rng: Uniforms, spec: RoomSpec, size, res, n_box_slots: int, n_box_req):
    """The boxes' edges (4 rows each), which are on, and their rows (x, y, sx, sy, yaw): `tries`
    candidates each, the first that keeps c from the reserved network `res` (a, b, on)."""
    c, T = spec.clearance, spec.tries
    res_a, res_b, res_on = res
    if not n_box_slots:
        return jnp.zeros((0, 4), jnp.float32), jnp.zeros((0,), bool), jnp.zeros((0, 5), jnp.float32)
    sides = rng.uniform((n_box_slots, T, 2), spec.box_side_min, spec.box_side_max)
    byaw = rng.uniform((n_box_slots, T), 0.0, jnp.pi)
    half = jnp.maximum(size / 2 - jnp.linalg.norm(sides, axis=-1, keepdims=True) / 2, 0.0)
    cen = -half + rng.u((n_box_slots, T, 2)) * 2 * half
    d = seg_box(res_a, res_b, cen[:, :, None], sides[:, :, None] / 2, byaw[..., None])  # [n, T, R]
    ok = jnp.all(~res_on | (d >= c), -1)
    t, any_ok = first_true(ok)
    box_on = any_ok & (jnp.arange(n_box_slots) < n_box_req)
    corners = box_corners(take_rows(cen, t), take_rows(sides, t), take_rows(byaw, t))  # [n, 4, 2]
    edges = jnp.concatenate([corners, jnp.roll(corners, -1, axis=-2)], -1)  # [n, 4, 4]
    box_segs = jnp.where(box_on[:, None, None], edges, 0.0).reshape(-1, 4)
    rows = jnp.concatenate([take_rows(cen, t), take_rows(sides, t), take_rows(byaw, t)[:, None]], -1)
    boxes = jnp.where(box_on[:, None], rows, 0.0)
    return box_segs, box_on, boxes


def generate(key: jax.Array, spec: RoomSpec, density=1.0) -> World:
    """One procedural room for `key` (pure JAX: jit and vmap over keys; `spec` is static).

    `density` (a float in [0, 1], may be traced) keeps floor(density * n) of the n walls, boxes
    and cylinders the room would have, from the same draws (a curriculum's sparse rooms;
    docs/generalization.md); the dense families thin their trunks, racks and pallets, maze walls
    or rock islands the same way. The construction's guarantee holds at any density. At 1 (the
    default) the room is exactly the unthinned one.

    Every World of one spec has the shapes `padded_shape(spec)`: segments rows are the 4 outer
    walls, then 2 per interior wall slot, then 4 per box slot, then padding (zero rows); circles
    one row per cylinder slot (zero rows unused); the dense families' layouts: docs/generator.md.
    Every start reaches every goal with clearance > D_c (see the module docstring for why).
    Raises WorldError for a bad spec (at trace time).
    """
    return generate_with_info(key, spec, density)[0]


@functools.partial(jax.jit, static_argnums=1)
def generate_batch(keys: jax.Array, spec: RoomSpec) -> World:
    """`generate` vmapped over keys [n] and jitted (compiled once per spec): a stacked World."""
    return jax.vmap(lambda k: generate(k, spec))(keys)


@functools.partial(jax.jit, static_argnums=1)
def generate_batch_with_info(keys: jax.Array, spec: RoomSpec) -> tuple[World, dict]:
    """`generate_with_info` vmapped over keys and jitted."""
    return jax.vmap(lambda k: generate_with_info(k, spec))(keys)


@functools.lru_cache(maxsize=16)
def jitted_generator(spec: RoomSpec):
    """The jitted one-room generator of a spec (shared by `suites.generate_to_file` and tests)."""
    return jax.jit(lambda k: generate(k, spec))
