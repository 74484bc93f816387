"""Culled lidar and clearance for many poses in one shared room (docs/dense_rooms.md, "Culling per tile").

`geometry.lidar(..., method="culled")` and `geometry.nearest_distance(..., method="culled")` land
here. For one pose, and under a `vmap` whose room is batched with its poses (the per-pose layout),
they are the chunked loop of `geometry`, unchanged. Under a `vmap` over the poses of one room (the
world arrays unbatched: evaluation of a fixed world, shared rooms) a custom batching rule
(`jax.custom_batching.custom_vmap`) sees the whole batch and culls per tile of poses instead of
per pose:

1. the units ((pose, beam sector) for the lidar, a pose for the clearance) are ordered along a
   Morton curve of the centres of their boxes (a sector's box holds the pose and the ends of its
   beams at `max_range`; a clearance unit's box is the pose +- `NEAREST_RADIUS`) and cut into tiles
   of `TILE` units;
2. a tile's candidates are the rows whose boxes reach the union of its units' boxes (plus
   `MARGIN`), listed in ascending row order: one list per tile, shared by all its units, so the
   cast over a tile stays the dense elementwise program of the chunked loop;
3. a `fori_loop` over the tiles casts each tile's units against its candidates only, in chunks,
   with the chunked loop's per-row arithmetic; the trip count of the loop over a tile's candidates
   is the tile's own (the loop over tiles is not batched), so nothing is padded to a capacity.

Exact: a row outside a unit's box cannot be hit by its beams (nor be within `NEAREST_RADIUS` of
its pose), so the rows left out would have left every running minimum as it was; the rows kept are
visited in the chunked loop's order. Segment hits are kept as fractions within a chunk and divided
at its end (geometry), so segments are culled per chunk (window) of the chunked loop, whole windows
kept or skipped, and circles row by row. A clearance farther than `NEAREST_RADIUS` is not covered
by the candidates: such a tile is measured again by the chunked loop over every row (`lax.cond`).
Results are bitwise those of the chunked loop (tests/test_cull.py), which took two more things of
the compiled program: the beams are read inside the tile loop from the [N, num_beams] arrays the
chunked loop computes, and rows of a kind that fit in one chunk (cast with no loop by the chunked
program) are cast for every pose the same way, outside the tiles (docs/dense_rooms.md).
"""

from __future__ import annotations

from functools import lru_cache

import jax
import jax.numpy as jnp
from jax import lax
from jax.custom_batching import custom_vmap

from fedjax_nav.env import raycast as g

TILE = 64  # units per tile of the lidar
NEAREST_TILE = 128  # poses per tile of the clearance
SECTORS = 4  # beam sectors per pose (a divisor of num_beams, else fewer)
NEAREST_RADIUS = 1.0  # m: the clearance a tile's candidates cover
MARGIN = 0.01  # m added to every box: far above float32 rounding in rooms of tens of metres
CIRCLE_CHUNK = 16  # circles per iteration of a tile's loop (a minimum: any grouping is exact)
_EMPTY = (jnp.inf, -jnp.inf)


# ----------------------------------------------------------------------------- tiles and candidates


def _spread(q: jax.Array) -> jax.Array:
    """uint32 with bit i moved to bit 2i (bits 0-15)."""
    for shift, mask in ((8, 0x00FF00FF), (4, 0x0F0F0F0F), (2, 0x33333333), (1, 0x55555555)):
        q = (q | (q << shift)) & mask
    return q


def _morton_order(xy: jax.Array) -> jax.Array:
    """The points f32[U, 2] in Z-order on a grid over their bounding box: int32[U], a permutation.
    One sort of uint32 keys (the cell's Morton index above the point's index, which makes keys
    unique): on the CPU several times faster than an argsort."""
    u = xy.shape[0]
    index_bits = max(1, (u - 1).bit_length())
    bits = (32 - index_bits) // 2  # per axis
    if bits < 1:  # more than 2^30 points: an argsort
        return jnp.argsort(xy[:, 0])
    lo, hi = xy.min(0), xy.max(0)
    q = ((xy - lo) / jnp.maximum(hi - lo, 1e-6) * (2**bits - 1)).astype(jnp.uint32)
    q = jnp.minimum(q, 2**bits - 1)
    cell = _spread(q[:, 0]) | (_spread(q[:, 1]) << 1)
    keys = (cell << index_bits) | jnp.arange(u, dtype=jnp.uint32)
    return (lax.sort(keys) & ((1 << index_bits) - 1)).astype(jnp.int32)


def _tiles(lo: jax.Array, hi: jax.Array, tile: int):
    """Units with boxes [lo, hi] f32[U, 2] in Morton order, cut into tiles of `tile` (the last one
    filled up with copies of the last unit): (order int[U], slots int[T * tile], tile boxes lo, hi
    f32[T, 2] with `MARGIN`)."""
    u = lo.shape[0]
    n_t = -(-u // tile)
    order = _morton_order(0.5 * (lo + hi))
    slots = jnp.concatenate([order, jnp.broadcast_to(order[-1:], (n_t * tile - u,))])
    tlo = lo[slots].reshape(n_t, tile, 2).min(1) - MARGIN
    thi = hi[slots].reshape(n_t, tile, 2).max(1) + MARGIN
    return order, slots, tlo, thi


def _cumsum(mask: jax.Array, block: int = 32) -> jax.Array:
    """Inclusive cumulative count of bool[T, n] along its rows: int32[T, n]. As two products with
    triangular matrices of ones (blocks of `block`, then the blocks' totals): exact (integers
    below 2^24 in float32) and on the CPU several times faster than `jnp.cumsum`."""
    t, n = mask.shape
    w = -(-n // block) * block
    m = jnp.pad(mask.astype(jnp.float32), ((0, 0), (0, w - n))).reshape(t, w // block, block)
    hp = lax.Precision.HIGHEST
    inner = jnp.matmul(m, jnp.triu(jnp.ones((block, block), jnp.float32)), precision=hp)
    before = jnp.matmul(inner[:, :, -1], jnp.triu(jnp.ones((w // block, w // block), jnp.float32), 1), precision=hp)
    return (inner + before[:, :, None]).reshape(t, w)[:, :n].astype(jnp.int32)


def _candidates(tlo, thi, rlo, rhi, chunk: int):
    """Per tile, the rows whose boxes [rlo, rhi] f32[n, 2] reach the tile's: (lists int[T, n'],
    ascending, then padded with n (n' = n rounded up to `chunk`); counts int[T])."""
    n = rlo.shape[0]
    mask = jnp.all((rhi[None] >= tlo[:, None]) & (rlo[None] <= thi[:, None]), -1)  # [T, n]
    width = -(-n // chunk) * chunk
    pos = jnp.where(mask, _cumsum(mask) - 1, width)  # width: dropped
    lists = jnp.full((tlo.shape[0], width), n, jnp.int32)
    lists = lists.at[jnp.arange(tlo.shape[0])[:, None], pos].set(jnp.arange(n, dtype=jnp.int32)[None], mode="drop")
    return lists, mask.sum(1)


def _circle_boxes(circles):
    """Boxes of circles f32[C, 3]; a circle of radius <= 0 (never hit, never near) has none."""
    r = circles[:, 2:3]
    lo, hi = circles[:, :2] - r, circles[:, :2] + r
    return jnp.where(r > 0.0, lo, _EMPTY[0]), jnp.where(r > 0.0, hi, _EMPTY[1])


def _segment_boxes(segments):
    """Boxes of segments f32[M, 4]; a zero-length segment (never hit, never near) has none."""
    a, b = segments[:, :2], segments[:, 2:]
    real = jnp.any(a != b, -1, keepdims=True)
    return jnp.where(real, jnp.minimum(a, b), _EMPTY[0]), jnp.where(real, jnp.maximum(a, b), _EMPTY[1])


def _windows(n: int, chunk: int) -> jax.Array:
    """First rows of the chunked loop's windows over n > chunk rows (geometry._over_chunks)."""
    return jnp.minimum(jnp.arange(-(-n // chunk)) * chunk, n - chunk)


def _window_boxes(segments, chunk: int):
    """Boxes of the chunked loop's windows of segments (the union of their rows' boxes)."""
    lo, hi = _segment_boxes(segments)
    rows = _windows(segments.shape[0], chunk)[:, None] + jnp.arange(chunk)
    return lo[rows].min(1), hi[rows].max(1)


def _loop_rows(lists, count, table, chunk, update, carry):
    """carry = update(rows, carry) over `table`'s rows listed in `lists` (padded with an index of
    a row that changes nothing), `chunk` at a time, for the first `count` entries."""
    if lists.shape[-1] == 0:
        return carry

    def body(j, c):
        return update(table[lax.dynamic_slice_in_dim(lists, j * chunk, chunk)], c)

    return lax.fori_loop(0, (count + chunk - 1) // chunk, body, carry)


def _over_tiles(tile, n_t: int, shape) -> jax.Array:
    """f32[n_t, *shape]: tile(t) for every tile, one after the other."""
    body = lambda t, out: out.at[t].set(tile(t))  # noqa: E731
    return lax.fori_loop(0, n_t, body, jnp.zeros((n_t, *shape), jnp.float32))


def _pad_row(table):
    return jnp.concatenate([table, jnp.zeros((1, table.shape[1]), table.dtype)])


# ----------------------------------------------------------------------------- the lidar of a batch


def _sectors(num_beams: int) -> int:
    return max(s for s in range(1, SECTORS + 1) if num_beams % s == 0)


def _sector_boxes(poses, dx, dy, max_range, s: int):
    """Boxes f32[N * s, 2] (lo, hi) of the s sectors of every pose: the pose and the far ends of
    the sector's beams (a beam cannot reach a row outside its sector's box)."""
    n, bps = poses.shape[0], dx.shape[1] // s
    ux, uy = jnp.repeat(poses[:, 0], s), jnp.repeat(poses[:, 1], s)
    ex = ux[:, None] + max_range * dx.reshape(n * s, bps)
    ey = uy[:, None] + max_range * dy.reshape(n * s, bps)
    lo = jnp.stack([jnp.minimum(ux, ex.min(1)), jnp.minimum(uy, ey.min(1))], -1)
    hi = jnp.stack([jnp.maximum(ux, ex.max(1)), jnp.maximum(uy, ey.max(1))], -1)
    return lo, hi


def _seg_update(rows, best, x, y, dx, dy):
    """geometry._lidar_chunked's update for one window of segments."""
    best_num, best_den = g._segment_hits(rows, x, y, dx, dy, best, jnp.ones_like(best))
    return best_num / best_den


def _lidar_batch(segments, circles, poses, max_range, num_beams: int):
    """The lidar of poses f32[N, 3] in one room: f32[N, num_beams], bitwise the chunked loop's."""
    m, c, chunk = segments.shape[0], circles.shape[0], g.LIDAR_CHUNK
    if m <= chunk and c <= chunk:  # nothing to cull
        return jax.vmap(lambda p: g._lidar_chunked(segments, p, num_beams, max_range, circles))(poses)
    n, s = poses.shape[0], _sectors(num_beams)
    bps = num_beams // s
    dx, dy = jax.vmap(lambda p: g._beams(p, num_beams))(poses)  # [N, num_beams], as the chunked loop
    order, slots, tlo, thi = _tiles(*_sector_boxes(poses, dx, dy, max_range, s), TILE)
    n_t = tlo.shape[0]
    # A tile's arrays are [beams of a sector, TILE]: the long axis last, where the CPU vectorises.
    pids = (slots // s).reshape(n_t, 1, TILE)
    beams = (slots % s * bps).reshape(n_t, 1, TILE) + jnp.arange(bps)[:, None]
    # The rows of one window (no loop in the chunked program) are cast as the chunked program
    # casts them, for every pose at once; the tiles take the others.
    best = jnp.full((n, num_beams), max_range, jnp.float32)
    if m <= chunk:
        best = _seg_update(segments, best, poses[:, :1], poses[:, 1:2], dx, dy) if m else best
    else:
        seg_lists, seg_counts = _candidates(tlo, thi, *_window_boxes(segments, chunk), 1)
        starts = _windows(m, chunk)
    if c > chunk:
        circ_lists, circ_counts = _candidates(tlo, thi, *_circle_boxes(circles), CIRCLE_CHUNK)
        circ_table = _pad_row(circles)

    def tile(t):
        # The beams are read here, inside the loop, from the [N, num_beams] arrays: computed in
        # another shape (a cosine fused into a gather outside the loop) they may round differently.
        pid, beam = pids[t], beams[t]
        x, y, dx_t, dy_t = poses[pid, 0], poses[pid, 1], dx[pid, beam], dy[pid, beam]
        b = best[pid, beam]
        if m > chunk:
            window = lambda j, bb: _seg_update(  # noqa: E731
                lax.dynamic_slice_in_dim(segments, starts[seg_lists[t, j]], chunk), bb, x, y, dx_t, dy_t
            )
            b = lax.fori_loop(0, seg_counts[t], window, b)
        if c > chunk:
            hits = lambda rows, bb: g._circle_hits(rows, x, y, dx_t, dy_t, bb)  # noqa: E731
            b = _loop_rows(circ_lists[t], circ_counts[t], circ_table, CIRCLE_CHUNK, hits, b)
        return b

    out = _over_tiles(tile, n_t, (bps, TILE)).swapaxes(1, 2)
    best = out.reshape(n_t * TILE, bps)[_inverse(order)].reshape(n, num_beams)
    if 0 < c <= chunk:
        best = g._circle_hits(circles, poses[:, :1], poses[:, 1:2], dx, dy, best)
    return jnp.minimum(best, max_range)


# ----------------------------------------------------------------------------- the clearance of a batch


def _nearest_batch(segments, circles, points):
    """The clearance of points f32[N, 2] in one room: f32[N], bitwise the chunked loop's."""
    m, c, chunk = segments.shape[0], circles.shape[0], g.NEAREST_CHUNK
    if m <= chunk and c <= chunk:  # nothing to cull
        return jax.vmap(lambda q: g._nearest_chunked(segments, q, circles))(points)
    order, slots, tlo, thi = _tiles(points - NEAREST_RADIUS, points + NEAREST_RADIUS, NEAREST_TILE)
    n_t = tlo.shape[0]
    pids = slots.reshape(n_t, NEAREST_TILE)
    pt = (points[:, 0], points[:, 1])
    # As in _lidar_batch: the obstacles of one chunk (no loop in the chunked program) for every
    # point as the chunked program does, the others per tile.
    best2 = jnp.full(points.shape[:1], g._BIG, jnp.float32)
    if 0 < m <= chunk:
        best2 = g._segment_dist2(segments, pt, best2)
    if m > chunk:
        seg_lists, seg_counts = _candidates(tlo, thi, *_segment_boxes(segments), chunk)
        seg_table = _pad_row(segments)
    if c > chunk:
        circ_lists, circ_counts = _candidates(tlo, thi, *_circle_boxes(circles), chunk)
        circ_table = _pad_row(circles)

    def tile(t):
        pid = pids[t]
        p = (points[pid, 0], points[pid, 1])
        seg_dist2, circ_dist = (lambda r, b: g._segment_dist2(r, p, b)), (lambda r, b: g._circle_dist(r, p, b))

        def rows(seg_rows, circ_rows):  # the tile's clearance over the rows given, as the chunked loop
            b2 = seg_rows(seg_dist2, best2[pid]) if m > chunk else best2[pid]
            return circ_rows(circ_dist, jnp.sqrt(b2)) if c > chunk else jnp.sqrt(b2)

        culled = rows(
            lambda f, b: _loop_rows(seg_lists[t], seg_counts[t], seg_table, chunk, f, b),
            lambda f, b: _loop_rows(circ_lists[t], circ_counts[t], circ_table, chunk, f, b),
        )
        # Farther than NEAREST_RADIUS a row left out may be the nearest: then every row.
        every = lambda: rows(  # noqa: E731
            lambda f, b: g._over_chunks(segments, chunk, f, b), lambda f, b: g._over_chunks(circles, chunk, f, b)
        )
        return lax.cond(jnp.all(culled <= NEAREST_RADIUS), lambda: culled, every)

    best = _over_tiles(tile, n_t, (NEAREST_TILE,)).reshape(-1)[_inverse(order)]
    if 0 < c <= chunk:
        best = g._circle_dist(circles, pt, best)
    return best


def _inverse(order):
    """The inverse of the permutation `order` int[U]."""
    return jnp.zeros_like(order).at[order].set(jnp.arange(order.shape[0], dtype=order.dtype))


# ----------------------------------------------------------------------------- the batching rules


def lidar(segments, pose, num_beams, max_range, circles):
    """geometry.lidar's "culled" method: the chunked loop, culled under a vmap over poses of one room."""
    return _lidar_one(num_beams)(segments, _circles(circles), pose, jnp.asarray(max_range, jnp.float32))


def nearest_distance(segments, point, circles):
    """geometry.nearest_distance's "culled" method (as `lidar`)."""
    return _nearest_one()(segments, _circles(circles), point)


def _circles(circles):
    return jnp.zeros((0, 3), jnp.float32) if circles is None else circles


def _chunked_lidar(num_beams):
    return lambda s, c, p, r: g._lidar_chunked(s, p, num_beams, r, c)


def _chunked_nearest(s, c, p):
    return g._nearest_chunked(s, p, c)


def _per_pose(fn, in_batched, args):
    """The chunked loop, vmapped as it is (worlds batched with their poses: the per-pose layout)."""
    return jax.vmap(fn, [0 if b else None for b in in_batched])(*args), True


def _one(chunked, many):
    """One pose: the chunked loop; its vmap over the poses of one room: `many`."""
    f = custom_vmap(chunked)

    @f.def_vmap
    def rule(axis_size, in_batched, segments, circles, pose, *rest):
        if in_batched[2] and not (in_batched[0] or in_batched[1] or any(in_batched[3:])):
            return many(segments, circles, pose, *rest), True
        return _per_pose(chunked, in_batched, (segments, circles, pose, *rest))

    return f


def _many(batch):
    """A batch of poses in one room: `batch`; vmapped again: over rooms one at a time (`lax.map`),
    or, the room still shared, all the poses as one batch."""
    f = custom_vmap(batch)

    @f.def_vmap
    def rule(axis_size, in_batched, segments, circles, poses, *rest):
        args = (segments, circles, poses, *rest)
        if in_batched[0] or in_batched[1] or any(in_batched[3:]):
            full = [a if b else jnp.broadcast_to(a, (axis_size, *jnp.shape(a))) for a, b in zip(args, in_batched)]
            return lax.map(lambda a: f(*a), full), True
        flat = poses.reshape(-1, poses.shape[-1])
        out = f(segments, circles, flat, *rest)
        return out.reshape(*poses.shape[:-1], *out.shape[1:]), True

    return f


@lru_cache(maxsize=None)
def _lidar_one(num_beams):
    return _one(_chunked_lidar(num_beams), _many(lambda s, c, p, r: _lidar_batch(s, c, p, r, num_beams)))


@lru_cache(maxsize=None)
def _nearest_one():
    return _one(_chunked_nearest, _many(_nearest_batch))
