"""The ``cave`` family: cellular-automaton occupancy on a grid, as the BARN benchmark worlds are made,
carved around a trail network and drawn as its outline (docs/generator.md).

1. Room size; cell side s (uniform in [cave_cell_min, cave_cell_max]); the grid nx = floor(W / s)
   by ny = floor(H / s) cells of W / nx x H / ny, filling the room exactly.
2. The trail network and the starts and goals with their connectors, as in the forest family.
3. Occupancy: each cell occupied with probability p ~ U[cave_fill_min, cave_fill_max], then
   `cave_smoothing` steps of the 4-5 rule (an occupied cell stays occupied with at least 4
   occupied of its 8 neighbours, a free cell becomes occupied with at least 5; outside the grid
   counts as free, so the rock forms islands rather than hugging the walls). Before and after
   every step the cells that come closer than c = D_c + clearance_margin to a trail or connector
   (exact segment-to-cell distances) are freed. The density knob d keeps floor(d n) of the n
   rock islands (4-connected), whole: a random subset, nested across densities.
4. The outline: every side between an occupied and a free cell, merged into runs along each grid
   line, the first `cave_segments` runs as segments (sides on the outer walls need none). A cave
   whose outline has more runs loses the rest (info["outline_dropped"]; 0 in the measured rooms
   of the default spec, docs/generator.md): that opens a blob, it never closes a passage.

Solvable: every outline segment is a side of an occupied cell, which keeps c from every trail and
connector, and trails and connectors lie in the room shrunk by c; so start -> connector -> trails
-> connector -> goal keeps c from everything. A sparser cave's rock is a subset of a denser one's.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fedjax_nav.worlds.layout import (
    assemble,
    common_info,
    compact,
    grid_runs,
    room_size,
    thin_by_rank,
    trails,
)
from fedjax_nav.worlds.rooms import RoomSpec
from fedjax_nav.worlds.sampling import Uniforms, all_clear, seg_aabb_sq
from fedjax_nav.worlds.shapes import cave_grid

OUTSIDE = False  # cells beyond the grid count as free: rock in islands, not hugging the walls (BARN-like)


def smooth(occ, valid, carved):
    """One step of the 4-5 rule on occ bool[NY, NX]; cells outside `valid` count as OUTSIDE."""
    full = jnp.pad(jnp.where(valid, occ, OUTSIDE), 1, constant_values=OUTSIDE)
    NY, NX = occ.shape
    around = sum(
        full[1 + dy : 1 + dy + NY, 1 + dx : 1 + dx + NX].astype(jnp.int32)
        for dy in (-1, 0, 1)
        for dx in (-1, 0, 1)
        if dy or dx
    )
    return jnp.where(occ, around >= 4, around >= 5) & valid & ~carved


def islands(occ, steps: int):
    """Labels i32[NY, NX] of the 4-connected islands of occ: the least cell index of the island
    (free cells: NY * NX), by `steps` rounds of passing the least label to the neighbours (exact
    for islands whose cells are at most `steps` steps from their least cell; a longer one may
    keep two labels and be thinned as two islands)."""
    NY, NX = occ.shape
    free = NY * NX

    def spread(_, lab):
        p = jnp.pad(lab, 1, constant_values=free)
        least = jnp.minimum(
            jnp.minimum(lab, jnp.minimum(p[:-2, 1:-1], p[2:, 1:-1])), jnp.minimum(p[1:-1, :-2], p[1:-1, 2:])
        )
        return jnp.where(occ, least, free)

    return jax.lax.fori_loop(0, steps, spread, jnp.where(occ, jnp.arange(free).reshape(NY, NX), free))


def build(rng: Uniforms, spec: RoomSpec, density=1.0):
    """One cave room (World, info); see the module docstring."""
    c = spec.clearance
    W, H = room_size(rng, spec)
    NX, NY = cave_grid(spec)
    s = rng.uniform((), spec.cave_cell_min, spec.cave_cell_max)
    nx = jnp.clip(jnp.floor(W / s), 1, NX).astype(jnp.int32)
    ny = jnp.clip(jnp.floor(H / s), 1, NY).astype(jnp.int32)
    sx, sy = W / nx, H / ny
    fill = rng.uniform((), spec.cave_fill_min, spec.cave_fill_max)
    pts, ep, res_a, res_b, res_on = trails(rng, spec, W, H, c)

    gx, gy = jnp.meshgrid(jnp.arange(NX, dtype=jnp.float32), jnp.arange(NY, dtype=jnp.float32))
    valid = (gx < nx) & (gy < ny)
    ctr = jnp.stack([-W / 2 + (gx + 0.5) * sx, -H / 2 + (gy + 0.5) * sy], -1)  # [NY, NX, 2]
    half = jnp.stack([sx, sy]) / 2
    carved = ~all_clear(lambda a, b: seg_aabb_sq(a, b, ctr, half), res_a, res_b, res_on, c * c)  # [NY, NX]
    occ = (rng.u((NY, NX)) < fill) & valid & ~carved
    for _ in range(spec.cave_smoothing):
        occ = smooth(occ, valid, carved)
    # density: keep floor(d n) of the n rock islands (4-connected), whole, a random subset
    label = islands(occ, NX + NY)
    in_use = jnp.zeros((NY * NX + 1,), bool).at[label].set(True)[:-1]  # the labels of rock cells
    keep = thin_by_rank(in_use, rng.u((NY * NX,)), density)
    occ = occ & keep[jnp.minimum(label, NY * NX - 1)]

    x, y = jnp.arange(NX), jnp.arange(NY)
    side_h = (occ[:-1] != occ[1:]) & (x[None] < nx) & (y[:-1, None] < ny - 1)  # [NY-1, NX]
    side_v = ((occ[:, :-1] != occ[:, 1:]) & (x[None, :-1] < nx - 1) & (y[:, None] < ny)).T  # [NX-1, NY]
    segs, on = grid_runs(side_h, side_v, W, H, sx, sy)
    segs, n_runs = compact(segs, on, spec.cave_segments)
    world = assemble(spec, W, H, segs, jnp.zeros((0, 3), jnp.float32), ep)
    info = common_info(ep, res_a, res_b, res_on) | {
        "occupied": jnp.sum(occ).astype(jnp.int32),
        "islands": jnp.sum(keep).astype(jnp.int32),
        "cells": (nx * ny).astype(jnp.int32),
        "outline_runs": n_runs.astype(jnp.int32),
        "outline_dropped": jnp.maximum(n_runs - spec.cave_segments, 0).astype(jnp.int32),
        "waypoints": pts,
    }
    return world, info
