"""The ``corridors`` family: a spine corridor with branches that end in side rooms or dead ends, turns
at its ends, and boxes of clutter (docs/generator.md).

The layout is drawn in a frame whose x axis runs along the spine, turned by 90 degrees (x and y
swapped) in half of the rooms. Walls are segments; what lies behind them is closed off.

1. Floor size (10-18 m); corridor width a ~ U[corridor_width_*] (the spine and every branch); the
   spine's centre line y = y_s in the middle half of the floor, at least corridor_room_min left
   beyond each of its sides.
2. n ~ U{corridor_branches_*} branches, one per slot (the spine's length cut into n equal slots),
   each off a random side of the spine. A branch ends in a side room with probability
   corridor_rooms (sides ~ U[corridor_room_*], the width at most the slot's, the depth at most
   what is left to the outer wall; the branch before it of random length, 0 for a door straight
   off the spine), else in a dead end 0.6-1 of the way to the outer wall.
3. Each end of the spine turns into its outermost branch with probability corridor_turns (with one
   branch, one end at most; the branch then sits at the far end of its slot): an L where one end
   turns, a U or a comb where both do; else the spine runs on to the outer wall.
4. The clear network: the spine's centre line (a / 2 from its ends), every branch's centre line
   from the spine's to a / 2 before a dead end or c into a side room, then to the room's hub (a
   random point of its core, the room shrunk by c).
5. Starts: a point of a random centre line (by length) moved across the corridor by at most
   a / 2 - c, the connector back to the line (the base families' distance rule, 64 candidates);
   goals at the end of a random branch: in its side room's core (the connector to the hub), or
   in the last metre of a dead end, moved across as the starts are.
6. Clutter: corridor_boxes_* axis-aligned boxes, each centred in the spine, a branch or a side
   room (by area) and inside the floor, `tries` candidates, the first that keeps c from the network
   is placed; a box may reach into a wall.
7. Density d keeps floor(d n) of the n wall segments (a random rank) and of the boxes.

Solvable: every centre line keeps a / 2 > c (`check_spec`: corridor_width_min > 2 c) from the
walls beside it, and from the walls it meets: a branch leaves the spine through an opening of
width a centred on it and enters a side room through one (corridor_room_min >= corridor_width_max
+ 2 c, so the opening has c beside it), a dead end's line stops a / 2 before its cap, the spine's
a / 2 before its ends. A room's core keeps c from the room's walls, and slots keep rooms and
branches apart. A start's connector stays in its corridor's band, at least c from its sides (at
the openings: c from their jambs); boxes keep c by step 6. So start -> connector -> centre lines
-> connector -> goal keeps c from every wall and box.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

from fedjax_nav.worlds.layout import assemble, box_edges, common_info, room_size, thin_count
from fedjax_nav.worlds.office import draw_endpoints, flip_endpoints, keep_random, pick_by_weight, swap_xy
from fedjax_nav.worlds.rooms import RoomSpec
from fedjax_nav.worlds.sampling import Uniforms, first_true, seg_aabb_sq, take_rows


def _h(x0, x1, y):
    """Horizontal segments (x0, y) - (x1, y), broadcast."""
    x0, x1, y = jnp.broadcast_arrays(x0, x1, y)
    return jnp.stack([x0, y, x1, y], -1)


def _v(x, y0, y1):
    """Vertical segments (x, y0) - (x, y1), broadcast."""
    x, y0, y1 = jnp.broadcast_arrays(x, y0, y1)
    return jnp.stack([x, y0, x, y1], -1)


class Spine(NamedTuple):
    """The spine: its centre line y = ys, width a, its ends (turned into a branch or at the floor's)."""

    a: object
    ys: object
    x_left: object
    x_right: object
    turn_l: object
    turn_r: object


class Branches(NamedTuple):
    """The branches [K], one per slot (`on`: the first n_b), in the frame along the spine."""

    on: object
    side: object  # +1: the branch leaves the spine upwards
    room: object  # ends in a side room (else a dead end)
    rw: object  # what the branch takes of its slot (its room's width, or a)
    xb: object  # the branch's axis
    rd: object  # its side room's depth
    bl: object  # its length from the spine's side
    y0: object  # from the spine's side ...
    ye: object  # ... to its end
    yf: object  # its side room's far wall
    s0: object  # its slot [s0, s1]
    s1: object


def _layout(rng: Uniforms, spec: RoomSpec, Lx, Ly) -> tuple[Spine, Branches, object]:
    """Steps 1-3 of the module docstring in the frame: the spine, its branches and their turns, and
    the number of branches."""
    K, rmin, rmax = spec.corridor_branches_max, spec.corridor_room_min, spec.corridor_room_max
    a = rng.uniform((), spec.corridor_width_min, spec.corridor_width_max)
    n_b = rng.randint(spec.corridor_branches_min, spec.corridor_branches_max)
    ys_hi = jnp.maximum(jnp.minimum(Ly / 4, Ly / 2 - a / 2 - rmin), 0.0)  # the middle half, rooms fit either side
    ys = (2 * rng.u(()) - 1) * ys_hi

    # 2. Branches, one per slot; side rooms or dead ends.
    k = jnp.arange(K)
    on = k < n_b
    slot = Lx / n_b
    s0 = -Lx / 2 + k * slot
    s1 = s0 + slot
    side = jnp.where(rng.u((K,)) < 0.5, 1.0, -1.0)
    room = rng.u((K,)) < spec.corridor_rooms
    rw = jnp.where(room, jnp.minimum(rng.uniform((K,), rmin, rmax), slot), a)
    # 3. Turns: an end of the spine turns into its outermost branch, moved to the end of its slot (one
    # branch: one end at most), so that the L, U or comb spans the floor.
    turn_l = rng.u(()) < spec.corridor_turns
    turn_r = (rng.u(()) < spec.corridor_turns) & ~(turn_l & (n_b == 1))
    xb = s0 + rw / 2 + rng.u((K,)) * jnp.maximum(slot - rw, 0.0)
    xb = jnp.where(turn_l & (k == 0), s0 + rw / 2, jnp.where(turn_r & (k == n_b - 1), s1 - rw / 2, xb))
    space = Ly / 2 - side * ys - a / 2  # from the spine's side to the outer wall (>= corridor_room_min)
    rd = jnp.minimum(rng.uniform((K,), rmin, rmax), space)
    u_len = rng.u((K,))
    bl = jnp.where(room, u_len * (space - rd), jnp.maximum(space * (0.6 + 0.4 * u_len), a))
    y0, ye = ys + side * a / 2, ys + side * (a / 2 + bl)
    yf = ye + side * rd
    x_left = jnp.where(turn_l, xb[0] - a / 2, -Lx / 2)
    x_right = jnp.where(turn_r, xb[jnp.maximum(n_b - 1, 0)] + a / 2, Lx / 2)
    spine = Spine(a, ys, x_left, x_right, turn_l, turn_r)
    return spine, Branches(on, side, room, rw, xb, rd, bl, y0, ye, yf, s0, s1), n_b


def _walls(sp: Spine, br: Branches):
    """Walls f32[rows, 4] and which exist: per slot the spine's two pieces on either side of it
    (around an opening), the branch's sides, its dead end or its room (entry either side of the
    opening, far wall, sides); the caps."""
    a, ys, xb, rw, on, ye, yf = sp.a, sp.ys, br.xb, br.rw, br.on, br.ye, br.yf
    rows, row_on = [], []
    for sgn in (1.0, -1.0):
        here = on & (br.side == sgn)
        y = ys + sgn * a / 2
        lo1, hi1 = jnp.maximum(br.s0, sp.x_left), jnp.minimum(jnp.where(here, xb - a / 2, br.s1), sp.x_right)
        lo2, hi2 = jnp.maximum(jnp.where(here, xb + a / 2, br.s1), sp.x_left), jnp.minimum(br.s1, sp.x_right)
        rows += [_h(lo1, hi1, y), _h(lo2, hi2, y)]
        row_on += [on & (hi1 > lo1), on & (hi2 > lo2)]
    rows += [_v(xb - a / 2, br.y0, ye), _v(xb + a / 2, br.y0, ye), _h(xb - a / 2, xb + a / 2, ye)]
    row_on += [on & (br.bl > 0), on & (br.bl > 0), on & ~br.room]
    rows += [_h(xb - rw / 2, xb - a / 2, ye), _h(xb + a / 2, xb + rw / 2, ye), _h(xb - rw / 2, xb + rw / 2, yf)]
    rows += [_v(xb - rw / 2, ye, yf), _v(xb + rw / 2, ye, yf)]
    row_on += [on & br.room] * 5
    walls = jnp.concatenate(
        [jnp.stack(rows, 1).reshape(-1, 4), _v(jnp.stack([sp.x_left, sp.x_right]), ys - a / 2, ys + a / 2)]
    )
    return walls, jnp.concatenate([jnp.stack(row_on, 1).reshape(-1), jnp.stack([sp.turn_l, sp.turn_r])])


def _areas(sp: Spine, br: Branches):
    """The spine, the branches and the side rooms as rectangles (lo, hi [1 + 2K, 2]) and the area
    of those that exist (what step 6 draws its boxes' places by)."""
    a, ys, xb, rw = sp.a, sp.ys, br.xb, br.rw
    rect_lo = jnp.concatenate(
        [
            jnp.stack([sp.x_left, ys - a / 2])[None],
            jnp.stack([xb - a / 2, jnp.minimum(br.y0, br.ye)], -1),
            jnp.stack([xb - rw / 2, jnp.minimum(br.ye, br.yf)], -1),
        ]
    )
    rect_hi = jnp.concatenate(
        [
            jnp.stack([sp.x_right, ys + a / 2])[None],
            jnp.stack([xb + a / 2, jnp.maximum(br.y0, br.ye)], -1),
            jnp.stack([xb + rw / 2, jnp.maximum(br.ye, br.yf)], -1),
        ]
    )
    area = jnp.prod(rect_hi - rect_lo, -1) * jnp.concatenate([jnp.ones((1,), bool), br.on, br.on & br.room])
    return rect_lo, rect_hi, area


def _clutter(rng: Uniforms, spec: RoomSpec, Lx, Ly, rects, res, density):
    """Step 6: (boxes on [P], centres, sides [P, 2] in the frame, boxes asked for): each in a
    rectangle of `rects` (by area) inside the floor, the first of `tries` that keeps c from the
    network `res` (its segments' ends and whether each exists)."""
    (rect_lo, rect_hi, area), (res_a, res_b, res_on), c = rects, res, spec.clearance
    P, T = spec.corridor_boxes_max, spec.tries
    n_box = rng.randint(spec.corridor_boxes_min, spec.corridor_boxes_max) if P else jnp.int32(0)
    j = pick_by_weight(rng.u((P, T)), area)
    sides = rng.uniform((P, T, 2), spec.corridor_box_side_min, spec.corridor_box_side_max)
    cen = rect_lo[j] + rng.u((P, T, 2)) * (rect_hi[j] - rect_lo[j])
    cen = jnp.clip(cen, -jnp.stack([Lx, Ly]) / 2 + sides / 2, jnp.stack([Lx, Ly]) / 2 - sides / 2)  # inside the floor
    # one broadcast pass over the network's segments [P, T, segments] (an unrolled loop compiles 3x longer)
    ok = jnp.all(~res_on | (seg_aabb_sq(res_a, res_b, cen[..., None, :], sides[..., None, :] / 2) >= c * c), -1)
    t, any_ok = first_true(ok)
    box_on = any_ok & (jnp.arange(P) < thin_count(n_box, density))
    return box_on, take_rows(cen, t), take_rows(sides, t), n_box


def build(rng: Uniforms, spec: RoomSpec, density=1.0):
    """One corridors room (World, info); see the module docstring."""
    c = spec.clearance
    W, H = room_size(rng, spec)
    flip = rng.u(()) < 0.5
    Lx, Ly = jnp.where(flip, H, W), jnp.where(flip, W, H)
    K = spec.corridor_branches_max
    sp, br, n_b = _layout(rng, spec, Lx, Ly)
    a, ys, on, side, room, rw, xb, rd, bl, ye = sp.a, sp.ys, br.on, br.side, br.room, br.rw, br.xb, br.rd, br.bl, br.ye
    walls, wall_on = _walls(sp, br)

    # 4. The clear network: the spine's and the branches' centre lines, the ways into the rooms.
    hub = jnp.stack(
        [xb - rw / 2 + c + rng.u((K,)) * (rw - 2 * c), ye + side * (c + rng.u((K,)) * jnp.maximum(rd - 2 * c, 0.0))], -1
    )
    door_in = jnp.stack([xb, ye + side * c], -1)
    line_a = jnp.concatenate(
        [jnp.stack([sp.x_left + a / 2, ys])[None], jnp.stack([xb, jnp.broadcast_to(ys, (K,))], -1)]
    )
    line_b = jnp.concatenate(
        [jnp.stack([sp.x_right - a / 2, ys])[None], jnp.stack([xb, jnp.where(room, ye, ys + side * bl)], -1)]
    )
    line_on = jnp.concatenate([jnp.ones((1,), bool), on])
    normal = jnp.concatenate([jnp.array([[0.0, 1.0]]), jnp.tile(jnp.array([[1.0, 0.0]]), (K, 1))])
    length = jnp.where(line_on, jnp.linalg.norm(line_b - line_a, axis=-1), 0.0)
    half = jnp.maximum(a / 2 - c, 0.0)

    def sample_start(u, *_):  # a point of a random centre line, moved across its corridor
        i = pick_by_weight(u[..., 0], length)
        foot = line_a[i] + u[..., 1:2] * (line_b[i] - line_a[i])
        return foot + ((2 * u[..., 2:3] - 1) * half) * normal[i], foot, i

    def sample_goal(u):  # the end of a random branch: its side room's core, or a dead end's last metre
        i = pick_by_weight(u[..., 0], on.astype(jnp.float32))
        in_room = jnp.stack(
            [xb[i] - rw[i] / 2 + c + u[..., 1] * (rw[i] - 2 * c), ye[i] + side[i] * (c + u[..., 2] * (rd[i] - 2 * c))],
            -1,
        )
        foot = jnp.stack([xb[i], ys + side[i] * (bl[i] - u[..., 1] * jnp.minimum(1.0, bl[i]))], -1)
        dead = foot + jnp.stack([(2 * u[..., 2] - 1) * half, jnp.zeros_like(u[..., 2])], -1)
        r = room[i][..., None]
        return jnp.where(r, in_room, dead), jnp.where(r, hub[i], foot), i + 1

    ep, s_line, g_line = draw_endpoints(rng, spec, sample_goal, sample_start, 3)
    ca, cb, con = ep.connectors()
    res = (jnp.concatenate([line_a, door_in, ca]), jnp.concatenate([line_b, hub, cb]))
    res_on = jnp.concatenate([line_on, on & room, con])
    rect_lo, rect_hi, area = rects = _areas(sp, br)
    box_on, box_c, box_s, n_box = _clutter(rng, spec, Lx, Ly, rects, (*res, res_on), density)
    box_c, box_s = swap_xy(box_c, flip), swap_xy(box_s, flip)
    edges = jnp.where(box_on[:, None, None], box_edges(box_c, box_s), 0.0)

    # 7. Walls thinned; the World in room coordinates.
    wall_on = keep_random(wall_on, rng.u(wall_on.shape), density, wall_on.shape[0])
    segs = jnp.concatenate([jnp.where(wall_on[:, None], swap_xy(walls, flip), 0.0), edges.reshape(-1, 4)])
    ep = flip_endpoints(ep, flip)
    world = assemble(spec, W, H, segs, jnp.zeros((0, 3), jnp.float32), ep)
    room_lo, room_hi = rect_lo[1 + K :], rect_hi[1 + K :]
    info = common_info(ep, swap_xy(res[0], flip), swap_xy(res[1], flip), res_on) | {
        "branches": n_b.astype(jnp.int32),
        "side_rooms": jnp.sum(on & room).astype(jnp.int32),
        "turns": (sp.turn_l.astype(jnp.int32) + sp.turn_r.astype(jnp.int32)),
        "corridor_width": a,
        "wall_rows": jnp.sum(wall_on).astype(jnp.int32),
        "boxes": jnp.sum(box_on).astype(jnp.int32),
        "boxes_requested": thin_count(n_box, density),
        "box_rows": jnp.where(
            box_on[:, None], jnp.concatenate([box_c, box_s, jnp.zeros((box_on.shape[0], 1))], -1), 0.0
        ),
        "box_on": box_on,
        "branch_on": on,
        "side_room": on & room,
        "room_boxes": jnp.concatenate([swap_xy(room_lo, flip), swap_xy(room_hi, flip)], -1),  # x0, y0, x1, y1
        "branch_end": swap_xy(jnp.stack([xb, ye], -1), flip),  # where a branch meets its room or dead end
        "start_line": s_line,  # 0: the spine, 1 + i: branch i
        "goal_branch": g_line - 1,
    }
    return world, info
