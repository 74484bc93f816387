"""The ``forest`` family: 40-150 trunks (cylinders) spread over the room on a jittered grid, kept
off a trail network that joins every start and goal (docs/generator.md).

1. Room size; the number of trunks n; the trail network: `trail_points` waypoints uniform in the
   room shrunk by c = D_c + clearance_margin, each joined to the nearest earlier one (a tree).
2. Goals and starts uniform in the shrunk room, each with a connector to its nearest waypoint.
3. Trunks: the room is cut into nx x ny >= n cells (nx = ceil(sqrt(n W / H))) and the trunks
   take n distinct cells in a random order; each trunk draws `tries` (radius, centre in its
   cell) candidates and keeps the first whose distance to every trail and connector is at least
   c, else it is dropped. One trunk per cell spreads them evenly (no clumps, no empty halves).

Solvable: trails and connectors lie in the shrunk room (convex: c from the outer walls) and keep
c from every trunk, so start -> connector -> trails -> connector -> goal keeps c from everything.
Density d keeps the first floor(d n) trunks (a random subset of the cells): fewer obstacles.
"""

from __future__ import annotations

import math

import jax.numpy as jnp

from fedjax_nav.worlds.layout import (
    assemble,
    common_info,
    room_size,
    thin_count,
    trails,
)
from fedjax_nav.worlds.rooms import RoomSpec
from fedjax_nav.worlds.sampling import Uniforms, all_clear, first_true, pt_seg_sq, take_rows


def _cell_slots(n_max: int) -> int:
    """Static cell slots: nx * ny <= n + nx - 1 and nx <= sqrt(10 n) + 1 (aspect ratio <= 30 / 3)."""
    return n_max + math.isqrt(10 * n_max) + 2


def build(rng: Uniforms, spec: RoomSpec, density=1.0):
    """One forest room (World, info); see the module docstring."""
    c = spec.clearance
    W, H = room_size(rng, spec)
    n_req = rng.randint(spec.trees_min, spec.trees_max)
    pts, ep, res_a, res_b, res_on = trails(rng, spec, W, H, c)

    N, T, L = spec.trees_max, spec.tries, _cell_slots(spec.trees_max)
    n = jnp.maximum(n_req, 1).astype(jnp.float32)
    nx = jnp.ceil(jnp.sqrt(n * W / H))
    ny = jnp.ceil(n / nx)
    cell = jnp.arange(L)
    order = jnp.argsort(jnp.where(cell < nx * ny, rng.u((L,)), 2.0))[:N]  # n distinct cells, random order
    ix, iy = (order % nx.astype(jnp.int32)).astype(jnp.float32), (order // nx.astype(jnp.int32)).astype(jnp.float32)
    rad = rng.uniform((N, T), spec.trunk_radius_min, spec.trunk_radius_max)
    u = rng.u((N, T, 2))
    x = -W / 2 + (ix[:, None] + u[..., 0]) * (W / nx)
    y = -H / 2 + (iy[:, None] + u[..., 1]) * (H / ny)
    cen = jnp.stack([jnp.clip(x, -W / 2 + rad, W / 2 - rad), jnp.clip(y, -H / 2 + rad, H / 2 - rad)], -1)
    ok = all_clear(lambda a, b: pt_seg_sq(cen, a, b), res_a, res_b, res_on, (c + rad) ** 2)  # [N, T]
    t, any_ok = first_true(ok)
    on = any_ok & (jnp.arange(N) < thin_count(n_req, density))
    circles = jnp.where(on[:, None], jnp.concatenate([take_rows(cen, t), take_rows(rad, t)[:, None]], -1), 0.0)
    world = assemble(spec, W, H, jnp.zeros((0, 4), jnp.float32), circles, ep)
    info = common_info(ep, res_a, res_b, res_on) | {
        "trees": jnp.sum(on).astype(jnp.int32),
        "trees_requested": thin_count(n_req, density),
        "waypoints": pts,
    }
    return world, info
