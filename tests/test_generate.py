"""Procedural rooms (fedjax_nav/worlds/rooms.py, procedural.py, suites.py): determinism, jit/vmap and fixed shapes,
the spec's ranges, bad specs, world-file round trips, held-out suites, the CLI verb, and
solvability of thousands of rooms against an independent float64 grid search.

Every family's rooms are drawn once per session (`batches`: 512 rooms per family in one
compiled, vmapped call each) and shared by the tests.
"""

import hashlib
import json
import math
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import ndimage

from fedjax_nav import worlds
from fedjax_nav.cli import build_parser
from fedjax_nav.worlds import WorldError, procedural, rooms, shapes, suites

# The generator's names in one namespace (specs: rooms, their static shapes: shapes, the JAX
# generator: procedural, keys, suites and files: suites).
gen = types.SimpleNamespace(**{**vars(rooms), **vars(shapes), **vars(procedural), **vars(suites)})

D_C = 0.25  # the collision distance
RES = 0.05  # grid resolution of the independent check (m)
ROOMS_PER_FAMILY = 512  # 4 x 512 = 2048 rooms checked


# ----------------------------------------------------------------------------- the independent check


def real_rows(world, i=None):
    """Float64 numpy arrays of one room's non-padding rows (room i of a stacked World)."""
    take = (lambda a: np.asarray(a)[i]) if i is not None else np.asarray
    segs = take(world.segments).astype(np.float64)
    circles = take(world.circles).astype(np.float64)
    return {
        "segments": segs[np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]) > 0],
        "circles": circles[circles[:, 2] > 0],
        "starts": take(world.starts).astype(np.float64)[: int(take(world.num_starts))],
        "goals": take(world.goals).astype(np.float64)[: int(take(world.num_goals))],
        "size": take(world.size).astype(np.float64),
    }


def free_grid(room, res=RES, clearance=D_C):
    """Occupancy grid over the room's inner area (cell centres (xs, ys), spacing `res`): a cell
    is free if its centre is more than `clearance` from every segment and circle (exact float64
    point-segment / point-circle distances; only cells within reach of an obstacle are tested)."""
    W, H = room["size"]
    nx, ny = int(W // res), int(H // res)
    xs = (np.arange(nx) - (nx - 1) / 2) * res
    ys = (np.arange(ny) - (ny - 1) / 2) * res
    free = np.ones((ny, nx), bool)
    reach = clearance + res

    def block(x0, x1, y0, y1):
        i = slice(np.searchsorted(xs, x0 - reach), np.searchsorted(xs, x1 + reach, "right"))
        j = slice(np.searchsorted(ys, y0 - reach), np.searchsorted(ys, y1 + reach, "right"))
        return j, i, xs[i][None, :], ys[j][:, None]

    for x1, y1, x2, y2 in room["segments"]:
        j, i, px, py = block(min(x1, x2), max(x1, x2), min(y1, y2), max(y1, y2))
        ex, ey = x2 - x1, y2 - y1
        t = np.clip(((px - x1) * ex + (py - y1) * ey) / (ex * ex + ey * ey), 0.0, 1.0)
        d = np.hypot(px - (x1 + t * ex), py - (y1 + t * ey))
        free[j, i] &= d > clearance
    for cx, cy, r in room["circles"]:
        j, i, px, py = block(cx - r, cx + r, cy - r, cy + r)
        free[j, i] &= np.hypot(px - cx, py - cy) - r > clearance
    return free, xs, ys


def unreachable_pairs(room, res=RES, clearance=D_C, connectivity=8):
    """The (start, goal) index pairs with no path of free cells (BFS = connected components of
    the free cells, 8- or 4-connected) from the start's cell to the goal's cell."""
    free, xs, ys = free_grid(room, res, clearance)
    structure = np.ones((3, 3), bool) if connectivity == 8 else ndimage.generate_binary_structure(2, 1)
    labels, _ = ndimage.label(free, structure=structure)

    def label_at(p):
        i = int(np.clip(np.rint(p[0] / res + (len(xs) - 1) / 2), 0, len(xs) - 1))
        j = int(np.clip(np.rint(p[1] / res + (len(ys) - 1) / 2), 0, len(ys) - 1))
        return labels[j, i]

    bad = []
    for si, s in enumerate(room["starts"]):
        ls = label_at(s[:2])
        for gi, g in enumerate(room["goals"]):
            if ls == 0 or label_at(g) != ls:
                bad.append((si, gi))
    return bad


def room_at(world, i):
    """Room i of a stacked World, as a World of jax arrays."""
    return jax.tree.map(lambda leaf: jnp.asarray(np.asarray(leaf)[i]), world)


def nearest(room, p):
    """Float64 distance from p to the nearest segment or circle surface of a room."""
    segs = room["segments"]
    d = worlds.point_segment_distance_np(np.asarray(p[:2]), segs).min()
    if len(room["circles"]):
        c = room["circles"]
        d = min(d, (np.hypot(p[0] - c[:, 0], p[1] - c[:, 1]) - c[:, 2]).min())
    return d


# ----------------------------------------------------------------------------- fixtures


def family_keys(family, n=ROOMS_PER_FAMILY, suite=50):
    """`n` keys: the first `suite` rooms of the family's held-out suite, then training keys."""
    suite_seeds = gen.suite_seeds(f"{family}-50")[:suite]
    suite_keys = jax.vmap(gen.room_key)(jnp.asarray(suite_seeds))
    train_keys = jax.vmap(gen.train_room_key)(jnp.arange(n - len(suite_seeds)))
    return jnp.concatenate([suite_keys, train_keys])


def draw_families(families, n, densities):
    """{family: (spec, {density: (World [n], info)})}: 4 held-out and n - 4 training rooms of each
    family at each density, one compiled, vmapped call per family (the density is traced)."""
    out = {}
    for family in families:
        spec = rooms.make_spec(family)
        f = jax.jit(jax.vmap(lambda k, d, spec=spec: procedural.generate_with_info(k, spec, d), (0, None)))
        keys = family_keys(family, n, suite=4)
        out[family] = (spec, {d: jax.device_get(f(keys, d)) for d in densities})
        assert f._cache_size() == 1  # one program for every density
    return out


@pytest.fixture(scope="session")
def batches():
    """{family: (spec, stacked World [512], info)} drawn once per session."""
    out = {}
    for family in gen.BASE_FAMILIES:
        spec = gen.RoomSpec(family=family)
        world, info = gen.generate_batch_with_info(family_keys(family), spec)
        out[family] = (spec, jax.device_get(world), jax.device_get(info))
    return out


# ----------------------------------------------------------------------------- the base families are unchanged

# sha256 (first 16 hex digits) of the session batches (World, then info: 50 suite rooms + 462
# training rooms per family) and of 8 mixture rooms at density 0.4, recorded on CPU (jax 0.10.2)
# with the generator as it was before the dense families were added: the base families' rooms,
# their held-out suites included, must stay bit for bit what they were.
BASE_DIGESTS = {
    "cylinders": ("604787aa8e4c17a7", "f41ee00e3359fe28"),
    "boxes": ("13233af2bb3f261d", "d44ca324c029f355"),
    "walls": ("b787d741eade1565", "c5631c2c592c8ec7"),
    "mixture": ("76275b4c2b7177ea", "1708c4c85a0e4fed"),
}
MIXTURE_DENSITY_04 = "788cb45516bfc278"
# The base families' suites: (family, rooms, seed block, overrides) and the groups, as they were.
BASE_SUITES = {
    **{f"{f}-50": (f, 50, i, ()) for i, f in enumerate(gen.BASE_FAMILIES)},
    **{f"{f}-50x4": (f, 50, 4 + i, (("goals_min", 4), ("goals_max", 4))) for i, f in enumerate(gen.BASE_FAMILIES)},
    **{f"{f}-probe": (f, 4, 8 + i, (("goals_min", 2), ("goals_max", 2))) for i, f in enumerate(gen.BASE_FAMILIES)},
}


def digest(tree):
    h = hashlib.sha256()
    for leaf in jax.tree.leaves(tree):
        a = np.asarray(leaf)
        h.update(str(a.dtype).encode())
        h.update(str(a.shape).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


@pytest.mark.parametrize("family", gen.BASE_FAMILIES)
def test_base_family_rooms_are_bitwise_what_they_were(batches, family):
    spec, world, info = batches[family]
    assert spec == gen.make_spec(family) and (spec.width_min, spec.width_max) == (4.0, 12.0)
    assert (digest(world), digest(info)) == BASE_DIGESTS[family]


def test_base_family_density_and_suites_are_what_they_were():
    spec = gen.RoomSpec(family="mixture")
    keys = jax.vmap(gen.train_room_key)(jnp.arange(8))
    assert digest(jax.jit(jax.vmap(lambda k: worlds.generate(k, spec, 0.4)))(keys)) == MIXTURE_DENSITY_04
    for name, (family, n, block, overrides) in BASE_SUITES.items():
        s = gen.SUITES[name]
        assert (s.family, s.rooms, s.index, s.overrides) == (family, n, block, overrides), name
    assert gen.SUITE_GROUPS["heldout"] == tuple(f"{f}-50x4" for f in gen.BASE_FAMILIES)
    assert gen.SUITE_GROUPS["probe"] == tuple(f"{f}-probe" for f in gen.BASE_FAMILIES)
    assert gen.SUITE_GROUPS["families-50"] == tuple(f"{f}-50" for f in gen.BASE_FAMILIES)


# ----------------------------------------------------------------------------- determinism, jit, vmap


def test_same_key_same_room_and_keys_differ(batches):
    spec, world, _ = batches["cylinders"]
    f = gen.jitted_generator(spec)  # the jitted one-room generator (shared with generate_to_file)
    key = gen.train_room_key(3)
    a, b = f(key), f(key)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    # jit of one key agrees with row 53 of the vmapped batch (training key 3 is row 50 + 3)
    row = jax.tree.map(lambda leaf: np.asarray(leaf)[53], world)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(row)):
        np.testing.assert_allclose(np.asarray(x), y, atol=1e-5)
    # different keys, different rooms
    assert len({tuple(np.asarray(world.size)[i].round(5)) for i in range(ROOMS_PER_FAMILY)}) == ROOMS_PER_FAMILY


@pytest.mark.parametrize("family", gen.BASE_FAMILIES)
def test_shapes_are_fixed_by_the_spec(batches, family):
    spec, world, _ = batches[family]
    M, C, S, G = gen.padded_shape(spec)
    n = ROOMS_PER_FAMILY
    assert world.segments.shape == (n, M, 4) and world.circles.shape == (n, C, 3)
    assert world.starts.shape == (n, S, 3) and world.goals.shape == (n, G, 2)
    assert world.num_starts.shape == (n,) and world.num_goals.shape == (n,) and world.size.shape == (n, 2)
    assert world.segments.dtype == jnp.float32 and world.num_starts.dtype == jnp.int32
    # larger maxima pad further (shapes only: no compilation)
    big = gen.RoomSpec(family=family, max_segments=64, max_circles=32, max_starts=6, max_goals=5)
    shaped = jax.eval_shape(lambda k: worlds.generate(k, big), jax.random.key(0))
    assert shaped.segments.shape == (64, 4) and shaped.circles.shape == (32, 3)
    assert shaped.starts.shape == (6, 3) and shaped.goals.shape == (5, 2)


def test_padded_shapes_of_each_family():
    assert gen.padded_shape(gen.RoomSpec(family="cylinders")) == (4, 8, 4, 2)
    assert gen.padded_shape(gen.RoomSpec(family="boxes")) == (4 + 4 * 5, 1, 4, 2)
    assert gen.padded_shape(gen.RoomSpec(family="walls")) == (4 + 2 * 3, 1, 4, 2)
    assert gen.padded_shape(gen.RoomSpec(family="mixture")) == (4 + 2 * 3 + 4 * 5, 8, 4, 2)


# ----------------------------------------------------------------------------- the spec's ranges


@pytest.mark.parametrize("family", gen.BASE_FAMILIES)
def test_counts_and_sizes_lie_in_the_spec_ranges(batches, family):
    spec, world, info = batches[family]
    n = ROOMS_PER_FAMILY
    size = np.asarray(world.size)
    assert np.all((size[:, 0] >= spec.width_min) & (size[:, 0] <= spec.width_max))
    assert np.all((size[:, 1] >= spec.height_min) & (size[:, 1] <= spec.height_max))
    ns, ng = np.asarray(world.num_starts), np.asarray(world.num_goals)
    assert np.all((ns >= spec.starts_min) & (ns <= spec.starts_max))
    assert np.all((ng >= spec.goals_min) & (ng <= spec.goals_max))
    assert set(ns) == set(range(spec.starts_min, spec.starts_max + 1))  # every count occurs
    n_wall_slots = spec.walls_max if spec.uses("walls") else 0
    for kind, lo, hi in (
        ("walls", spec.walls_min, spec.walls_max),
        ("boxes", spec.boxes_min, spec.boxes_max),
        ("cylinders", spec.cylinders_min, spec.cylinders_max),
    ):
        placed, asked = np.asarray(info[kind]), np.asarray(info[f"{kind}_requested"])
        if not spec.uses(kind):
            assert np.all(placed == 0) and np.all(asked == 0)
            continue
        assert np.all((asked >= lo) & (asked <= hi)) and set(asked) == set(range(lo, hi + 1))
        assert np.all(placed <= asked)
        # a few obstacles or walls may not fit a small room; nearly all do
        assert placed.sum() >= 0.95 * asked.sum(), (kind, placed.sum(), asked.sum())
    if spec.uses("walls"):
        assert np.all(np.asarray(info["walls"]) >= 1)  # the first wall always fits (check_spec)
    segs = np.asarray(world.segments)
    circles = np.asarray(world.circles)
    for i in range(n):
        room = real_rows(world, i)
        # segments: 4 walls + 2 per interior wall + 4 per box, in their blocks
        nw, nb = int(info["walls"][i]), int(info["boxes"][i])
        assert len(room["segments"]) == 4 + 2 * nw + 4 * nb
        np.testing.assert_allclose(segs[i, :4], worlds.wall_segments(size[i]), atol=1e-6)
        r = room["circles"][:, 2]
        assert len(r) == int(info["cylinders"][i])
        assert np.all((r >= spec.radius_min - 1e-6) & (r <= spec.radius_max + 1e-6))
        assert np.all(np.abs(room["circles"][:, :2]) <= size[i] / 2 + 1e-5)
        # boxes: slot k is segment rows 4 + 2 * wall slots + 4k .. +4, the box's edges, or zeros
        n_box_slots = spec.boxes_max if spec.uses("boxes") else 0
        blk = segs[i, 4 + 2 * n_wall_slots :][: 4 * n_box_slots].reshape(n_box_slots, 4, 4)
        for k in range(n_box_slots):
            b = np.asarray(info["box_rows"])[i, k]
            if np.asarray(info["box_on"])[i, k]:
                assert np.all((b[2:4] >= spec.box_side_min - 1e-6) & (b[2:4] <= spec.box_side_max + 1e-6))
                np.testing.assert_allclose(blk[k], worlds.box_segments(*b), atol=1e-4)
            else:
                assert np.all(blk[k] == 0) and np.all(b == 0)
        assert int(np.asarray(info["box_on"])[i].sum()) == nb if n_box_slots else nb == 0
        # walls: slot w is segment rows 4 + 2w, 5 + 2w around its doorway, or zeros
        for w in range(n_wall_slots):
            s1, s2 = segs[i, 4 + 2 * w], segs[i, 5 + 2 * w]
            if not s1.any():
                assert not s2.any()
                continue
            gap = math.hypot(s2[0] - s1[2], s2[1] - s1[3])
            assert spec.door_width_min - 1e-4 <= gap <= spec.door_width_max + 1e-4
        # starts and goals: inside, at least D_c + margin from every obstacle, far apart
        c = spec.clearance
        for p in np.concatenate([room["starts"][:, :2], room["goals"]]):
            assert np.all(np.abs(p) < size[i] / 2)
            assert nearest(room, p) >= c - 1e-4
        assert np.all(np.abs(room["starts"][:, 2]) <= math.pi)
        dist = np.hypot(*(room["starts"][:, None, :2] - room["goals"][None]).transpose(2, 0, 1))
        assert dist.min() >= spec.min_start_goal_distance - 1e-4
        # padding rows: starts and goals repeat row 0, unused obstacle rows are zero
        np.testing.assert_array_equal(
            np.asarray(world.starts)[i, len(room["starts"]) :],
            np.broadcast_to(np.asarray(world.starts)[i, 0], (spec.starts_max - len(room["starts"]), 3)),
        )
        assert np.all(circles[i][circles[i, :, 2] == 0] == 0)
    assert np.all(np.asarray(info["distance_ok"]))
    # start yaw is random: spread over the circle
    yaws = np.asarray(world.starts)[:, 0, 2]
    assert yaws.min() < -2.5 and yaws.max() > 2.5


# ----------------------------------------------------------------------------- bad specs


@pytest.mark.parametrize(
    "overrides, field",
    [
        ({"family": "jungle"}, "family"),
        ({"width_min": 1.0}, "width_min"),
        ({"width_max": 3.5}, "width_max"),  # < width_min
        ({"height_max": 99.0}, "height_max"),
        ({"cylinders_max": 40}, "cylinders_max"),
        ({"cylinders_max": 2.5}, "cylinders_max"),
        ({"radius_min": float("nan")}, "radius_min"),
        ({"boxes_min": -1}, "boxes_min"),
        ({"box_side_max": 0.2}, "box_side_max"),  # < box_side_min
        ({"walls_max": 9}, "walls_max"),
        ({"door_width_min": 0.55}, "door_width_min"),  # not > 2 (D_c + margin) = 0.6
        ({"room_side_min": 1.5}, "room_side_min"),  # < door_width_max + 0.6
        ({"room_side_min": 2.5}, "room_side_min"),  # > max(width_min, height_min) / 2
        ({"starts_min": 0}, "starts_min"),
        ({"goals_max": 17}, "goals_max"),
        ({"min_start_goal_distance": -1.0}, "min_start_goal_distance"),
        ({"clearance_margin": 0.0}, "clearance_margin"),
        ({"tries": 0}, "tries"),
        ({"max_segments": 20}, "max_segments"),  # mixture needs 30
        ({"max_circles": 4}, "max_circles"),
        ({"max_starts": 2}, "max_starts"),
        ({"max_goals": 1}, "max_goals"),
    ],
)
def test_bad_spec_raises_world_error_naming_the_field(overrides, field):
    with pytest.raises(WorldError) as e:
        gen.check_spec(gen.RoomSpec(**overrides))
    msg = str(e.value)
    assert f"'{field}'" in msg and "allowed" in msg and "\n" not in msg
    with pytest.raises(WorldError, match=field):  # generate checks too
        jax.eval_shape(lambda k: worlds.generate(k, gen.RoomSpec(**overrides)), jax.random.key(0))


def test_fields_of_unused_kinds_do_not_matter_but_are_still_range_checked():
    gen.check_spec(gen.RoomSpec(family="cylinders", door_width_min=0.3, room_side_min=0.5))  # no walls: fine
    with pytest.raises(WorldError, match="boxes_max"):
        gen.check_spec(gen.RoomSpec(family="cylinders", boxes_max=99))
    with pytest.raises(WorldError, match="unknown RoomSpec field 'cylinder_max'"):
        gen.make_spec("cylinders", cylinder_max=3)


def test_every_field_documented_with_a_range():
    ranges = gen.field_ranges()
    assert set(ranges) == set(gen.SPEC_FIELDS) - {"family"}
    for name, (default, lo, hi, doc) in ranges.items():
        assert doc and lo < hi
        assert default is None or lo <= default <= hi, name
    gen.check_spec(gen.RoomSpec())  # the defaults are valid


# ----------------------------------------------------------------------------- files


@pytest.mark.parametrize("family", gen.BASE_FAMILIES)
@pytest.mark.parametrize("suffix", [".json", ".yaml"])
def test_save_load_round_trip_gives_the_same_obstacles(batches, family, suffix, tmp_path):
    spec, world, _ = batches[family]
    for i in (0, 7, 301):
        one = room_at(world, i)
        path = gen.save_world(one, tmp_path / f"{family}-{i}{suffix}")
        loaded = worlds.load(path)
        a, b = real_rows(one), real_rows(loaded)
        for k in a:
            np.testing.assert_array_equal(a[k].astype(np.float32), b[k].astype(np.float32), err_msg=f"{k}")
        assert loaded.segments.shape[0] == len(a["segments"])  # no padding written
        d = gen.to_spec_dict(one)
        assert len(d["segments"]) == len(a["segments"]) - 4  # the outer walls are not written
        assert len(d["starts"]) == int(one.num_starts) and len(d["goals"]) == int(one.num_goals)
        # padded back to the generator's shapes: the same starts and goals, padding included
        repadded = worlds.pad(loaded, *gen.padded_shape(spec))
        np.testing.assert_array_equal(np.asarray(repadded.starts), np.asarray(one.starts))
        np.testing.assert_array_equal(np.asarray(repadded.goals), np.asarray(one.goals))
        assert int(repadded.num_starts) == int(one.num_starts) and int(repadded.num_goals) == int(one.num_goals)


def test_to_spec_dict_refuses_a_stacked_world(batches):
    with pytest.raises(WorldError, match="one world at a time"):
        gen.to_spec_dict(batches["walls"][1])


def test_generate_to_file_and_generated_worlds_stack_with_shipped_ones(tmp_path):
    path = gen.generate_to_file("cylinders", 12, tmp_path / "room.json")
    spec = json.loads(path.read_text())
    assert spec["name"] == "room" and "family=cylinders, seed=12" in spec["description"]
    assert 1 <= len(spec["circles"]) <= 8 and spec["segments"] == []
    w = worlds.load(path)
    stacked = worlds.stack([w, worlds.load("train-0")])
    assert stacked.segments.shape[0] == 2
    again = gen.generate_to_file("cylinders", 12, tmp_path / "again.json")
    assert json.loads(again.read_text())["circles"] == spec["circles"]  # same seed, same room
    with pytest.raises(WorldError, match="seed"):
        gen.generate_to_file("cylinders", -1, tmp_path / "x.json")
    with pytest.raises(WorldError, match="family"):
        gen.generate_to_file("jungle", 1, tmp_path / "x.json")


# ----------------------------------------------------------------------------- solvability


@pytest.mark.parametrize("family", gen.BASE_FAMILIES)
def test_every_start_reaches_every_goal_by_an_independent_grid_search(batches, family):
    """Each of 512 rooms per family (2048 in all): a BFS over a 0.05 m grid whose free cells are
    more than D_c (exact float64 distances) from every obstacle finds a path from every start's
    cell to every goal's cell."""
    _, world, _ = batches[family]
    failures = []
    for i in range(ROOMS_PER_FAMILY):
        bad = unreachable_pairs(real_rows(world, i))
        if bad:
            failures.append((i, bad))
    assert not failures, f"{len(failures)} unsolvable rooms, first: {failures[:5]}"


def test_solvable_with_a_continuous_guarantee_on_a_finer_grid(batches):
    """A stricter check on some rooms: 4-connected cells whose centres are more than
    D_c + res/2 from everything (so the polyline through the cell centres itself keeps > D_c)."""
    for family in ("walls", "mixture"):
        _, world, _ = batches[family]
        for i in range(0, ROOMS_PER_FAMILY, 16):
            room = real_rows(world, i)
            assert not unreachable_pairs(room, res=0.02, clearance=D_C + 0.01, connectivity=4), (family, i)


def test_the_checker_detects_unsolvable_rooms():
    def room(**kw):
        w, _ = worlds.from_dict({"size": [6.0, 4.0], "starts": [[-2.0, 0.0, 0.0]], "goals": [[2.0, 0.0]], **kw})
        return real_rows(w)

    assert not unreachable_pairs(room())  # empty room: solvable
    # a dividing wall with a 0.7 m doorway (> 2 D_c): solvable; 0.4 m (< 2 D_c): not
    assert not unreachable_pairs(room(segments=[[0.0, -2.0, 0.0, -0.35], [0.0, 0.35, 0.0, 2.0]]))
    assert unreachable_pairs(room(segments=[[0.0, -2.0, 0.0, -0.2], [0.0, 0.2, 0.0, 2.0]])) == [(0, 0)]
    # a closed wall
    assert unreachable_pairs(room(segments=[[0.0, -2.0, 0.0, 2.0]])) == [(0, 0)]
    # the goal ringed by cylinders whose gaps (0.3 m) are narrower than 2 D_c
    ring = [[2.0 + 0.8 * math.cos(a), 0.8 * math.sin(a), 0.2] for a in np.linspace(0, 2 * math.pi, 9)[:-1]]
    gaps = 2 * 0.8 * math.sin(math.pi / 8) - 0.4
    assert gaps < 2 * D_C
    assert unreachable_pairs(room(circles=ring)) == [(0, 0)]
    # two starts, two goals: only the goal inside a closed square of thin walls is unreachable
    square = [[1.4, -0.6, 2.6, -0.6], [2.6, -0.6, 2.6, 0.6], [2.6, 0.6, 1.4, 0.6], [1.4, 0.6, 1.4, -0.6]]
    w, _ = worlds.from_dict(
        {
            "size": [6.0, 4.0],
            "starts": [[-2.0, 0.0, 0.0], [-2.0, 1.0, 0.0]],
            "goals": [[2.0, 0.0], [-1.0, -1.0]],
            "segments": square,
        }
    )
    assert unreachable_pairs(real_rows(w)) == [(0, 0), (1, 0)]
    # a start boxed in by the room's walls and a box
    assert unreachable_pairs(room(boxes=[[-1.5, 0.0, 1.4, 6.0, 0.0]], starts=[[-2.6, 0.0, 0.0]])) == [(0, 0)]


def test_segment_box_distance_is_exact():
    """The generator's segment-to-box distance against a float64 reference: 0 when the segment
    crosses an edge or lies inside, else the least of the edge-to-segment distances."""
    rng = np.random.default_rng(0)
    n = 1500
    a, b = rng.uniform(-2, 2, (n, 2)), rng.uniform(-2, 2, (n, 2))
    b[:150] = a[:150] + rng.uniform(-0.05, 0.05, (150, 2))  # short ones, some inside
    b[150:250, 1] = a[150:250, 1]  # axis-parallel ones
    cen, half, yaw = rng.uniform(-1, 1, (n, 2)), rng.uniform(0.05, 1.0, (n, 2)), rng.uniform(0, np.pi, n)
    yaw[250:350] = 0.0
    got = np.asarray(
        gen.seg_box(
            jnp.asarray(a, jnp.float32),
            jnp.asarray(b, jnp.float32),
            jnp.asarray(cen, jnp.float32),
            jnp.asarray(half, jnp.float32),
            jnp.asarray(yaw, jnp.float32),
        )
    )

    def cross(u, v):
        return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]

    def pt_seg(p, q, r):  # float64 point-segment distance, vectorised
        qr, qp = r - q, p - q
        t = np.clip((qp * qr).sum(-1) / np.maximum((qr * qr).sum(-1), 1e-300), 0, 1)
        return np.linalg.norm(qp - t[..., None] * qr, axis=-1)

    want = np.full(n, np.inf)
    for k in range(4):  # edge k of every box, in float64 from worlds.box_segments
        e = np.array([worlds.box_segments(*cen[i], *(2 * half[i]), yaw[i])[k] for i in range(n)])
        r, q = e[:, :2], e[:, 2:]
        crossing = (cross(b - a, r - a) * cross(b - a, q - a) < 0) & (cross(q - r, a - r) * cross(q - r, b - r) < 0)
        d = np.minimum(np.minimum(pt_seg(a, r, q), pt_seg(b, r, q)), np.minimum(pt_seg(r, a, b), pt_seg(q, a, b)))
        want = np.minimum(want, np.where(crossing, 0.0, d))
    rel = a - cen
    lx = np.cos(yaw) * rel[:, 0] + np.sin(yaw) * rel[:, 1]
    ly = -np.sin(yaw) * rel[:, 0] + np.cos(yaw) * rel[:, 1]
    want[(np.abs(lx) <= half[:, 0]) & (np.abs(ly) <= half[:, 1])] = 0.0  # wholly inside
    np.testing.assert_allclose(got, want, atol=2e-5)
    assert (got == 0).sum() > 200 and (got > 0).sum() > 200


# ----------------------------------------------------------------------------- suites and key streams


def test_suite_seeds_are_test_seeds_and_training_keys_never_are():
    all_test = np.concatenate([gen.suite_seeds(name) for name in gen.SUITES])
    # per family: the 50-room suite, the 50-room 4-goal suite and the 4-room probe
    assert len(set(all_test.tolist())) == len(all_test) == (50 + 50 + 4) * len(gen.FAMILIES)
    assert np.all(gen.is_test_seed(all_test))
    assert not gen.is_test_seed(0) and not gen.is_test_seed(2**31 - 1) and gen.is_test_seed(2**31)
    # train_room_key maps every counter into the training half: counter 2**31 + j is seed j
    idx = jnp.asarray([0, 5, 2**31 - 1], jnp.uint32)
    same = jax.vmap(gen.train_room_key)(idx + jnp.uint32(2**31))
    np.testing.assert_array_equal(jax.random.key_data(same), jax.random.key_data(jax.vmap(gen.train_room_key)(idx)))
    # and no training key equals a test key (fold_in is injective in the seed)
    test_keys = np.asarray(jax.random.key_data(jax.vmap(gen.room_key)(jnp.asarray(all_test))))
    train = np.asarray(jax.random.key_data(jax.vmap(gen.train_room_key)(jnp.arange(20000))))

    def as_set(a):
        return {tuple(r) for r in a.tolist()}

    assert not as_set(test_keys) & as_set(train)
    assert len(as_set(train)) == 20000 and len(as_set(test_keys)) == len(all_test)
    with pytest.raises(WorldError, match="no test suite"):
        gen.suite_seeds("nope")


def test_suite_returns_its_rooms(batches):
    world, spec = gen.suite("cylinders-50")
    assert spec == gen.RoomSpec(family="cylinders")
    assert world.size.shape == (50, 2)
    # the suite's rooms are rows 0..49 of the session batch (generated from the same keys)
    np.testing.assert_allclose(np.asarray(world.circles), np.asarray(batches["cylinders"][1].circles)[:50], atol=1e-5)


def test_generation_inside_lax_scan():
    spec = gen.RoomSpec(family="cylinders", starts_max=2, goals_max=1, cylinders_max=3, tries=4)

    def body(carry, i):
        w = worlds.generate(gen.train_room_key(i), spec)
        return carry + w.size.sum(), w.num_starts

    total, ns = jax.jit(lambda: jax.lax.scan(body, 0.0, jnp.arange(4, dtype=jnp.uint32)))()
    assert ns.shape == (4,) and float(total) > 4 * 2 * 4.0


# ----------------------------------------------------------------------------- CLI


def cli(argv):
    args = build_parser().parse_args(argv)
    return args.func(args)


def test_cli_generate_writes_a_loadable_file(tmp_path, capsys):
    out = tmp_path / "r.yaml"
    assert (
        cli(
            [
                "worlds",
                "generate",
                "--family",
                "cylinders",
                "--seed",
                "4",
                "--out",
                str(out),
                "--set",
                "starts_min=4",
                "--set",
                "max_goals=none",
            ]
        )
        == 0
    )
    assert "wrote" in capsys.readouterr().out
    w = worlds.load(out)
    assert w.starts.shape == (4, 3) and w.segments.shape == (4, 4)


@pytest.mark.parametrize(
    "argv, words",
    [
        (["--family", "jungle", "--seed", "1"], ["family", "jungle", "cylinders", "forest", "cave"]),
        (["--family", "walls", "--seed", "x"], ["seed"]),
        (["--family", "walls", "--seed", "1", "--set", "nope=3"], ["unknown", "nope"]),
        (["--family", "walls", "--seed", "1", "--set", "walls_max=lots"], ["walls_max", "integer"]),
        (["--family", "walls", "--seed", "1", "--set", "walls_max=20"], ["walls_max", "allowed"]),
        (["--family", "walls", "--seed", "1", "--set", "walls_max"], ["field=value"]),
    ],
)
def test_cli_bad_input_exits_2_with_one_line(tmp_path, capsys, argv, words):
    assert cli(["worlds", "generate", "--out", str(tmp_path / "x.json"), *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err and "Traceback" not in err
    for w in words:
        assert w in err
    assert not (tmp_path / "x.json").exists()
