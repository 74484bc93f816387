"""Occupancy grids as worlds (docs/worlds.md, "Maps you already have"): occupied cells merged into
few axis-aligned boxes, and starts and goals drawn in the free space with clearance, all in one
connected region. numpy only; `rosmap` reads the map files and calls these.

A grid is bool[rows, cols], True = an obstacle, row 0 at the top (the largest y), as in the
map's image. Positions here are "grid metres": (x, y) from the lower-left corner of the
lower-left cell, x along the columns, y up the rows; a cell of row r and column c spans
x in [c, c + 1) * res and y in [rows - r - 1, rows - r) * res. The map's outside counts as an
obstacle (the world's walls stand at the map's border).
"""

from __future__ import annotations

import math

import numpy as np

# Drawn starts and goals keep the collision distance plus this margin (m) from every obstacle and
# from the border: a robot placed there is not about to collide, and the straight moves between
# neighbouring clear cells that connect them lose less than res^2 / (8 * (clearance + margin)) of
# that distance (0.9 mm at 5 cm cells), so they keep the collision distance for any res < 0.5 m.
MARGIN = 0.1


class MapError(ValueError):
    """A map cannot become a world; the message is one line naming the file and the key."""


# ----------------------------------------------------------------------------- boxes


def coarsen(occ: np.ndarray, k: int) -> np.ndarray:
    """Cells of k x k cells, occupied where any of theirs is (max-pooling). A grid whose sides are
    not multiples of k is first padded with occupied cells on the top rows and the right columns,
    so that the lower-left corner (the map's origin) stays where it was."""
    if k == 1:
        return occ
    h, w = occ.shape
    hh, ww = -(-h // k) * k, -(-w // k) * k
    padded = np.ones((hh, ww), bool)
    padded[hh - h :, :w] = occ
    return padded.reshape(hh // k, k, ww // k, k).any(axis=(1, 3))


def _runs(row: np.ndarray) -> list[tuple[int, int]]:
    """The maximal runs [c0, c1) of True in a bool row."""
    d = np.diff(np.concatenate([[0], row.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def _merge_rows(occ: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Rectangles (r0, r1, c0, c1), half-open, covering exactly the True cells: each row's maximal
    runs, a run merged down into the rows below it while they have a run of the same extent."""
    out, open_runs = [], {}  # (c0, c1) -> the row it began on
    for r in range(occ.shape[0] + 1):
        runs = _runs(occ[r]) if r < occ.shape[0] else []
        still = {run: open_runs.pop(run, r) for run in runs}
        out += [(r0, r, c0, c1) for (c0, c1), r0 in open_runs.items()]
        open_runs = still
    return sorted(out)


def merge_cells(occ: np.ndarray) -> np.ndarray:
    """Few rectangles covering exactly the occupied cells: int[n, 4] rows (r0, r1, c0, c1),
    half-open. Runs along the rows merged down, or runs down the columns merged across, whichever
    gives fewer (greedy, not the fewest possible)."""
    by_rows = _merge_rows(occ)
    by_cols = [(r0, r1, c0, c1) for c0, c1, r0, r1 in _merge_rows(occ.T)]
    best = by_rows if len(by_rows) <= len(by_cols) else sorted(by_cols)
    return np.asarray(best, np.int64).reshape(-1, 4)


def boxes(rects: np.ndarray, shape: tuple[int, int], res: float) -> np.ndarray:
    """Rectangles of cells as world boxes f64[n, 5] (cx, cy, sx, sy, yaw = 0) in the world's frame:
    the grid's centre at (0, 0)."""
    h, w = shape
    r0, r1, c0, c1 = (rects[:, i].astype(np.float64) for i in range(4))
    cx = (c0 + c1) / 2 * res - w * res / 2
    cy = h * res / 2 - (r0 + r1) / 2 * res
    return np.stack([cx, cy, (c1 - c0) * res, (r1 - r0) * res, np.zeros_like(cx)], 1)


# ----------------------------------------------------------------------------- free space


def clear_cells(occ: np.ndarray, res: float, dist: float) -> np.ndarray:
    """bool[rows, cols]: the cells whose centres are at least `dist` from every occupied cell and
    from the border (exact for squares: each row of offsets dilates by a sliding window)."""
    h, w = occ.shape
    big = math.ceil(dist / res + 0.5)  # cells farther than this many away are >= dist away
    padded = np.pad(occ, big, constant_values=True).astype(np.int32)
    sums = np.concatenate([np.zeros((padded.shape[0], 1), np.int32), np.cumsum(padded, 1)], 1)
    blocked = occ.copy()
    for di in range(-big, big + 1):
        dy = max(abs(di) * res - res / 2, 0.0)
        if dy >= dist:
            continue
        m = math.ceil(math.sqrt(dist**2 - dy**2) / res + 0.5) - 1  # |dj| <= m: nearer than dist
        rows = sums[big + di : big + di + h]
        blocked |= rows[:, big + m + 1 : big + m + 1 + w] - rows[:, big - m : big - m + w] > 0
    return ~blocked


def point_clearance(occ: np.ndarray, res: float, q: np.ndarray, upto: float) -> np.ndarray:
    """f64[n]: each point's (grid metres, [n, 2]) distance to the nearest occupied cell or the
    border, exact up to `upto` (farther reads `upto`); 0 inside an occupied cell or outside."""
    h, w = occ.shape
    big = math.ceil(upto / res) + 1
    out = np.empty(len(q))
    for i, (x, y) in enumerate(np.asarray(q, np.float64)):
        border = min(x, w * res - x, y, h * res - y)
        c, r = int(math.floor(x / res)), h - 1 - int(math.floor(y / res))
        rr, cc = np.nonzero(occ[max(r - big, 0) : r + big + 1, max(c - big, 0) : c + big + 1])
        xc = (cc + max(c - big, 0) + 0.5) * res
        yc = (h - (rr + max(r - big, 0)) - 0.5) * res
        d = np.hypot(np.maximum(np.abs(x - xc) - res / 2, 0), np.maximum(np.abs(y - yc) - res / 2, 0))
        out[i] = max(0.0, min(border, upto, d.min() if len(d) else upto))
    return out


def _flood(flat: np.ndarray, w: int, seed: int, label: np.ndarray, n: int) -> int:
    """Mark with `n` in `label` the clear cells (`flat`, a raveled grid of rows of `w`) 4-connected
    to the cell `seed`, one numpy step per ring of a breadth-first search; returns how many."""
    label[seed] = n
    frontier, size = np.array([seed]), 1
    while len(frontier):
        col = frontier % w
        nb = np.concatenate([frontier[col > 0] - 1, frontier[col < w - 1] + 1, frontier - w, frontier + w])
        nb = nb[(nb >= 0) & (nb < len(flat))]
        nb = np.unique(nb[flat[nb] & (label[nb] == 0)])
        label[nb] = n
        frontier, size = nb, size + len(nb)
    return size


def region(clear: np.ndarray, seed: int) -> np.ndarray:
    """bool mask: the clear cells 4-connected to the cell of flat index `seed`."""
    label = np.zeros(clear.size, np.int32)
    _flood(clear.ravel(), clear.shape[1], seed, label, 1)
    return label.reshape(clear.shape) == 1


def largest_region(clear: np.ndarray) -> np.ndarray:
    """The largest 4-connected region of clear cells (of equal ones, the first in row order).
    Work: linear in the cells, plus one flood per region until the rest cannot be larger."""
    flat, label = clear.ravel(), np.zeros(clear.size, np.int32)
    cells, at, n, best, best_size, labelled = np.flatnonzero(flat), 0, 0, 0, 0, 0
    while at < len(cells) and len(cells) - labelled > best_size:
        free = np.flatnonzero(label[cells[at : at + 4096]] == 0)  # the next cells not in a region yet
        if not len(free):
            at += 4096
            continue
        at, n = at + int(free[0]), n + 1
        size = _flood(flat, clear.shape[1], int(cells[at]), label, n)
        labelled += size
        if size > best_size:
            best, best_size = n, size
    return label.reshape(clear.shape) == best if best else np.zeros_like(clear)


def cell_centres(mask: np.ndarray, res: float) -> np.ndarray:
    """f64[n, 2]: the centres (grid metres) of the True cells, in row order."""
    r, c = np.nonzero(mask)
    return np.stack([(c + 0.5) * res, (mask.shape[0] - r - 0.5) * res], 1)


def draw(occ: np.ndarray, res: float, clearance: float, n_starts: int, n_goals: int, seed: int, near=None):
    """`n_starts` poses f64[n, 3] and `n_goals` points f64[m, 2] (grid metres) at distinct cell
    centres at least clearance + MARGIN from every obstacle, all in one 4-connected region of such
    cells: the one nearest the point `near` (grid metres) when given, else the largest. Seeded:
    numpy's default_rng(seed). None, None when the region has too few cells."""
    clear = clear_cells(occ, res, clearance + MARGIN)
    if not clear.any():
        return None, None
    if near is None:
        part = largest_region(clear)
    else:
        centres = cell_centres(clear, res)
        nearest = np.argmin(np.hypot(*(centres - np.asarray(near)[:2]).T))
        part = region(clear, int(np.flatnonzero(clear)[nearest]))
    cells = cell_centres(part, res)
    if len(cells) < n_starts + n_goals:
        return None, None
    rng = np.random.default_rng(seed)
    pick = cells[rng.choice(len(cells), n_starts + n_goals, replace=False)]
    theta = rng.uniform(-math.pi, math.pi, n_starts)
    return np.column_stack([pick[:n_starts], theta]), pick[n_starts:]
