"""Lidar raycasting and nearest-obstacle distance against float64 numpy references and hand cases.

The references below are written independently of the JAX code: a ray is intersected with a
segment's supporting line through the line's normal and the hit point is then projected onto
the segment; a ray is intersected with a circle through its closest approach to the centre.

Both implementations are tested: the unrolled loop (small rooms, `method="auto"` here) and the
chunked loop of dense rooms (docs/dense_rooms.md): the hand cases run on both (the `lidar_jit`
and `nearest_jit` fixtures of this module), the chunked loop is checked against the references
on dense random worlds, and the unrolled loop is checked bitwise against a copy of the code it
replaced on the shipped playgrounds.
"""

import math
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fedjax_nav import worlds
from fedjax_nav.env import beam_angles, geometry, lidar, nearest_distance

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
    circ = np.concatenate([rng.uniform(-extent, extent, (num_circles, 2)), rng.uniform(0.1, 0.7, (num_circles, 1))], -1)
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


# ----------------------------------------------------------------------------- both implementations
# These override the session fixtures of conftest.py in this module: every hand case below runs
# once through `lidar` / `nearest_distance` (small worlds: the unrolled loop) and once through the
# chunked loop with chunks of 2 rows, so that a few rows already exercise both the loop over full
# chunks and the rows left over after it.


def _chunked_lidar(segments, pose, num_beams=NUM_BEAMS, max_range=MAX_RANGE, circles=None):
    return geometry._lidar_chunked(segments, pose, num_beams, max_range, circles, chunk=2)


def _chunked_nearest(segments, point, circles=None):
    return geometry._nearest_chunked(segments, point, circles, chunk=2)


@pytest.fixture(scope="module", params=["unrolled", "chunked"])
def implementation(request):
    return request.param


@pytest.fixture(scope="module")
def lidar_jit(implementation):
    fn = lidar if implementation == "unrolled" else _chunked_lidar
    return jax.jit(fn, static_argnames=("num_beams", "max_range"))


@pytest.fixture(scope="module")
def nearest_jit(implementation):
    return jax.jit(nearest_distance if implementation == "unrolled" else _chunked_nearest)


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

    cast = jax.jit(jax.vmap(jax.vmap(lambda s, p, c: lidar(s, p, num_beams, max_range, c), (None, 0, None))))
    got = np.asarray(
        cast(jnp.asarray(segs, jnp.float32), jnp.asarray(poses, jnp.float32), jnp.asarray(circs, jnp.float32))
    )
    want = np.stack(
        [
            [lidar_ref(segs[w], poses[w, i], num_beams, max_range, circs[w]) for i in range(n_poses)]
            for w in range(n_worlds)
        ]
    )
    assert got.shape == (n_worlds, n_poses, num_beams) and got.dtype == np.float32
    err = np.abs(got - want)
    assert err.max() < 1e-3, f"max error {err.max():.3g} m at {np.unravel_index(err.argmax(), err.shape)}"
    # The comparison is not vacuous: many beams hit something, many see nothing.
    hit = want < max_range
    assert 0.2 < hit.mean() < 0.95
    # ... and circles are hit too (the segments-only cast is longer on some beams).
    segs_only = np.stack(
        [[lidar_ref(segs[w], poses[w, i], num_beams, max_range) for i in range(n_poses)] for w in range(n_worlds)]
    )
    assert (want < segs_only - 1e-6).mean() > 0.02


def test_lidar_matches_reference_on_shipped_worlds():
    """All shipped playgrounds stacked (so padded), at random collision-free poses."""
    rng = np.random.default_rng(99)
    stacked = worlds.load_many(worlds.SHIPPED)
    n_poses = 40
    poses = []
    for name in worlds.SHIPPED:
        w, meta = worlds.load_with_meta(name)
        half = np.asarray(w.size, np.float64) / 2
        boxes = meta["boxes"]

        def inside(p, boxes=boxes):
            return any(_in_box(p, b) for b in boxes)

        poses.append(
            random_free_poses(
                rng,
                np.asarray(w.segments),
                np.asarray(w.circles),
                n_poses,
                -half[0],
                half[0],
                margin=0.25,
                inside=inside,
            )
        )
    poses = np.stack(poses)
    cast = jax.jit(jax.vmap(jax.vmap(lambda s, p, c: lidar(s, p, circles=c), (None, 0, None))))
    got = np.asarray(cast(stacked.segments, jnp.asarray(poses, jnp.float32), stacked.circles))
    segs, circs = np.asarray(stacked.segments, np.float64), np.asarray(stacked.circles, np.float64)
    want = np.stack(
        [
            [lidar_ref(segs[w], poses[w, i], circles=circs[w]) for i in range(n_poses)]
            for w in range(len(worlds.SHIPPED))
        ]
    )
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
    d1 = float(nearest_jit(jnp.asarray(padded_segs, jnp.float32), jnp.asarray(pose[:2]), jnp.asarray(padded_circ)))
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
    got = np.asarray(
        dist(jnp.asarray(segs, jnp.float32), jnp.asarray(pts, jnp.float32), jnp.asarray(circs, jnp.float32))
    )
    want = np.array([[nearest_ref(segs[w], pts[w, i], circs[w]) for i in range(n_points)] for w in range(n_worlds)])
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


# ----------------------------------------------------------------------------- dense rooms: the chunked loop


def _count_eqns(jaxpr) -> int:
    """Equations of a jaxpr, those of its sub-jaxprs (loop bodies) included."""
    n = 0
    for eqn in jaxpr.eqns:
        n += 1
        for v in eqn.params.values():
            for sub in v if isinstance(v, (tuple, list)) else (v,):
                if hasattr(sub, "eqns"):  # a Jaxpr
                    n += _count_eqns(sub)
                elif hasattr(getattr(sub, "jaxpr", None), "eqns"):  # a ClosedJaxpr
                    n += _count_eqns(sub.jaxpr)
    return n


def _has_loop(fn, *args) -> bool:
    jaxpr = jax.make_jaxpr(fn)(*args).jaxpr
    return any(e.primitive.name in ("while", "scan") for e in jaxpr.eqns)


def test_path_chosen_by_row_count():
    pose = jnp.zeros(3, jnp.float32)
    limit = geometry.UNROLL_MAX_ROWS
    # The shipped playgrounds, even stacked to their common padded shape, stay unrolled.
    stacked = worlds.load_many(worlds.SHIPPED)
    assert stacked.segments.shape[1] + stacked.circles.shape[1] <= limit
    for m, c, loop in [(limit - 10, 10, False), (limit - 9, 10, True), (limit + 1, 0, True)]:
        segs, circ = jnp.zeros((m, 4)), jnp.zeros((c, 3))
        assert _has_loop(lambda s, p, cc: lidar(s, p, circles=cc), segs, pose, circ) == loop, (m, c)
        assert _has_loop(lambda s, p, cc: nearest_distance(s, p[:2], cc), segs, pose, circ) == loop, (m, c)
    # circles=None counts no rows.
    assert not _has_loop(lambda s, p: lidar(s, p), jnp.zeros((limit, 4)), pose)
    # Forced either way.
    assert _has_loop(lambda s, p: lidar(s, p, method="chunked"), jnp.zeros((16, 4)), pose)
    assert not _has_loop(lambda s, p: lidar(s, p, method="unrolled"), jnp.zeros((limit + 1, 4)), pose)
    with pytest.raises(ValueError, match="method"):
        lidar(jnp.zeros((4, 4)), pose, method="fast")


# A copy of the unrolled code as it was before the chunked path existed (the reference for
# "the thesis rooms' numerics are unchanged"): the auto path must reproduce it bit for bit.


def _old_lidar(segments, pose, num_beams=24, max_range=3.5, circles=None):
    x, y, theta = pose[0], pose[1], pose[2]
    ang = theta + beam_angles(num_beams)
    dx, dy = jnp.cos(ang), jnp.sin(ang)
    best_num = jnp.full((num_beams,), max_range, jnp.float32)
    best_den = jnp.ones((num_beams,), jnp.float32)
    for m in range(segments.shape[0]):
        seg = segments[m]
        px, py = seg[0] - x, seg[1] - y
        ex, ey = seg[2] - seg[0], seg[3] - seg[1]
        w_cross_e = px * ey - py * ex
        den = dx * ey - dy * ex
        w_cross_d = px * dy - py * dx
        sgn = jnp.where(den >= 0.0, 1.0, -1.0)
        t_num, u_num, t_den = w_cross_e * sgn, w_cross_d * sgn, den * sgn
        closer = (
            (t_den > 1e-12) & (t_num >= 0.0) & (u_num >= 0.0) & (u_num <= t_den) & (t_num * best_den < best_num * t_den)
        )
        best_num = jnp.where(closer, t_num, best_num)
        best_den = jnp.where(closer, t_den, best_den)
    best = best_num / best_den
    if circles is not None:
        for c in range(circles.shape[0]):
            wx, wy, r = circles[c, 0] - x, circles[c, 1] - y, circles[c, 2]
            cc = wx * wx + wy * wy - r * r
            b = wx * dx + wy * dy
            disc = b * b - cc
            t = b - jnp.sqrt(jnp.maximum(disc, 0.0))
            hit = (r > 0.0) & (disc >= 0.0) & (b >= 0.0) & (t >= 0.0) & (t < best)
            best = jnp.where(hit, t, best)
    return jnp.minimum(best, max_range)


def _old_nearest(segments, point, circles=None):
    best2 = jnp.float32(1e9)
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


def test_shipped_worlds_bitwise_unchanged():
    """All shipped playgrounds stacked (69 rows after padding), poses anywhere in and around
    them (inside obstacles too), one room per pose (the layout of a per-robot vmap)."""
    stacked = worlds.load_many(worlds.SHIPPED)
    n_worlds, n_poses = len(worlds.SHIPPED), 64
    rng = np.random.default_rng(2024)
    half = np.asarray(stacked.size)[:, None, :] / 2
    poses = np.concatenate(
        [rng.uniform(-1.05, 1.05, (n_worlds, n_poses, 2)) * half, rng.uniform(-7, 7, (n_worlds, n_poses, 1))], -1
    ).astype(np.float32)
    poses = jnp.asarray(poses)

    def step(lid, near):
        return lambda s, p, c: (lid(s, p, 24, 3.5, c), near(s, p[:2], c))

    idx = np.repeat(np.arange(n_worlds), n_poses)
    got, want = (
        jax.jit(jax.vmap(f))(stacked.segments[idx], poses.reshape(-1, 3), stacked.circles[idx])
        for f in (step(lidar, nearest_distance), step(_old_lidar, _old_nearest))
    )
    np.testing.assert_array_equal(np.asarray(got[0]), np.asarray(want[0]))
    np.testing.assert_array_equal(np.asarray(got[1]), np.asarray(want[1]))
    assert (np.asarray(got[0]) < MAX_RANGE).mean() > 0.3  # not vacuous


def test_chunked_matches_float64_reference_on_dense_worlds():
    """Worlds of 160 segments (some padding) and 80 circles (one padding) in 12 x 12 m: the
    default (auto) path is the chunked loop; vmapped over worlds and over poses."""
    rng = np.random.default_rng(31)
    n_worlds, n_poses = 3, 48
    segs, circs, poses = [], [], []
    for _ in range(n_worlds):
        s, c = random_world(rng, num_segments=160, num_circles=80, extent=6.0)
        segs.append(s)
        circs.append(c)
        poses.append(random_free_poses(rng, s, c, n_poses, -6.0, 6.0))
    segs, circs, poses = np.stack(segs), np.stack(circs), np.stack(poses)
    assert segs.shape[1] + circs.shape[1] > geometry.UNROLL_MAX_ROWS

    step = jax.jit(
        jax.vmap(
            jax.vmap(
                lambda s, p, c: (lidar(s, p, NUM_BEAMS, MAX_RANGE, c), nearest_distance(s, p[:2], c)), (None, 0, None)
            )
        )
    )
    got, got_near = (
        np.asarray(a)
        for a in step(jnp.asarray(segs, jnp.float32), jnp.asarray(poses, jnp.float32), jnp.asarray(circs, jnp.float32))
    )
    want = np.stack(
        [[lidar_ref(segs[w], poses[w, i], circles=circs[w]) for i in range(n_poses)] for w in range(n_worlds)]
    )
    want_near = np.array(
        [[nearest_ref(segs[w], poses[w, i, :2], circs[w]) for i in range(n_poses)] for w in range(n_worlds)]
    )
    err = np.abs(got - want)
    # The existing tests' bound is 1e-3 m; measured here: 1.1e-5 m (nearest_distance: 1e-7 m).
    assert err.max() < 1e-4, f"max error {err.max():.3g} m at {np.unravel_index(err.argmax(), err.shape)}"
    np.testing.assert_allclose(got_near, want_near, atol=1e-5)
    hit = want < MAX_RANGE
    assert 0.5 < hit.mean() < 0.99  # dense, but some beams see nothing within range
    # The chunked loop agrees with the unrolled one where both are cheap to compile.
    s, c, p = (jnp.asarray(a[0, :20], jnp.float32) for a in (segs, circs, poses))
    both = [
        jax.jit(jax.vmap(lambda pp, m=m: lidar(s, pp, NUM_BEAMS, MAX_RANGE, c, method=m)))(p)
        for m in ("unrolled", "chunked")
    ]
    np.testing.assert_allclose(np.asarray(both[1]), np.asarray(both[0]), atol=1e-4)  # measured 4e-5 (a graze)


def test_thousand_cylinders_compile_fast_and_match_reference():
    """1,000 cylinders in a 20 x 20 m room: a bounded program (it does not grow with the rows),
    compiled in seconds (the unrolled program took 2-4 minutes and 1 GB more for this alone), exact."""
    rng = np.random.default_rng(5)
    walls = worlds.wall_segments([20.0, 20.0]).reshape(-1, 4).astype(np.float32)
    circ = np.c_[rng.uniform(-9.7, 9.7, (1000, 2)), rng.uniform(0.05, 0.15, 1000)].astype(np.float32)
    poses = np.c_[rng.uniform(-9.5, 9.5, (64, 2)), rng.uniform(-np.pi, np.pi, 64)].astype(np.float32)
    poses = poses[[all(math.hypot(p[0] - x, p[1] - y) > r for x, y, r in circ) for p in poses]]

    def step(s, p, c):
        return lidar(s, p, NUM_BEAMS, MAX_RANGE, c), nearest_distance(s, p[:2], c)

    fn = jax.jit(jax.vmap(step, (None, 0, None)))
    args = (jnp.asarray(walls), jnp.asarray(poses), jnp.asarray(circ))
    assert _count_eqns(jax.make_jaxpr(fn)(*args).jaxpr) < 3000  # measured 1,395; unrolled: 77,425
    t0 = time.perf_counter()
    compiled = fn.lower(*args).compile()
    assert time.perf_counter() - t0 < 30.0
    got, got_near = (np.asarray(a) for a in compiled(*args))
    for i in range(0, len(poses), 8):
        np.testing.assert_allclose(got[i], lidar_ref(walls, poses[i], circles=circ), atol=1e-4)
        assert got_near[i] == pytest.approx(nearest_ref(walls, poses[i, :2], circ), abs=1e-5)
    assert (got < MAX_RANGE).mean() > 0.3
