"""Analytic 2D geometry for one robot: lidar raycasting and distance to the nearest obstacle.

Everything here is written for one pose and is jittable and vmappable; batch axes are added by
the caller. Padding rows (zero-length segments, zero-radius circles) never hit and are never near.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

_BIG = 1e9


def beam_angles(num_beams: int) -> jnp.ndarray:
    """Beam i points at heading + 2 pi i / num_beams (beam 0 straight ahead)."""
    return 2.0 * jnp.pi * jnp.arange(num_beams, dtype=jnp.float32) / num_beams


def lidar(
    segments: jax.Array,
    pose: jax.Array,
    num_beams: int = 24,
    max_range: float = 3.5,
    circles: jax.Array | None = None,
) -> jax.Array:
    """Ranges of `num_beams` beams from `pose` to the nearest segment or circle: f32[num_beams].

    segments: f32[M, 4] rows (x1, y1, x2, y2); circles: f32[C, 3] rows (cx, cy, r), optional;
    pose: (x, y, theta). Beam i points at theta + 2 pi i / num_beams. A beam that hits nothing
    within `max_range` reads `max_range`. Zero-length segments and zero-radius circles never hit.

    Speed (measured, docs/benchmarks.md): the loop over obstacles is unrolled in Python, so that
    under `vmap` every operation is elementwise over [batch, beams] and XLA fuses the whole cast
    into one vectorised loop; a [beams, M] formulation with a min-reduction over M ran 5.7x
    slower on CPU. The nearest hit is kept as a fraction (num / den) and compared by
    cross-multiplication, so there is one division per beam instead of one per beam-segment pair.
    """
    x, y, theta = pose[0], pose[1], pose[2]
    ang = theta + beam_angles(num_beams)
    dx, dy = jnp.cos(ang), jnp.sin(ang)
    best_num = jnp.full((num_beams,), max_range, jnp.float32)
    best_den = jnp.ones((num_beams,), jnp.float32)
    # Ray o + t d against segment p + u e.  With w = p - o: t = (w x e) / (d x e) and
    # u = (w x d) / (d x e); multiplying through by sign(d x e) keeps the tests division-free.
    for m in range(segments.shape[0]):
        seg = segments[m]
        px, py = seg[0] - x, seg[1] - y
        ex, ey = seg[2] - seg[0], seg[3] - seg[1]
        w_cross_e = px * ey - py * ex  # beam-independent
        den = dx * ey - dy * ex
        w_cross_d = px * dy - py * dx
        sgn = jnp.where(den >= 0.0, 1.0, -1.0)
        t_num, u_num, t_den = w_cross_e * sgn, w_cross_d * sgn, den * sgn
        closer = (
            (t_den > 1e-12)
            & (t_num >= 0.0)
            & (u_num >= 0.0)
            & (u_num <= t_den)
            & (t_num * best_den < best_num * t_den)
        )
        best_num = jnp.where(closer, t_num, best_num)
        best_den = jnp.where(closer, t_den, best_den)
    best = best_num / best_den
    if circles is not None:
        # Ray against circle: with w = c - o, b = w.d, t = b - sqrt(b^2 - (|w|^2 - r^2)).
        for c in range(circles.shape[0]):
            wx, wy, r = circles[c, 0] - x, circles[c, 1] - y, circles[c, 2]
            cc = wx * wx + wy * wy - r * r  # > 0 when the robot is outside
            b = wx * dx + wy * dy
            disc = b * b - cc
            t = b - jnp.sqrt(jnp.maximum(disc, 0.0))
            hit = (r > 0.0) & (disc >= 0.0) & (b >= 0.0) & (t >= 0.0) & (t < best)
            best = jnp.where(hit, t, best)
    return jnp.minimum(best, max_range)


def nearest_distance(segments: jax.Array, point: jax.Array, circles: jax.Array | None = None) -> jax.Array:
    """Exact distance from `point` (x, y) to the nearest segment or circle surface: f32[].

    Unrolled over obstacles for the same reason as `lidar`.
    """
    best2 = jnp.float32(_BIG)
    for m in range(segments.shape[0]):
        ax, ay = segments[m, 0], segments[m, 1]
        ex, ey = segments[m, 2] - ax, segments[m, 3] - ay
        px, py = point[0] - ax, point[1] - ay
        len2 = ex * ex + ey * ey
        pad = len2 <= 0.0
        t = jnp.clip((px * ex + py * ey) / jnp.where(pad, 1.0, len2), 0.0, 1.0)
        qx, qy = px - t * ex, py - t * ey
        best2 = jnp.where(pad, best2, jnp.minimum(best2, qx * qx + qy * qy))
    best = jnp.sqrt(best2)
    if circles is not None:
        for c in range(circles.shape[0]):
            dc = jnp.hypot(point[0] - circles[c, 0], point[1] - circles[c, 1]) - circles[c, 2]
            best = jnp.where(circles[c, 2] > 0.0, jnp.minimum(best, dc), best)
    return best
