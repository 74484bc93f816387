"""The ``maze`` family: a grid maze whose walls are segments, passages one cell wide (docs/generator.md).

1. Room size; cell side s (uniform in [maze_cell_min, maze_cell_max]); the grid nx = floor(W / s)
   by ny = floor(H / s) cells of W / nx x H / ny (>= s), filling the room exactly.
2. A perfect maze (a spanning tree of the cells) by the recursive backtracker: a depth-first walk
   from a random cell that steps to a random unvisited neighbour (opening the wall between) and
   backs up when there is none. It runs as a `lax.scan` of 2 (NX NY - 1) steps (NX x NY: the
   spec's largest grid), enough to visit every cell of any room's grid; steps after the walk is
   done change nothing.
3. A fraction `maze_loops` of the remaining inner walls is removed at random (loops, open spots),
   then the density knob keeps floor(d n) of the n walls left (a random subset).
4. The walls, one cell side each, are merged into runs along each grid line: one segment row per
   run, at most ceil(n / 2) runs on a line of n sides (`shapes.maze_wall_rows`).
5. Goals and starts: a random cell's centre moved by at most s_x / 2 - c, s_y / 2 - c; the
   connector goes back to the centre.

Solvable: the open walls join every pair of cells (a spanning tree; removing walls keeps it). The
path between the centres of two joined cells is straight, crosses their shared side at its middle,
and keeps min(s_x, s_y) / 2 >= maze_cell_min / 2 > c (check_spec) from every wall: walls lie on
grid lines only, the side it crosses is open, and the grid points at its ends are s / 2 away. A
connector stays in its cell, at least c from the cell's sides.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from fedjax_nav.worlds.layout import assemble, common_info, endpoints, grid_runs, room_size, thin_by_rank
from fedjax_nav.worlds.rooms import RoomSpec
from fedjax_nav.worlds.sampling import Uniforms, gumbel_argmax
from fedjax_nav.worlds.shapes import maze_grid


def backtracker(u0, steps_u, nx, ny, NX: int, NY: int):
    """A perfect maze on the nx x ny cells (traced; <= NX x NY static) of a grid with cell id
    y * NX + x, by the recursive backtracker. u0 f32[]: the first cell; steps_u f32[steps, 4]:
    each step's choice among the 4 neighbours (east, west, north, south). Returns open_e
    bool[NX * NY] (the wall between cell i and its east neighbour is open) and open_n (north)."""
    N = NX * NY
    first = jnp.minimum(jnp.floor(u0 * nx * ny), nx * ny - 1).astype(jnp.int32)
    first = (first // nx) * NX + first % nx
    carry = (
        jnp.zeros((N,), bool).at[first].set(True),  # visited
        jnp.zeros((N,), jnp.int32).at[0].set(first),  # the walk's stack of cells
        jnp.int32(1),  # stack size
        jnp.zeros((N,), bool),  # open_e
        jnp.zeros((N,), bool),  # open_n
    )

    def step(carry, u):
        visited, stack, sp, open_e, open_n = carry
        cur = stack[jnp.maximum(sp - 1, 0)]
        x, y = cur % NX, cur // NX
        nb = jnp.stack([cur + 1, cur - 1, cur + NX, cur - NX])
        inside = jnp.stack([x + 1 < nx, x > 0, y + 1 < ny, y > 0])
        free = inside & ~visited[jnp.clip(nb, 0, N - 1)] & (sp > 0)
        k = gumbel_argmax(jnp.where(free, 0.0, -jnp.inf), u)
        go = jnp.any(free)
        nxt = jnp.clip(nb[k], 0, N - 1)
        e_idx = jnp.clip(jnp.where(k == 0, cur, cur - 1), 0, N - 1)  # the wall east of cur or of its west neighbour
        n_idx = jnp.clip(jnp.where(k == 2, cur, cur - NX), 0, N - 1)
        open_e = open_e.at[e_idx].set(open_e[e_idx] | (go & (k < 2)))
        open_n = open_n.at[n_idx].set(open_n[n_idx] | (go & (k >= 2)))
        visited = visited.at[nxt].set(visited[nxt] | go)
        stack = stack.at[jnp.minimum(sp, N - 1)].set(jnp.where(go, nxt, stack[jnp.minimum(sp, N - 1)]))
        sp = jnp.where(go, sp + 1, jnp.maximum(sp - 1, 0))
        return (visited, stack, sp, open_e, open_n), None

    (_, _, _, open_e, open_n), _ = jax.lax.scan(step, carry, steps_u)
    return open_e, open_n


def build(rng: Uniforms, spec: RoomSpec, density=1.0):
    """One maze room (World, info); see the module docstring."""
    c = spec.clearance
    W, H = room_size(rng, spec)
    NX, NY = maze_grid(spec)
    N = NX * NY
    s = rng.uniform((), spec.maze_cell_min, spec.maze_cell_max)
    nx = jnp.clip(jnp.floor(W / s), 1, NX).astype(jnp.int32)
    ny = jnp.clip(jnp.floor(H / s), 1, NY).astype(jnp.int32)
    sx, sy = W / nx, H / ny
    open_e, open_n = backtracker(rng.u(()), rng.u((max(2 * (N - 1), 0), 4)), nx, ny, NX, NY)

    # Inner walls: between rows l and l+1 at column x (h), between columns l and l+1 at row y (v).
    x, y = jnp.arange(NX), jnp.arange(NY)
    wall_h = ~open_n.reshape(NY, NX)[:-1] & (x[None] < nx) & (y[:-1, None] < ny - 1)  # [NY-1, NX]
    wall_v = (~open_e.reshape(NY, NX)[:, :-1] & (x[None, :-1] < nx - 1) & (y[:, None] < ny)).T  # [NX-1, NY]
    walls = jnp.concatenate([wall_h.reshape(-1), wall_v.reshape(-1)])
    walls = walls & (rng.u(walls.shape) >= spec.maze_loops)
    walls = thin_by_rank(walls, rng.u(walls.shape), density)
    n_h = wall_h.size
    segs, _ = grid_runs(walls[:n_h].reshape(wall_h.shape), walls[n_h:].reshape(wall_v.shape), W, H, sx, sy)

    def centre(ix, iy):
        return jnp.stack([-W / 2 + (ix + 0.5) * sx, -H / 2 + (iy + 0.5) * sy], -1)

    def sample(u):  # a random cell's centre, moved within the cell's core
        cell = jnp.minimum(jnp.floor(u[..., 0] * nx * ny), nx * ny - 1).astype(jnp.int32)
        ctr = centre((cell % nx).astype(jnp.float32), (cell // nx).astype(jnp.float32))
        half = jnp.stack([sx, sy]) / 2 - c
        return ctr + (2 * u[..., 1:] - 1) * half, ctr

    ep = endpoints(rng, spec, sample, 3)
    # the passages (centre to centre through every open side) and the connectors: the clear network
    cx_, cy_ = jnp.meshgrid(x.astype(jnp.float32), y.astype(jnp.float32))
    here = centre(cx_, cy_).reshape(-1, 2)
    inside = ((cx_ < nx) & (cy_ < ny)).reshape(-1)
    pass_e = open_e & inside & (cx_.reshape(-1) + 1 < nx)
    pass_n = open_n & inside & (cy_.reshape(-1) + 1 < ny)
    ca, cb, con = ep.connectors()
    res_a = jnp.concatenate([here, here, ca])
    res_b = jnp.concatenate([here + jnp.stack([sx, 0.0]), here + jnp.stack([0.0, sy]), cb])
    res_on = jnp.concatenate([pass_e, pass_n, con])
    world = assemble(spec, W, H, segs, jnp.zeros((0, 3), jnp.float32), ep)
    info = common_info(ep, res_a, res_b, res_on) | {
        "maze_walls": jnp.sum(walls).astype(jnp.int32),
        "cells": (nx * ny).astype(jnp.int32),
        "cell_side": jnp.minimum(sx, sy),
    }
    return world, info
