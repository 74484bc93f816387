"""ROS map_server maps as worlds (docs/worlds.md, "Maps you already have"): the map's YAML and
image read as an occupancy grid the way map_server reads them, then `grid` turns it into a world
file's mapping (size, boxes, starts, goals) that `world.from_dict` validates. numpy and yaml;
Pillow (a dependency of matplotlib) only for images other than PGM.

The YAML's keys (map_server's): `image` (a path, relative to the YAML's folder), `resolution`
(m per pixel), `origin` [x, y, yaw] (the pose of the lower-left pixel's corner in the map frame),
`negate`, `occupied_thresh`, `free_thresh`, and optionally `mode` (trinary, scale or raw).
Other keys are ignored, as map_server ignores them, but for our own optional `fedjax_nav` section
(`OWN_KEYS`): starts and goals in the map frame (or how many to draw), the draw's seed, a cell size.
"""

from __future__ import annotations

import io
import math
import re
from pathlib import Path

import numpy as np

from fedjax_nav.messages import show
from fedjax_nav.worlds import grid, input_files
from fedjax_nav.worlds.grid import MapError

ROS_KEYS = ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh")
MODES = ("trinary", "scale", "raw")
OWN_KEYS = ("starts", "goals", "seed", "cell")
DEFAULT_DRAWN = 1  # starts, and goals, drawn when the map gives none
# An image is read only when a regular file of at most this many bytes and this many pixels
# (4096 x 4096: 205 m square at 5 cm); the bounds are checked before any pixel is decoded.
MAX_IMAGE_BYTES = 64 * input_files.MIB
MAX_MAP_PIXELS = 4096 * 4096
# The finest cells taken (m), after any coarsening: the drawing's work grows with the clearance in
# cells (0.35 m is 70 cells of 5 mm); maps are rarely finer than 1-5 cm.
MIN_CELL = 0.005


def is_map(data) -> bool:
    """Whether a parsed YAML/JSON file is a map_server map (it has `image` or `resolution`) rather
    than a world file (which has neither)."""
    return isinstance(data, dict) and ("image" in data or "resolution" in data)


def _real(value, bound: float) -> bool:
    """Whether `value` is a number (not a bool) with |value| <= bound (so finite, even an int of
    400 digits, which has no float)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and abs(value) <= bound


def _number(data: dict, key: str, src: str, lo: float, hi: float, what: str) -> float:
    """data[key], a finite number in [lo, hi], else a MapError naming the key."""
    value = data[key]
    if not _real(value, max(abs(lo), abs(hi))) or not lo <= value <= hi:
        raise MapError(f"{src}: key '{key}' must be {what}, got {show(value)}")
    return float(value)


def settings(data: dict, src: str, max_coord: float) -> dict:
    """The map_server keys checked: image (Path), resolution, origin (x, y, yaw), negate (bool),
    occupied_thresh, free_thresh, mode. A missing or bad key: a MapError naming it."""
    for key in ROS_KEYS:
        if key not in data:
            raise MapError(f"{src}: missing key '{key}' (a map_server YAML has {', '.join(ROS_KEYS)})")
    if not isinstance(data["image"], str) or not data["image"]:
        raise MapError(f"{src}: key 'image' must be the image file's path, got {show(data['image'])}")
    out = {"image": Path(src).parent / data["image"]}
    out["resolution"] = _number(data, "resolution", src, 0.0, max_coord, "the cell size in m (> 0)")
    if out["resolution"] <= 0:
        raise MapError(f"{src}: key 'resolution' must be the cell size in m (> 0), got {show(data['resolution'])}")
    origin = data["origin"]
    if not (isinstance(origin, list) and len(origin) == 3 and all(_real(v, max_coord) for v in origin)):
        raise MapError(
            f"{src}: key 'origin' must be [x, y, yaw] (m, m, rad; finite, within +-{max_coord:g}), got {show(origin)}"
        )
    out["origin"] = tuple(float(v) for v in origin)
    for key in ("occupied_thresh", "free_thresh"):
        out[key] = _number(data, key, src, 0.0, 1.0, "a number in [0, 1]")
    if out["free_thresh"] > out["occupied_thresh"]:
        raise MapError(f"{src}: key 'free_thresh' ({out['free_thresh']:g}) is above occupied_thresh")
    if data["negate"] not in (0, 1) or isinstance(data["negate"], float):
        raise MapError(f"{src}: key 'negate' must be 0 or 1 (or false / true), got {show(data['negate'])}")
    out["negate"] = bool(data["negate"])
    out["mode"] = data.get("mode", "trinary")
    if out["mode"] not in MODES:
        raise MapError(f"{src}: key 'mode' must be one of {', '.join(MODES)}, got {show(out['mode'])}")
    return out


# ----------------------------------------------------------------------------- the image


# "P5" or "P2", then width, height and maxval, each after whitespace or comment lines; one whitespace
_PGM = re.compile(rb"(P[25])(?:\s|#[^\n]*\n)+(\d+)(?:\s|#[^\n]*\n)+(\d+)(?:\s|#[^\n]*\n)+(\d+)\s")


def _pgm(data: bytes) -> np.ndarray:
    """The grey levels of a binary (P5) or plain (P2) PGM, scaled to 0..255: f64[rows, cols]."""
    m = _PGM.match(data)
    if not m:
        raise ValueError("no PGM header (P5 or P2, width, height, maxval)")
    w, h, maxval = (int(x) for x in m.groups()[1:])
    if not (w > 0 and h > 0 and 0 < maxval < 65536) or w * h > MAX_MAP_PIXELS:
        raise ValueError(f"{w} x {h} pixels, maxval {maxval}; at most {MAX_MAP_PIXELS:,} pixels, maxval < 65536")
    if m.group(1) == b"P2":
        values = np.array(data[m.end() :].split()[: w * h], np.int64)
    else:
        dtype = np.dtype(">u2" if maxval > 255 else "u1")
        count = min(w * h, (len(data) - m.end()) // dtype.itemsize)
        values = np.frombuffer(data, dtype, count=count, offset=m.end())
    if values.size != w * h:
        raise ValueError(f"{values.size:,} of its {w * h:,} pixels present")
    values = np.minimum(values.reshape(h, w).astype(np.int64), maxval)
    return values * (255 / maxval)


def _pillow(data: bytes) -> np.ndarray:
    """An image that Pillow reads (PNG, ...): the mean of its colour channels (alpha left out),
    0..255: f64[rows, cols]."""
    from PIL import Image, UnidentifiedImageError

    try:
        opened = Image.open(io.BytesIO(data))
    except UnidentifiedImageError:
        raise ValueError("not an image format that map_server or Pillow knows") from None
    with opened as im:
        if im.width * im.height > MAX_MAP_PIXELS:
            raise ValueError(f"{im.width} x {im.height} pixels; at most {MAX_MAP_PIXELS:,} pixels")
        if im.mode.startswith("I;16"):
            return np.asarray(im, np.float64) * (255 / 65535)
        if im.mode not in ("1", "L", "LA", "P", "PA", "RGB", "RGBA"):
            raise ValueError(f"pixel mode {im.mode}, not grey, grey with alpha, palette or RGB(A)")
        rgb = np.asarray(im.convert("RGB") if im.mode not in ("L", "LA") else im.convert("L"), np.int64)
    return rgb.astype(np.float64) if rgb.ndim == 2 else rgb.sum(-1) / 3


def read_image(path: Path, src: str) -> np.ndarray:
    """The map image's grey levels f64[rows, cols] (row 0 the top). A problem: one MapError line."""
    try:
        data = input_files.read_bytes(path, "map image", MAX_IMAGE_BYTES)
        if data[:2] in (b"P2", b"P5"):
            return _pgm(data)
        return _pillow(data)
    except input_files.InputError as e:
        raise MapError(f"{src}: key 'image': {path} {e}") from None
    except Exception as e:  # an unknown format, a truncated file, ... (Pillow's own errors included)
        why = " ".join(str(e).split()) or type(e).__name__
        raise MapError(f"{src}: key 'image': {path}: cannot be read as a PGM or PNG image ({why})") from None


def occupied(values: np.ndarray, s: dict) -> np.ndarray:
    """bool[rows, cols]: the cells that map_server does not call free (occupied or unknown: both
    are obstacles here, so only free_thresh decides). The grey level v, 255 - v with `negate`;
    trinary and scale: free if (255 - v) / 255 < free_thresh; raw: v is the occupancy in percent
    (over 100: unknown), free if v / 100 < free_thresh."""
    v = 255 - values if s["negate"] else values
    p = v / 100 if s["mode"] == "raw" else (255 - v) / 255
    return ~(p < s["free_thresh"])


# ----------------------------------------------------------------------------- our own section


def _name(key: str, flags: dict) -> str:
    """How a message names a setting: the command-line flag that gave it, else the YAML key."""
    return f"--{key}" if key in flags else f"key 'fedjax_nav.{key}'"


def _rows_or_count(value, name: str, ncol: int, src: str, max_rows: int, max_coord: float):
    """Starts or goals: rows of `ncol` numbers (map frame), or how many to draw."""
    if isinstance(value, int) and not isinstance(value, bool):
        if not 1 <= value <= max_rows:
            raise MapError(f"{src}: {name} must be a count in [1, {max_rows}] or rows, got {show(value)}")
        return value
    try:
        arr = np.asarray(value, np.float64)
    except (TypeError, ValueError, OverflowError, RecursionError):
        arr = np.zeros(0)
    if arr.ndim != 2 or arr.shape[1] != ncol or not 1 <= len(arr) <= max_rows:
        what = "[x, y, theta]" if ncol == 3 else "[x, y]"
        raise MapError(f"{src}: {name} must be rows {what} in the map frame or a count, got {show(value)}")
    if not np.all(np.isfinite(arr) & (np.abs(arr) <= max_coord)):
        raise MapError(f"{src}: {name} holds a number that is not finite or beyond +-{max_coord:g}")
    return arr


def own_settings(data: dict, src: str, max_rows: int, max_coord: float, flags: dict) -> dict:
    """The optional `fedjax_nav` section, with the command line's `flags` (starts, goals, seed,
    cell; None: not given) over it: starts, goals (rows or counts; default DEFAULT_DRAWN each),
    seed (default 0), cell (m; None: the map's resolution)."""
    sec = data.get("fedjax_nav")
    sec = {} if sec is None else sec
    if not isinstance(sec, dict):
        raise MapError(f"{src}: key 'fedjax_nav' must be a mapping with keys {', '.join(OWN_KEYS)}")
    unknown = [k for k in sec if k not in OWN_KEYS]
    if unknown:
        raise MapError(f"{src}: unknown key 'fedjax_nav.{unknown[0]}' (allowed: {', '.join(OWN_KEYS)})")
    flags = {k: v for k, v in flags.items() if v is not None}
    sec = {**sec, **flags}
    out = {
        k: _rows_or_count(sec.get(k, DEFAULT_DRAWN), _name(k, flags), n, src, max_rows, max_coord)
        for k, n in (("starts", 3), ("goals", 2))
    }
    seed = sec.get("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool) or not 0 <= seed < 2**32:
        raise MapError(f"{src}: {_name('seed', flags)} must be an integer in [0, {2**32 - 1}], got {show(seed)}")
    cell = sec.get("cell")
    if cell is not None and not (_real(cell, max_coord) and cell > 0):
        raise MapError(f"{src}: {_name('cell', flags)} must be a cell size in m (> 0), got {show(cell)}")
    return {**out, "seed": seed, "cell": cell, "cell_name": _name("cell", flags)}


def cell_factor(cell: float | None, res: float, src: str, name: str) -> int:
    """How many map cells a side of a coarse cell spans: cell / res, a whole number >= 1."""
    if cell is None:
        return 1
    k = cell / res
    if not (round(k) >= 1 and abs(k - round(k)) <= 1e-6 * k):
        raise MapError(f"{src}: {name} ({cell:g} m) must be a whole multiple of the map's resolution, {res:g} m")
    return int(round(k))


# ----------------------------------------------------------------------------- the world


def _to_grid(points: np.ndarray, origin) -> np.ndarray:
    """Map-frame points (x, y[, theta]) in grid metres (the lower-left corner at (0, 0))."""
    ox, oy, yaw = origin
    c, s = math.cos(yaw), math.sin(yaw)
    dx, dy = points[:, 0] - ox, points[:, 1] - oy
    out = np.array(points, np.float64)
    out[:, 0], out[:, 1] = c * dx + s * dy, -s * dx + c * dy
    if points.shape[1] == 3:
        out[:, 2] = points[:, 2] - yaw
    return out


def _check_given(occ, res, q, given, key, src, clearance) -> None:
    """Given starts (clearance > 0) or goals inside the map, not in an obstacle, starts clear."""
    d = grid.point_clearance(occ, res, q[:, :2], max(clearance, res))
    for i, p in enumerate(given):
        where = f"{src}: fedjax_nav.{key}[{i}] = {show(p.tolist())} (map frame)"
        if d[i] <= 0:
            raise MapError(f"{where} is outside the map or in an occupied or unknown cell")
        if d[i] < clearance:
            raise MapError(
                f"{where} is {d[i]:.3f} m from an obstacle or the map's border; a start must be at least "
                f"{clearance} m away (the collision distance)"
            )


def _places(occ, res, origin, own, src, clearance):
    """Starts f64[n, 3] and goals f64[m, 2] in grid metres: the given ones (checked) and drawn ones."""
    given = {k: _to_grid(v, origin) for k, v in own.items() if k in ("starts", "goals") and not isinstance(v, int)}
    for key, q in given.items():
        _check_given(occ, res, q, own[key], key, src, clearance if key == "starts" else 0.0)
    if len(given) == 2:
        return given["starts"], given["goals"]
    n = {k: 0 if k in given else own[k] for k in ("starts", "goals")}
    near = next((q[0] for q in given.values()), None)
    starts, goals = grid.draw(occ, res, clearance, n["starts"], n["goals"], own["seed"], near)
    if starts is None:
        raise MapError(
            f"{src}: no room to draw {n['starts']} start(s) and {n['goals']} goal(s): too few cells "
            f"{clearance + grid.MARGIN:g} m from every obstacle, connected to each other"
        )
    return given.get("starts", starts), given.get("goals", goals)


def map_spec(data: dict, src: str, *, clearance: float, max_primitives: int, max_coord: float, **draw) -> dict:
    """A world file's mapping (name, description, size, boxes, starts, goals) from a map_server
    YAML's content `data` (its file `src`). `draw` overrides the fedjax_nav section: starts,
    goals (counts), seed, cell. Problems: one MapError line naming the file and the key."""
    s = settings(data, src, max_coord)
    own = own_settings(data, src, max_primitives, max_coord, draw)
    k = cell_factor(own["cell"], s["resolution"], src, own["cell_name"])
    occ = grid.coarsen(occupied(read_image(s["image"], src), s), k)
    res, (h, w) = s["resolution"] * k, occ.shape
    if res < MIN_CELL:
        flag = own["cell_name"] if own["cell"] is not None else "--cell, or fedjax_nav: cell:"
        raise MapError(
            f"{src}: cells of {res:g} m are finer than {MIN_CELL:g} m, the finest taken; coarsen them ({flag} "
            f"a multiple of {s['resolution']:g} m of at least {MIN_CELL:g})"
        )
    size = np.array([w * res, h * res])
    if size.max() > max_coord:
        raise MapError(f"{src}: the map is {size[0]:g} x {size[1]:g} m; a world is at most {max_coord:g} m a side")
    rects = grid.merge_cells(occ)
    if len(rects) > max_primitives:
        raise MapError(
            f"{src}: the map is too detailed: its occupied cells make {len(rects)} boxes, at most "
            f"{max_primitives} are allowed; coarsen it (--cell, or fedjax_nav: cell: {2 * res:g})"
        )
    starts, goals = _places(occ, res, s["origin"], own, src, clearance)
    ox, oy, yaw = s["origin"]
    return {
        "name": Path(src).stem,
        "description": (
            f"ROS map {Path(src).name}: {w} x {h} cells of {res:g} m, {len(rects)} boxes; a world point p is the "
            f"map point ({ox:g}, {oy:g}) + R({yaw:g}) (p + ({size[0] / 2:g}, {size[1] / 2:g}))"
        ),
        "size": np.round(size, 9).tolist(),
        "boxes": np.round(grid.boxes(rects, occ.shape, res), 9).tolist(),
        "starts": np.round(np.column_stack([starts[:, :2] - size / 2, starts[:, 2]]), 9).tolist(),
        "goals": np.round(goals - size / 2, 9).tolist(),
    }
