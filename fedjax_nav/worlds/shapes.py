"""The static shapes of a spec's rooms: how many grid cells, slots and World rows the largest
room of a `RoomSpec` needs (`needed_shape`) and the rows every generated World has (`padded_shape`).
Pure functions of the spec's fields, read at trace time by the family modules (maze.py, cave.py,
warehouse.py, office.py, procedural.py, layout.py) and by `rooms.check_spec`. docs/generator.md.

Every `spec` here is a `rooms.RoomSpec`, not annotated: rooms.py imports this module (check_spec
reads `needed_shape`), and modules never import each other (tests/test_layers.py).
"""

from __future__ import annotations


def slot_counts(spec) -> tuple[int, int, int]:
    """(cylinder slots, box slots, wall slots) this spec's family uses."""
    return (
        spec.cylinders_max if spec.uses("cylinders") else 0,
        spec.boxes_max if spec.uses("boxes") else 0,
        spec.walls_max if spec.uses("walls") else 0,
    )


def grid_cells(side_max: float, cell_min: float) -> int:
    """The most grid cells along a side: a room of side <= side_max cut into cells >= cell_min."""
    return max(1, int(side_max // cell_min))


def maze_grid(spec) -> tuple[int, int]:
    """The maze's static grid (columns, rows): the most cells any of its rooms has."""
    return grid_cells(spec.width_max, spec.maze_cell_min), grid_cells(spec.height_max, spec.maze_cell_min)


def cave_grid(spec) -> tuple[int, int]:
    """The cave's static grid (columns, rows)."""
    return grid_cells(spec.width_max, spec.cave_cell_min), grid_cells(spec.height_max, spec.cave_cell_min)


def maze_wall_rows(spec) -> int:
    """Segment rows of a maze's inner walls: on each inner grid line, walls merged into runs, at
    most ceil(n / 2) runs of n cell sides (two runs are apart by at least one open side)."""
    nx, ny = maze_grid(spec)
    return (ny - 1) * (-(-nx // 2)) + (nx - 1) * (-(-ny // 2))


def warehouse_slots(spec) -> tuple[int, int]:
    """(rack rows, sections per row): the most that fit the longest room side with the narrowest
    aisles and the smallest racks (the layout may be turned by 90 degrees)."""
    side, a = max(spec.width_max, spec.height_max), spec.aisle_width_min
    return max(0, int((side - a) // (spec.rack_depth_min + a))), max(0, int((side - a) // (spec.rack_length_min + a)))


def office_grid(spec) -> tuple[int, int]:
    """The office's static grid of rooms (columns, rows): the most either side of any floor holds
    (the layout may be turned by 90 degrees, so both sides are bounded by the longest)."""
    cells = grid_cells(max(spec.width_max, spec.height_max), spec.office_room_min)
    return min(spec.office_cols_max, cells), min(spec.office_rows_max, cells)


def office_slots(spec) -> tuple[int, int, int]:
    """(wall-piece segment rows, desk slots, round-thing slots) of the office: 2 pieces per
    shared wall (either side of its door), the slots at most one per possible piece of furniture."""
    nx, ny = office_grid(spec)
    n, walls = nx * ny, 2 * ((nx - 1) * ny + (ny - 1) * nx)
    return (
        walls,
        min(spec.office_boxes, n * spec.office_desks_max),
        min(spec.office_circles, n * spec.office_cylinders_max),
    )


def needed_shape(spec) -> tuple[int, int, int, int]:
    """The least (segments, circles, starts, goals) rows that fit every room of the spec."""
    S, G = spec.starts_max, spec.goals_max
    if spec.family == "forest":
        return 4, max(1, spec.trees_max), S, G
    if spec.family == "warehouse":
        return 4 + 4 * spec.warehouse_boxes, 1, S, G
    if spec.family == "maze":
        return 4 + maze_wall_rows(spec), 1, S, G
    if spec.family == "cave":
        return 4 + spec.cave_segments, 1, S, G
    if spec.family == "office":
        walls, boxes, circles = office_slots(spec)
        return 4 + walls + 4 * boxes, max(1, circles), S, G
    if spec.family == "corridors":
        # per branch slot 4 spine pieces, 2 branch sides, an end cap, a side room's 5 walls; the 2 spine ends
        return 4 + 12 * spec.corridor_branches_max + 2 + 4 * spec.corridor_boxes_max, 1, S, G
    n_cyl, n_box, n_wall = slot_counts(spec)
    return 4 + 2 * n_wall + 4 * n_box, max(1, n_cyl), S, G


def padded_shape(spec) -> tuple[int, int, int, int]:
    """The (segments, circles, starts, goals) rows of every World `generate(key, spec)` returns."""
    need = needed_shape(spec)
    given = (spec.max_segments, spec.max_circles, spec.max_starts, spec.max_goals)
    return tuple(n if g is None else g for n, g in zip(need, given))
