"""The procedural generator's tools (fedjax_nav/worlds/procedural.py): exact point-segment and
segment-box distances, box corners, branch-free first-true and row picks, and the counted
stream of uniform draws the generator consumes.
"""

from __future__ import annotations

import math

import jax.numpy as jnp


def pt_seg(p, a, b):
    """Distance from points p to segments a-b (all [..., 2], broadcast)."""
    ab, ap = b - a, p - a
    den = jnp.sum(ab * ab, -1)
    t = jnp.clip(jnp.sum(ap * ab, -1) / jnp.where(den > 0, den, 1.0), 0.0, 1.0)
    q = ap - t[..., None] * ab
    return jnp.sqrt(jnp.sum(q * q, -1))


def seg_box(a, b, centre, half, yaw):
    """Exact distance between segments a-b and solid rotated boxes (centre, half sides, yaw);
    0 if the segment touches or enters the box. Shapes broadcast: a, b, centre, half [..., 2],
    yaw [...].

    In the box's frame: 0 if the segment clips the box (Liang-Barsky), else the distance between
    two disjoint convex sets, attained at a vertex of one of them: min(segment ends to the box,
    box corners to the segment).
    """
    cs, sn = jnp.cos(yaw), jnp.sin(yaw)

    def local(p):
        r = p - centre
        return jnp.stack([cs * r[..., 0] + sn * r[..., 1], -sn * r[..., 0] + cs * r[..., 1]], -1)

    p0, p1 = local(a), local(b)
    d = p1 - p0
    tiny = jnp.abs(d) < 1e-12
    safe = jnp.where(tiny, 1.0, d)
    ta, tb = (-half - p0) / safe, (half - p0) / safe
    t_in = jnp.where(tiny, -jnp.inf, jnp.minimum(ta, tb)).max(-1)
    t_out = jnp.where(tiny, jnp.inf, jnp.maximum(ta, tb)).min(-1)
    parallel_out = jnp.any(tiny & (jnp.abs(p0) > half), -1)
    clips = (jnp.maximum(t_in, 0.0) <= jnp.minimum(t_out, 1.0)) & ~parallel_out

    def to_box(p):
        q = jnp.maximum(jnp.abs(p) - half, 0.0)
        return jnp.sqrt(jnp.sum(q * q, -1))

    corners = jnp.stack(
        [jnp.stack([sx * half[..., 0], sy * half[..., 1]], -1) for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))], -2
    )  # [..., 4, 2]
    to_seg = pt_seg(corners, p0[..., None, :], p1[..., None, :]).min(-1)
    return jnp.where(clips, 0.0, jnp.minimum(jnp.minimum(to_box(p0), to_box(p1)), to_seg))


def first_true(ok):
    """(index of the first True along the last axis (0 if none), any True)."""
    return jnp.argmax(ok, axis=-1), jnp.any(ok, axis=-1)


def take_rows(arr, idx):
    """arr [..., T, ...k] at idx [...] along axis len(idx.shape)."""
    return jnp.take_along_axis(arr, idx.reshape(idx.shape + (1,) * (arr.ndim - idx.ndim)), axis=idx.ndim).squeeze(
        idx.ndim
    )


class Uniforms:
    """All of a room's randomness comes from ONE `jax.random.uniform` draw, sliced in order: one
    threefry call instead of ~30 (XLA compiles every threefry call separately, and the compile
    time of `generate` was dominated by them). With `flat=None` it only counts (the size of the
    draw is found by tracing the generator once with a counting stream, `_num_uniforms`)."""

    def __init__(self, flat):
        self.flat, self.used = flat, 0

    def u(self, shape=()):
        shape = tuple(shape)
        n = math.prod(shape)
        if self.flat is None:
            out = jnp.full(shape, 0.5, jnp.float32)
        else:
            out = self.flat[self.used : self.used + n].reshape(shape)
        self.used += n
        return out

    def uniform(self, shape=(), minval=0.0, maxval=1.0):
        return minval + self.u(shape) * (maxval - minval)

    def randint(self, lo: int, hi: int, shape=()):
        """Integers in [lo, hi] (inclusive)."""
        return jnp.minimum(lo + jnp.floor(self.u(shape) * (hi - lo + 1)).astype(jnp.int32), hi)

    def categorical(self, logits, shape=()):
        """Indices drawn with probabilities softmax(logits)."""
        return gumbel_argmax(logits, self.u((*shape, logits.shape[-1])))


def gumbel_argmax(logits, u):
    """The Gumbel-max trick: argmax(logits + Gumbel noise) from uniforms u [..., n]."""
    return jnp.argmax(logits - jnp.log(-jnp.log(u)), axis=-1)


def box_corners(centre, sides, yaw):
    """Corners [..., 4, 2] of boxes (centre [..., 2], full sides [..., 2], yaw [...])."""
    cs, sn = jnp.cos(yaw)[..., None], jnp.sin(yaw)[..., None]
    local = jnp.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]]) * 0.5  # [4, 2]
    lx, ly = local[:, 0] * sides[..., :1], local[:, 1] * sides[..., 1:]  # [..., 4]
    return jnp.stack([centre[..., :1] + cs * lx - sn * ly, centre[..., 1:] + sn * lx + cs * ly], -1)


# The dense families' distance tests. Written per coordinate (no reductions over a trailing axis
# of 2) and, in the `*_all` forms, as a static loop over the network's segments: each segment is
# one fused elementwise pass over the candidates, about 20x cheaper on CPU than the broadcast
# [candidates, segments, 2] arrays of `pt_seg` (measured on 4096 forest rooms).


def pt_seg_sq(p, a, b):
    """Squared distance from points p to segments a-b (all [..., 2], broadcast)."""
    px, py, ax, ay = p[..., 0], p[..., 1], a[..., 0], a[..., 1]
    ex, ey = b[..., 0] - ax, b[..., 1] - ay
    den = ex * ex + ey * ey
    t = jnp.clip(((px - ax) * ex + (py - ay) * ey) / jnp.where(den > 0, den, 1.0), 0.0, 1.0)
    qx, qy = px - ax - t * ex, py - ay - t * ey
    return qx * qx + qy * qy


def seg_aabb_sq(a, b, centre, half):
    """Squared exact distance between segments a-b and solid axis-aligned boxes (centre, half
    sides), 0 if the segment touches or enters the box: `seg_box` at yaw 0 without rotations or
    square roots (shapes broadcast, [..., 2])."""
    x0, y0 = a[..., 0] - centre[..., 0], a[..., 1] - centre[..., 1]
    x1, y1 = b[..., 0] - centre[..., 0], b[..., 1] - centre[..., 1]
    hx, hy = half[..., 0], half[..., 1]

    def slab(p0, d, h):  # Liang-Barsky along one axis: (t_in, t_out, parallel and outside)
        tiny = jnp.abs(d) < 1e-12
        safe = jnp.where(tiny, 1.0, d)
        ta, tb = (-h - p0) / safe, (h - p0) / safe
        return (
            jnp.where(tiny, -jnp.inf, jnp.minimum(ta, tb)),
            jnp.where(tiny, jnp.inf, jnp.maximum(ta, tb)),
            tiny & (jnp.abs(p0) > h),
        )

    ix, ox, px = slab(x0, x1 - x0, hx)
    iy, oy, py = slab(y0, y1 - y0, hy)
    clips = (jnp.maximum(jnp.maximum(ix, iy), 0.0) <= jnp.minimum(jnp.minimum(ox, oy), 1.0)) & ~px & ~py

    def to_box(x, y):
        qx, qy = jnp.maximum(jnp.abs(x) - hx, 0.0), jnp.maximum(jnp.abs(y) - hy, 0.0)
        return qx * qx + qy * qy

    seg0, seg1 = jnp.stack([x0, y0], -1), jnp.stack([x1, y1], -1)
    d = jnp.minimum(to_box(x0, y0), to_box(x1, y1))
    for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
        d = jnp.minimum(d, pt_seg_sq(jnp.stack([sx * hx, sy * hy], -1), seg0, seg1))
    return jnp.where(clips, 0.0, d)


def aabb_gap_sq(lo1, hi1, lo2, hi2):
    """Squared distance between axis-aligned boxes [lo, hi] (a segment along an axis is one of zero
    width); 0 if they touch or overlap. Shapes broadcast, [..., 2]."""
    gx = jnp.maximum(jnp.maximum(lo2[..., 0] - hi1[..., 0], lo1[..., 0] - hi2[..., 0]), 0.0)
    gy = jnp.maximum(jnp.maximum(lo2[..., 1] - hi1[..., 1], lo1[..., 1] - hi2[..., 1]), 0.0)
    return gx * gx + gy * gy


def all_clear(dist_sq, a, b, on, r2):
    """Whether candidates keep a squared distance >= r2 from every used segment a-b [R, 2]
    (on bool[R]): `dist_sq(a_r, b_r)` gives one segment's squared distances to every candidate."""
    ok = None
    for r in range(a.shape[0]):
        ok_r = ~on[r] | (dist_sq(a[r], b[r]) >= r2)
        ok = ok_r if ok is None else ok & ok_r
    return ok
