"""The culled lidar and clearance (fedjax_nav/env/cull.py, docs/dense_rooms.md "Culling per tile").

`method="culled"` must return, bit for bit, what the chunked loop returns: under a vmap over the
poses of one room (the culled program), under a vmap whose rooms are batched with the poses (the
chunked loop, vmapped), for one pose, and for poses vmapped twice over one room; and both must
agree with the float64 references of tests/test_geometry.py. Rooms are small (12 x 12 m and less),
but have more rows than a chunk of every kind, so that each code path of the culled program runs:
segments culled by window or cast for every pose, circles culled by row or cast for every pose.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_geometry import lidar_ref, nearest_ref, random_world

from fedjax_nav import worlds
from fedjax_nav.env import cull, geometry, raycast

NUM_BEAMS, MAX_RANGE = 24, 3.5


def _room(seed, num_segments, num_circles, extent=6.0):
    """Walls of a 2 extent square, random segments (padding rows among them) and circles."""
    rng = np.random.default_rng(seed)
    segs, circ = random_world(rng, num_segments=max(num_segments, 2), num_circles=max(num_circles, 2), extent=extent)
    walls = worlds.wall_segments([2 * extent, 2 * extent]).reshape(-1, 4).astype(np.float32)
    segs = np.concatenate([walls, segs[:num_segments]]).astype(np.float32)
    circ = circ[:num_circles]
    circ[:, 2] *= 0.3  # thinner cylinders: more of them are seen
    return segs, circ.astype(np.float32)


def _poses(seed, n, extent=6.0, grid=False):
    """Random poses inside the walls, or (grid) poses on a 0.5 m grid with headings along the axes
    (beams exactly parallel to the walls: the grazing cases)."""
    rng = np.random.default_rng(seed)
    if grid:
        xs = np.arange(-extent + 0.5, extent, 0.5)
        xy = np.stack(np.meshgrid(xs, xs), -1).reshape(-1, 2)[:n]
        th = (np.arange(len(xy)) % 4) * (np.pi / 2)
        return np.c_[xy, th].astype(np.float32)
    return np.c_[rng.uniform(-extent + 0.2, extent - 0.2, (n, 2)), rng.uniform(-np.pi, np.pi, n)].astype(np.float32)


def _step(method):
    def step(s, p, c):
        return (
            geometry.lidar(s, p, NUM_BEAMS, MAX_RANGE, c, method=method),
            geometry.nearest_distance(s, p[:2], c, method=method),
        )

    return step


def _same(a, b):
    for x, y in zip(a, b):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


# Rows per kind against the chunks (lidar 8, clearance 16): segments culled or cast for all.
ROOMS = {
    "walls+circles": (0, 120),  # 4 segments (cast for every pose), 120 circles (culled)
    "segments+circles": (60, 90),  # both culled (segments by window)
    "segments+few circles": (60, 6),  # circles cast for every pose after the tiles
}


@pytest.mark.parametrize("kind", list(ROOMS))
def test_shared_room_bitwise_chunked_and_near_the_references(kind):
    segs, circ = _room(1, *ROOMS[kind])
    poses = np.concatenate([_poses(2, 200), _poses(3, 100, grid=True)])
    args = (jnp.asarray(segs), jnp.asarray(poses), jnp.asarray(circ))
    got, want = (jax.jit(jax.vmap(_step(m), (None, 0, None)))(*args) for m in ("culled", "chunked"))
    _same(got, want)
    ranges, near = (np.asarray(a) for a in got)
    for i in range(0, len(poses), 15):
        if nearest_ref(segs, poses[i, :2], circ) > 0.02:  # outside every obstacle
            np.testing.assert_allclose(ranges[i], lidar_ref(segs, poses[i], circles=circ), atol=1e-4)
        assert near[i] == pytest.approx(nearest_ref(segs, poses[i, :2], circ), abs=1e-5)
    assert 0.3 < (ranges < MAX_RANGE).mean() < 1.0  # beams see something, not everything


def test_rooms_batched_with_their_poses_keep_the_chunked_loop():
    """Per-pose layout (a room per pose) and a stack of rooms each shared by its poses (the
    culled program run room by room), against the chunked loop; and one pose unbatched."""
    rooms = [_room(s, 20, 40) for s in (4, 5)]
    segs = jnp.asarray(np.stack([r[0] for r in rooms]))
    circ = jnp.asarray(np.stack([r[1] for r in rooms]))
    poses = jnp.asarray(np.stack([_poses(6, 64), _poses(7, 64)]))
    shared = [jax.jit(jax.vmap(jax.vmap(_step(m), (None, 0, None))))(segs, poses, circ) for m in ("culled", "chunked")]
    _same(*shared)
    idx = np.repeat(np.arange(2), 64)
    flat = (segs[idx], poses.reshape(-1, 3), circ[idx])
    per_pose = [jax.jit(jax.vmap(_step(m)))(*flat) for m in ("culled", "chunked")]
    _same(*per_pose)
    one = (segs[0], poses[0, 0], circ[0])
    _same(jax.jit(_step("culled"))(*one), jax.jit(_step("chunked"))(*one))


def test_per_pose_layout_is_the_chunked_program():
    """With a room per pose the batching rule hands back the chunked loop: no sort in the program."""
    segs, circ = _room(8, 20, 40)
    n = 8
    args = (jnp.broadcast_to(segs, (n, *segs.shape)), jnp.asarray(_poses(9, n)), jnp.broadcast_to(circ, (n, 40, 3)))
    per_pose = str(jax.make_jaxpr(jax.vmap(_step("culled")))(*args))
    shared = str(jax.make_jaxpr(jax.vmap(_step("culled"), (None, 0, None)))(args[0][0], args[1], args[2][0]))
    assert " sort[" not in per_pose and " sort[" in shared


def test_poses_vmapped_twice_over_one_room_are_one_batch():
    segs, circ = _room(10, 12, 50)
    poses = jnp.asarray(_poses(11, 96).reshape(3, 32, 3))
    fns = [jax.vmap(jax.vmap(_step(m), (None, 0, None)), (None, 0, None)) for m in ("culled", "chunked")]
    _same(*(jax.jit(f)(jnp.asarray(segs), poses, jnp.asarray(circ)) for f in fns))


def test_clearance_beyond_the_radius_falls_back_to_every_row():
    """Poses farther than NEAREST_RADIUS from every obstacle: the tile is measured again over
    every row (and the result is still the chunked loop's)."""
    segs, circ = _room(12, 20, 30, extent=6.0)
    far = np.array([[20.0 + i, -20.0, 0.3] for i in range(40)], np.float32)  # outside the room, far from it
    poses = jnp.asarray(np.concatenate([_poses(13, 40), far]))
    fns = [jax.jit(jax.vmap(_step(m), (None, 0, None))) for m in ("culled", "chunked")]
    got, want = (f(jnp.asarray(segs), poses, jnp.asarray(circ)) for f in fns)
    _same(got, want)
    assert (np.asarray(got[1])[40:] > cull.NEAREST_RADIUS).all()


def test_tiles_cull_most_rows_of_a_large_room():
    """Not vacuous: in a 20 x 20 m room of 400 cylinders a tile's candidates are a small part."""
    rng = np.random.default_rng(14)
    circ = jnp.asarray(np.c_[rng.uniform(-9.7, 9.7, (400, 2)), rng.uniform(0.05, 0.15, 400)].astype(np.float32))
    poses = jnp.asarray(_poses(15, 512, extent=10.0))
    dx, dy = jax.vmap(lambda p: raycast._beams(p, NUM_BEAMS))(poses)
    _, _, tlo, thi = cull._tiles(*cull._sector_boxes(poses, dx, dy, MAX_RANGE, 4), cull.TILE)
    _, counts = cull._candidates(tlo, thi, *cull._circle_boxes(circ), cull.CIRCLE_CHUNK)
    assert 0 < np.asarray(counts).mean() < 0.25 * 400


def test_helpers_exact():
    rng = np.random.default_rng(16)
    mask = jnp.asarray(rng.random((5, 1003)) < 0.3)
    np.testing.assert_array_equal(np.asarray(cull._cumsum(mask)), np.cumsum(np.asarray(mask), 1))
    order = np.asarray(cull._morton_order(jnp.asarray(rng.uniform(-5, 5, (777, 2)).astype(np.float32))))
    np.testing.assert_array_equal(np.sort(order), np.arange(777))
    row_lo, row_hi = jnp.asarray([[0.5, 0.5], [2, 2], [-1, 0.2]]), jnp.asarray([[0.6, 0.6], [3, 3], [0.1, 0.3]])
    lists, counts = cull._candidates(jnp.zeros((1, 2)), jnp.ones((1, 2)), row_lo, row_hi, 4)
    assert int(counts[0]) == 2 and np.asarray(lists[0]).tolist() == [0, 2, 3, 3]
