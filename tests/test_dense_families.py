"""The dense procedural families (forest, warehouse, maze, cave; docs/generator.md): fixed shapes,
solvability by the independent grid search of tests/test_generate.py (also at lower densities),
the density knob, the spec checks, the held-out suites and the CLI.

Each family's rooms are drawn once (`drawn`: one compiled, vmapped call per family with the
density traced, so every density reuses it). docs/generator.md says how many more rooms were
checked by hand with the same checker.
"""

import math
from dataclasses import replace

import jax
import numpy as np
import pytest
from test_generate import D_C, cli, draw_families, family_keys, nearest, real_rows, room_at, unreachable_pairs

from fedjax_nav import worlds
from fedjax_nav.worlds import WorldError, procedural, rooms, shapes, suites

KEYS = 12  # rooms per family at density 1: 4 of the family's held-out suite, 8 training rooms
DENSITIES = (1.0, 0.5, 0.0)
LOW = 4  # rooms per family checked at each lower density


@pytest.fixture(scope="module")
def drawn():
    """{family: (spec, {density: (World [KEYS], info)})}; one compilation per family."""
    return draw_families(rooms.DENSE_FAMILIES, KEYS, DENSITIES)


def obstacles(room):
    """Segment rows beyond the 4 outer walls and circle rows of a room (float64, padding dropped)."""
    return room["segments"][4:], room["circles"]


# ----------------------------------------------------------------------------- shapes and the spec


def test_families_and_their_padded_shapes():
    assert rooms.FAMILIES == rooms.BASE_FAMILIES + rooms.DENSE_FAMILIES + rooms.INDOOR_FAMILIES
    nx, ny = shapes.maze_grid(rooms.make_spec("maze"))  # 10 m / 0.8 m cells
    assert (nx, ny) == (12, 12)
    rows, secs = shapes.warehouse_slots(rooms.make_spec("warehouse"))  # 18 m, aisles 0.9, racks 0.6 x 2
    assert (rows, secs) == (11, 5)
    assert shapes.padded_shape(rooms.make_spec("forest")) == (4, 150, 4, 2)
    assert shapes.padded_shape(rooms.make_spec("warehouse")) == (4 + 4 * 40, 1, 4, 2)  # warehouse_boxes
    assert shapes.padded_shape(rooms.make_spec("maze")) == (4 + 2 * 11 * 6, 1, 4, 2)
    assert shapes.padded_shape(rooms.make_spec("cave")) == (4 + 192, 1, 4, 2)
    # larger maxima pad further (shapes only), e.g. to one shape with the base families and playgrounds
    for family in rooms.DENSE_FAMILIES:
        big = rooms.make_spec(family, max_segments=300, max_circles=160, max_starts=6, max_goals=5)
        shaped = jax.eval_shape(lambda k, big=big: worlds.generate(k, big), jax.random.key(0))
        assert (shaped.segments.shape, shaped.circles.shape) == ((300, 4), (160, 3))
        assert (shaped.starts.shape, shaped.goals.shape) == ((6, 3), (5, 2))
    # None sizes take the family's; given ones are kept
    assert (rooms.RoomSpec(family="forest").width_min, rooms.RoomSpec(family="cave").trail_points) == (8.0, 2)
    assert rooms.make_spec("maze", width_max=7.0).width_max == 7.0


@pytest.mark.parametrize("family", rooms.DENSE_FAMILIES)
def test_shapes_counts_and_endpoints(drawn, family):
    spec, by_density = drawn[family]
    M, C, S, G = shapes.padded_shape(spec)
    world, info = by_density[1.0]
    assert world.segments.shape == (KEYS, M, 4) and world.circles.shape == (KEYS, C, 3)
    assert world.starts.shape == (KEYS, S, 3) and world.goals.shape == (KEYS, G, 2)
    assert np.all(info["distance_ok"])
    for i in range(KEYS):
        room = real_rows(world, i)
        size = room["size"]
        assert spec.width_min <= size[0] <= spec.width_max and spec.height_min <= size[1] <= spec.height_max
        np.testing.assert_allclose(np.asarray(world.segments)[i, :4], worlds.wall_segments(size), atol=1e-6)
        segs, circles = obstacles(room)
        assert np.all(np.abs(segs.reshape(-1, 2)) <= size / 2 + 1e-4)  # every obstacle inside the room
        assert np.all(np.abs(circles[:, :2]) + circles[:, 2:] <= size / 2 + 1e-4)
        for p in np.concatenate([room["starts"][:, :2], room["goals"]]):
            assert np.all(np.abs(p) < size / 2) and nearest(room, p) >= spec.clearance - 1e-4
        dist = np.hypot(*(room["starts"][:, None, :2] - room["goals"][None]).transpose(2, 0, 1))
        assert dist.min() >= spec.min_start_goal_distance - 1e-4
    if family == "forest":
        trees = np.count_nonzero(np.asarray(world.circles)[..., 2] > 0, axis=1)
        np.testing.assert_array_equal(trees, info["trees"])
        assert np.all((info["trees_requested"] >= spec.trees_min) & (info["trees_requested"] <= spec.trees_max))
        assert info["trees"].sum() >= 0.9 * info["trees_requested"].sum()
        r = np.asarray(world.circles)[..., 2]
        assert np.all((r[r > 0] >= spec.trunk_radius_min - 1e-6) & (r[r > 0] <= spec.trunk_radius_max + 1e-6))
    if family == "warehouse":
        assert np.all(info["racks"] >= 1) and info["racks"].max() >= 8
        # box slot k is segment rows 4 + 4k .. 4k + 7: the edges of the box info["box_rows"][k], or zeros;
        # the used slots come first: racks, then pallets
        np.testing.assert_array_equal(np.asarray(info["box_on"]).sum(1), info["racks"] + info["pallets"])
        assert np.all(info["boxes_dropped"] == 0)
        blocks = np.asarray(world.segments)[:, 4:].reshape(KEYS, -1, 4, 4)
        on, rows = np.asarray(info["box_on"]), np.asarray(info["box_rows"])
        for i, k in zip(*np.nonzero(on)):
            corners = np.sort(blocks[i, k, :, :2].round(4), axis=0)
            want = np.sort(worlds.box_segments(*rows[i, k])[:, :2].round(4), axis=0)
            np.testing.assert_allclose(corners, want, atol=2e-4)
        assert np.all(blocks[~on] == 0)
    if family == "cave":
        assert np.all(info["outline_dropped"] == 0) and np.all(info["occupied"] > 0)


# ----------------------------------------------------------------------------- solvability


@pytest.mark.parametrize("density", DENSITIES)
@pytest.mark.parametrize("family", rooms.DENSE_FAMILIES)
def test_every_start_reaches_every_goal_with_clearance(drawn, family, density):
    """The independent check of tests/test_generate.py: a 4-connected grid search over 0.04 m
    cells whose centres keep more than D_c + 0.02 m from every obstacle (exact float64
    distances). A path through such cell centres keeps more than D_c everywhere, and the
    generator's guaranteed path (clearance c = D_c + 0.05) passes through such cells."""
    _, by_density = drawn[family]
    world, _ = by_density[density]
    n = KEYS if density == 1.0 else LOW
    failures = [i for i in range(n) if unreachable_pairs(real_rows(world, i), 0.04, D_C + 0.02, 4)]
    assert not failures, f"{family} at density {density}: unsolvable rooms {failures}"


def test_the_check_sees_a_blocked_maze():
    """A maze room with one passage closed by a segment across it is reported unsolvable."""
    w, _ = worlds.from_dict(
        {
            "size": [3.0, 1.0],
            "segments": [[-0.5, -0.5, -0.5, 0.5]],
            "starts": [[-1.0, 0.0, 0.0]],
            "goals": [[1.0, 0.0]],
        }
    )
    assert unreachable_pairs(real_rows(w), 0.04, D_C + 0.02, 4) == [(0, 0)]


# ----------------------------------------------------------------------------- density


@pytest.mark.parametrize("family", rooms.DENSE_FAMILIES)
def test_density_thins_toward_an_empty_room(drawn, family):
    spec, by_density = drawn[family]
    full, half, empty = (by_density[d] for d in DENSITIES)
    # density 1 is the room `generate` draws by default
    default = jax.jit(lambda k: worlds.generate(k, spec))(family_keys(family, KEYS, suite=4)[5])
    for a, b in zip(jax.tree.leaves(default), jax.tree.leaves(room_at(full[0], 5))):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-5)
    for i in range(LOW):
        r1, r5, r0 = (real_rows(w, i) for w, _ in (full, half, empty))
        assert all(len(x) == 0 for x in obstacles(r0)), "density 0: walls only"
        np.testing.assert_array_equal(r5["starts"], r1["starts"])  # starts, goals and size do not move
        np.testing.assert_array_equal(r5["goals"], r1["goals"])
        s1, c1 = obstacles(r1)
        s5, c5 = obstacles(r5)
        if family == "forest":  # the kept trunks are trunks of the full room
            assert len(c5) == int(half[1]["trees"][i]) <= len(c1)
            assert all(np.any(np.all(np.abs(c1 - c) < 1e-6, -1)) for c in c5)
        if family in ("warehouse", "maze"):  # every segment lies on one of the full room's
            assert len(s5) < len(s1) or family == "maze"
            for x1, y1, x2, y2 in s5:
                d = np.maximum(
                    worlds.point_segment_distance_np(np.array([x1, y1]), s1),
                    worlds.point_segment_distance_np(np.array([x2, y2]), s1),
                )
                assert d.min() < 1e-5
            length = lambda s: np.hypot(s[:, 2] - s[:, 0], s[:, 3] - s[:, 1]).sum()  # noqa: E731
            assert length(s5) < length(s1)
        if family == "cave":
            assert int(half[1]["occupied"][i]) <= int(full[1]["occupied"][i])


# ----------------------------------------------------------------------------- structure


def test_warehouse_slots_are_tight_and_the_maze_is_perfect():
    wh = rooms.make_spec(
        "warehouse",
        width_min=18.0,
        height_min=18.0,
        aisle_width_max=0.9,
        rack_depth_max=0.6,
        rack_length_max=2.0,
        rack_fill=1.0,
        pallets_min=0,
        pallets_max=0,
        warehouse_boxes=64,
    )
    _, info = jax.jit(lambda k: procedural.generate_with_info(k, wh))(suites.train_room_key(1))
    assert int(info["racks"]) == math.prod(shapes.warehouse_slots(wh)) == 55  # the largest layout fills every slot
    # with fewer box slots than racks the last racks go (fewer obstacles), reported
    _, info = jax.jit(lambda k: procedural.generate_with_info(k, replace(wh, warehouse_boxes=40)))(
        suites.train_room_key(1)
    )
    assert (int(info["racks"]), int(info["boxes_dropped"])) == (40, 15)
    mz = rooms.make_spec("maze", maze_loops=0.0, width_min=10.0, height_min=10.0, maze_cell_max=0.8)
    _, info = jax.jit(lambda k: procedural.generate_with_info(k, mz))(suites.train_room_key(2))
    nx, ny = shapes.maze_grid(mz)
    assert int(info["cells"]) == nx * ny
    # a spanning tree of n cells opens n - 1 of the (nx - 1) ny + nx (ny - 1) inner sides
    assert int(info["maze_walls"]) == (nx - 1) * ny + nx * (ny - 1) - (nx * ny - 1)


@pytest.mark.parametrize(
    "family, overrides, field",
    [
        ("warehouse", {"aisle_width_min": 0.6}, "aisle_width_min"),  # not > 2 (D_c + margin)
        ("maze", {"maze_cell_min": 0.5, "maze_cell_max": 0.9}, "maze_cell_min"),
        ("maze", {"maze_cell_max": 5.5}, "maze_cell_max"),
        ("maze", {"maze_cell_max": 4.8, "maze_cell_min": 4.6, "width_min": 4.0}, "maze_cell_max"),  # > width_min
        ("forest", {"trees_max": 20}, "trees_max"),  # < trees_min
        ("forest", {"trees_max": 500}, "trees_max"),
        ("cave", {"cave_fill_max": 1.5}, "cave_fill_max"),
        ("cave", {"cave_segments": 4}, "cave_segments"),
        ("cave", {"max_segments": 100}, "max_segments"),  # cave needs 196
    ],
)
def test_bad_dense_spec_names_the_field(family, overrides, field):
    with pytest.raises(WorldError) as e:
        rooms.make_spec(family, **overrides)
    assert f"'{field}'" in str(e.value) and "allowed" in str(e.value) and "\n" not in str(e.value)


# ----------------------------------------------------------------------------- suites, files, CLI


def test_dense_suites_are_held_out_and_disjoint():
    names = [n for n, s in suites.SUITES.items() if s.family in rooms.DENSE_FAMILIES]
    assert len(names) == 3 * len(rooms.DENSE_FAMILIES)
    dense = np.concatenate([suites.suite_seeds(n) for n in names])
    base = np.concatenate([suites.suite_seeds(n) for n, s in suites.SUITES.items() if s.family in rooms.BASE_FAMILIES])
    assert np.all(suites.is_test_seed(dense)) and not set(dense.tolist()) & set(base.tolist())
    assert len(set(dense.tolist())) == len(dense)
    assert suites.suite_names("dense-heldout") == tuple(f"{f}-50x4" for f in rooms.DENSE_FAMILIES)
    assert suites.SUITES["maze-50x4"].spec().goals_min == 4


def test_a_dense_suite_is_the_rooms_of_its_seeds(drawn):
    world, spec = suites.suite("maze-50")
    assert spec == rooms.make_spec("maze") and world.size.shape == (50, 2)
    np.testing.assert_allclose(
        np.asarray(world.segments)[:4], np.asarray(drawn["maze"][1][1.0][0].segments)[:4], atol=1e-5
    )


@pytest.mark.parametrize("family", rooms.DENSE_FAMILIES)
def test_world_file_round_trip(drawn, family, tmp_path):
    _, by_density = drawn[family]
    one = room_at(by_density[1.0][0], 3)
    loaded = worlds.load(suites.save_world(one, tmp_path / f"{family}.json"))
    a, b = real_rows(one), real_rows(loaded)
    for k in a:
        np.testing.assert_array_equal(a[k].astype(np.float32), b[k].astype(np.float32), err_msg=k)


def test_cli_generates_a_dense_room(tmp_path, capsys):
    out = tmp_path / "maze.json"
    assert cli(["worlds", "generate", "--family", "maze", "--seed", "5", "--out", str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    w = worlds.load(out)
    assert w.segments.shape[0] > 10  # the maze's walls
    assert (
        cli(["worlds", "generate", "--family", "maze", "--seed", "5", "--out", str(out), "--set", "maze_cell_min=0.5"])
        == 2
    )
    assert "maze_cell_min" in capsys.readouterr().err


def test_the_configs_room_families_are_the_generators():
    """`env.room_families` accepts exactly the generator's families (and `fixed`): config keeps
    its own tuple because it does not import jax."""
    from fedjax_nav.config import ROOM_FAMILIES
    from fedjax_nav.worlds.rooms import FAMILIES

    assert set(ROOM_FAMILIES) == {*FAMILIES, "fixed"}
