"""The indoor procedural families (office, corridors; docs/generator.md): fixed shapes, what each
draws (rooms and doors, obstacle counts, starts and goals in different rooms; corridor widths, goals
at the ends of branches), solvability by the independent grid search of tests/test_generate.py at
every density, the density knob, the spec checks, the held-out suites, files and one traced
program for a family mix. (The other families' rooms are held bit for bit by tests/test_generate.py.)

Each family's rooms are drawn once (`drawn`: one compiled, vmapped call per family with the density
traced, so every density reuses it).
"""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_generate import D_C, draw_families, nearest, real_rows, room_at, unreachable_pairs

from fedjax_nav import worlds
from fedjax_nav.worlds import WorldError, procedural, rooms, shapes, suites

FAMILIES = rooms.INDOOR_FAMILIES
KEYS = 200  # rooms per family at density 1: 4 of the family's held-out suite, 196 training rooms
DENSITIES = (1.0, 0.5, 0.0)
LOW = 8  # rooms per family checked at each lower density


@pytest.fixture(scope="module")
def drawn():
    """{family: (spec, {density: (World [KEYS], info)})}; one compilation per family."""
    return draw_families(FAMILIES, KEYS, DENSITIES)


def obstacles(room):
    """Segment rows beyond the 4 outer walls and circle rows of a room (float64, padding dropped)."""
    return room["segments"][4:], room["circles"]


def inside(p, box, tol=1e-4):
    """Whether points p [..., 2] lie in the box (x0, y0, x1, y1)."""
    return np.all((p >= box[..., :2] - tol) & (p <= box[..., 2:] + tol), -1)


# ----------------------------------------------------------------------------- shapes and the spec


def test_families_are_one_tuple_and_shapes_are_fixed():
    assert rooms.FAMILIES == rooms.BASE_FAMILIES + rooms.DENSE_FAMILIES + rooms.INDOOR_FAMILIES
    assert set(procedural.DENSE_BUILDERS) == set(rooms.DENSE_FAMILIES + rooms.INDOOR_FAMILIES)
    office = rooms.make_spec("office")
    assert shapes.office_grid(office) == (4, 3) and shapes.office_slots(office) == (34, 32, 48)
    assert shapes.padded_shape(office) == (4 + 34 + 4 * 32, 48, 4, 2)
    assert shapes.padded_shape(rooms.make_spec("corridors")) == (4 + 12 * 4 + 2 + 4 * 8, 1, 4, 2)
    for family in FAMILIES:  # larger maxima pad further; None sizes take the family's
        big = rooms.make_spec(family, max_segments=300, max_circles=160, max_starts=6, max_goals=5)
        shaped = jax.eval_shape(lambda k, big=big: worlds.generate(k, big), jax.random.key(0))
        assert (shaped.segments.shape, shaped.circles.shape) == ((300, 4), (160, 3))
        assert (shaped.starts.shape, shaped.goals.shape) == ((6, 3), (5, 2))
        assert (rooms.RoomSpec(family=family).width_min, rooms.RoomSpec(family=family).height_max) == (10.0, 18.0)


@pytest.mark.parametrize("family", FAMILIES)
def test_shapes_counts_and_endpoints(drawn, family):
    spec, by_density = drawn[family]
    M, C, S, G = shapes.padded_shape(spec)
    world, info = by_density[1.0]
    assert world.segments.shape == (KEYS, M, 4) and world.circles.shape == (KEYS, C, 3)
    assert world.starts.shape == (KEYS, S, 3) and world.goals.shape == (KEYS, G, 2)
    assert np.mean(info["distance_ok"]) >= 0.98
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
    if family == "office":
        assert set(np.unique(info["rooms"])) <= set(range(4, 13)) and info["rooms"].max() == 12
        w = np.asarray(info["door_width"])
        assert np.all((w[w > 0] >= spec.office_door_min - 1e-6) & (w[w > 0] <= spec.office_door_max + 1e-6))
        assert np.all(info["doors"] >= info["rooms"] - 1)  # a spanning tree of doors at least
        n = np.asarray(info["obstacles"])  # wall pieces + desks + round things
        assert n.max() <= 120 and np.mean((n >= 40) & (n <= 120)) >= 0.95, (n.min(), np.median(n), n.max())
        assert np.all(info["rooms_apart"])
        for i in range(KEYS):  # every start in a room, every goal in another
            boxes, room = np.asarray(info["room_boxes"])[i], real_rows(world, i)
            sr, gr = info["start_room"][i][: len(room["starts"])], info["goal_room"][i][: len(room["goals"])]
            assert np.all(inside(room["starts"][:, :2], boxes[sr])) and np.all(inside(room["goals"], boxes[gr]))
            assert not set(sr.tolist()) & set(gr.tolist())
    if family == "corridors":
        a = np.asarray(info["corridor_width"])
        assert np.all((a >= spec.corridor_width_min) & (a <= spec.corridor_width_max))
        assert set(np.unique(info["branches"])) == {1, 2, 3, 4} and info["side_rooms"].max() >= 3
        assert info["turns"].max() == 2 and np.any(info["boxes"] >= 5)
        for i in range(KEYS):  # every goal at the end of a branch: in its side room or its dead end's last metre
            goals = real_rows(world, i)["goals"]
            for g, b in zip(goals, np.asarray(info["goal_branch"])[i]):
                assert info["branch_on"][i, b]
                if info["side_room"][i, b]:
                    assert inside(g, np.asarray(info["room_boxes"])[i, b])
                else:
                    assert np.hypot(*(g - info["branch_end"][i, b])) <= 1.0 + a[i]


# ----------------------------------------------------------------------------- solvability


@pytest.mark.parametrize("density", DENSITIES)
@pytest.mark.parametrize("family", FAMILIES)
def test_every_start_reaches_every_goal_with_clearance(drawn, family, density):
    """The independent check of tests/test_generate.py in the strict form of the dense families: a
    4-connected grid search over 0.04 m cells whose centres keep more than D_c + 0.02 m from every
    obstacle (exact float64 distances), so a path through the cell centres keeps more than D_c."""
    world, _ = drawn[family][1][density]
    n = KEYS if density == 1.0 else LOW
    failures = [i for i in range(n) if unreachable_pairs(real_rows(world, i), 0.04, D_C + 0.02, 4)]
    assert not failures, f"{family} at density {density}: unsolvable rooms {failures}"


def test_the_check_sees_closed_doors(drawn):
    """An office with every door gap closed by a segment: no start reaches a goal (they are in
    different rooms), and the check says so."""
    spec, by_density = drawn["office"]
    world, _ = by_density[1.0]
    walls, _, _ = shapes.office_slots(spec)
    for i in range(3):
        room = real_rows(world, i)
        pieces = np.asarray(world.segments, np.float64)[i, 4 : 4 + walls].reshape(-1, 2, 4)
        gap = np.all(pieces != 0, axis=(1, 2))  # a wall of two pieces: a door between them
        doors = np.concatenate([pieces[gap, 0, 2:], pieces[gap, 1, :2]], -1)
        closed = dict(room, segments=np.concatenate([room["segments"], doors]))
        pairs = len(room["starts"]) * len(room["goals"])
        assert len(doors) >= 3 and len(unreachable_pairs(closed, 0.04, D_C + 0.02, 4)) == pairs
        assert not unreachable_pairs(room, 0.04, D_C + 0.02, 4)


# ----------------------------------------------------------------------------- density


@pytest.mark.parametrize("family", FAMILIES)
def test_density_thins_toward_an_empty_room(drawn, family):
    spec, by_density = drawn[family]
    full, half, empty = (by_density[d] for d in DENSITIES)
    fewer = 0
    for i in range(LOW):
        r1, r5, r0 = (real_rows(w, i) for w, _ in (full, half, empty))
        assert all(len(x) == 0 for x in obstacles(r0)), "density 0: the outer walls only"
        for k in ("starts", "goals", "size"):  # starts, goals and the floor do not move
            np.testing.assert_array_equal(r5[k], r1[k])
        (s1, c1), (s5, c5) = obstacles(r1), obstacles(r5)
        assert all(np.any(np.all(np.abs(s1 - s) < 1e-6, -1)) for s in s5)  # a subset of the full room's
        assert all(np.any(np.all(np.abs(c1 - c) < 1e-6, -1)) for c in c5)
        fewer += len(s5) + len(c5) < len(s1) + len(c1)
    assert fewer == LOW


# ----------------------------------------------------------------------------- the spec's rules


@pytest.mark.parametrize(
    "family, overrides, field",
    [
        ("office", {"office_door_min": 0.55}, "office_door_min"),  # not > 2 (D_c + margin)
        ("office", {"office_door_max": 0.6}, "office_door_max"),  # < office_door_min
        ("office", {"office_room_min": 2.4}, "office_room_min"),  # (1.2 + 0.6) / 0.7 > 2.4
        ("office", {"office_jitter": 0.3}, "office_room_min"),  # 3 (1 - 0.6) < 1.8
        ("office", {"office_desk_length_max": 2.5}, "office_room_min"),  # a desk larger than the least room
        ("office", {"office_room_min": 6.0}, "office_room_min"),  # 2 x 2 rooms no longer fit 10 m
        ("office", {"office_cols_max": 9}, "office_cols_max"),
        ("corridors", {"corridor_width_min": 0.6}, "corridor_width_min"),
        ("corridors", {"corridor_room_min": 2.0}, "corridor_room_min"),  # < 1.5 + 0.6
        ("corridors", {"corridor_branches_max": 5}, "corridor_room_min"),  # 10 m / 5 slots < 2.2
        ("corridors", {"corridor_boxes_max": 1}, "corridor_boxes_max"),
        ("corridors", {"max_segments": 80}, "max_segments"),  # corridors need 86
    ],
)
def test_bad_spec_names_the_field(family, overrides, field):
    with pytest.raises(WorldError) as e:
        rooms.make_spec(family, **overrides)
    assert f"'{field}'" in str(e.value) and "allowed" in str(e.value) and "\n" not in str(e.value)


def test_other_families_ignore_the_indoor_fields():
    assert rooms.make_spec("mixture", office_room_min=1.0, corridor_room_min=0.5).family == "mixture"


# ----------------------------------------------------------------------------- suites, files, one program


def test_indoor_suites_are_held_out_and_disjoint():
    names = [n for n, s in suites.SUITES.items() if s.family in FAMILIES]
    assert sorted(names) == sorted(f"{f}-{k}" for f in FAMILIES for k in ("50", "50x4", "probe"))
    assert sorted(suites.SUITES[n].index for n in names) == list(range(24, 24 + 3 * len(FAMILIES)))
    mine = np.concatenate([suites.suite_seeds(n) for n in names])
    others = np.concatenate([suites.suite_seeds(n) for n, s in suites.SUITES.items() if s.family not in FAMILIES])
    assert np.all(suites.is_test_seed(mine)) and len(set(mine.tolist())) == len(mine)
    assert not set(mine.tolist()) & set(others.tolist())
    assert suites.suite_names("indoor-heldout") == tuple(f"{f}-50x4" for f in FAMILIES)
    assert suites.suite_names("indoor-probe") == tuple(f"{f}-probe" for f in FAMILIES)
    assert suites.SUITES["office-50x4"].spec().goals_min == 4
    np.testing.assert_array_equal(suites.suite_seeds("office-50")[:4], suites.SUITES["office-50"].seeds()[:4])


@pytest.mark.parametrize("family", FAMILIES)
def test_world_file_round_trip(drawn, family, tmp_path):
    one = room_at(drawn[family][1][1.0][0], 3)
    loaded = worlds.load(suites.save_world(one, tmp_path / f"{family}.json"))
    a, b = real_rows(one), real_rows(loaded)
    for k in a:
        np.testing.assert_array_equal(a[k].astype(np.float32), b[k].astype(np.float32), err_msg=k)


def test_a_family_mix_is_one_traced_program():
    """A training run's rooms (training.rooms.TrainRooms) with office, corridors and mixture robots:
    one program, every room padded to one shape, the density traced (traced, not compiled: the
    families compile in the fixture)."""
    from fedjax_nav.config import load_config
    from fedjax_nav.training.rooms import TrainRooms

    cfg = load_config(None, ["env.rooms=procedural", "env.worlds=[train-0,train-1,train-2]"])
    cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, room_families=("office", "corridors", "mixture")))
    tr = TrainRooms(cfg)
    assert tr.shape == tuple(max(x) for x in zip(*(shapes.padded_shape(rooms.make_spec(f)) for f in tr.families)))
    traces = []

    def draw(stream, block, density):
        traces.append(1)
        return tr.draw(stream, block, density)

    f = jax.jit(draw)
    for d in (0.25, 1.0):
        out = f.trace(jnp.uint32(7), jnp.int32(3), jnp.float32(d)).out_info
    assert len(traces) == 1 and out.segments.shape == (3, tr.shape[0], 4) and out.circles.shape == (3, tr.shape[1], 3)


def test_the_docs_list_every_family_and_indoor_field():
    """docs/generator.md follows the one tuple of families and the RoomSpec fields: a row of the
    families table per family, the CLI's error line with all of them, every indoor field documented."""
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "generator.md").read_text()
    assert all(f"\n| `{f}` |" in text for f in rooms.FAMILIES)
    assert f"(families: {', '.join(rooms.FAMILIES)})" in text
    indoor = [n for n in rooms.SPEC_FIELDS if n.startswith(("office_", "corridor_"))]
    assert len(indoor) == 33 and all(f"`{n}`" in text for n in indoor)
