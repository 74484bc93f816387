"""The per-row arithmetic of the lidar and the clearance, and its two programs for one pose: the
loop over rows unrolled (small rooms) and chunked (dense rooms). `geometry` chooses between them
(and the culled program of `cull`, which runs the same arithmetic); docs/dense_rooms.md.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import lax

_BIG = 1e9

# Rows per chunk of the chunked loops (each chunk is unrolled): lidar casts `LIDAR_CHUNK` rows
# against every beam per iteration, nearest_distance measures `NEAREST_CHUNK` rows per iteration.
LIDAR_CHUNK = 8
NEAREST_CHUNK = 16


def beam_angles(num_beams: int) -> jnp.ndarray:
    """Beam i points at heading + 2 pi i / num_beams (beam 0 straight ahead)."""
    return 2.0 * jnp.pi * jnp.arange(num_beams, dtype=jnp.float32) / num_beams


# ----------------------------------------------------------------------------- per-row arithmetic
#
# Shared by both paths: each helper runs its Python loop over the rows it is given (all of them
# in the unrolled path, one chunk in the chunked path).


def _segment_hits(rows, x, y, dx, dy, best_num, best_den):
    """Nearest hit so far as a fraction best_num / best_den per beam, updated with `rows`."""
    # Ray o + t d against segment p + u e.  With w = p - o: t = (w x e) / (d x e) and
    # u = (w x d) / (d x e); multiplying through by sign(d x e) keeps the tests division-free.
    for m in range(rows.shape[0]):
        seg = rows[m]
        px, py = seg[0] - x, seg[1] - y
        ex, ey = seg[2] - seg[0], seg[3] - seg[1]
        w_cross_e = px * ey - py * ex  # beam-independent
        den = dx * ey - dy * ex
        w_cross_d = px * dy - py * dx
        sgn = jnp.where(den >= 0.0, 1.0, -1.0)
        t_num, u_num, t_den = w_cross_e * sgn, w_cross_d * sgn, den * sgn
        closer = (
            (t_den > 1e-12) & (t_num >= 0.0) & (u_num >= 0.0) & (u_num <= t_den) & (t_num * best_den < best_num * t_den)
        )
        best_num = jnp.where(closer, t_num, best_num)
        best_den = jnp.where(closer, t_den, best_den)
    return best_num, best_den


def _circle_hits(rows, x, y, dx, dy, best):
    """Nearest hit so far per beam (a distance), updated with the circles `rows`."""
    # Ray against circle: with w = c - o, b = w.d, t = b - sqrt(b^2 - (|w|^2 - r^2)).
    for c in range(rows.shape[0]):
        wx, wy, r = rows[c, 0] - x, rows[c, 1] - y, rows[c, 2]
        cc = wx * wx + wy * wy - r * r  # > 0 when the robot is outside
        b = wx * dx + wy * dy
        disc = b * b - cc
        t = b - jnp.sqrt(jnp.maximum(disc, 0.0))
        hit = (r > 0.0) & (disc >= 0.0) & (b >= 0.0) & (t >= 0.0) & (t < best)
        best = jnp.where(hit, t, best)
    return best


def _segment_dist2(rows, point, best2):
    """Squared distance to the nearest of `rows` so far."""
    for m in range(rows.shape[0]):
        ax, ay = rows[m, 0], rows[m, 1]
        ex, ey = rows[m, 2] - ax, rows[m, 3] - ay
        px, py = point[0] - ax, point[1] - ay
        len2 = ex * ex + ey * ey
        pad = len2 <= 0.0
        t = jnp.clip((px * ex + py * ey) / jnp.where(pad, 1.0, len2), 0.0, 1.0)
        qx, qy = px - t * ex, py - t * ey
        best2 = jnp.where(pad, best2, jnp.minimum(best2, qx * qx + qy * qy))
    return best2


def _circle_dist(rows, point, best):
    """Distance to the nearest circle surface of `rows` so far."""
    for c in range(rows.shape[0]):
        dc = jnp.hypot(point[0] - rows[c, 0], point[1] - rows[c, 1]) - rows[c, 2]
        best = jnp.where(rows[c, 2] > 0.0, jnp.minimum(best, dc), best)
    return best


def _beams(pose, num_beams):
    ang = pose[2] + beam_angles(num_beams)
    return jnp.cos(ang), jnp.sin(ang)


# ----------------------------------------------------------------------------- unrolled (small rooms)


def _lidar_unrolled(segments, pose, num_beams, max_range, circles):
    x, y = pose[0], pose[1]
    dx, dy = _beams(pose, num_beams)
    best_num = jnp.full((num_beams,), max_range, jnp.float32)
    best_den = jnp.ones((num_beams,), jnp.float32)
    best_num, best_den = _segment_hits(segments, x, y, dx, dy, best_num, best_den)
    best = best_num / best_den
    if circles is not None:
        best = _circle_hits(circles, x, y, dx, dy, best)
    return jnp.minimum(best, max_range)


def _nearest_unrolled(segments, point, circles):
    best = jnp.sqrt(_segment_dist2(segments, point, jnp.float32(_BIG)))
    if circles is not None:
        best = _circle_dist(circles, point, best)
    return best


# ----------------------------------------------------------------------------- chunked (dense rooms)
#
# The same per-row arithmetic in a `fori_loop` over chunks of rows whose body is one chunk
# unrolled. The last chunk overlaps the one before instead of being padded, so the world arrays
# are never copied and the program holds exactly one chunk of rows per loop. The loop index is
# never batched, so under `vmap` (of poses, of worlds, or both) the body stays the fused
# elementwise program of the unrolled path over `chunk` rows at a time, and `dynamic_slice` reads
# one chunk of a batched world array in place. No culling: every pose tests every row (why, with
# the measured alternatives, in docs/dense_rooms.md).


def _over_chunks(rows, chunk, update, carry):
    """carry = update(window, carry) over windows of `chunk` consecutive rows covering `rows`.

    The last window ends at the last row, so it may overlap the one before: every update here is
    a running minimum, for which seeing a row twice changes nothing. Fewer rows than a chunk are
    unrolled as they are.
    """
    n = rows.shape[0]
    if n <= chunk:
        return update(rows, carry) if n else carry

    def body(i, c):
        start = jnp.minimum(i * chunk, n - chunk)
        return update(lax.dynamic_slice_in_dim(rows, start, chunk), c)

    return lax.fori_loop(0, -(-n // chunk), body, carry)


def _lidar_chunked(segments, pose, num_beams, max_range, circles, chunk: int = LIDAR_CHUNK):
    x, y = pose[0], pose[1]
    dx, dy = _beams(pose, num_beams)

    def seg_update(rows, best):
        # Within a chunk the nearest hit is a fraction, as in the unrolled loop; one division per
        # beam at the end of the chunk (a chunk without a hit returns best / 1 = best).
        best_num, best_den = _segment_hits(rows, x, y, dx, dy, best, jnp.ones_like(best))
        return best_num / best_den

    best = jnp.full((num_beams,), max_range, jnp.float32)
    best = _over_chunks(segments, chunk, seg_update, best)
    if circles is not None:
        best = _over_chunks(circles, chunk, lambda rows, b: _circle_hits(rows, x, y, dx, dy, b), best)
    return jnp.minimum(best, max_range)


def _nearest_chunked(segments, point, circles, chunk: int = NEAREST_CHUNK):
    best2 = _over_chunks(segments, chunk, lambda rows, b: _segment_dist2(rows, point, b), jnp.float32(_BIG))
    best = jnp.sqrt(best2)
    if circles is not None:
        best = _over_chunks(circles, chunk, lambda rows, b: _circle_dist(rows, point, b), best)
    return best
