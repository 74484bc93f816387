"""Playgrounds as data: the shipped worlds, building, padding and stacking, and bad world files."""

import json
import math

import numpy as np
import pytest
import yaml

from fedjax_nav import worlds
from fedjax_nav.worlds import WorldError

D_C = 0.25  # the collision distance


def seg_dist(p, segs):
    """Float64: distance from point p to each segment (zero-length rows are skipped)."""
    out = []
    for x1, y1, x2, y2 in np.asarray(segs, np.float64):
        a, b = np.array([x1, y1]), np.array([x2, y2])
        ab = b - a
        if not ab.any():
            continue
        u = np.clip(np.dot(p - a, ab) / np.dot(ab, ab), 0, 1)
        out.append(np.linalg.norm(p - (a + u * ab)))
    return np.array(out)


def in_box(p, box):
    cx, cy, sx, sy, yaw = box
    c, s = math.cos(yaw), math.sin(yaw)
    dx, dy = p[0] - cx, p[1] - cy
    return abs(c * dx + s * dy) <= sx / 2 and abs(-s * dx + c * dy) <= sy / 2


# ----------------------------------------------------------------------------- shipped worlds


@pytest.mark.parametrize("name", worlds.SHIPPED)
def test_shipped_world_loads_with_collision_free_starts_and_free_goals(name):
    world, meta = worlds.load_with_meta(name)
    raw = json.loads(worlds.resolve(name).read_text())
    segs = np.asarray(world.segments, np.float64)
    circles = np.asarray(world.circles, np.float64).reshape(-1, 3)
    size = np.asarray(world.size, np.float64)
    n_starts, n_goals = int(world.num_starts), int(world.num_goals)
    assert n_starts >= 1 and n_goals >= 1
    assert world.starts.shape == (n_starts, 3) and world.goals.shape == (n_goals, 2)
    # Every obstacle of the file is there: 4 walls, 4 edges per box, the thin walls, the cylinders.
    assert segs.shape == (4 + 4 * len(raw.get("boxes") or []) + len(raw.get("segments") or []), 4)
    assert circles.shape == (len(raw.get("circles") or []), 3)
    # The square walls are there, from the size.
    np.testing.assert_allclose(segs[:4], worlds.wall_segments(size), atol=1e-6)
    for i, s in enumerate(np.asarray(world.starts, np.float64)):
        p = s[:2]
        assert np.all(np.abs(p) < size / 2), f"{name}: start {i} outside the walls"
        assert not any(in_box(p, b) for b in meta["boxes"]), f"{name}: start {i} inside a box"
        d_seg = seg_dist(p, segs).min()
        d_circ = (np.hypot(*(p - circles[:, :2]).T) - circles[:, 2]).min() if len(circles) else np.inf
        assert min(d_seg, d_circ) > D_C, f"{name}: start {i} only {min(d_seg, d_circ):.3f} m from an obstacle"
    for i, g in enumerate(np.asarray(world.goals, np.float64)):
        assert np.all(np.abs(g) < size / 2), f"{name}: goal {i} outside the walls"
        assert not any(in_box(g, b) for b in meta["boxes"]), f"{name}: goal {i} inside a box"
        if len(circles):
            assert np.all(np.hypot(*(g - circles[:, :2]).T) > circles[:, 2]), f"{name}: goal {i} in a cylinder"
        assert seg_dist(g, segs).min() > 0.0
        # Reachable: the goal disc (D_g = 0.5) holds points the robot may stand on.
        start = np.asarray(world.starts[0, :2], np.float64)
        assert np.linalg.norm(g - start) > 0.5, f"{name}: goal {i} already reached at the start"


def test_shipped_worlds_match_the_scenario():
    """Sizes and starts per the thesis's playgrounds (docs/worlds.md): the 6x6 rooms with 3 starts
    (room 1, which the thesis dropped, with its one start), the 10x10 rooms with 4, the 12x12
    arena with 4 corner goals."""
    expected = {
        "train-0": (6, 3),
        "train-1": (6, 1),
        "train-2": (6, 3),
        "train-3": (10, 4),
        "train-4": (10, 4),
        "train-5": (10, 4),
        "eval": (12, 1),
        "eval-crossing": (12, 4),  # the arena for a fleet of four (docs/shared_rooms.md)
    }
    assert set(expected) == set(worlds.SHIPPED)
    for name, (side, n_starts) in expected.items():
        w = worlds.load(name)
        np.testing.assert_array_equal(np.asarray(w.size), [side, side])
        assert int(w.num_starts) == n_starts, name
    ev = worlds.load("eval")
    corners = {tuple(np.sign(g)) for g in np.asarray(ev.goals)}
    assert corners == {(1, 1), (1, -1), (-1, 1), (-1, -1)}
    np.testing.assert_allclose(np.abs(np.asarray(ev.goals)), 5.0)
    assert set(worlds.THESIS_TRAIN) < set(worlds.PAPER_TRAIN) <= set(worlds.SHIPPED)
    assert "train-1" not in worlds.THESIS_TRAIN and len(worlds.THESIS_TRAIN) == 5


def test_load_by_path_equals_load_by_name(tmp_path):
    path = worlds.resolve("train-2")
    a, b = worlds.load("train-2"), worlds.load(path)
    for x, y in zip(a.__dict__.values(), b.__dict__.values()):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    # The same world as YAML.
    yml = tmp_path / "train-2.yaml"
    yml.write_text(yaml.safe_dump(json.loads(path.read_text())))
    c = worlds.load(yml)
    for x, y in zip(a.__dict__.values(), c.__dict__.values()):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


# ----------------------------------------------------------------------------- building worlds


def test_boxes_walls_and_segments_become_segments():
    spec = {
        "size": [4.0, 2.0],
        "boxes": [[1.0, 0.0, 0.4, 0.2, math.pi / 2]],
        "segments": [[-1.5, -0.5, -1.5, 0.5]],
        "circles": [[-0.5, 0.5, 0.2]],
        "starts": [[0.0, 0.0, 0.0]],
        "goals": [[1.5, -0.8]],
    }
    w, meta = worlds.from_dict(spec, "inline")
    segs = np.asarray(w.segments, np.float64)
    assert segs.shape == (4 + 1 + 4, 4)
    np.testing.assert_allclose(segs[:4], [[-2, -1, 2, -1], [2, -1, 2, 1], [2, 1, -2, 1], [-2, 1, -2, -1]])
    np.testing.assert_allclose(segs[4], [-1.5, -0.5, -1.5, 0.5])
    # The box turned by 90 deg: 0.2 wide in x, 0.4 tall in y, around (1, 0).
    pts = segs[5:].reshape(-1, 2)
    np.testing.assert_allclose(pts.min(0), [0.9, -0.2], atol=1e-6)
    np.testing.assert_allclose(pts.max(0), [1.1, 0.2], atol=1e-6)
    # Closed: each edge ends where the next begins.
    np.testing.assert_allclose(segs[5:, 2:], np.roll(segs[5:, :2], -1, axis=0), atol=1e-12)
    # yaw turns counter-clockwise: corners (+-sx/2, +-sy/2) rotated by exp(i yaw) about the centre.
    cx, cy, sx, sy, yaw = 0.5, -0.2, 0.8, 0.3, 0.3
    corners = [complex(cx, cy) + complex(a * sx / 2, b * sy / 2) * np.exp(1j * yaw) for a in (-1, 1) for b in (-1, 1)]
    got = worlds.box_segments(cx, cy, sx, sy, yaw)[:, :2]
    assert sorted(map(tuple, np.round(got, 9))) == sorted((round(z.real, 9), round(z.imag, 9)) for z in corners)
    np.testing.assert_allclose(np.asarray(w.circles), [[-0.5, 0.5, 0.2]])
    assert meta["name"] == "inline" and meta["boxes"] == spec["boxes"]


def test_pad_and_stack():
    a = worlds.load("train-0")  # 4 segments, 1 circle, 3 starts, 1 goal
    b = worlds.load("train-1")  # 16 segments, 0 circles, 1 start, 1 goal
    e = worlds.load("eval")  # 36 segments, 21 circles, 1 start, 4 goals
    s = worlds.stack([a, b, e])
    assert s.segments.shape == (3, 36, 4) and s.circles.shape == (3, 21, 3)
    assert s.starts.shape == (3, 3, 3) and s.goals.shape == (3, 4, 2)
    np.testing.assert_array_equal(np.asarray(s.num_starts), [3, 1, 1])
    np.testing.assert_array_equal(np.asarray(s.num_goals), [1, 1, 4])
    # Padding: zero-length segments, zero-radius circles, repeated start 0 and goal 0.
    segs = np.asarray(s.segments[0])
    np.testing.assert_array_equal(segs[:4], np.asarray(a.segments))
    assert np.all(segs[4:, :2] == segs[4:, 2:])
    assert np.all(np.asarray(s.circles[1])[:, 2] == 0) and np.all(np.asarray(s.circles[0])[1:, 2] == 0)
    np.testing.assert_array_equal(np.asarray(s.starts[1]), np.repeat(np.asarray(b.starts[:1]), 3, 0))
    np.testing.assert_array_equal(np.asarray(s.goals[0]), np.repeat(np.asarray(a.goals[:1]), 4, 0))
    m = worlds.load_many(["train-0", "train-1", "eval"])
    for x, y in zip(s.__dict__.values(), m.__dict__.values()):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    with pytest.raises(ValueError):
        worlds.pad(e, 10, 21, 1, 4)  # cannot pad down


# ----------------------------------------------------------------------------- bad world files

GOOD = {
    "size": [4.0, 4.0],
    "boxes": [[1.0, 1.0, 0.6, 0.6, 0.0]],
    "circles": [[-1.0, 1.0, 0.3]],
    "starts": [[0.0, -1.0, 0.0]],
    "goals": [[-1.0, -1.0]],
}


def _with(**changes):
    spec = json.loads(json.dumps(GOOD))
    for k, v in changes.items():
        if v is None:
            spec.pop(k)
        else:
            spec[k] = v
    return spec


BAD = {
    "missing starts": (_with(starts=None), ["starts", "missing"]),
    "missing goals": (_with(goals=None), ["goals", "missing"]),
    "missing size": (_with(size=None), ["size", "missing"]),
    "start with 2 numbers": (_with(starts=[[0.0, -1.0]]), ["starts", "shape"]),
    "ragged boxes": (_with(boxes=[[1.0, 1.0, 0.6, 0.6, 0.0], [1.0, 2.0]]), ["boxes"]),
    "goal as a flat list": (_with(goals=[1.0, 1.0]), ["goals"]),
    "size with 3 numbers": (_with(size=[4.0, 4.0, 1.0]), ["size"]),
    "empty starts": (_with(starts=[]), ["starts"]),
    "start inside a box": (_with(starts=[[1.0, 1.1, 0.0]]), ["starts[0]", "boxes[0]"]),
    "start inside a circle": (_with(starts=[[-1.0, 1.0, 0.0]]), ["starts[0]", "circles[0]"]),
    "start too near a wall": (_with(starts=[[0.0, -1.9, 0.0]]), ["starts[0]", "0.25"]),
    "second start outside the walls": (_with(starts=[[0.0, -1.0, 0.0], [2.5, 0.0, 0.0]]), ["starts[1]", "outside"]),
    "goal inside a box": (_with(goals=[[-1.0, -1.0], [0.9, 0.9]]), ["goals[1]", "boxes[0]"]),
    "goal inside a circle": (_with(goals=[[-1.0, 1.1]]), ["goals[0]", "circles[0]"]),
    "goal outside the walls": (_with(goals=[[-1.0, -3.0]]), ["goals[0]", "outside"]),
    "unknown field": (_with(obstacles=[[0, 0, 1]]), ["obstacles", "unknown"]),
    "negative box size": (_with(boxes=[[1.0, 1.0, -0.6, 0.6, 0.0]]), ["boxes"]),
    "zero radius": (_with(circles=[[-1.0, 1.0, 0.0]]), ["circles"]),
    "non-numeric start": (_with(starts=[["a", 0.0, 0.0]]), ["starts"]),
    # numpy reads true as 1.0 and parses "3": neither may pass for a number
    "size of booleans": (_with(size=[True, True]), ["field 'size'", "a boolean (true)", "where a number belongs"]),
    "size of numbers as text": (_with(size=["3", "3"]), ["field 'size'", "text ('3')", "where a number belongs"]),
    "size as text": (_with(size="44"), ["field 'size'", "text ('44')"]),
    "a boolean yaw": (_with(starts=[[0.0, -1.0, False]]), ["starts[0]", "a boolean (false)"]),
    "a goal as text": (_with(goals=[[-1.0, -1.0], ["-1", "1"]]), ["goals[1]", "text ('-1')"]),
    "a box of booleans": (_with(boxes=[[1.0, 1.0, True, True, 0.0]]), ["boxes[0]", "a boolean"]),
    "a null radius": (_with(circles=[[-1.0, 1.0, None]]), ["circles[0]", "null"]),
}


@pytest.mark.parametrize("fmt", ["json", "yaml"])
@pytest.mark.parametrize("case", list(BAD))
def test_bad_world_file_names_file_and_field(tmp_path, case, fmt):
    spec, words = BAD[case]
    path = tmp_path / f"bad-world.{fmt}"
    path.write_text(json.dumps(spec) if fmt == "json" else yaml.safe_dump(spec))
    with pytest.raises(WorldError) as err:
        worlds.load(str(path))
    msg = str(err.value)
    assert str(path) in msg, msg
    for w in words:
        assert w in msg, f"{w!r} not in {msg!r}"


def test_good_world_file_loads(tmp_path):
    """The base of the bad cases is itself valid (so each bad case fails for its own reason)."""
    for fmt in ("json", "yaml"):
        path = tmp_path / f"good.{fmt}"
        path.write_text(json.dumps(GOOD) if fmt == "json" else yaml.safe_dump(GOOD))
        w = worlds.load(path)
        assert w.segments.shape == (8, 4) and int(w.num_starts) == 1


def test_a_python_caller_s_numpy_numbers_are_numbers():
    spec = _with(size=list(np.asarray([4.0, 4.0])), starts=np.asarray([[0.0, -1.0, 0.0]]), goals=[[np.int64(-1), -1]])
    assert int(worlds.from_dict(spec, "<test>")[0].num_starts) == 1
    with pytest.raises(WorldError, match=r"a boolean \(true\).*starts\[0\]"):
        worlds.from_dict(_with(starts=np.asarray([[True, False, True]])), "<test>")


def test_a_symlink_loop_is_named_as_one(tmp_path):
    """Not "no such world file": the path exists as a link that leads nowhere."""
    loop, dangling = tmp_path / "loop.json", tmp_path / "dangling.yaml"
    loop.symlink_to(loop)
    dangling.symlink_to(tmp_path / "gone.yaml")
    for path, words in ((loop, "is a symlink loop"), (dangling, "is a symbolic link to a missing file")):
        with pytest.raises(WorldError) as err:
            worlds.load(str(path))
        msg = str(err.value)
        assert msg.startswith(str(path)) and words in msg and "no such" not in msg and "\n" not in msg, msg


def test_missing_file_and_unparsable_files(tmp_path):
    missing = tmp_path / "nope.json"
    with pytest.raises(WorldError, match="nope.json"):
        worlds.load(str(missing))
    with pytest.raises(WorldError, match="train-9"):
        worlds.load("train-9")
    bad_json = tmp_path / "broken.json"
    bad_json.write_text('{"size": [4, 4], "starts": [[0, 0, 0]')
    with pytest.raises(WorldError, match="broken.json"):
        worlds.load(bad_json)
    bad_yaml = tmp_path / "broken.yaml"
    bad_yaml.write_text("size: [4, 4\nstarts: {")
    with pytest.raises(WorldError, match="broken.yaml"):
        worlds.load(bad_yaml)
    not_a_mapping = tmp_path / "list.yaml"
    not_a_mapping.write_text("- 1\n- 2\n")
    with pytest.raises(WorldError, match="list.yaml"):
        worlds.load(not_a_mapping)
