"""The ``office`` family: a multi-room office floor, its rooms joined by doors and furnished with desks
and round things (chairs, columns, bins) (docs/generator.md).

The layout is drawn in a frame turned by 90 degrees (x and y swapped) in half of the floors.

1. Floor size (10-18 m); a grid of nx x ny rooms, nx ~ U{office_cols_*}, ny ~ U{office_rows_*},
   each at most floor(L / office_room_min) along a side L; the inner wall lines at their regular
   places moved by up to office_jitter of a room's side, so every room side is at least
   s = office_room_min (1 - 2 office_jitter) (`check_spec`: s >= office_door_max + 2 c, c = D_c +
   clearance_margin, and no desk or round thing is larger than s).
2. Doors: every wall of a spanning tree of the rooms (the recursive backtracker of the maze family,
   on the grid of rooms) has one, every other shared wall one with probability office_extra_doors.
   A door of width w ~ U[office_door_*] has its centre at least w / 2 + c from both ends of its
   wall. A wall is two segments, either side of its door (one without a door).
3. A hub in each room's core (the room shrunk by c). The clear network: per door, hub -> the point c
   inside the room in front of the door -> the point c inside the other room -> that room's hub.
4. Goals in random rooms (by core area); starts, by the base families' distance rule (64
   candidates each), in rooms that hold no goal (when there is one), so that every start's way
   to a goal goes through a door; each start and goal is joined to its room's hub.
5. Furniture, per room: office_desks_* desks (axis-aligned boxes, depth x length, turned by 90
   degrees in half of the candidates) and office_cylinders_* round things, inside the room. Each
   kind draws a pool of (its most per room + `tries`) candidates per room; the room's n pieces
   are the first n that keep c from the room's part of the network (fewer if fewer do).
6. Density d keeps floor(d n) of the n wall segments, desks and round things (random ranks: a
   sparser floor's obstacles are a subset of a denser one's); desks and round things fill at most
   office_boxes and office_circles slots, a random subset of them on a floor with more.

Solvable: walls lie on room boundaries only, so a room's core keeps c from every wall, and it is
convex; a door crossing keeps w / 2 > c from its jambs, w / 2 + c from the walls at its wall's ends,
and s - c >= c from the far sides of the two rooms. Furniture keeps c from the network by step 5,
and testing a room's part suffices: a piece of furniture lies inside its room, every other hub
segment lies in another room's core (c from that room's boundary, so c from this room), and every
other door crossing lies in the two rooms of its door, c from their other sides and w / 2 + c from
the corners where this room can touch them. So start -> hub -> doors -> hub -> goal keeps c.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from fedjax_nav.worlds.layout import Endpoints, assemble, box_edges, common_info, compact, room_size, thin_count
from fedjax_nav.worlds.maze import backtracker
from fedjax_nav.worlds.rooms import _START_TRIES, RoomSpec
from fedjax_nav.worlds.sampling import Uniforms, first_true, pt_seg_sq, seg_aabb_sq, take_rows
from fedjax_nav.worlds.shapes import office_grid, office_slots


def swap_xy(p, flip):
    """Frame -> room coordinates: swap x and y of every point (last axis a multiple of 2)."""
    q = p.reshape(*p.shape[:-1], -1, 2)
    return jnp.where(flip, q[..., ::-1], q).reshape(p.shape)


def flip_endpoints(ep: Endpoints, flip) -> Endpoints:
    """The endpoints drawn in the frame, in room coordinates (`swap_xy` of each point)."""
    return ep._replace(
        starts=swap_xy(ep.starts, flip),
        start_anchor=swap_xy(ep.start_anchor, flip),
        goals=swap_xy(ep.goals, flip),
        goal_anchor=swap_xy(ep.goal_anchor, flip),
    )


def grid_lines(u, n, N: int, L, jitter: float):
    """N + 1 wall lines f32[N + 1] across a side L cut into n (traced, <= N) parts: the inner ones
    at their regular places moved by up to `jitter` of a part (u f32[N + 1]); those beyond n at L / 2."""
    k = jnp.arange(N + 1, dtype=jnp.float32)
    nf = n.astype(jnp.float32)
    x = -L / 2 + (k + jnp.where((k > 0) & (k < nf), jitter * (2 * u - 1), 0.0)) * L / nf
    return jnp.where(k >= nf, L / 2, x)


def keep_random(on, u, density, cap: int):
    """Keep min(floor(density * count), cap) of the True entries of `on` [n], those of the smallest
    `u` [n]: nested across densities, a random subset where `cap` slots are too few."""
    order = jnp.argsort(jnp.where(on, u, 2.0))
    rank = jnp.zeros(on.shape, jnp.int32).at[order].set(jnp.arange(on.shape[0], dtype=jnp.int32))
    return on & (rank < jnp.minimum(thin_count(jnp.sum(on), density), cap))


def draw_endpoints(rng: Uniforms, spec: RoomSpec, sample_goal, sample_start, k: int):
    """Goals from `sample_goal(u f32[G, k])` -> (points, anchors f32[G, 2], tags i32[G]), then each
    start by the base families' distance rule (of 64 candidates the first at least
    min_start_goal_distance from every goal, else the farthest) from `sample_start(u f32[S, 64, k],
    goal tags, goals used bool[G])` -> (points, anchors, tags). The tags say where a point is (a
    room, a branch). Returns (Endpoints, the starts' tags i32[S], the goals' tags i32[G])."""
    S, G = spec.starts_max, spec.goals_max
    n_starts = rng.randint(spec.starts_min, spec.starts_max)
    n_goals = rng.randint(spec.goals_min, spec.goals_max)
    goal_on = jnp.arange(G) < n_goals
    goals, g_anchor, g_tag = sample_goal(rng.u((G, k)))
    cand, cand_anchor, cand_tag = sample_start(rng.u((S, _START_TRIES, k)), g_tag, goal_on)
    gd = jnp.sqrt(jnp.sum((cand[:, :, None] - goals[None, None]) ** 2, -1))  # [S, T, G]
    gd = jnp.min(jnp.where(goal_on, gd, jnp.inf), -1)
    first, any_ok = first_true(gd >= spec.min_start_goal_distance)
    pick = jnp.where(any_ok, first, jnp.argmax(gd, -1))
    ep = Endpoints(
        starts=take_rows(cand, pick),
        start_anchor=take_rows(cand_anchor, pick),
        yaw=rng.uniform((S,), -jnp.pi, jnp.pi),
        goals=goals,
        goal_anchor=g_anchor,
        num_starts=n_starts,
        num_goals=n_goals,
        distance_ok=jnp.all((jnp.arange(S) >= n_starts) | any_ok),
    )
    return ep, take_rows(cand_tag, pick), g_tag


def first_fits(ok, n, k: int):
    """Per row of ok bool[R, P] (the candidates that fit): the indices i32[R, k] of the first k that
    fit, and which of the k slots are used bool[R, k] (the first min(n, fitting) of them; n i32[R])."""
    R, P = ok.shape
    rank = jnp.cumsum(ok, -1) - 1
    slot = jnp.where(ok & (rank < k), rank, k)
    idx = jnp.zeros((R, k), jnp.int32).at[jnp.arange(R)[:, None], slot].set(jnp.arange(P, dtype=jnp.int32), mode="drop")
    return idx, jnp.arange(k) < jnp.minimum(n, jnp.sum(ok, -1))[:, None]


def take_along(x, idx):
    """x f32[R, P, m] at idx i32[R, k] along axis 1: f32[R, k, m]."""
    return jnp.take_along_axis(x, idx[..., None], axis=1)


def pick_by_weight(u, w):
    """Indices i32[...] drawn with probabilities w / sum(w) (w f32[n] >= 0) from uniforms u [...]."""
    cum = jnp.cumsum(w)
    return jnp.minimum(jnp.sum(cum <= u[..., None] * cum[-1], -1), w.shape[0] - 1).astype(jnp.int32)


def _doors(rng: Uniforms, spec: RoomSpec, lo, hi, present, tree, axis: int, c: float):
    """One shared wall per room on its side `axis` (0: east, x = hi_x; 1: north, y = hi_y), R of them
    (present bool[R]). Returns (door bool[R], width f32[R], the two wall pieces f32[R, 2, 4] with
    their flags bool[R, 2], the door's points c inside this room and c inside the other f32[R, 2])."""
    R = lo.shape[0]
    door = present & (tree | (rng.u((R,)) < spec.office_extra_doors))
    w = rng.uniform((R,), spec.office_door_min, spec.office_door_max)
    along = 1 - axis  # the coordinate that runs along the wall
    a0, a1, at = lo[:, along], hi[:, along], hi[:, axis]
    t = a0 + w / 2 + c + rng.u((R,)) * jnp.maximum(a1 - a0 - w - 2 * c, 0.0)
    end1 = jnp.where(door, t - w / 2, a1)

    def point(a, b):  # (along, across) -> (x, y)
        return jnp.stack([b, a], -1) if axis == 0 else jnp.stack([a, b], -1)

    pieces = jnp.stack(
        [
            jnp.concatenate([point(a0, at), point(end1, at)], -1),
            jnp.concatenate([point(t + w / 2, at), point(a1, at)], -1),
        ],
        1,
    )
    return door, jnp.where(door, w, 0.0), pieces, jnp.stack([present, door], -1), point(t, at - c), point(t, at + c)


class Furniture(NamedTuple):
    """An office floor's furniture in the frame: desk rows (centre, sides) and cylinder rows
    (centre, radius), compacted to their slots, with how many were placed; what was asked for and
    what fitted but found no slot (info's furniture_requested, furniture_dropped)."""

    desks: jax.Array  # f32[office_boxes, 4]
    n_desks: jax.Array
    circles: jax.Array  # f32[office_circles, 3]
    n_circles: jax.Array
    requested: jax.Array
    dropped: jax.Array


def _furniture(rng: Uniforms, spec: RoomSpec, rooms, net, density) -> Furniture:
    """Step 5: desks and cylinders in every active room (`rooms`: lo, hi [R, 2], active [R]), each
    kept from its room's part of the network (`net`: la, lb [R, L, 2], lon [R, L])."""
    (lo, hi, active), (la, lb, lon), c, R = rooms, net, spec.clearance, rooms[0].shape[0]

    def clear(dist_sq, r2):  # candidates [R, P, ...] keep sqrt(r2) from every segment of their room's network
        d = dist_sq(la[:, None], lb[:, None])  # [R, P, L]: one broadcast pass, small to compile
        return jnp.all(~lon[:, None] | (d >= r2[..., None]), -1)

    # A pool of (slots + tries) candidates per room and kind: the room's n pieces are the first n
    # that keep c (one pool per room, not `tries` per piece: the room's network is the same for all).
    (_, n_box, n_circ), T = office_slots(spec), spec.tries
    D, C = spec.office_desks_max, spec.office_cylinders_max
    room_lo, room_ext = lo[:, None], (hi - lo)[:, None]
    n_d = rng.randint(spec.office_desks_min, spec.office_desks_max, (R,))
    dep = rng.uniform((R, D + T), spec.office_desk_depth_min, spec.office_desk_depth_max)
    length = rng.uniform((R, D + T), spec.office_desk_length_min, spec.office_desk_length_max)
    sides = jnp.where((rng.u((R, D + T)) < 0.5)[..., None], jnp.stack([dep, length], -1), jnp.stack([length, dep], -1))
    cen = room_lo + sides / 2 + rng.u((R, D + T, 2)) * jnp.maximum(room_ext - sides, 0.0)
    ok = clear(lambda a, b: seg_aabb_sq(a, b, cen[..., None, :], sides[..., None, :] / 2), jnp.full((R, D + T), c * c))
    pick, desk_fit = first_fits(ok, n_d, D)
    desk_fit = (desk_fit & active[:, None]).reshape(-1)
    desk_on = keep_random(desk_fit, rng.u((R * D,)), density, n_box)
    rows = jnp.concatenate([take_along(cen, pick), take_along(sides, pick)], -1).reshape(-1, 4)
    desks, n_desks = compact(rows, desk_on, n_box)
    n_c = rng.randint(spec.office_cylinders_min, spec.office_cylinders_max, (R,))
    rad = rng.uniform((R, C + T), spec.office_radius_min, spec.office_radius_max)
    cen = room_lo + rad[..., None] + rng.u((R, C + T, 2)) * jnp.maximum(room_ext - 2 * rad[..., None], 0.0)
    pick, circ_fit = first_fits(clear(lambda a, b: pt_seg_sq(cen[..., None, :], a, b), (c + rad) ** 2), n_c, C)
    circ_fit = (circ_fit & active[:, None]).reshape(-1)
    circ_on = keep_random(circ_fit, rng.u((R * C,)), density, n_circ)
    rows = jnp.concatenate([take_along(cen, pick), take_along(rad[..., None], pick)], -1).reshape(-1, 3)
    circles, n_circles = compact(rows, circ_on, n_circ)
    requested = thin_count(jnp.sum(active * n_d), density) + thin_count(jnp.sum(active * n_c), density)
    fitted = thin_count(jnp.sum(desk_fit), density) + thin_count(jnp.sum(circ_fit), density)
    dropped = (fitted - jnp.sum(desk_on) - jnp.sum(circ_on)).astype(jnp.int32)
    return Furniture(desks, n_desks, circles, n_circles, requested, dropped)


def _grid(rng: Uniforms, spec: RoomSpec, Lx, Ly):
    """Step 1 in the frame: the nx x ny rooms used of the NX x NY grid (room r = iy * NX + ix;
    `active`: r is used), their corners lo, hi [R, 2], and their hubs (a random point of each core)."""
    c, (NX, NY) = spec.clearance, office_grid(spec)
    fit_x = jnp.clip(jnp.floor(Lx / spec.office_room_min), 1, NX)
    fit_y = jnp.clip(jnp.floor(Ly / spec.office_room_min), 1, NY)
    nx = jnp.clip(rng.randint(spec.office_cols_min, spec.office_cols_max), 1, fit_x).astype(jnp.int32)
    ny = jnp.clip(rng.randint(spec.office_rows_min, spec.office_rows_max), 1, fit_y).astype(jnp.int32)
    X = grid_lines(rng.u((NX + 1,)), nx, NX, Lx, spec.office_jitter)
    Y = grid_lines(rng.u((NY + 1,)), ny, NY, Ly, spec.office_jitter)
    ix, iy = (a.reshape(-1) for a in np.meshgrid(np.arange(NX), np.arange(NY)))
    active = (ix < nx) & (iy < ny)
    lo, hi = jnp.stack([X[ix], Y[iy]], -1), jnp.stack([X[ix + 1], Y[iy + 1]], -1)
    hubs = lo + c + rng.u((NX * NY, 2)) * jnp.maximum(hi - lo - 2 * c, 0.0)
    return nx, ny, ix, iy, active, lo, hi, hubs


def _placed(f: Furniture, spec: RoomSpec, flip):
    """The furniture in room coordinates: (desks on [office_boxes], their rows (centre, sides), the
    desks' edge segments [office_boxes, 4, 4], the cylinder rows)."""
    _, n_box, _ = office_slots(spec)
    box_on = jnp.arange(n_box) < f.n_desks
    rows = jnp.concatenate([swap_xy(f.desks[:, :2], flip), swap_xy(f.desks[:, 2:], flip)], -1)
    edges = jnp.where(box_on[:, None, None], box_edges(rows[:, :2], rows[:, 2:]), 0.0)
    return (
        box_on,
        jnp.where(box_on[:, None], rows, 0.0),
        edges,
        jnp.concatenate([swap_xy(f.circles[:, :2], flip), f.circles[:, 2:]], -1),
    )


def build(rng: Uniforms, spec: RoomSpec, density=1.0):
    """One office floor (World, info); see the module docstring."""
    c = spec.clearance
    W, H = room_size(rng, spec)
    flip = rng.u(()) < 0.5
    Lx, Ly = jnp.where(flip, H, W), jnp.where(flip, W, H)
    NX, NY = office_grid(spec)
    R = NX * NY
    nx, ny, ix, iy, active, lo, hi, hubs = _grid(rng, spec, Lx, Ly)

    # 2. Doors: the east wall (to room r + 1) and the north wall (to room r + NX) of every room.
    open_e, open_n = backtracker(rng.u(()), rng.u((max(2 * (R - 1), 0), 4)), nx, ny, NX, NY)
    e_door, e_w, e_pieces, e_on, e_near, e_far = _doors(rng, spec, lo, hi, (ix + 1 < nx) & active, open_e, 0, c)
    n_door, n_w, n_pieces, n_on, n_near, n_far = _doors(rng, spec, lo, hi, (iy + 1 < ny) & active, open_n, 1, c)
    east, north = np.flatnonzero(ix < NX - 1), np.flatnonzero(iy < NY - 1)  # the walls that can exist
    pieces = jnp.concatenate([e_pieces[east], n_pieces[north]]).reshape(-1, 4)
    piece_on = jnp.concatenate([e_on[east], n_on[north]]).reshape(-1)
    nxt_e, nxt_n = np.minimum(np.arange(R) + 1, R - 1), np.minimum(np.arange(R) + NX, R - 1)
    doors = jnp.concatenate([e_door, n_door])
    net_a = jnp.concatenate([hubs, e_near, e_far, hubs, n_near, n_far])
    net_b = jnp.concatenate([e_near, e_far, hubs[nxt_e], n_near, n_far, hubs[nxt_n]])
    net_on = jnp.concatenate([e_door, e_door, e_door, n_door, n_door, n_door])

    # 4. Goals and starts in the room cores, the starts in rooms without a goal.
    core = jnp.where(active, jnp.prod(jnp.maximum(hi - lo - 2 * c, 0.0), -1), 0.0)

    def in_room(u, w):
        r = pick_by_weight(u[..., 0], w)
        return lo[r] + c + u[..., 1:] * (hi[r] - lo[r] - 2 * c), hubs[r], r

    def sample_start(u, g_room, g_on):
        w = jnp.where(jnp.zeros(R, jnp.int32).at[g_room].add(g_on.astype(jnp.int32)) > 0, 0.0, core)
        return in_room(u, jnp.where(jnp.sum(w) > 0, w, core))

    ep, s_room, g_room = draw_endpoints(rng, spec, lambda u: in_room(u, core), sample_start, 3)
    ca, cb, con = ep.connectors()
    ends_room = jnp.concatenate([s_room, g_room])

    # 5. Furniture, tested against its room's part of the network: the hub's way to the door
    # crossings on its four sides, the crossings, and the connectors of the starts and goals in it.
    west, south = np.maximum(np.arange(R) - 1, 0), np.maximum(np.arange(R) - NX, 0)
    w_door, s_door = e_door[west] & (ix > 0), n_door[south] & (iy > 0)
    near = jnp.stack([e_near, e_far[west], n_near, n_far[south]], 1)  # [R, 4, 2]
    far = jnp.stack([e_far, e_near[west], n_far, n_near[south]], 1)
    side_on = jnp.stack([e_door, w_door, n_door, s_door], 1)
    la = jnp.concatenate([jnp.broadcast_to(hubs[:, None], near.shape), near, jnp.broadcast_to(ca, (R, *ca.shape))], 1)
    lb = jnp.concatenate([near, far, jnp.broadcast_to(cb, (R, *cb.shape))], 1)
    lon = jnp.concatenate([side_on, side_on, (ends_room[None] == jnp.arange(R)[:, None]) & con[None]], 1)

    f = _furniture(rng, spec, (lo, hi, active), (la, lb, lon), density)
    _, n_box, n_circ = office_slots(spec)

    # 6. Walls thinned like the furniture; the World in room coordinates.
    piece_on = keep_random(piece_on, rng.u(piece_on.shape), density, piece_on.shape[0])
    box_on, box_rows, edges, circles = _placed(f, spec, flip)
    segs = jnp.concatenate([jnp.where(piece_on[:, None], swap_xy(pieces, flip), 0.0), edges.reshape(-1, 4)])
    ep = flip_endpoints(ep, flip)
    world = assemble(spec, W, H, segs, circles, ep)
    res_a, res_b = swap_xy(jnp.concatenate([net_a, ca]), flip), swap_xy(jnp.concatenate([net_b, cb]), flip)
    n_walls = jnp.sum(piece_on).astype(jnp.int32)
    info = common_info(ep, res_a, res_b, jnp.concatenate([net_on, con])) | {
        "rooms": (nx * ny).astype(jnp.int32),
        "room_boxes": jnp.where(active[:, None], swap_xy(jnp.concatenate([lo, hi], -1), flip), 0.0),  # x0, y0, x1, y1
        "doors": jnp.sum(doors).astype(jnp.int32),
        "door_width": jnp.concatenate([e_w, n_w]),  # 0 where no door
        "start_room": s_room,
        "goal_room": g_room,
        "rooms_apart": jnp.all(~ep.start_on[:, None] | ~ep.goal_on[None] | (s_room[:, None] != g_room[None])),
        "wall_pieces": n_walls,
        "desks": jnp.minimum(f.n_desks, n_box).astype(jnp.int32),
        "cylinders": jnp.minimum(f.n_circles, n_circ).astype(jnp.int32),
        "obstacles": (n_walls + jnp.minimum(f.n_desks, n_box) + jnp.minimum(f.n_circles, n_circ)).astype(jnp.int32),
        "box_rows": box_rows,
        "box_on": box_on,
        # furniture that fitted but found no slot (office_boxes, office_circles), and what was asked for
        "furniture_dropped": f.dropped,
        "furniture_requested": f.requested,
    }
    return world, info
