"""Playgrounds as data: the `World` pytree, the shipped rooms, and loading users' files (re-exported
by `fedjax_nav.worlds`, which the package's modules do not import: tests/test_layers.py).

A world file (JSON or YAML, see docs/worlds.md) has::

    size:     [W, H]                  inner free space in m; walls at x = +-W/2, y = +-H/2
    boxes:    [[cx, cy, sx, sy, yaw]]  optional; full sizes in m, yaw in rad
    segments: [[x1, y1, x2, y2]]       optional; thin walls
    circles:  [[cx, cy, r]]            optional; cylinders
    starts:   [[x, y, theta]]          at least one; start 0 is the default start
    goals:    [[x, y]]                 at least one

Boxes become four segments each; the square walls become four segments. Everything is padded
(zero-length segments, zero-radius circles, repeated starts and goals) so that worlds of
different sizes `stack` into one pytree and run in one `vmap`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from importlib import resources
from pathlib import Path

import jax.numpy as jnp
import numpy as np
from flax import struct

from fedjax_nav.messages import shorten, show
from fedjax_nav.worlds import input_files, rosmap
from fedjax_nav.worlds.grid import MapError

SHIPPED = ("train-0", "train-1", "train-2", "train-3", "train-4", "train-5", "eval", "eval-crossing")
THESIS_TRAIN = ("train-0", "train-2", "train-3", "train-4", "train-5")  # thesis dropped room 1
PAPER_TRAIN = ("train-0", "train-1", "train-2", "train-3", "train-4", "train-5")
# Starts and goals must keep this clearance from every obstacle (the collision distance D_c).
CLEARANCE = 0.25
# Upper bound on the rows of each field of a world file (boxes, segments, circles, starts, goals).
MAX_PRIMITIVES = 5000
# Every number of a world file (m, or rad for an angle) within +-MAX_COORD: a world is float32 in
# the program, where 1e4 still resolves millimetres (and 1e39 is inf, 1e20 squared is too).
MAX_COORD = 1e4
# A world file is read only when it is a regular file of at most this many bytes and, in YAML, at
# most this many values (5 fields x 5000 rows x 6 fit); the largest shipped one is 3 KiB.
MAX_FILE_BYTES = 8 * 2**20
MAX_NODES = 200_000


class WorldError(ValueError):
    """A world file is malformed; the message names the file and the field."""


@struct.dataclass
class World:
    """One playground as arrays (stack several with `stack` for a leading playground axis).

    segments: f32[M, 4]  rows (x1, y1, x2, y2); zero-length rows are padding
    circles:  f32[C, 3]  rows (cx, cy, r); r = 0 rows are padding
    starts:   f32[S, 3]  rows (x, y, theta); rows >= num_starts repeat start 0
    num_starts: i32[]
    goals:    f32[G, 2]  rows >= num_goals repeat goal 0
    num_goals: i32[]
    size:     f32[2]     inner width and height in m (walls at +-size/2)
    """

    segments: jnp.ndarray
    circles: jnp.ndarray
    starts: jnp.ndarray
    num_starts: jnp.ndarray
    goals: jnp.ndarray
    num_goals: jnp.ndarray
    size: jnp.ndarray


# ----------------------------------------------------------------------------- parsing


def box_segments(cx: float, cy: float, sx: float, sy: float, yaw: float) -> np.ndarray:
    """The four edges of a box (full sizes sx, sy, rotated by yaw about its centre): f64[4, 4]."""
    c, s = math.cos(yaw), math.sin(yaw)
    hx, hy = sx / 2, sy / 2
    corners = [(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)]
    pts = [(cx + c * x - s * y, cy + s * x + c * y) for x, y in corners]
    return np.array([[*pts[i], *pts[(i + 1) % 4]] for i in range(4)], dtype=np.float64)


def wall_segments(size) -> np.ndarray:
    w, h = size[0] / 2, size[1] / 2
    return np.array([[-w, -h, w, -h], [w, -h, w, h], [w, h, -w, h], [-w, h, -w, -h]], dtype=np.float64)


def _array(spec: dict, field: str, ncol: int, src: str, required: bool) -> np.ndarray:
    if field not in spec or spec[field] is None:
        if required:
            raise WorldError(f"{src}: missing field '{field}' (a list of rows with {ncol} numbers)")
        return np.zeros((0, ncol))
    try:
        arr = np.asarray(spec[field], dtype=np.float64)
    except (TypeError, ValueError, OverflowError, RecursionError) as e:
        raise WorldError(f"{src}: field '{field}' must be a list of rows of {ncol} numbers ({e})") from None
    if arr.size == 0:
        arr = arr.reshape(0, ncol)
    if arr.ndim != 2 or arr.shape[1] != ncol:
        raise WorldError(
            f"{src}: field '{field}' has shape {list(arr.shape)}, expected [n, {ncol}] (rows of {ncol} numbers)"
        )
    if required and len(arr) == 0:
        raise WorldError(f"{src}: field '{field}' is empty; at least one row is needed")
    if len(arr) > MAX_PRIMITIVES:
        raise WorldError(
            f"{src}: field '{field}' has {len(arr)} rows; at most {MAX_PRIMITIVES} are allowed per world file"
        )
    _check_types(spec[field], field, src)
    _check_numbers(arr, field, src)
    return arr


def _check_types(value, field: str, src: str) -> None:
    """Every entry of a numeric field (`value` as the file gave it, already known to convert) is a
    number: numpy would read true and false as 1.0 and 0.0 and parse a string ("3"), so neither
    passes as one (docs/worlds.md). One WorldError naming the row (of a field of rows) otherwise."""
    todo = [((), value)]
    while todo:
        at, v = todo.pop()
        if isinstance(v, np.ndarray) and v.dtype.kind in "iuf":
            continue
        if isinstance(v, np.ndarray):  # booleans, text or objects: look at each entry
            v = v.tolist()
        if isinstance(v, (list, tuple)):
            todo.extend(((*at, i), x) for i, x in reversed(list(enumerate(v))))
            continue
        if isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool):
            continue
        where = f"{field}[{at[0]}]" if at and field != "size" else field
        row = value if where == field else value[at[0]]
        if isinstance(v, (bool, np.bool_)):
            what = f"a boolean ({str(bool(v)).lower()})"
        else:
            what = f"text ({show(v)})" if isinstance(v, (str, bytes)) else "null" if v is None else show(v)
        raise WorldError(
            f"{src}: field '{field}' holds {what} where a number belongs ({where} = {show(_plain(row))}); "
            "allowed: numbers (m, or rad for an angle)"
        )


def _plain(value):
    """A numpy array as the list it holds (for an error message), anything else as it is."""
    return value.tolist() if isinstance(value, np.ndarray) else value


def _check_numbers(arr: np.ndarray, field: str, src: str) -> None:
    """Finite and within +-MAX_COORD (so also finite in float32), else one WorldError naming the row."""
    bad = ~np.isfinite(arr) | (np.abs(np.nan_to_num(arr)) > MAX_COORD)
    if np.any(bad):
        row = int(np.argwhere(bad)[0][0]) if arr.ndim == 2 else None
        shown = arr[row] if row is not None else arr
        at = f"{field}[{row}]" if row is not None else field
        what = "a non-finite number" if not np.all(np.isfinite(shown)) else f"a number beyond +-{MAX_COORD:g}"
        value = shown.tolist()
        raise WorldError(
            f"{src}: field '{field}' holds {what} ({at} = {show(value)}); allowed: finite, |value| <= "
            f"{MAX_COORD:g} (m, or rad for an angle)"
        )


def point_segment_distance_np(p: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Distance from points p [..., 2] to every segment [M, 4] -> [..., M] (float64 reference)."""
    a, b = seg[:, :2], seg[:, 2:]
    ab = b - a
    ap = p[..., None, :] - a
    denom = np.maximum((ab * ab).sum(-1), 1e-300)
    t = np.clip((ap * ab).sum(-1) / denom, 0.0, 1.0)
    closest = a + t[..., None] * ab
    return np.linalg.norm(p[..., None, :] - closest, axis=-1)


def _inside_box(p, box) -> bool:
    cx, cy, sx, sy, yaw = box
    c, s = math.cos(yaw), math.sin(yaw)
    dx, dy = p[0] - cx, p[1] - cy
    lx, ly = c * dx + s * dy, -s * dx + c * dy
    return abs(lx) <= sx / 2 and abs(ly) <= sy / 2


def from_dict(spec: dict, src: str = "<dict>") -> tuple[World, dict]:
    """Validate a world description and build the `World` (unpadded) and its metadata."""
    if not isinstance(spec, dict):
        raise WorldError(f"{src}: a world file must hold a mapping with fields size, starts, goals")
    allowed = {"name", "description", "size", "boxes", "segments", "circles", "starts", "goals"}
    unknown = [k for k in spec if k not in allowed]
    if unknown:
        raise WorldError(f"{src}: unknown field {str(unknown[0])!r} (allowed: {', '.join(sorted(allowed))})")
    if "size" not in spec:
        raise WorldError(f"{src}: missing field 'size' ([width, height] of the inner free space in m)")
    try:
        size = np.asarray(spec["size"], dtype=np.float64).reshape(-1)
    except (TypeError, ValueError, OverflowError, RecursionError):
        raise WorldError(f"{src}: field 'size' must be [width, height] in m") from None
    _check_types(spec["size"], "size", src)
    if size.shape != (2,) or not np.all(size > 0) or not np.all(np.isfinite(size)):
        raise WorldError(f"{src}: field 'size' must be [width, height] with both > 0, got {show(spec['size'])}")
    _check_numbers(size, "size", src)
    for field in ("name", "description"):
        if field in spec and not isinstance(spec[field], str):
            raise WorldError(f"{src}: field '{field}' must be a string, got {show(spec[field])}")
    boxes = _array(spec, "boxes", 5, src, False)
    segs = _array(spec, "segments", 4, src, False)
    circles = _array(spec, "circles", 3, src, False)
    starts = _array(spec, "starts", 3, src, True)
    goals = _array(spec, "goals", 2, src, True)
    if len(boxes) and np.any(boxes[:, 2:4] <= 0):
        raise WorldError(f"{src}: field 'boxes' has a box with a size <= 0 (columns sx, sy must be > 0)")
    if len(circles) and np.any(circles[:, 2] <= 0):
        raise WorldError(f"{src}: field 'circles' has a radius <= 0")
    if len(segs) and np.any(np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]) == 0):
        raise WorldError(f"{src}: field 'segments' has a zero-length segment")

    all_segs = [wall_segments(size), segs] + [box_segments(*b) for b in boxes]
    all_segs = np.concatenate([s.reshape(-1, 4) for s in all_segs], axis=0)
    half = size / 2

    def check_point(p, field, i, clearance):
        if np.any(np.abs(p[:2]) >= half):
            raise WorldError(
                f"{src}: {field}[{i}] = {p.tolist()} is outside the walls (|x| < {half[0]:g}, |y| < {half[1]:g})"
            )
        for j, b in enumerate(boxes):
            if _inside_box(p, b):
                raise WorldError(f"{src}: {field}[{i}] = {p.tolist()} is inside boxes[{j}]")
        for j, c in enumerate(circles):
            if math.hypot(p[0] - c[0], p[1] - c[1]) <= c[2]:
                raise WorldError(f"{src}: {field}[{i}] = {p.tolist()} is inside circles[{j}]")
        if clearance > 0:
            d = min(
                point_segment_distance_np(p[:2], all_segs).min(),
                (np.hypot(*(p[:2] - circles[:, :2]).T) - circles[:, 2]).min() if len(circles) else np.inf,
            )
            if d < clearance:
                raise WorldError(
                    f"{src}: {field}[{i}] = {p.tolist()} is {d:.3f} m from an obstacle; it must be at "
                    f"least {clearance} m away (the collision distance)"
                )

    for i, s in enumerate(starts):
        check_point(s, "starts", i, CLEARANCE)
    for i, g in enumerate(goals):
        check_point(g, "goals", i, 0.0)

    world = World(
        segments=jnp.asarray(all_segs, jnp.float32),
        circles=jnp.asarray(circles.reshape(-1, 3), jnp.float32),
        starts=jnp.asarray(starts, jnp.float32),
        num_starts=jnp.asarray(len(starts), jnp.int32),
        goals=jnp.asarray(goals, jnp.float32),
        num_goals=jnp.asarray(len(goals), jnp.int32),
        size=jnp.asarray(size, jnp.float32),
    )
    meta = {
        "name": spec.get("name", Path(src).stem),
        "description": spec.get("description", ""),
        "boxes": boxes.tolist(),
        "source": src,
    }
    return world, meta


def _read(path: Path) -> dict:
    """A world file's content; any problem reading or parsing it is one WorldError line. Bounded
    (`input_files`): a regular file of at most MAX_FILE_BYTES, at most MAX_NODES YAML
    values once aliases are expanded, no key given twice."""
    try:
        text = input_files.read_text(path, "world", MAX_FILE_BYTES, formats="JSON or YAML")
        if path.suffix.lower() in (".yaml", ".yml"):
            return input_files.load_yaml(text, MAX_NODES)
        return input_files.load_json(text)
    except input_files.InputError as e:
        raise WorldError(f"{path}: {e}") from None


def resolve(name_or_path: str | Path) -> Path:
    """The file behind a shipped name or a user's path."""
    name = str(name_or_path)
    if name in SHIPPED:
        return Path(str(resources.files("fedjax_nav.worlds") / "data" / f"{name}.json"))
    path = Path(name)
    try:
        exists = path.exists()
    except (OSError, ValueError) as e:  # e.g. a NUL byte or an over-long name
        why = getattr(e, "strerror", None) or type(e).__name__
        raise WorldError(f"{show(name, 240)}: cannot be read as a world file ({why})") from None
    if not exists:
        if why := input_files.missing_link(path):  # a symlink loop is not "no such file"
            raise WorldError(f"{shorten(name, 240)}: {why}; not a world file")
        raise WorldError(
            f"{shorten(name, 240)}: no such world file, and not a shipped world (shipped: {', '.join(SHIPPED)})"
        )
    return path


def map_spec(path: str | Path, **draw) -> dict:
    """The world file's mapping (size, boxes, starts, goals) of a ROS map_server map: its YAML
    `path` and the image it names (docs/worlds.md, "Maps you already have"). `draw` (starts, goals:
    counts; seed; cell: m; None: the map's `fedjax_nav` section or the defaults) sets how starts
    and goals are drawn and how coarse the cells are. Problems: one WorldError line."""
    path = resolve(path)
    return _from_map(_read(path), path, **draw)


def _from_map(data, path: Path, **draw) -> dict:
    if not rosmap.is_map(data):
        raise WorldError(f"{path}: not a ROS map_server map (it has no key 'image' nor 'resolution')")
    try:
        return rosmap.map_spec(
            data, str(path), clearance=CLEARANCE, max_primitives=MAX_PRIMITIVES, max_coord=MAX_COORD, **draw
        )
    except MapError as e:
        raise WorldError(str(e)) from None


def load_with_meta(name_or_path: str | Path) -> tuple[World, dict]:
    path = resolve(name_or_path)
    data = _read(path)
    return from_dict(_from_map(data, path) if rosmap.is_map(data) else data, str(path))


def load(name_or_path: str | Path) -> World:
    """Load a shipped playground by name ("train-0" .. "train-5", "eval"), a JSON/YAML world file,
    or a ROS map_server map's YAML (`map_spec`: its occupied cells become boxes)."""
    return load_with_meta(name_or_path)[0]


# ----------------------------------------------------------------------------- padding


def pad(world: World, num_segments: int, num_circles: int, num_starts: int, num_goals: int) -> World:
    """Pad to fixed shapes: zero segments/circles never hit; extra starts/goals repeat row 0."""

    def pad_rows(a, n, fill_row=None):
        a = np.asarray(a)
        if len(a) > n:
            raise ValueError(f"cannot pad {len(a)} rows down to {n}")
        extra = np.zeros((n - len(a), a.shape[1]), a.dtype) if fill_row is None else np.repeat(a[:1], n - len(a), 0)
        return jnp.asarray(np.concatenate([a, extra], 0))

    return world.replace(
        segments=pad_rows(world.segments, num_segments),
        circles=pad_rows(world.circles, num_circles),
        starts=pad_rows(world.starts, num_starts, fill_row=True),
        goals=pad_rows(world.goals, num_goals, fill_row=True),
    )


def stack(worlds: Sequence[World]) -> World:
    """Pad worlds to common shapes and stack them on a new leading axis."""
    dims = [
        max(max(w.segments.shape[0] for w in worlds), 1),
        max(max(w.circles.shape[0] for w in worlds), 1),
        max(w.starts.shape[0] for w in worlds),
        max(w.goals.shape[0] for w in worlds),
    ]
    padded = [pad(w, *dims) for w in worlds]
    return World(
        *[
            jnp.stack(leaves)
            for leaves in zip(
                *[(w.segments, w.circles, w.starts, w.num_starts, w.goals, w.num_goals, w.size) for w in padded]
            )
        ]
    )


def load_many(names: Sequence[str | Path]) -> World:
    """Load and stack several worlds: a World with a leading playground axis."""
    return stack([load(n) for n in names])
