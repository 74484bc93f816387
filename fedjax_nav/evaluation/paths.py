"""The shortest safe path in a room: the denominator of a held-out suite's path-length ratio
(docs/generalization.md, "Tail metrics"). Numpy/scipy on the host, float64, once per
(room, start, goal); nothing here is traced.

    room_arrays(world, i)                       one room's obstacles without their padding rows
    clearance_grid(room, clearance, res)        which cell centres keep the clearance
    shortest_path(room, start, goal, ...)       m from `start` into the goal disk; NaN: no safe path
    shortest_paths(world, clearance, goal_radius, res) -> f64[R, G]   start 0 to every goal, every room

The method, in three steps (cost: docs/generalization.md, "Tail metrics"):

1. Occupancy grid inflated by the robot's collision distance `c`: a cell (side `res`, centres
   inside the walls) is free when its centre is at least `c` from every segment and circle
   (exact float64 point-segment / point-circle distances, each obstacle tested only on the cells
   within its reach). The same idea as the independent solvability check of the procedural rooms
   (a grid search over cells that keep the collision distance), here with path lengths.
2. 8-connected Dijkstra over the free cells (`scipy.sparse.csgraph.dijkstra`, edges of `res`
   and `res * sqrt(2)`), from the start's cell; the goal's target is the free cell inside the goal
   disk (radius `D_g`: an episode succeeds on entering it) that the search reaches first.
3. String pulling of that cell path, with exact checks: from the start, the path jumps to the
   farthest later cell the straight segment reaches keeping >= `c` from every obstacle (exact
   segment-segment and segment-circle distances), and it ends with the straight leg into the goal
   disk as soon as that leg is clear. The corners, cell centres up to a cell off the inflated
   obstacles, then slide towards the obstacle each turns around while both of its segments stay
   clear, the segments beside a corner split once so that the string wraps an inflated corner's
   arc (`_relax`). An 8-connected path alone is up to 8 % longer than the straight line (at
   22.5 deg); the pulled one is a polyline of clear segments: in an empty room the straight line
   |goal - start| - D_g, around a wall's end within a cell of the tangent-arc-tangent length.

The length returned is that of a safe path (every jump is checked), so it is at least the true
shortest; it can exceed it by the grid's resolution around each corner, or more where the
8-connected metric prefers another way round an obstacle than the true shortest path does (two
ways within 8 % of each other).
"""

from __future__ import annotations

import math

import numpy as np

from fedjax_nav.worlds import point_segment_distance_np

RES = 0.05  # m, the grid's cell side
_BLOCK = 64  # candidate cells tested per visibility call while pulling the string
_EPS = 1e-9  # m: a segment exactly at the clearance is clear


def room_arrays(world, i: int | None = None) -> dict:
    """Float64 arrays of one room of a World (room `i` of a stacked one): segments and circles
    without their padding rows (zero length, zero radius), starts and goals without their
    repeated rows, and the size."""

    def take(a):
        a = np.asarray(a)
        return a if i is None else a[i]

    segs = take(world.segments).astype(np.float64).reshape(-1, 4)
    circles = take(world.circles).astype(np.float64).reshape(-1, 3)
    return {
        "segments": segs[np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]) > 0],
        "circles": circles[circles[:, 2] > 0],
        "starts": take(world.starts).astype(np.float64)[: int(take(world.num_starts))],
        "goals": take(world.goals).astype(np.float64)[: int(take(world.num_goals))],
        "size": take(world.size).astype(np.float64),
    }


def cell_centres(size, res: float = RES) -> tuple[np.ndarray, np.ndarray]:
    """x and y of the cell centres covering the inner area [-W/2, W/2] x [-H/2, H/2]."""
    W, H = (float(v) for v in size)
    nx, ny = max(int(W // res), 1), max(int(H // res), 1)
    return -W / 2 + res * (np.arange(nx) + 0.5), -H / 2 + res * (np.arange(ny) + 0.5)


def clearance_grid(room: dict, clearance: float, res: float = RES) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """free bool[ny, nx] (a cell centre at least `clearance` m from every obstacle), xs, ys."""
    xs, ys = cell_centres(room["size"], res)
    free = np.ones((len(ys), len(xs)), bool)
    reach = clearance + res

    def window(x0, x1, y0, y1):
        i = slice(np.searchsorted(xs, x0 - reach), np.searchsorted(xs, x1 + reach, "right"))
        j = slice(np.searchsorted(ys, y0 - reach), np.searchsorted(ys, y1 + reach, "right"))
        return j, i, np.stack(np.meshgrid(xs[i], ys[j]), axis=-1)  # points [rows, cols, 2]

    for seg in room["segments"]:
        j, i, pts = window(min(seg[0], seg[2]), max(seg[0], seg[2]), min(seg[1], seg[3]), max(seg[1], seg[3]))
        if pts.size:
            free[j, i] &= point_segment_distance_np(pts, seg[None])[..., 0] >= clearance
    for cx, cy, r in room["circles"]:
        j, i, pts = window(cx - r, cx + r, cy - r, cy + r)
        if pts.size:
            free[j, i] &= np.hypot(pts[..., 0] - cx, pts[..., 1] - cy) - r >= clearance
    return free, xs, ys


def _graph(free: np.ndarray, res: float):
    """The 8-connected graph of the free cells (csr, undirected), nodes numbered row-major."""
    from scipy.sparse import coo_matrix

    ny, nx = free.shape
    ids = np.arange(ny * nx).reshape(ny, nx)
    rows, cols, w = [], [], []
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        here = (slice(0, ny - dy), slice(max(0, -dx), nx - max(0, dx)))  # cell (y, x)
        there = (slice(dy, ny), slice(max(0, dx), nx - max(0, -dx)))  # its neighbour (y + dy, x + dx)
        both = free[here] & free[there]
        rows.append(ids[here][both])
        cols.append(ids[there][both])
        w.append(np.full(int(both.sum()), res * math.hypot(dx, dy)))
    r, c, v = np.concatenate(rows), np.concatenate(cols), np.concatenate(w)
    return coo_matrix((v, (r, c)), shape=(ny * nx, ny * nx)).tocsr()


def _clear(p: np.ndarray, qs: np.ndarray, room: dict, clearance: float) -> np.ndarray:
    """bool[n]: the segment p -> qs[k] keeps >= `clearance` from every obstacle (`_clear_pairs`)."""
    return _clear_pairs(np.broadcast_to(p, qs.shape), qs, room, clearance)


def _clear_pairs(ps: np.ndarray, qs: np.ndarray, room: dict, clearance: float) -> np.ndarray:
    """bool[n]: the segment ps[k] -> qs[k] keeps >= `clearance` from every obstacle (exact
    float64 segment-segment and segment-circle distances). Only the obstacles near the segments'
    common bounding box are tested."""
    if not len(qs):
        return np.ones(0, bool)
    lo = np.minimum(ps.min(0), qs.min(0)) - clearance
    hi = np.maximum(ps.max(0), qs.max(0)) + clearance
    ok = np.ones(len(qs), bool)
    px, py, qx, qy = ps[:, 0:1], ps[:, 1:2], qs[:, 0:1], qs[:, 1:2]  # [n, 1]: against obstacles [1, M]
    segs = room["segments"]
    if len(segs):
        x0, x1 = np.minimum(segs[:, 0], segs[:, 2]), np.maximum(segs[:, 0], segs[:, 2])
        y0, y1 = np.minimum(segs[:, 1], segs[:, 3]), np.maximum(segs[:, 1], segs[:, 3])
        s = segs[(x0 <= hi[0]) & (x1 >= lo[0]) & (y0 <= hi[1]) & (y1 >= lo[1])]
        if len(s):
            ax, ay, bx, by = s[None, :, 0], s[None, :, 1], s[None, :, 2], s[None, :, 3]
            d = np.minimum(
                np.minimum(_point_segment(px, py, ax, ay, bx, by), _point_segment(qx, qy, ax, ay, bx, by)),
                np.minimum(_point_segment(ax, ay, px, py, qx, qy), _point_segment(bx, by, px, py, qx, qy)),
            )
            cross = (_orient(px, py, qx, qy, ax, ay) * _orient(px, py, qx, qy, bx, by) < 0) & (
                _orient(ax, ay, bx, by, px, py) * _orient(ax, ay, bx, by, qx, qy) < 0
            )
            ok &= ~cross.any(-1) & (d >= clearance - _EPS).all(-1)
    circles = room["circles"]
    if len(circles):
        c = circles[((circles[:, :2] + circles[:, 2:] >= lo) & (circles[:, :2] - circles[:, 2:] <= hi)).all(-1)]
        if len(c):
            d = _point_segment(c[None, :, 0], c[None, :, 1], px, py, qx, qy) - c[None, :, 2]
            ok &= (d >= clearance - _EPS).all(-1)
    return ok


def _point_segment(px, py, ax, ay, bx, by):
    """Distance from points (px, py) to segments (a, b), all broadcast together (float64)."""
    ex, ey = bx - ax, by - ay
    len2 = ex * ex + ey * ey
    t = np.clip(((px - ax) * ex + (py - ay) * ey) / np.where(len2 > 0, len2, 1.0), 0.0, 1.0)
    return np.hypot(px - ax - t * ex, py - ay - t * ey)


def _orient(ox, oy, ax, ay, bx, by):
    """The sign of the turn o -> a -> b (cross product), broadcast."""
    return (ax - ox) * (by - oy) - (ay - oy) * (bx - ox)


def _disk_entry(p: np.ndarray, q: np.ndarray, goal: np.ndarray, radius: float) -> float | None:
    """The distance along p -> q (p outside the disk) at which it enters the goal disk, or None."""
    d = q - p
    L = float(np.hypot(*d))
    if L == 0:
        return None
    f = p - goal
    a, b, c = L * L, 2 * float(f @ d), float(f @ f) - radius * radius
    disc = b * b - 4 * a * c
    if disc < 0:
        return None
    s = (-b - math.sqrt(disc)) / (2 * a)
    return s * L if 0 <= s <= 1 else None


def _disk_point(p: np.ndarray, goal: np.ndarray, radius: float) -> np.ndarray:
    """The point of the goal disk nearest to p (p outside it)."""
    to_goal = goal - p
    return goal - radius * to_goal / float(np.hypot(*to_goal))


def _pull(room, cells: np.ndarray, start: np.ndarray, goal: np.ndarray, clearance: float, radius: float):
    """The pulled string from `start` through the cell path `cells` [n, 2] (its end next to or
    inside the goal disk) until it enters the disk: its vertices [k, 2] (the last one on the
    disk's edge), or None when the disk is not reached by clear segments."""
    p, i, corners = start, -1, [start]  # i: index in `cells` of the corner p (-1: the start)
    while True:
        if np.hypot(*(goal - p)) <= radius:
            return np.asarray(corners)
        entry = _disk_point(p, goal, radius)
        if _clear(p, entry[None], room, clearance)[0]:
            return np.asarray([*corners, entry])
        if i == len(cells) - 1:  # the path's end, and the disk not clear from it
            return None
        best = i + 1
        for lo in range(i + 1, len(cells), _BLOCK):
            ok = _clear(p, cells[lo : lo + _BLOCK], room, clearance)
            if not ok.any():
                break  # out of sight along the path: a later cell seen again is not worth the search
            best = lo + int(np.flatnonzero(ok)[-1])
        q = cells[best]
        into = _disk_entry(p, q, goal, radius)
        if into is not None:
            return np.asarray([*corners, p + into * (q - p) / float(np.hypot(*(q - p)))])
        p, i = q, best
        corners.append(q)


_STEPS = 2.0 ** -np.arange(1, 16)  # fractions of a corner's shorter segment tried as its move, largest first
_ITERATIONS = 30  # sweeps over the corners per round at most


def _relax(v: np.ndarray, room, goal: np.ndarray, clearance: float, radius: float, rounds: int = 2) -> np.ndarray:
    """Tighten the pulled string. Its corners are cell centres, up to a cell off the inflated
    obstacles: each corner slides down the length's gradient (the bisector of its two segments,
    towards the obstacle it turns around) as far as both of its segments stay clear and the
    length shrinks (every other corner at a time, all of them in one check), and the end follows
    to the disk point nearest the last corner. Between rounds every segment beside a corner is
    split at its midpoint, so the string can wrap an inflated corner's arc. Every segment stays
    checked: the string stays safe."""
    v = v.copy()
    S = len(_STEPS)
    for r in range(rounds):
        if r:
            v = _split(v)
        before = _length(v)
        for _ in range(_ITERATIONS):
            for parity in (1, 2):
                k = np.arange(parity, len(v) - 1, 2)
                if not len(k):
                    continue
                a, b = v[k] - v[k - 1], v[k] - v[k + 1]  # [K, 2]
                la, lb = np.hypot(*a.T), np.hypot(*b.T)
                d = -(a / np.maximum(la, 1e-12)[:, None] + b / np.maximum(lb, 1e-12)[:, None])
                nd = np.hypot(*d.T)
                move = (nd > 1e-9) & (la > 0) & (lb > 0)
                k, d, la, lb = k[move], d[move] / nd[move, None], la[move], lb[move]
                if not len(k):
                    continue
                step = _STEPS[None, :] * np.minimum(la, lb)[:, None]  # [K, S]
                cand = v[k][:, None] + step[..., None] * d[:, None]  # [K, S, 2]
                prev, nxt = np.repeat(v[k - 1], S, 0), np.repeat(v[k + 1], S, 0)
                flat = cand.reshape(-1, 2)
                shorter = np.hypot(*(flat - prev).T) + np.hypot(*(flat - nxt).T) < np.repeat(la + lb, S)
                i = np.flatnonzero(shorter)
                i = i[_clear_pairs(prev[i], flat[i], room, clearance)]
                i = i[_clear_pairs(nxt[i], flat[i], room, clearance)]
                ok = np.zeros(len(flat), bool)
                ok[i] = True
                ok = ok.reshape(-1, S)
                took = ok.any(1)
                v[k[took]] = cand[took, np.argmax(ok[took], 1)]
            if len(v) >= 2 and np.hypot(*(goal - v[-2])) > radius:
                end = _disk_point(v[-2], goal, radius)
                if _clear(v[-2], end[None], room, clearance)[0]:
                    v[-1] = end
            after = _length(v)
            if before - after < 1e-6:
                break
            before = after
    return v


def _split(v: np.ndarray) -> np.ndarray:
    """The string with the midpoint of every segment beside a corner (a turn above 1 deg) added."""
    turn = np.zeros(len(v), bool)
    for k in range(1, len(v) - 1):
        a, b = v[k] - v[k - 1], v[k + 1] - v[k]
        turn[k] = abs(math.atan2(a[0] * b[1] - a[1] * b[0], float(a @ b))) > math.radians(1.0)
    out = [v[0]]
    for k in range(1, len(v)):
        if turn[k - 1] or turn[k]:
            out.append((v[k - 1] + v[k]) / 2)
        out.append(v[k])
    return np.asarray(out)


def _length(v: np.ndarray) -> float:
    return float(np.hypot(*np.diff(v, axis=0).T).sum()) if len(v) > 1 else 0.0


class _Search:
    """One room's grid and graph, searched once per start."""

    def __init__(self, room: dict, clearance: float, res: float):
        self.room, self.clearance, self.res = room, float(clearance), float(res)
        self.free, self.xs, self.ys = clearance_grid(room, clearance, res)
        self.graph = _graph(self.free, res)
        gx, gy = np.meshgrid(self.xs, self.ys)
        self.centres = np.stack([gx.ravel(), gy.ravel()], -1)  # [cells, 2]

    def _cell(self, p) -> int | None:
        """The free cell nearest to p within 3 cells (a start keeps the clearance; its own cell
        centre may not), or None."""
        d = np.hypot(*(self.centres - p[:2]).T)
        d[~self.free.ravel()] = np.inf
        k = int(np.argmin(d))
        return k if d[k] <= 3 * self.res else None

    def from_start(self, start) -> tuple[np.ndarray, np.ndarray] | None:
        from scipy.sparse.csgraph import dijkstra

        src = self._cell(np.asarray(start, np.float64))
        if src is None:
            return None
        dist, pred = dijkstra(self.graph, directed=False, indices=src, return_predecessors=True)
        return dist, pred

    def length(self, searched, start, goal, radius: float) -> float:
        start, goal = np.asarray(start, np.float64)[:2], np.asarray(goal, np.float64)[:2]
        if np.hypot(*(goal - start)) <= radius:
            return 0.0
        if searched is None:
            return float("nan")
        dist, pred = searched
        near = np.hypot(*(self.centres - goal).T)
        inside = (near < radius) & self.free.ravel()
        if not inside.any():  # a disk smaller than a cell, or hugging a wall: end next to it
            inside = (near < radius + 2 * self.res) & self.free.ravel()
        d = np.where(inside, dist, np.inf)
        t = int(np.argmin(d))
        if not np.isfinite(d[t]):
            return float("nan")
        path = [t]
        while pred[path[-1]] >= 0:
            path.append(int(pred[path[-1]]))
        cells = self.centres[np.asarray(path[::-1])]
        v = _pull(self.room, cells, start, goal, self.clearance, radius)
        return float("nan") if v is None else _length(_relax(v, self.room, goal, self.clearance, radius))


def shortest_path(room: dict, start, goal, clearance: float, goal_radius: float, res: float = RES) -> float:
    """m of the shortest path (method: the module docstring) from `start` (x, y[, theta]) into the
    disk of radius `goal_radius` around `goal` keeping >= `clearance` from every obstacle of `room`
    (`room_arrays`); 0 when the start is in the disk, NaN when no safe path exists on the grid."""
    s = _Search(room, clearance, res)
    return s.length(s.from_start(start), start, goal, goal_radius)


def shortest_paths(world, clearance: float, goal_radius: float, res: float = RES) -> np.ndarray:
    """f64[R, G]: `shortest_path` from start 0 to every goal row of every room of a stacked World
    (the evaluation's start; NaN on the padding rows beyond a room's goals); one grid search per
    room."""
    R, G = np.asarray(world.goals).shape[:2]
    out = np.full((R, G), np.nan)
    for r in range(R):
        room = room_arrays(world, r)
        s = _Search(room, clearance, res)
        searched = s.from_start(room["starts"][0])
        for g, goal in enumerate(room["goals"]):
            out[r, g] = s.length(searched, room["starts"][0], goal, goal_radius)
    return out
