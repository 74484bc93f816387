"""Room specs of the procedural generator: `RoomSpec`, its allowed ranges and checks, the families.

`fedjax_nav.worlds.procedural` draws the rooms (pure JAX), `fedjax_nav.worlds.suites` holds the
room keys, the held-out test suites and world files. docs/generator.md describes all three.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from fedjax_nav.messages import shorten, show
from fedjax_nav.worlds.shapes import needed_shape
from fedjax_nav.worlds.world import CLEARANCE, WorldError

# The first four families draw cylinders, boxes and walls around a reserved network
# (`procedural`); the dense ones build a structure (forest, warehouse, maze, cave) in their own
# modules (fedjax_nav/worlds/forest.py, warehouse.py, maze.py, cave.py), and so do the indoor ones
# (multi-room offices, corridors: office.py, corridors.py). FAMILIES is the one list of them all;
# new families go at the end of a new tuple, so the suites' seed blocks of the others stay.
BASE_FAMILIES = ("cylinders", "boxes", "walls", "mixture")
DENSE_FAMILIES = ("forest", "warehouse", "maze", "cave")
INDOOR_FAMILIES = ("office", "corridors")
FAMILIES = BASE_FAMILIES + DENSE_FAMILIES + INDOOR_FAMILIES
# The fields a spec leaves None take the family's value (the room size: 4-12 m for the base families).
_SIZES = {"forest": (8.0, 16.0), "warehouse": (10.0, 18.0), "maze": (5.0, 10.0), "cave": (5.0, 9.0)}
_SIZES |= {"office": (10.0, 18.0), "corridors": (10.0, 18.0), None: (4.0, 12.0)}
_BY_FAMILY = {
    **{f"{side}_min": {f: lo for f, (lo, _) in _SIZES.items()} for side in ("width", "height")},
    **{f"{side}_max": {f: hi for f, (_, hi) in _SIZES.items()} for side in ("width", "height")},
    "trail_points": {"cave": 2, None: 6},
}
# Which obstacle kinds each base family draws.
_KINDS = {k: (k,) for k in ("cylinders", "boxes", "walls")} | {"mixture": ("cylinders", "boxes", "walls")}
_START_TRIES = 64  # candidates per start for the start-goal distance rule


def _f(default, lo, hi, doc):
    return dataclasses.field(default=default, metadata={"range": (lo, hi), "doc": doc})


@dataclasses.dataclass(frozen=True)
class RoomSpec:
    """What `generate` draws. Lengths in m; every count and size is drawn uniformly from its
    ``[*_min, *_max]`` range (integers inclusive). `check_spec` enforces the allowed ranges
    (the ``range`` metadata of each field) and the rules between fields.

    family: one of `FAMILIES`: "cylinders", "boxes", "walls", "mixture" (all three kinds), a
        dense family "forest", "warehouse", "maze", "cave", or an indoor one "office",
        "corridors" (docs/generator.md); the fields of the kinds a family does not use are ignored.
    width_*, height_*: the inner size of the room (walls at +-W/2, +-H/2); None (the default)
        is the family's default: 4-12 m, forest 8-16, warehouse 10-18, maze 5-10, cave 5-9,
        office and corridors 10-18.
    cylinders_*, radius_*: number of cylinders and their radius.
    boxes_*, box_side_*: number of boxes and their side lengths (each side drawn separately);
        the yaw is uniform in [0, pi).
    walls_*: number of interior dividing walls (a binary space partition into sub-rooms);
        door_width_*: width of the one doorway in each wall (must exceed 2 (D_c + margin));
        room_side_min: the smallest side of a sub-room (>= door_width_max + 2 (D_c + margin)).
    starts_*, goals_*: number of starts and goals; start yaw is uniform in [-pi, pi).
    min_start_goal_distance: each start is drawn (up to 64 candidates) at least this far from
        every goal; if no candidate qualifies the farthest one is kept (best effort).
    clearance_margin: the reserved paths keep D_c + clearance_margin from every obstacle.
    tries: candidates drawn per obstacle or wall before it is dropped.
    trees_*, trunk_radius_*, trail_points: forest: trunks on a jittered grid, kept off a trail
        network of `trail_points` random waypoints (forest and cave).
    aisle_width_*, rack_*, pallet*, warehouse_boxes: warehouse: rows of rack sections (depth x
        length), aisles and cross-aisles of at least aisle_width_min > 2 (D_c + margin), a rack
        section present with probability rack_fill, loose pallets (axis-aligned boxes), at most
        warehouse_boxes boxes in all.
    maze_cell_*, maze_loops: maze: a perfect grid maze (cells > 2 (D_c + margin), wall segments)
        with a fraction maze_loops of its remaining inner walls removed.
    cave_*: cave: a cellular automaton (initial fill, smoothing steps) on a grid of cave cells,
        carved around the trail network; its outline as at most cave_segments segments.
    office_*: office: a grid of rooms with doors along a spanning tree (and extra ones), desks and
        round things in the rooms (fedjax_nav/worlds/office.py).
    corridor_*: corridors: a spine corridor, branches ending in side rooms or dead ends, turns,
        boxes of clutter (fedjax_nav/worlds/corridors.py).
    max_segments, max_circles, max_starts, max_goals: the padded array shapes; None = the
        least that fits the spec (`padded_shape`), a larger value pads further (e.g. to stack
        with other worlds).
    """

    family: str = "mixture"
    width_min: float | None = _f(None, 3.0, 30.0, "room width, lower end (m; None: the family's)")
    width_max: float | None = _f(None, 3.0, 30.0, "room width, upper end (m; None: the family's)")
    height_min: float | None = _f(None, 3.0, 30.0, "room height, lower end (m; None: the family's)")
    height_max: float | None = _f(None, 3.0, 30.0, "room height, upper end (m; None: the family's)")
    cylinders_min: int = _f(2, 0, 32, "number of cylinders, lower end")
    cylinders_max: int = _f(8, 0, 32, "number of cylinders, upper end")
    radius_min: float = _f(0.15, 0.05, 2.0, "cylinder radius, lower end (m)")
    radius_max: float = _f(0.5, 0.05, 2.0, "cylinder radius, upper end (m)")
    boxes_min: int = _f(1, 0, 16, "number of boxes, lower end")
    boxes_max: int = _f(5, 0, 16, "number of boxes, upper end")
    box_side_min: float = _f(0.3, 0.1, 4.0, "box side length, lower end (m)")
    box_side_max: float = _f(1.5, 0.1, 4.0, "box side length, upper end (m)")
    walls_min: int = _f(1, 0, 8, "number of interior walls, lower end")
    walls_max: int = _f(3, 0, 8, "number of interior walls, upper end")
    door_width_min: float = _f(0.8, 0.1, 4.0, "doorway width, lower end (m)")
    door_width_max: float = _f(1.2, 0.1, 4.0, "doorway width, upper end (m)")
    room_side_min: float = _f(2.0, 0.5, 15.0, "smallest side of a sub-room (m)")
    starts_min: int = _f(1, 1, 16, "number of starts, lower end")
    starts_max: int = _f(4, 1, 16, "number of starts, upper end")
    goals_min: int = _f(1, 1, 16, "number of goals, lower end")
    goals_max: int = _f(2, 1, 16, "number of goals, upper end")
    min_start_goal_distance: float = _f(2.0, 0.0, 20.0, "least start-goal distance (m)")
    clearance_margin: float = _f(0.05, 0.01, 1.0, "extra clearance of the reserved paths over D_c (m)")
    tries: int = _f(16, 1, 256, "candidates per obstacle or wall")
    trees_min: int = _f(40, 0, 400, "forest: number of trunks, lower end")
    trees_max: int = _f(150, 0, 400, "forest: number of trunks, upper end")
    trunk_radius_min: float = _f(0.1, 0.03, 1.0, "forest: trunk radius, lower end (m)")
    trunk_radius_max: float = _f(0.3, 0.03, 1.0, "forest: trunk radius, upper end (m)")
    trail_points: int | None = _f(None, 1, 32, "forest, cave: trail network waypoints (None: 6, cave 2)")
    aisle_width_min: float = _f(0.9, 0.1, 5.0, "warehouse: aisle width, lower end (m)")
    aisle_width_max: float = _f(1.8, 0.1, 5.0, "warehouse: aisle width, upper end (m)")
    rack_depth_min: float = _f(0.6, 0.2, 4.0, "warehouse: rack depth, lower end (m)")
    rack_depth_max: float = _f(1.2, 0.2, 4.0, "warehouse: rack depth, upper end (m)")
    rack_length_min: float = _f(2.0, 0.5, 20.0, "warehouse: rack section length, lower end (m)")
    rack_length_max: float = _f(6.0, 0.5, 20.0, "warehouse: rack section length, upper end (m)")
    rack_fill: float = _f(0.9, 0.0, 1.0, "warehouse: probability that a rack section is there")
    pallets_min: int = _f(2, 0, 32, "warehouse: number of loose pallets, lower end")
    pallets_max: int = _f(12, 0, 32, "warehouse: number of loose pallets, upper end")
    pallet_side_min: float = _f(0.4, 0.1, 2.0, "warehouse: pallet side, lower end (m)")
    pallet_side_max: float = _f(0.9, 0.1, 2.0, "warehouse: pallet side, upper end (m)")
    warehouse_boxes: int = _f(40, 1, 1024, "warehouse: box slots, racks first (a room with more loses the last)")
    maze_cell_min: float = _f(0.8, 0.2, 5.0, "maze: cell side (= passage width), lower end (m)")
    maze_cell_max: float = _f(1.4, 0.2, 5.0, "maze: cell side (= passage width), upper end (m)")
    maze_loops: float = _f(0.1, 0.0, 1.0, "maze: fraction of the perfect maze's inner walls removed")
    cave_cell_min: float = _f(0.35, 0.1, 2.0, "cave: grid cell side, lower end (m)")
    cave_cell_max: float = _f(0.5, 0.1, 2.0, "cave: grid cell side, upper end (m)")
    cave_fill_min: float = _f(0.45, 0.0, 1.0, "cave: initial occupied fraction, lower end")
    cave_fill_max: float = _f(0.55, 0.0, 1.0, "cave: initial occupied fraction, upper end")
    cave_smoothing: int = _f(1, 0, 8, "cave: cellular-automaton smoothing steps")
    cave_segments: int = _f(192, 8, 2048, "cave: segment rows of the outline (longer outlines are cut)")
    office_cols_min: int = _f(2, 1, 8, "office: rooms along the floor's first side, lower end")
    office_cols_max: int = _f(4, 1, 8, "office: rooms along the floor's first side, upper end")
    office_rows_min: int = _f(2, 1, 8, "office: rooms along the other side, lower end")
    office_rows_max: int = _f(3, 1, 8, "office: rooms along the other side, upper end")
    office_room_min: float = _f(3.0, 1.0, 15.0, "office: least room side before the jitter (m; fewer rooms fit)")
    office_jitter: float = _f(0.15, 0.0, 0.4, "office: each inner wall line moved by up to this share of a room side")
    office_door_min: float = _f(0.7, 0.1, 4.0, "office: door width, lower end (m)")
    office_door_max: float = _f(1.2, 0.1, 4.0, "office: door width, upper end (m)")
    office_extra_doors: float = _f(0.3, 0.0, 1.0, "office: probability of a door in a wall off the spanning tree")
    office_desks_min: int = _f(2, 0, 16, "office: desks per room, lower end")
    office_desks_max: int = _f(5, 0, 16, "office: desks per room, upper end")
    office_desk_depth_min: float = _f(0.5, 0.1, 4.0, "office: desk depth, lower end (m)")
    office_desk_depth_max: float = _f(0.8, 0.1, 4.0, "office: desk depth, upper end (m)")
    office_desk_length_min: float = _f(0.8, 0.1, 4.0, "office: desk length, lower end (m)")
    office_desk_length_max: float = _f(1.6, 0.1, 4.0, "office: desk length, upper end (m)")
    office_cylinders_min: int = _f(4, 0, 16, "office: round things (chairs, columns, bins) per room, lower end")
    office_cylinders_max: int = _f(8, 0, 16, "office: round things per room, upper end")
    office_radius_min: float = _f(0.12, 0.03, 1.0, "office: radius of a round thing, lower end (m)")
    office_radius_max: float = _f(0.3, 0.03, 1.0, "office: radius of a round thing, upper end (m)")
    office_boxes: int = _f(32, 1, 1024, "office: desk slots (a room with more loses a random few)")
    office_circles: int = _f(48, 1, 1024, "office: round-thing slots (a room with more loses a random few)")
    corridor_width_min: float = _f(0.8, 0.1, 5.0, "corridors: corridor width, lower end (m)")
    corridor_width_max: float = _f(1.5, 0.1, 5.0, "corridors: corridor width, upper end (m)")
    corridor_branches_min: int = _f(1, 1, 16, "corridors: branches off the spine, lower end")
    corridor_branches_max: int = _f(4, 1, 16, "corridors: branches off the spine, upper end")
    corridor_turns: float = _f(0.5, 0.0, 1.0, "corridors: probability that an end of the spine turns into a branch")
    corridor_rooms: float = _f(0.6, 0.0, 1.0, "corridors: probability that a branch ends in a side room")
    corridor_room_min: float = _f(2.2, 0.5, 15.0, "corridors: side room side, lower end (m)")
    corridor_room_max: float = _f(4.0, 0.5, 15.0, "corridors: side room side, upper end (m)")
    corridor_boxes_min: int = _f(2, 0, 32, "corridors: boxes of clutter, lower end")
    corridor_boxes_max: int = _f(8, 0, 32, "corridors: boxes of clutter, upper end")
    corridor_box_side_min: float = _f(0.2, 0.05, 2.0, "corridors: clutter box side, lower end (m)")
    corridor_box_side_max: float = _f(0.6, 0.05, 2.0, "corridors: clutter box side, upper end (m)")
    max_segments: int | None = _f(None, 4, 4096, "padded segment rows (None: least that fits)")
    max_circles: int | None = _f(None, 1, 4096, "padded circle rows (None: least that fits)")
    max_starts: int | None = _f(None, 1, 256, "padded start rows (None: starts_max)")
    max_goals: int | None = _f(None, 1, 256, "padded goal rows (None: goals_max)")

    def __post_init__(self):
        for name, by in _BY_FAMILY.items():  # None: the family's value
            if getattr(self, name) is None:
                object.__setattr__(self, name, by.get(self.family, by[None]))

    def uses(self, kind: str) -> bool:
        """Whether this spec's family draws `kind` ("cylinders", "boxes" or "walls")."""
        return kind in _KINDS.get(self.family, ())

    @property
    def clearance(self) -> float:
        """c = D_c + clearance_margin: the clearance the reserved paths keep."""
        return CLEARANCE + self.clearance_margin


SPEC_FIELDS = tuple(f.name for f in dataclasses.fields(RoomSpec))


def _unknown_field(name: str) -> str:
    """One line for a field RoomSpec lacks: the nearest names (there are over fifty fields, one
    family's at a time: docs/generator.md lists them by family)."""
    import difflib

    near = difflib.get_close_matches(name, [f for f in SPEC_FIELDS if f != "family"], n=3, cutoff=0.5)
    hint = f"did you mean {', '.join(near)}? " if near else ""
    return f"unknown RoomSpec field '{shorten(name)}' ({hint}every field and its range: docs/generator.md)"


_INT_FIELDS = {f.name for f in dataclasses.fields(RoomSpec) if f.type in ("int", "int | None")}
_OPTIONAL_FIELDS = {f.name for f in dataclasses.fields(RoomSpec) if "None" in str(f.type)}


def field_ranges() -> dict[str, tuple[Any, Any, Any, str]]:
    """{field: (default, low, high, description)} of every numeric RoomSpec field."""
    return {
        f.name: (f.default, *f.metadata["range"], f.metadata["doc"])
        for f in dataclasses.fields(RoomSpec)
        if "range" in f.metadata
    }


# The fields of the form {base}_min, {base}_max (checked: max >= min).
_PAIRS = tuple(n[:-4] for n in SPEC_FIELDS if n.endswith("_min") and f"{n[:-4]}_max" in SPEC_FIELDS)


def check_spec(spec: RoomSpec) -> RoomSpec:
    """Raise `WorldError` (one line naming the field and its allowed range) if `spec` is bad;
    return it otherwise."""
    if not isinstance(spec, RoomSpec):
        raise WorldError(f"expected a RoomSpec, got {type(spec).__name__}")
    if spec.family not in FAMILIES:
        raise WorldError(f"RoomSpec field 'family' = {spec.family!r} is not allowed (allowed: {', '.join(FAMILIES)})")
    ranges = field_ranges()
    for name, (_, lo, hi, doc) in ranges.items():
        v = getattr(spec, name)
        if v is None and name in _OPTIONAL_FIELDS:
            continue
        is_int = isinstance(v, (int, np.integer)) and not isinstance(v, bool)
        kind = "an integer" if name in _INT_FIELDS else "a number"
        ok_type = is_int if name in _INT_FIELDS else (is_int or isinstance(v, (float, np.floating)))
        if not ok_type or not (is_int or math.isfinite(v)):  # float() of a 400-digit int overflows
            raise WorldError(
                f"RoomSpec field '{name}' = {show(v)} must be {kind} in the allowed range [{lo}, {hi}] ({doc})"
            )
        if not lo <= v <= hi:
            raise WorldError(f"RoomSpec field '{name}' = {show(v)} is outside the allowed range [{lo}, {hi}] ({doc})")
    for base in _PAIRS:
        lo_v, hi_v = getattr(spec, f"{base}_min"), getattr(spec, f"{base}_max")
        if hi_v < lo_v:
            _, lo, hi, _ = ranges[f"{base}_max"]
            raise WorldError(
                f"RoomSpec field '{base}_max' = {hi_v!r} must be >= {base}_min = {lo_v!r} "
                f"(allowed range [{lo_v}, {hi}])"
            )
    c = spec.clearance
    if spec.uses("walls") and spec.walls_max > 0:
        if not spec.door_width_min > 2 * c:
            raise WorldError(
                f"RoomSpec field 'door_width_min' = {spec.door_width_min!r} must be > 2 (D_c + "
                f"clearance_margin) = {2 * c:g} m so the robot fits through a doorway (allowed range "
                f"({2 * c:g}, {ranges['door_width_min'][2]}])"
            )
        lo_room = spec.door_width_max + 2 * c
        hi_room = max(spec.width_min, spec.height_min) / 2
        if not lo_room <= spec.room_side_min <= hi_room:
            raise WorldError(
                f"RoomSpec field 'room_side_min' = {spec.room_side_min!r} is outside the allowed range "
                f"[door_width_max + 2 (D_c + clearance_margin), max(width_min, height_min) / 2] = "
                f"[{lo_room:g}, {hi_room:g}] for this spec"
            )
    _check_dense(spec, c, ranges)
    _check_indoor(spec, c, ranges)
    need = needed_shape(spec)
    for name, n in zip(("max_segments", "max_circles", "max_starts", "max_goals"), need):
        v = getattr(spec, name)
        if v is not None and v < n:
            raise WorldError(
                f"RoomSpec field '{name}' = {show(v)} is outside the allowed range [{n}, "
                f"{ranges[name][2]}] for this spec (None: {n})"
            )
    return spec


def _check_dense(spec: RoomSpec, c: float, ranges) -> None:
    """The rules between fields of the dense families (the passages the robot must fit through)."""
    if spec.family == "warehouse" and not spec.aisle_width_min > 2 * c:
        raise WorldError(
            f"RoomSpec field 'aisle_width_min' = {spec.aisle_width_min!r} must be > 2 (D_c + clearance_margin) = "
            f"{2 * c:g} m so the robot fits through an aisle (allowed range ({2 * c:g}, "
            f"{ranges['aisle_width_min'][2]}])"
        )
    if spec.family == "maze":
        if not spec.maze_cell_min > 2 * c:
            raise WorldError(
                f"RoomSpec field 'maze_cell_min' = {spec.maze_cell_min!r} must be > 2 (D_c + clearance_margin) = "
                f"{2 * c:g} m so the robot fits through a passage (allowed range ({2 * c:g}, "
                f"{ranges['maze_cell_min'][2]}])"
            )
        hi = min(spec.width_min, spec.height_min)
        if spec.maze_cell_max > hi:
            raise WorldError(
                f"RoomSpec field 'maze_cell_max' = {spec.maze_cell_max!r} is outside the allowed range "
                f"[maze_cell_min, min(width_min, height_min)] = [{spec.maze_cell_min:g}, {hi:g}] for this spec"
            )


def _check_indoor(spec: RoomSpec, c: float, ranges) -> None:
    """The office's and corridors' rules between fields: the robot fits every door and corridor with c
    beside it, furniture fits the least office room, a side room fits its slot and either side of the spine."""
    side, prefix = min(spec.width_min, spec.height_min), {"office": "office_", "corridors": "corridor_"}
    furniture = max(spec.office_desk_length_max, spec.office_desk_depth_max, 2 * spec.office_radius_max)
    c2 = "2 (D_c + clearance_margin)"
    rules = {  # field: (low, high, why); a why starting with ">" excludes the low end
        "office_door_min": (2 * c, ranges["office_door_min"][2], f"> {c2}"),
        "office_room_min": (
            max(spec.office_door_max + 2 * c, furniture) / (1 - 2 * spec.office_jitter),
            side / 2,
            f"max(office_door_max + {c2}, the longest desk side, 2 office_radius_max) / (1 - 2 office_jitter) "
            ".. min(width_min, height_min) / 2",
        ),
        "corridor_width_min": (2 * c, ranges["corridor_width_min"][2], f"> {c2}"),
        "corridor_room_min": (
            spec.corridor_width_max + 2 * c,
            min(side / spec.corridor_branches_max, (side - spec.corridor_width_max) / 2),
            f"corridor_width_max + {c2} .. min(width_min, height_min) / corridor_branches_max, and "
            "(min(width_min, height_min) - corridor_width_max) / 2",
        ),
    }
    for name, (lo, hi, why) in rules.items():
        v, open_lo = getattr(spec, name), why.startswith(">")
        if name.startswith(prefix.get(spec.family, "-")) and ((v <= lo if open_lo else v < lo) or v > hi):
            raise WorldError(
                f"RoomSpec field '{name}' = {v!r} is outside the allowed range {'(' if open_lo else '['}{lo:g}, "
                f"{hi:g}] for this spec ({why})"
            )


def make_spec(family: str = "mixture", **overrides) -> RoomSpec:
    """A checked RoomSpec; an unknown field raises WorldError naming it."""
    unknown = sorted(set(overrides) - set(SPEC_FIELDS))
    if unknown:
        raise WorldError(_unknown_field(unknown[0]))
    return check_spec(RoomSpec(family=family, **overrides))


def parse_overrides(items: Sequence[str]) -> dict[str, Any]:
    """``["field=value", ...]`` (the CLI's --set) -> typed overrides; WorldError on a bad one."""
    out: dict[str, Any] = {}
    for item in items or ():
        name, sep, text = item.partition("=")
        name, text = name.strip(), text.strip()
        if not sep or not name:
            raise WorldError(f"--set {show(item)}: expected field=value, e.g. cylinders_max=4")
        if name == "family":
            raise WorldError("--set family=...: give the family with --family")
        if name not in SPEC_FIELDS:
            raise WorldError(_unknown_field(name))
        _, lo, hi, doc = field_ranges()[name]
        if name in _OPTIONAL_FIELDS and text.lower() in ("none", "auto", "null"):
            out[name] = None
            continue
        try:
            out[name] = int(text) if name in _INT_FIELDS else float(text)
        except ValueError:
            kind = "an integer" if name in _INT_FIELDS else "a number"
            raise WorldError(
                f"RoomSpec field '{name}' = {show(text)} must be {kind} in the allowed range [{lo}, {hi}] ({doc})"
            ) from None
    return out
