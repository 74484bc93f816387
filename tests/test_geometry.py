"""Lidar raycasting and nearest-obstacle distance against float64 numpy references and hand cases.

The references below are written independently of the JAX code: a ray is intersected with a
segment's supporting line through the line's normal and the hit point is then projected onto
the segment; a ray is intersected with a circle through its closest approach to the centre.
"""
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fedjax_nav import worlds
from fedjax_nav.env import beam_angles, lidar, nearest_distance

MAX_RANGE = 3.5
NUM_BEAMS = 24


# ----------------------------------------------------------------------------- float64 references


def lidar_ref(segments, pose, num_beams=NUM_BEAMS, max_range=MAX_RANGE, circles=None):
    """Float64 ranges of `num_beams` beams from `pose`: f64[num_beams]."""
    segs = np.asarray(segments, np.float64).reshape(-1, 4)
    x, y, th = (float(v) for v in pose)
    ang = th + 2.0 * np.pi * np.arange(num_beams) / num_beams
    d = np.stack([np.cos(ang), np.sin(ang)], -1)  # [n, 2] unit beam directions
    o = np.array([x, y])
    best = np.full(num_beams, np.inf)

    a, b = segs[:, :2], segs[:, 2:]
    e = b - a  # [M, 2]
    len2 = (e * e).sum(-1)
    normal = np.stack([-e[:, 1], e[:, 0]], -1)  # [M, 2], not normalised
    # Points p on the line satisfy normal . (p - a) = 0; p = o + t d gives t.
    off = ((a - o) * normal).sum(-1)  # [M]
    along = d @ normal.T  # [n, M]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = off[None, :] / along
        hit = o[None, None, :] + t[..., None] * d[:, None, :]  # [n, M, 2]
        s = ((hit - a[None]) * e[None]).sum(-1) / len2[None]  # position along the segment
    ok = (len2[None] > 0) & (np.abs(along) > 1e-12) & (t >= 0) & (s >= -1e-12) & (s <= 1 + 1e-12)
    if ok.any():
        best = np.minimum(best, np.where(ok, t, np.inf).min(-1))

    if circles is not None and len(circles):
        circ = np.asarray(circles, np.float64).reshape(-1, 3)
        w = circ[:, :2] - o  # [C, 2]
        r = circ[:, 2]
        t_close = d @ w.T  # [n, C]: distance along the beam to the closest approach
        perp = d[:, None, 0] * w[None, :, 1] - d[:, None, 1] * w[None, :, 0]  # signed offset
        chord2 = r[None] ** 2 - perp**2
        t_hit = t_close - np.sqrt(np.maximum(chord2, 0.0))
        ok = (r[None] > 0) & (chord2 >= 0) & (t_close >= 0) & (t_hit >= 0)
        if ok.any():
            best = np.minimum(best, np.where(ok, t_hit, np.inf).min(-1))
    return np.minimum(best, max_range)


def nearest_ref(segments, point, circles=None):
    """Float64 brute force: distance from `point` to the nearest segment or circle surface."""
    segs = np.asarray(segments, np.float64).reshape(-1, 4)
    p = np.asarray(point, np.float64)
    out = np.inf
    for x1, y1, x2, y2 in segs:
        a, b = np.array([x1, y1]), np.array([x2, y2])
        if np.all(a == b):
            continue  # padding
        # Minimum over a dense parametrisation refined by the exact foot of the perpendicular.
        ab = b - a
        u = np.clip(np.dot(p - a, ab) / np.dot(ab, ab), 0.0, 1.0)
        cands = [a, b, a + u * ab]
        out = min(out, min(np.linalg.norm(p - c) for c in cands))
    if circles is not None:
        for cx, cy, r in np.asarray(circles, np.float64).reshape(-1, 3):
            if r > 0:
                out = min(out, math.hypot(p[0] - cx, p[1] - cy) - r)
    return out


def _f32(a):
    """Round to float32 (what the JAX code sees), back to float64 for the reference."""
    return np.asarray(np.asarray(a, np.float32), np.float64)


def random_world(rng, num_segments=12, num_circles=4, extent=3.0):
    """Random segments and circles, with padding rows (zero-length / zero-radius) mixed in."""
    centre = rng.uniform(-extent, extent, (num_segments, 2))
    length = rng.uniform(0.2, 3.0, num_segments)
    phi = rng.uniform(0, 2 * np.pi, num_segments)
    half = 0.5 * length[:, None] * np.stack([np.cos(phi), np.sin(phi)], -1)
    segs = np.concatenate([centre - half, centre + half], -1)
    pad_rows = rng.choice(num_segments, 2, replace=False)
    segs[pad_rows, 2:] = segs[pad_rows, :2]  # zero-length: padding
    circ = np.concatenate([rng.uniform(-extent, extent, (num_circles, 2)),
                           rng.uniform(0.1, 0.7, (num_circles, 1))], -1)
    circ[rng.integers(num_circles), 2] = 0.0  # zero radius: padding
    return _f32(segs), _f32(circ)


def random_free_poses(rng, segs, circ, n, lo, hi, margin=0.02, inside=None):
    """Poses uniformly in [lo, hi]^2 with any heading, at least `margin` from every obstacle,
    outside every circle and (optionally) outside every region `inside(p)` says is solid."""
    poses = []
    while len(poses) < n:
        p = rng.uniform(lo, hi, 2)
        if nearest_ref(segs, p, circ) < margin:
            continue
        if inside is not None and inside(p):
            continue
        poses.append([p[0], p[1], rng.uniform(-2 * np.pi, 2 * np.pi)])
    return _f32(poses)


# ----------------------------------------------------------------------------- the references


def test_references_agree_on_hand_case():
    """The references themselves: a unit square around the origin, seen from the centre."""
    square = [[-1, -1, 1, -1], [1, -1, 1, 1], [1, 1, -1, 1], [-1, 1, -1, -1]]
    r = lidar_ref(square, (0, 0, 0), 8, 3.5)
    np.testing.assert_allclose(r, [1, math.sqrt(2)] * 4, rtol=1e-12)
    r = lidar_ref([], (0, 0, 0), 4, 3.5, circles=[[2, 0, 0.5], [0, -3, 1.0]])
    np.testing.assert_allclose(r, [1.5, 3.5, 3.5, 2.0], rtol=1e-12)
    assert nearest_ref(square, (0.5, 0)) == pytest.approx(0.5)
    assert nearest_ref(square, (3, 3)) == pytest.approx(2 * math.sqrt(2))


# ----------------------------------------------------------------------------- lidar: random


@pytest.mark.parametrize("num_beams,max_range", [(24, 3.5), (36, 8.0)])
def test_lidar_matches_float64_reference_on_random_worlds(num_beams, max_range):
    rng = np.random.default_rng(1234 + num_beams)
    n_worlds, n_poses = 16, 48
    segs, circs, poses = [], [], []
    for _ in range(n_worlds):
        s, c = random_world(rng)
        segs.append(s)
        circs.append(c)
        poses.append(random_free_poses(rng, s, c, n_poses, -4.0, 4.0))
    segs, circs, poses = np.stack(segs), np.stack(circs), np.stack(poses)

    cast = jax.jit(jax.vmap(jax.vmap(
        lambda s, p, c: lidar(s, p, num_beams, max_range, c), (None, 0, None))))
    got = np.asarray(cast(jnp.asarray(segs, jnp.float32), jnp.asarray(poses, jnp.float32),
                          jnp.asarray(circs, jnp.float32)))
    want = np.stack([[lidar_ref(segs[w], poses[w, i], num_beams, max_range, circs[w])
                      for i in range(n_poses)] for w in range(n_worlds)])
    assert got.shape == (n_worlds, n_poses, num_beams) and got.dtype == np.float32
    err = np.abs(got - want)
    assert err.max() < 1e-3, f"max error {err.max():.3g} m at {np.unravel_index(err.argmax(), err.shape)}"
    # The comparison is not vacuous: many beams hit something, many see nothing.
    hit = want < max_range
    assert 0.2 < hit.mean() < 0.95
    # ... and circles are hit too (the segments-only cast is longer on some beams).
    segs_only = np.stack([[lidar_ref(segs[w], poses[w, i], num_beams, max_range)
                           for i in range(n_poses)] for w in range(n_worlds)])
    assert (want < segs_only - 1e-6).mean() > 0.02


def test_lidar_matches_reference_on_shipped_worlds(lidar_jit):
    """All shipped playgrounds stacked (so padded), at random collision-free poses."""
    rng = np.random.default_rng(99)
    stacked = worlds.load_many(worlds.SHIPPED)
    n_poses = 40
    poses = []
    for i, name in enumerate(worlds.SHIPPED):
        w, meta = worlds.load_with_meta(name)
        half = np.asarray(w.size, np.float64) / 2
        boxes = meta["boxes"]

        def inside(p, boxes=boxes):
            return any(_in_box(p, b) for b in boxes)

        poses.append(random_free_poses(rng, np.asarray(w.segments), np.asarray(w.circles), n_poses,
                                       -half[0], half[0], margin=0.25, inside=inside))
    poses = np.stack(poses)
    cast = jax.jit(jax.vmap(jax.vmap(lambda s, p, c: lidar(s, p, circles=c), (None, 0, None))))
    got = np.asarray(cast(stacked.segments, jnp.asarray(poses, jnp.float32), stacked.circles))
    segs, circs = np.asarray(stacked.segments, np.float64), np.asarray(stacked.circles, np.float64)
    want = np.stack([[lidar_ref(segs[w], poses[w, i], circles=circs[w]) for i in range(n_poses)]
                     for w in range(len(worlds.SHIPPED))])
    err = np.abs(got - want)
    assert err.max() < 1e-3, f"max error {err.max():.3g} m"
    assert (want < MAX_RANGE).mean() > 0.3
    # Free poses are never closer than the collision distance along any beam.
    assert got.min() >= 0.25 - 1e-5


def _in_box(p, box):
    cx, cy, sx, sy, yaw = box
    c, s = math.cos(yaw), math.sin(yaw)
    dx, dy = p[0] - cx, p[1] - cy
    return abs(c * dx + s * dy) <= sx / 2 and abs(-s * dx + c * dy) <= sy / 2


# ----------------------------------------------------------------------------- lidar: hand cases


def _cast(fn, segs, pose, circles=None, **kw):
    segs = jnp.asarray(np.asarray(segs, np.float32).reshape(-1, 4))
    circ = None if circles is None else jnp.asarray(np.asarray(circles, np.float32).reshape(-1, 3))
    return np.asarray(fn(segs, jnp.asarray(pose, jnp.float32), circles=circ, **kw))


def test_wall_straight_ahead(lidar_jit):
    wall = [[2.0, -1.0, 2.0, 1.0]]
    r = _cast(lidar_jit, wall, (0.0, 0.0, 0.0))
    assert r[0] == 2.0  # exact
    assert r[12] == MAX_RANGE  # behind: nothing
    r = _cast(lidar_jit, wall, (0.5, 0.25, 0.0))
    assert r[0] == 1.5
    # Beam 1 (15 deg) hits the same wall at 1.5 / cos(15 deg).
    assert r[1] == pytest.approx(1.5 / math.cos(math.radians(15)), abs=1e-5)
    # The same wall seen from the other side, robot turned around: beam 0 still reads it.
    r = _cast(lidar_jit, wall, (3.25, 0.0, math.pi))
    assert r[0] == pytest.approx(1.25, abs=1e-6)
    # A wall ahead of a robot heading +y (the beam is rotated with the heading).
    r = _cast(lidar_jit, [[-1.0, 1.75, 1.0, 1.75]], (0.0, 0.0, math.pi / 2))
    assert r[0] == pytest.approx(1.75, abs=1e-6)


def test_beam_exactly_through_box_corner(lidar_jit):
    # Axis-aligned box [2, 4] x [0, 2]: beam 0 from the origin runs along its bottom edge
    # (collinear, so no hit from that edge) and enters at the corner (2, 0).
    box = worlds.box_segments(3.0, 1.0, 2.0, 2.0, 0.0)
    assert _cast(lidar_jit, box, (0.0, 0.0, 0.0))[0] == 2.0
    # A box entirely below the beam that touches it only at its corner (2, 0): a graze.
    box = worlds.box_segments(2.5, -0.5, 1.0, 1.0, 0.0)
    assert _cast(lidar_jit, box, (0.0, 0.0, 0.0))[0] == 2.0
    # Diagonal: beam 3 (45 deg) through the corner (1, 1) of the box [1, 2] x [1, 2]; whatever
    # rounding does to the beam direction, it must not slip between the two edges.
    box = worlds.box_segments(1.5, 1.5, 1.0, 1.0, 0.0)
    r = _cast(lidar_jit, box, (0.0, 0.0, 0.0))
    assert r[3] == pytest.approx(math.sqrt(2), abs=1e-5)
    # A wedge of two segments whose apex points at the robot.
    wedge = [[2.0, 0.0, 3.0, 1.0], [2.0, 0.0, 3.0, -1.0]]
    assert _cast(lidar_jit, wedge, (0.0, 0.0, 0.0))[0] == 2.0


def test_circle_tangent_to_beam(lidar_jit):
    pose = (0.0, 0.0, 0.0)
    # Beam 0 (along y = 0) touches the circle of radius 0.5 centred at (2, 0.5) at (2, 0).
    assert _cast(lidar_jit, np.zeros((0, 4)), pose, [[2.0, 0.5, 0.5]])[0] == 2.0
    # Moved off by 1 mm: a miss.
    assert _cast(lidar_jit, np.zeros((0, 4)), pose, [[2.0, 0.501, 0.5]])[0] == MAX_RANGE
    # Radius 1 cm larger: a hit at the chord's near end.
    r = _cast(lidar_jit, np.zeros((0, 4)), pose, [[2.0, 0.5, 0.51]])[0]
    assert r == pytest.approx(2.0 - math.sqrt(0.51**2 - 0.25), abs=1e-5)
    # Centre on the beam: front surface.
    assert _cast(lidar_jit, np.zeros((0, 4)), pose, [[3.0, 0.0, 0.5]])[0] == 2.5
    # A circle behind the robot is not seen ahead.
    assert _cast(lidar_jit, np.zeros((0, 4)), pose, [[-2.0, 0.0, 0.5]])[0] == MAX_RANGE


def test_beyond_max_range_reads_max_range(lidar_jit):
    wall = [[5.0, -10.0, 5.0, 10.0]]
    r = _cast(lidar_jit, wall, (0.0, 0.0, 0.0))
    assert r[0] == MAX_RANGE
    assert np.all(r == MAX_RANGE)
    r = _cast(lidar_jit, wall, (0.0, 0.0, 0.0), num_beams=24, max_range=6.0)
    assert r[0] == 5.0
    assert r[1] == pytest.approx(5.0 / math.cos(math.radians(15)), abs=1e-5)
    assert r[12] == 6.0
    # Exactly at max range, and a circle just beyond it.
    assert _cast(lidar_jit, [[3.5, -1.0, 3.5, 1.0]], (0.0, 0.0, 0.0))[0] == MAX_RANGE
    assert _cast(lidar_jit, np.zeros((0, 4)), (0.0, 0.0, 0.0), [[4.0, 0.0, 0.4]])[0] == MAX_RANGE
    # Nothing at all: everything max_range.
    assert np.all(_cast(lidar_jit, np.zeros((0, 4)), (1.0, 2.0, 0.3)) == MAX_RANGE)


def test_padding_is_ignored(lidar_jit, nearest_jit):
    pose = (0.3, -0.2, 0.7)
    segs = [[2.0, -3.0, 2.0, 3.0], [-1.0, 1.0, 1.0, 1.5]]
    circ = [[-1.0, -1.0, 0.4]]
    padded_segs = segs + [
        [0.3, -0.2, 0.3, -0.2],  # at the robot position
        [1.0, 0.4, 1.0, 0.4],  # on a beam, in front of the real wall
        [0.0, 0.0, 0.0, 0.0],
    ]
    padded_circ = circ + [[0.3, -0.2, 0.0], [1.2, 0.7, 0.0], [0.0, 0.0, 0.0]]
    base = _cast(lidar_jit, segs, pose, circ)
    padded = _cast(lidar_jit, padded_segs, pose, padded_circ)
    # (not bitwise: a different program shape may contract multiply-adds differently)
    np.testing.assert_allclose(padded, base, atol=1e-5)
    assert base.min() > 0.5  # the padding rows at 0 m would have shown
    # Padding is also never the nearest obstacle.
    d0 = float(nearest_jit(jnp.asarray(segs, jnp.float32), jnp.asarray(pose[:2]), jnp.asarray(circ)))
    d1 = float(nearest_jit(jnp.asarray(padded_segs, jnp.float32), jnp.asarray(pose[:2]),
                           jnp.asarray(padded_circ)))
    assert d0 == pytest.approx(d1, abs=1e-6) and d0 > 0.5
    # A world of nothing but padding sees nothing.
    only_pad = _cast(lidar_jit, padded_segs[2:], pose, padded_circ[1:])
    assert np.all(only_pad == MAX_RANGE)
    # No circles (None) and an empty circle array agree.
    np.testing.assert_array_equal(_cast(lidar_jit, segs, pose), _cast(lidar_jit, segs, pose, np.zeros((0, 3))))


def test_beam_index_convention(lidar_jit):
    angles = np.asarray(beam_angles(24))
    assert angles[0] == 0.0
    assert angles[6] == pytest.approx(math.pi / 2, abs=1e-6)
    assert angles[12] == pytest.approx(math.pi, abs=1e-6)
    np.testing.assert_allclose(np.diff(angles), 2 * math.pi / 24, rtol=1e-5)
    # A short wall 1.5 m to the left (+y) of a robot heading +x: only beam 6 sees it.
    left = [[-0.05, 1.5, 0.05, 1.5]]
    r = _cast(lidar_jit, left, (0.0, 0.0, 0.0))
    assert r[6] == pytest.approx(1.5, abs=1e-6)
    assert np.all(np.delete(r, 6) == MAX_RANGE)
    # To the right: beam 18. At 45 deg to the left: beam 3 (counter-clockwise order).
    r = _cast(lidar_jit, [[-0.05, -1.5, 0.05, -1.5]], (0.0, 0.0, 0.0))
    assert np.argmin(r) == 18 and np.sum(r < MAX_RANGE) == 1
    c = math.sqrt(0.5)
    r = _cast(lidar_jit, [[c - 0.05, c + 0.05, c + 0.05, c - 0.05]], (0.0, 0.0, 0.0))
    assert np.argmin(r) == 3 and np.sum(r < MAX_RANGE) == 1
    # Rotating the robot by +90 deg brings the left wall to beam 0.
    r = _cast(lidar_jit, left, (0.0, 0.0, math.pi / 2))
    assert r[0] == pytest.approx(1.5, abs=1e-6) and np.sum(r < MAX_RANGE) == 1
    # Rotating by a whole beam step shifts the readings by one beam.
    wall = [[2.0, -3.0, 2.0, 3.0], [-3.0, 1.0, 3.0, 1.0]]
    r0 = _cast(lidar_jit, wall, (0.0, 0.0, 0.0))
    r1 = _cast(lidar_jit, wall, (0.0, 0.0, 2 * math.pi / 24))
    np.testing.assert_allclose(r1[:-1], r0[1:], atol=1e-5)


# ----------------------------------------------------------------------------- nearest distance


def test_nearest_distance_matches_brute_force(nearest_jit):
    rng = np.random.default_rng(77)
    n_worlds, n_points = 10, 40
    segs, circs, pts = [], [], []
    for _ in range(n_worlds):
        s, c = random_world(rng)
        segs.append(s)
        circs.append(c)
        p = []
        while len(p) < n_points:  # outside every circle (inside, see the next test)
            q = rng.uniform(-4, 4, 2)
            if all(math.hypot(q[0] - cx, q[1] - cy) > r for cx, cy, r in c):
                p.append(q)
        pts.append(_f32(p))
    segs, circs, pts = np.stack(segs), np.stack(circs), np.stack(pts)
    dist = jax.jit(jax.vmap(jax.vmap(nearest_distance, (None, 0, None))))
    got = np.asarray(dist(jnp.asarray(segs, jnp.float32), jnp.asarray(pts, jnp.float32),
                          jnp.asarray(circs, jnp.float32)))
    want = np.array([[nearest_ref(segs[w], pts[w, i], circs[w]) for i in range(n_points)]
                     for w in range(n_worlds)])
    np.testing.assert_allclose(got, want, atol=1e-5)
    # Both kinds of obstacle are the nearest one somewhere.
    seg_only = np.array([[nearest_ref(segs[w], pts[w, i]) for i in range(n_points)] for w in range(n_worlds)])
    assert 0.05 < (want < seg_only - 1e-9).mean() < 0.95


def test_nearest_distance_hand_cases(nearest_jit):
    seg = jnp.asarray([[0.0, 0.0, 2.0, 0.0]], jnp.float32)

    def nd(p, circles=None):
        c = None if circles is None else jnp.asarray(circles, jnp.float32)
        return float(nearest_jit(seg, jnp.asarray(p, jnp.float32), c))

    assert nd((1.0, 0.75)) == 0.75  # perpendicular foot inside the segment
    assert nd((3.0, 0.0)) == 1.0  # beyond an endpoint: distance to the endpoint
    assert nd((-0.3, -0.4)) == pytest.approx(0.5, abs=1e-6)
    assert nd((1.0, 0.0)) == 0.0  # on the segment
    assert nd((1.0, 3.0), [[1.0, 2.0, 0.5]]) == pytest.approx(0.5, abs=1e-6)  # circle surface
    # Inside a cylinder is a collision (reads below any positive collision distance).
    assert nd((1.0, 2.0), [[1.0, 2.0, 0.5]]) < 0.25
