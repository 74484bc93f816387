"""The ``warehouse`` family: rows of rack sections (boxes) with aisles between the rows, cross-aisles
between the sections and a perimeter aisle along the walls, plus loose pallets (docs/generator.md).

The layout is drawn in a frame whose x axis runs along the racks; with probability 1/2 the frame
is turned (x and y swapped), so racks run along either side of the room.

1. Room size; aisle width a, rack depth d, section length l (uniform in their ranges).
2. Rows: n_r = floor((Ly - a) / (d + a)) rows of depth d, a apart, centred: the two perimeter
   aisles (between the block and the walls) take the rest, m_y >= a each; sections likewise
   along x (n_s sections of length l, cross-aisles a, perimeter m_x >= a). Each of the
   n_r x n_s sections is there with probability `rack_fill`.
3. The aisle network: the centre line of every aisle (n_r + 1 along x, n_s + 1 along y); every
   line along x crosses every line along y, so the network is connected.
4. Goals and starts: a point on a random aisle's centre line (by length), moved across the aisle
   (width g: a, or m at the perimeter) by at most g / 2 - c; its connector is the perpendicular
   back to the centre line.
5. Pallets (axis-aligned boxes): `tries` candidates each, the first that keeps c from the aisle
   network and the connectors and does not overlap a rack is placed, else it is dropped.
6. The racks, then the pallets, fill the first `warehouse_boxes` box slots (4 segment rows each);
   a room with more boxes loses the last ones (info["boxes_dropped"]; 11 rooms in 16,384 of the
   default spec, docs/generator.md): fewer obstacles, never a closed passage.

Solvable: an aisle's band (g >= a wide, between rack faces or a rack face and a wall) holds no
rack, so its centre line keeps g / 2 >= a / 2 > c from racks and walls (check_spec: aisle_width_min > 2c),
and a connector stays in its band at least c from the band's sides; pallets keep c by step 5.
Density d keeps floor(d n) of the racks (a random subset) and of the pallets.
"""

from __future__ import annotations

import jax.numpy as jnp

from fedjax_nav.worlds.layout import (
    assemble,
    box_edges,
    common_info,
    compact,
    endpoints,
    room_size,
    thin_by_rank,
    thin_count,
)
from fedjax_nav.worlds.rooms import RoomSpec
from fedjax_nav.worlds.sampling import Uniforms, aabb_gap_sq, all_clear, first_true, take_rows
from fedjax_nav.worlds.shapes import warehouse_slots


def _swap(p, flip):
    """Frame -> room coordinates: swap x and y of every point (last axis a multiple of 2)."""
    q = p.reshape(*p.shape[:-1], -1, 2)
    return jnp.where(flip, q[..., ::-1], q).reshape(p.shape)


def build(rng: Uniforms, spec: RoomSpec, density=1.0):
    """One warehouse room (World, info); see the module docstring."""
    c = spec.clearance
    W, H = room_size(rng, spec)
    flip = rng.u(()) < 0.5
    Lx, Ly = jnp.where(flip, H, W), jnp.where(flip, W, H)
    a = rng.uniform((), spec.aisle_width_min, spec.aisle_width_max)
    d = rng.uniform((), spec.rack_depth_min, spec.rack_depth_max)
    ln = rng.uniform((), spec.rack_length_min, spec.rack_length_max)
    R, K = warehouse_slots(spec)
    n_r = jnp.clip(jnp.floor((Ly - a) / (d + a)), 0, R)
    n_s = jnp.clip(jnp.floor((Lx - a) / (ln + a)), 0, K)
    # the block of racks is centred; the perimeter aisles take what is left (>= a by the floor above)
    my = jnp.where(n_r > 0, (Ly - n_r * d - (n_r - 1) * a) / 2, Ly)
    mx = jnp.where(n_s > 0, (Lx - n_s * ln - (n_s - 1) * a) / 2, Lx)

    # Racks: section (i, j) spans x0 + [0, ln], y0 + [0, d].
    i, j = jnp.meshgrid(jnp.arange(R, dtype=jnp.float32), jnp.arange(K, dtype=jnp.float32), indexing="ij")
    rack_c = jnp.stack([-Lx / 2 + mx + j * (ln + a) + ln / 2, -Ly / 2 + my + i * (d + a) + d / 2], -1).reshape(-1, 2)
    rack_full = ((i < n_r) & (j < n_s) & (rng.u((R, K)) < spec.rack_fill)).reshape(-1)
    rack_on = thin_by_rank(rack_full, rng.u((R * K,)), density)
    rack_side = jnp.broadcast_to(jnp.stack([ln, d]), (R * K, 2))

    # Aisles: R + 1 centre lines along x, then K + 1 along y; (start, end, width, unit normal).
    aisle_a, aisle_b, aisle_w, aisle_n, aisle_on = _aisles(R, K, Lx, Ly, mx, my, a, d, ln, n_r, n_s)
    length = jnp.where(aisle_on, jnp.linalg.norm(aisle_b - aisle_a, axis=-1), 0.0)
    cum = jnp.cumsum(length)

    def sample(u):  # a point of a random aisle (by length), moved across it, and its foot on the centre line
        k = jnp.minimum(jnp.sum(cum <= u[..., :1] * cum[-1], -1), R + K + 1)
        foot = aisle_a[k] + u[..., 1:2] * (aisle_b[k] - aisle_a[k])
        off = (2 * u[..., 2:3] - 1) * jnp.maximum(aisle_w[k][..., None] / 2 - c, 0.0)
        return foot + off * aisle_n[k], foot

    ep = endpoints(rng, spec, sample, 3)
    ca, cb, con = ep.connectors()
    res_a, res_b = jnp.concatenate([aisle_a, ca]), jnp.concatenate([aisle_b, cb])
    res_on = jnp.concatenate([aisle_on, con])

    # Pallets: axis-aligned boxes off the network and off the racks.
    pal_c, pal_s, pal_on, n_pal = _pallets(
        rng, spec, Lx, Ly, (res_a, res_b, res_on), (rack_c, rack_side, rack_full), density
    )

    # racks, then pallets, packed into the spec's `warehouse_boxes` slots (the shape stays small:
    # the slots of every layout would be 4x what a room holds on average)
    rows = jnp.concatenate([jnp.concatenate([rack_c, rack_side], -1), jnp.concatenate([pal_c, pal_s], -1)])
    placed = jnp.concatenate([rack_on, pal_on])
    rows, n_boxes = compact(rows, placed, spec.warehouse_boxes)
    box_on = jnp.arange(spec.warehouse_boxes) < n_boxes
    edges = jnp.where(box_on[:, None, None], _swap(box_edges(rows[:, :2], rows[:, 2:]), flip), 0.0)
    ep = ep._replace(
        starts=_swap(ep.starts, flip),
        start_anchor=_swap(ep.start_anchor, flip),
        goals=_swap(ep.goals, flip),
        goal_anchor=_swap(ep.goal_anchor, flip),
    )
    world = assemble(spec, W, H, edges.reshape(-1, 4), jnp.zeros((0, 3), jnp.float32), ep)
    rows = jnp.concatenate(
        [_swap(rows[:, :2], flip), _swap(rows[:, 2:], flip), jnp.zeros((spec.warehouse_boxes, 1))], -1
    )
    info = common_info(ep, _swap(res_a, flip), _swap(res_b, flip), res_on) | {
        "racks": jnp.minimum(jnp.sum(rack_on), spec.warehouse_boxes).astype(jnp.int32),  # racks come first
        "pallets": (
            jnp.minimum(n_boxes, spec.warehouse_boxes) - jnp.minimum(jnp.sum(rack_on), spec.warehouse_boxes)
        ).astype(jnp.int32),
        "pallets_requested": thin_count(n_pal, density),
        "box_rows": jnp.where(box_on[:, None], rows, 0.0),
        "box_on": box_on,
        "boxes_dropped": jnp.maximum(n_boxes - spec.warehouse_boxes, 0).astype(jnp.int32),
        "aisle_width": a,
    }
    return world, info


def _aisles(R: int, K: int, Lx, Ly, mx, my, a, d, ln, n_r, n_s):
    """The aisles' centre lines in the frame: R + 1 along x, then K + 1 along y; (start, end, width,
    unit normal across, on) of each (n_r rows and n_s sections of racks, d deep, ln long, a apart)."""
    k_r, k_s = jnp.arange(R + 1, dtype=jnp.float32), jnp.arange(K + 1, dtype=jnp.float32)
    ya = jnp.where(
        k_r == 0, -Ly / 2 + my / 2, jnp.where(k_r == n_r, Ly / 2 - my / 2, -Ly / 2 + my + k_r * (d + a) - a / 2)
    )
    xa = jnp.where(
        k_s == 0, -Lx / 2 + mx / 2, jnp.where(k_s == n_s, Lx / 2 - mx / 2, -Lx / 2 + mx + k_s * (ln + a) - a / 2)
    )
    wy = jnp.where((k_r == 0) | (k_r == n_r), my, a)
    wx = jnp.where((k_s == 0) | (k_s == n_s), mx, a)
    x_ends = jnp.broadcast_to(jnp.stack([-Lx / 2 + mx / 2, Lx / 2 - mx / 2]), (R + 1, 2))
    y_ends = jnp.broadcast_to(jnp.stack([-Ly / 2 + my / 2, Ly / 2 - my / 2]), (K + 1, 2))
    aisle_a = jnp.concatenate([jnp.stack([x_ends[:, 0], ya], -1), jnp.stack([xa, y_ends[:, 0]], -1)])
    aisle_b = jnp.concatenate([jnp.stack([x_ends[:, 1], ya], -1), jnp.stack([xa, y_ends[:, 1]], -1)])
    aisle_w = jnp.concatenate([wy, wx])
    aisle_n = jnp.concatenate(
        [jnp.tile(jnp.array([[0.0, 1.0]]), (R + 1, 1)), jnp.tile(jnp.array([[1.0, 0.0]]), (K + 1, 1))]
    )
    aisle_on = jnp.concatenate([k_r <= n_r, k_s <= n_s])
    return aisle_a, aisle_b, aisle_w, aisle_n, aisle_on


def _pallets(rng: Uniforms, spec: RoomSpec, Lx, Ly, network, racks, density):
    """The pallets in the frame: `tries` candidates each, the first that keeps c from the `network`
    (res_a, res_b, res_on) and overlaps none of the `racks` (centres, sides, full at density 1).
    Returns their centres, sides, which are placed, and the number requested."""
    c = spec.clearance
    res_a, res_b, res_on = network
    rack_c, rack_side, rack_full = racks
    P, T = spec.pallets_max, spec.tries
    n_pal = rng.randint(spec.pallets_min, spec.pallets_max) if P else jnp.int32(0)
    sides = rng.uniform((P, T, 2), spec.pallet_side_min, spec.pallet_side_max)
    half = jnp.stack([Lx, Ly]) / 2 - sides / 2
    cen = -half + rng.u((P, T, 2)) * 2 * half
    # every network segment runs along an axis (aisle centre lines, connectors across them), so its
    # distance to an axis-aligned pallet is the gap between two axis-aligned boxes (exact)
    lo, hi = cen - sides / 2, cen + sides / 2
    clear = all_clear(
        lambda a, b: aabb_gap_sq(jnp.minimum(a, b), jnp.maximum(a, b), lo, hi), res_a, res_b, res_on, c * c
    )  # [P, T]
    gap = jnp.abs(cen[:, :, None] - rack_c) - (sides[:, :, None] + rack_side) / 2  # [P, T, racks, 2]
    apart = jnp.all(~rack_full | jnp.any(gap >= 0.0, -1), -1)  # the racks at density 1: pallets do not move with it
    t, any_ok = first_true(clear & apart)
    pal_on = any_ok & (jnp.arange(P) < thin_count(n_pal, density))
    pal_c, pal_s = take_rows(cen, t), take_rows(sides, t)
    return pal_c, pal_s, pal_on, n_pal
