"""Analytic 2D geometry for one robot: lidar raycasting and distance to the nearest obstacle.

Everything here is written for one pose and is jittable and vmappable (over poses, over worlds,
or both); batch axes are added by the caller. Padding rows (zero-length segments, zero-radius
circles) never hit and are never near.

Two implementations of each function, chosen from the static obstacle count M + C
(docs/dense_rooms.md):

- up to `UNROLL_MAX_ROWS` rows (every shipped playground, also when stacked): the Python loop
  over obstacles is unrolled at trace time (the code of the thesis runs, unchanged). Under
  `vmap` every operation is elementwise over [batch, beams] and XLA fuses the whole cast into
  one loop, but the program, its compile time and its compile memory grow with every row (354
  rows: 20-55 s to compile one step on the development machine; a training run in a
  1,000-cylinder room was still compiling at 4 GB after 5 minutes);
- above it: a `lax.fori_loop` over fixed-size chunks of rows, each chunk unrolled, so the program
  and its compile time are bounded by the chunk size whatever the number of obstacles. Same
  per-row arithmetic; results agree with the unrolled path to float32 rounding (not bitwise).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import lax

_BIG = 1e9

# Rows (segments + circles) up to which the unrolled loop is used. It must be >= 69: the shipped
# playgrounds stacked (48 + 21 rows after padding) keep the unrolled program and so their
# numbers bit for bit, and so do the procedural rooms of the default RoomSpec. Measured
# (docs/dense_rooms.md), the unrolled program is never faster: per CPU-second the chunked loop
# steps as fast at 32-48 rows and 8-50% faster from 64 to 192 rows, and its compile time stays
# flat while the unrolled one grows with every row. So the threshold is as low as the shipped
# rooms allow, with a margin of a few obstacles (11 rows) for small edits of them.
UNROLL_MAX_ROWS = 80
# Rows per chunk of the chunked loops (each chunk is unrolled): lidar casts `LIDAR_CHUNK` rows
# against every beam per iteration, nearest_distance measures `NEAREST_CHUNK` rows per iteration.
LIDAR_CHUNK = 8
NEAREST_CHUNK = 16

METHODS = ("auto", "unrolled", "chunked")


def beam_angles(num_beams: int) -> jnp.ndarray:
    """Beam i points at heading + 2 pi i / num_beams (beam 0 straight ahead)."""
    return 2.0 * jnp.pi * jnp.arange(num_beams, dtype=jnp.float32) / num_beams


def _num_rows(segments: jax.Array, circles: jax.Array | None) -> int:
    return segments.shape[-2] + (0 if circles is None else circles.shape[-2])


def _use_unrolled(segments: jax.Array, circles: jax.Array | None, method: str) -> bool:
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if method == "auto":
        return _num_rows(segments, circles) <= UNROLL_MAX_ROWS
    return method == "unrolled"


def lidar(
    segments: jax.Array,
    pose: jax.Array,
    num_beams: int = 24,
    max_range: float = 3.5,
    circles: jax.Array | None = None,
    *,
    method: str = "auto",
) -> jax.Array:
    """Ranges of `num_beams` beams from `pose` to the nearest segment or circle: f32[num_beams].

    segments: f32[M, 4] rows (x1, y1, x2, y2); circles: f32[C, 3] rows (cx, cy, r), optional;
    pose: (x, y, theta). Beam i points at theta + 2 pi i / num_beams. A beam that hits nothing
    within `max_range` reads `max_range`. Zero-length segments and zero-radius circles never hit.

    method (static): "auto" (unrolled up to `UNROLL_MAX_ROWS` rows, chunked above), "unrolled"
    or "chunked".

    Speed (measured, docs/benchmarks.md, docs/dense_rooms.md): for small rooms the loop over
    obstacles is unrolled in Python, so that under `vmap` every operation is elementwise over
    [batch, beams] and XLA fuses the whole cast into one vectorised loop; a [beams, M]
    formulation with a min-reduction over M ran 5.7x slower on CPU. The nearest hit is kept as a
    fraction (num / den) and compared by cross-multiplication, so there is one division per beam
    (per chunk, in the chunked loop) instead of one per beam-segment pair.
    """
    if _use_unrolled(segments, circles, method):
        return _lidar_unrolled(segments, pose, num_beams, max_range, circles)
    return _lidar_chunked(segments, pose, num_beams, max_range, circles)


def nearest_distance(
    segments: jax.Array, point: jax.Array, circles: jax.Array | None = None, *, method: str = "auto"
) -> jax.Array:
    """Exact distance from `point` (x, y) to the nearest segment or circle surface: f32[].

    Negative inside a circle. Unrolled over obstacles for the same reason as `lidar`, chunked
    above `UNROLL_MAX_ROWS` rows (method as in `lidar`).
    """
    if _use_unrolled(segments, circles, method):
        return _nearest_unrolled(segments, point, circles)
    return _nearest_chunked(segments, point, circles)


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
