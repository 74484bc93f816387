"""ROS map_server maps as worlds (fedjax_nav/worlds/rosmap.py, grid.py; docs/worlds.md, "Maps you
already have"): maps drawn here, imported, and checked against an independent rasterisation."""

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fedjax_nav import cli, worlds
from fedjax_nav.env.geometry import beam_angles, lidar
from fedjax_nav.worlds import WorldError, grid, rosmap

FREE, OCCUPIED, UNKNOWN = 254, 0, 205  # what map_saver writes
RES = 0.1
EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "maps" / "flat.yaml"
ROS = {"resolution": RES, "origin": [-3.0, 1.5, 0.0], "negate": 0, "occupied_thresh": 0.65, "free_thresh": 0.196}


def room() -> tuple[np.ndarray, np.ndarray]:
    """(image u8[50, 80], obstacle bool[50, 80]): an 8 x 5 m room at 0.1 m with a few blocks, a
    one-pixel wall with a gap, an unknown patch and obstacle pixels on the border."""
    obstacle = np.zeros((50, 80), bool)
    unknown = np.zeros((50, 80), bool)
    obstacle[10:16, 12:30] = True  # a table
    obstacle[30:34, 50:53] = True  # a pillar
    obstacle[20:23, 60:70] = True  # a shelf ...
    obstacle[23:27, 60:63] = True  # ... in an L
    obstacle[0:50, 40] = True  # a thin wall ...
    obstacle[22:33, 40] = False  # ... with a 1.1 m gap
    obstacle[45:50, 0:6] = True  # a block in the lower-left corner
    obstacle[0, 70:80] = True  # a strip along the top border
    unknown[36:42, 20:27] = True  # never seen by the mapping run
    image = np.where(obstacle, OCCUPIED, np.where(unknown, UNKNOWN, FREE)).astype(np.uint8)
    return image, obstacle | unknown


def write_pgm(path: Path, image: np.ndarray, plain: bool = False) -> Path:
    h, w = image.shape
    if plain:
        rows = "\n".join(" ".join(str(v) for v in r) for r in image)
        path.write_text(f"P2\n# drawn by a test\n{w} {h}\n255\n{rows}\n")
    else:
        path.write_bytes(b"P5\n# drawn by a test\n%d %d\n255\n" % (w, h) + image.astype(np.uint8).tobytes())
    return path


def write_map(folder: Path, pixels=None, name="room", **keys) -> Path:
    """A map's PGM and YAML in `folder` (the ROS keys, `keys` over them; None drops a key)."""
    write_pgm(folder / f"{name}.pgm", room()[0] if pixels is None else pixels)
    spec = {"image": f"{name}.pgm", **ROS, **keys}
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump({k: v for k, v in spec.items() if v is not None}))
    return path


def rasterise(boxes, shape, res) -> np.ndarray:
    """Independent of the importer: the cells whose centres lie inside a world box (yaw 0)."""
    h, w = shape
    xs = (np.arange(w) + 0.5) * res - w * res / 2
    ys = h * res / 2 - (np.arange(h) + 0.5) * res
    out = np.zeros(shape, bool)
    for cx, cy, sx, sy, yaw in boxes:
        assert yaw == 0
        out |= (np.abs(ys[:, None] - cy) < sy / 2) & (np.abs(xs[None, :] - cx) < sx / 2)
    return out


def march(obstacle: np.ndarray, res: float, pose, angles, step: float) -> np.ndarray:
    """Float64 ray march over the grid: the first sample, `step` apart along each beam, that lies
    in an obstacle cell or outside the map (the world's walls stand at the map's border)."""
    h, w = obstacle.shape
    x0, y0 = pose[0] + w * res / 2, pose[1] + h * res / 2  # grid metres
    t = np.arange(0.0, math.hypot(w, h) * res + step, step)
    out = []
    for a in np.asarray(angles, np.float64) + pose[2]:
        x, y = x0 + t * math.cos(a), y0 + t * math.sin(a)
        inside = (x >= 0) & (x < w * res) & (y >= 0) & (y < h * res)
        c = np.clip(np.floor(x / res).astype(int), 0, w - 1)
        r = np.clip(h - 1 - np.floor(y / res).astype(int), 0, h - 1)
        out.append(t[np.argmax(~inside | obstacle[r, c])])
    return np.asarray(out)


# ----------------------------------------------------------------------------- the geometry


def test_boxes_rasterise_back_to_exactly_the_occupied_and_unknown_cells(tmp_path):
    _, expected = room()
    world, meta = worlds.load_with_meta(write_map(tmp_path))
    assert np.asarray(world.size).tolist() == [8.0, 5.0]
    assert np.array_equal(rasterise(meta["boxes"], expected.shape, RES), expected)
    assert len(meta["boxes"]) <= 12  # merged: 9 obstacles, the thin wall in two pieces, the L in two
    assert world.segments.shape == (4 + 4 * len(meta["boxes"]), 4)


def test_lidar_of_the_imported_world_agrees_with_a_ray_march_over_the_grid(tmp_path):
    """The boxes cover exactly the obstacle cells and the walls stand at the map's border, so the
    analytic range is the exact distance to the first obstacle cell along the beam; the march
    stops at its first sample inside one, at most one step (res / 50) later. Within one cell:
    that step plus float32 rounding, with room to spare, while a box missing or misplaced by a
    cell would show on some beam."""
    _, obstacle = room()
    world = worlds.load(write_map(tmp_path))
    poses = [(-2.0, 0.0, 0.3), (-0.6, -1.5, 2.0), (1.5, 0.2, -1.0), (3.3, -1.8, 3.0), (-3.4, 1.6, -2.5)]
    beams = 90
    for pose in poses:
        got = np.asarray(lidar(world.segments, np.asarray(pose, np.float32), beams, 20.0, world.circles), np.float64)
        ref = march(obstacle, RES, pose, beam_angles(beams), RES / 50)
        assert np.all(np.abs(got - ref) <= RES), (pose, np.max(np.abs(got - ref)))
        assert np.all(got <= ref + 1e-4)  # never beyond the first sample inside an obstacle


def test_coarser_cells_are_the_max_pooled_map(tmp_path):
    """--cell 0.3 on 80 x 50 pixels: 27 x 17 cells, the top row padded with obstacles (so that the
    lower-left corner stays at the origin); a cell is an obstacle where any of its pixels is."""
    _, obstacle = room()
    spec = worlds.map_spec(write_map(tmp_path), cell=0.3)
    padded = np.ones((51, 81), bool)
    padded[1:, :80] = obstacle
    pooled = np.array([[padded[3 * r : 3 * r + 3, 3 * c : 3 * c + 3].any() for c in range(27)] for r in range(17)])
    assert spec["size"] == [8.1, 5.1]
    assert np.array_equal(rasterise(spec["boxes"], (17, 27), 0.3), pooled)
    assert "27 x 17 cells of 0.3 m" in spec["description"]


def test_merging_picks_the_fewer_of_row_and_column_runs():
    stripes = np.zeros((6, 8), bool)
    stripes[:, ::2] = True  # 4 columns: 4 boxes down the columns, 24 along the rows
    assert len(grid.merge_cells(stripes)) == 4
    assert len(grid.merge_cells(stripes.T)) == 4
    assert len(grid.merge_cells(np.zeros((3, 3), bool))) == 0


def test_clear_cells_is_the_exact_distance_to_the_nearest_obstacle_square():
    rng = np.random.default_rng(0)
    occ = rng.random((20, 30)) < 0.1
    res, dist = 0.1, 0.35
    clear = grid.clear_cells(occ, res, dist)
    centres = grid.cell_centres(np.ones_like(occ), res)
    d = grid.point_clearance(occ, res, centres, 10.0).reshape(occ.shape)
    assert np.array_equal(clear, d >= dist)


# ----------------------------------------------------------------------------- starts and goals


def test_drawn_starts_and_goals_are_clear_connected_and_reproducible(tmp_path):
    path = write_map(tmp_path)
    a = worlds.map_spec(path, starts=4, goals=3, seed=7)
    assert a == worlds.map_spec(path, starts=4, goals=3, seed=7)
    assert a["starts"] != worlds.map_spec(path, starts=4, goals=3, seed=8)["starts"]
    world = worlds.from_dict(a)[0]
    segs = np.asarray(world.segments, np.float64)
    points = [s[:2] for s in a["starts"]] + a["goals"]
    d = worlds.point_segment_distance_np(np.asarray(points), segs).min(-1)
    assert np.all(d >= worlds.CLEARANCE + grid.MARGIN - 1e-9)
    assert not any(rasterise(a["boxes"], (50, 80), RES)[24 - int(y // RES), 40 + int(x // RES)] for x, y in points)


def test_draws_stay_in_the_region_of_a_given_start(tmp_path):
    """A closed wall splits the room; goals are drawn on the given start's side, else in the larger part."""
    image = np.full((50, 80), FREE, np.uint8)
    image[:, 20] = OCCUPIED  # the left part: 2 m of 8
    right = worlds.map_spec(write_map(tmp_path, image), goals=5)
    assert all(g[0] > -2.0 for g in right["goals"]) and right["starts"][0][0] > -2.0
    start = [-3.0 + 0.5, 1.5 + 2.5, 1.0]  # map frame: origin (-3, 1.5) + grid metres (0.5, 2.5)
    left = worlds.map_spec(write_map(tmp_path, image, fedjax_nav={"starts": [start], "goals": 5}))
    assert left["starts"] == [[-3.5, 0.0, 1.0]]
    assert all(g[0] < -2.0 for g in left["goals"])


def test_given_starts_and_goals_in_a_rotated_map_frame(tmp_path):
    """origin (ox, oy, yaw): a world point p is the map point (ox, oy) + R(yaw) (p + size / 2)."""
    ox, oy, yaw = 2.0, -1.0, math.pi / 2
    p_start, p_goal = np.array([1.0, 0.5]), np.array([2.5, 1.0])  # world
    c, s = math.cos(yaw), math.sin(yaw)

    def to_map(p):
        q = p + [4.0, 2.5]
        return [float(ox + c * q[0] - s * q[1]), float(oy + s * q[0] + c * q[1])]

    own = {"starts": [[*to_map(p_start), yaw + 0.25]], "goals": [to_map(p_goal)]}
    spec = worlds.map_spec(write_map(tmp_path, origin=[ox, oy, yaw], fedjax_nav=own))
    np.testing.assert_allclose(spec["starts"], [[*p_start, 0.25]], atol=1e-9)
    np.testing.assert_allclose(spec["goals"], [p_goal], atol=1e-9)


# ----------------------------------------------------------------------------- readers and modes


def test_pgm_plain_png_negate_and_raw_give_the_same_world(tmp_path):
    from PIL import Image

    image, _ = room()
    base = worlds.map_spec(write_map(tmp_path))["boxes"]
    write_pgm(tmp_path / "plain.pgm", image, plain=True)
    rgba = np.dstack([image, image, image, np.full_like(image, 7)])  # alpha is left out, as map_server does
    Image.fromarray(rgba, "RGBA").save(tmp_path / "rgba.png")
    Image.fromarray(image, "L").save(tmp_path / "grey.png")
    write_pgm(tmp_path / "negated.pgm", 255 - image)
    raw = np.where(image == FREE, 0, np.where(image == OCCUPIED, 100, 255)).astype(np.uint8)
    write_pgm(tmp_path / "raw.pgm", raw)
    for name, keys in [
        ("plain.pgm", {}),
        ("rgba.png", {}),
        ("grey.png", {"mode": "scale"}),
        ("negated.pgm", {"negate": 1}),
        ("raw.pgm", {"mode": "raw"}),
    ]:
        path = tmp_path / "m.yaml"
        path.write_text(yaml.safe_dump({**ROS, "image": name, **keys}))
        assert worlds.map_spec(path)["boxes"] == base, name


def test_thresholds_follow_map_server(tmp_path):
    """p = (255 - v) / 255: free below free_thresh; between the thresholds unknown, an obstacle here."""
    values = np.array([[254, 206, 205, 204, 100, 0]], np.int64)
    occ = rosmap.occupied(values, {"negate": False, "mode": "trinary", "free_thresh": 0.196})
    assert occ.tolist() == [[False, False, True, True, True, True]]  # 49/255 = 0.192 is free, 50/255 not


# ----------------------------------------------------------------------------- the command line


def test_cli_import_writes_the_world_that_load_reads(tmp_path, capsys):
    path = write_map(tmp_path)
    out = tmp_path / "out" / "room.json"
    argv = ["worlds", "import", str(path), "--out", str(out), "--starts", "3", "--goals", "2", "--seed", "5"]
    assert cli.main(argv) == 0
    assert "wrote" in capsys.readouterr().out
    written = yaml.safe_load(out.read_text())
    assert written == worlds.map_spec(path, starts=3, goals=2, seed=5)
    a, b = worlds.load(out), worlds.from_dict(written)[0]
    assert np.array_equal(a.segments, b.segments) and np.array_equal(a.starts, b.starts)


def test_the_example_map_imports(tmp_path):
    world, meta = worlds.load_with_meta(EXAMPLE)
    assert np.asarray(world.size).tolist() == [10.0, 6.0]
    assert int(world.num_starts) == 1 and int(world.num_goals) == 2
    np.testing.assert_allclose(np.asarray(world.starts)[0], [-3.5, 0.0, 0.0], atol=1e-6)
    assert 10 <= len(meta["boxes"]) <= 30
    assert cli.main(["worlds", "import", str(EXAMPLE), "--out", str(tmp_path / "flat.yaml")]) == 0


def test_a_folder_of_maps_and_world_files_is_a_suite(tmp_path):
    from fedjax_nav.evaluation.suite_files import file_suite

    write_map(tmp_path)
    worlds.save_world(worlds.load("train-0"), tmp_path / "zz.json")
    world, fams, _, files = file_suite(str(tmp_path))
    assert fams.tolist() == ["room", "zz"] and world.segments.shape[0] == 2


# ----------------------------------------------------------------------------- refusals


def _checkerboard(n):
    image = np.full((n, n), FREE, np.uint8)
    image[: n // 2][(np.indices((n // 2, n)).sum(0) % 2) == 0] = OCCUPIED
    return image


def test_too_detailed_is_refused_and_cell_coarsens_it(tmp_path):
    path = write_map(tmp_path, _checkerboard(150))  # 5625 single-cell boxes in the upper half
    with pytest.raises(WorldError, match=r"room.yaml: the map is too detailed: .*5625 boxes.*--cell"):
        worlds.load(path)
    world = worlds.from_dict(worlds.map_spec(path, cell=0.2))[0]
    assert world.segments.shape[0] <= 4 + 4 * 5000


@pytest.mark.parametrize(
    "keys, words",
    [
        ({"resolution": None}, ["missing key 'resolution'"]),
        ({"free_thresh": None}, ["missing key 'free_thresh'"]),
        ({"resolution": 0}, ["'resolution'", "> 0"]),
        ({"resolution": "fine"}, ["'resolution'"]),
        ({"origin": ["a", 0, 0]}, ["'origin'", "[x, y, yaw]"]),
        ({"origin": [0, 0]}, ["'origin'"]),
        ({"occupied_thresh": 1.5}, ["'occupied_thresh'", "[0, 1]"]),
        ({"free_thresh": -0.1}, ["'free_thresh'", "[0, 1]"]),
        ({"free_thresh": 0.9}, ["'free_thresh'", "above"]),
        ({"negate": 2}, ["'negate'"]),
        ({"mode": "fancy"}, ["'mode'", "trinary"]),
        ({"image": "gone.pgm"}, ["'image'", "gone.pgm", "No such file"]),
        ({"image": "junk.pgm"}, ["'image'", "junk.pgm", "cannot be read"]),
        ({"image": "short.pgm"}, ["'image'", "short.pgm", "pixels present"]),
        ({"image": 3}, ["'image'"]),
        ({"fedjax_nav": {"start": 1}}, ["unknown key 'fedjax_nav.start'"]),
        ({"fedjax_nav": {"starts": [[0, 0]]}}, ["'fedjax_nav.starts'", "[x, y, theta]"]),
        ({"fedjax_nav": {"seed": -1}}, ["'fedjax_nav.seed'"]),
        ({"fedjax_nav": {"cell": 0.15}}, ["fedjax_nav.cell", "whole multiple", "0.1 m"]),
        ({"fedjax_nav": {"starts": [[-2.8, 4.0, 0.0]]}}, ["fedjax_nav.starts[0]", "0.200 m", "0.25 m"]),
        ({"fedjax_nav": {"goals": [[-1.0, 5.2]]}}, ["fedjax_nav.goals[0]", "occupied"]),
        ({"fedjax_nav": {"goals": [[-9.0, 3.0]]}}, ["fedjax_nav.goals[0]", "outside"]),
    ],
)
def test_a_malformed_map_is_one_line_naming_the_file_and_key(tmp_path, capsys, keys, words):
    (tmp_path / "junk.pgm").write_bytes(b"\x89PNG not really")
    (tmp_path / "short.pgm").write_bytes(b"P5 80 50 255\n" + bytes(100))
    path = write_map(tmp_path, **keys)
    with pytest.raises(WorldError) as e:
        worlds.load(path)
    msg = str(e.value)
    assert msg.startswith(str(path)) and "\n" not in msg
    for w in words:
        assert w in msg
    assert cli.main(["worlds", "import", str(path), "--out", str(tmp_path / "w.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err and words[0] in err
    assert not (tmp_path / "w.json").exists()


def test_no_room_to_draw_is_one_line(tmp_path):
    image = np.full((50, 80), OCCUPIED, np.uint8)
    image[20:25, 30:35] = FREE  # 0.5 m square: no cell 0.35 m from every wall
    with pytest.raises(WorldError, match=r"room.yaml: no room to draw 1 start\(s\) and 1 goal\(s\)"):
        worlds.load(write_map(tmp_path, image))


@pytest.mark.parametrize(
    "flags, words",
    [
        (["--cell", "0.25"], ["--cell", "whole multiple"]),
        (["--cell", "nan"], ["--cell"]),
        (["--seed", "x"], ["--seed"]),
        (["--starts", "6000"], ["--starts", "5000"]),
    ],
)
def test_bad_import_flags_exit_2_with_one_line(tmp_path, capsys, flags, words):
    argv = ["worlds", "import", str(write_map(tmp_path)), "--out", str(tmp_path / "w.json"), *flags]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err
    for w in words:
        assert w in err


def test_a_file_that_is_not_a_map_is_refused_by_map_spec(tmp_path):
    with pytest.raises(WorldError, match="not a ROS map_server map"):
        worlds.map_spec("train-0")


def test_cells_finer_than_the_finest_taken_are_refused_and_cell_coarsens_them(tmp_path):
    path = write_map(tmp_path, np.full((500, 500), FREE, np.uint8), resolution=0.004)
    with pytest.raises(WorldError, match=r"room.yaml: cells of 0.004 m are finer than 0.005 m.*fedjax_nav: cell"):
        worlds.load(path)
    assert "100 x 100 cells of 0.02 m" in worlds.map_spec(path, cell=0.02)["description"]


def test_largest_region_is_the_largest_4_connected_component():
    """Against a plain breadth-first labelling (ties: the region met first in row order)."""
    rng = np.random.default_rng(1)
    for density in (0.45, 0.55, 0.65):
        clear = rng.random((30, 40)) < density
        label, sizes = np.zeros(clear.shape, int), [0]
        for start in zip(*np.nonzero(clear)):
            if label[start]:
                continue
            sizes.append(0)
            todo = [start]
            label[start] = len(sizes) - 1
            while todo:
                r, c = todo.pop()
                sizes[-1] += 1
                for nb in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
                    if 0 <= nb[0] < 30 and 0 <= nb[1] < 40 and clear[nb] and not label[nb]:
                        label[nb] = len(sizes) - 1
                        todo.append(nb)
        assert np.array_equal(grid.largest_region(clear), label == int(np.argmax(sizes)))


keys = st.sampled_from([*rosmap.ROS_KEYS, "mode", "fedjax_nav", "other"])
junk = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(10**30), 10**30),
    st.floats(allow_nan=True),
    st.text(max_size=8),
    st.lists(st.floats(-10, 10) | st.integers(-3, 3), max_size=4),
    st.dictionaries(st.sampled_from([*rosmap.OWN_KEYS, "x"]), st.integers(-2, 6) | st.floats(-1, 1), max_size=3),
)
good = {"image": "room.pgm", **ROS, "mode": "raw", "fedjax_nav": {"goals": 2}}


@settings(max_examples=60, deadline=None, database=None, suppress_health_check=list(HealthCheck))
@given(changes=st.dictionaries(keys, junk, max_size=3), drop=st.lists(keys, max_size=2))
def test_random_maps_load_or_give_one_line(tmp_path_factory, changes, drop):
    folder = tmp_path_factory.mktemp("fuzz")
    write_pgm(folder / "room.pgm", room()[0])
    spec = {k: v for k, v in {**good, **changes}.items() if k not in drop}
    path = folder / "m.yaml"
    path.write_text(yaml.safe_dump(spec))
    try:
        assert isinstance(worlds.load(path), worlds.World)
    except WorldError as e:
        assert "\n" not in str(e) and str(e).startswith(str(path)), str(e)


def test_an_out_path_below_a_file_is_one_line_exit_2(tmp_path, capsys):
    (tmp_path / "f").write_text("x")
    assert cli.main(["worlds", "import", str(write_map(tmp_path)), "--out", str(tmp_path / "f" / "w.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"error: {tmp_path / 'f'}: file exists"  # the command line's path for a bad --out
