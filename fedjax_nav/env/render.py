"""Pictures of playgrounds and trajectories (matplotlib, Agg; imported only when drawing).

- `draw_world(ax, world)`: walls, obstacles, starts (arrows with their index), goals (circles
  of the goal radius with their index), in metres with equal aspect.
- `draw_trajectories(ax, xy, ...)`: one or more paths, with a marker where each ended
  (success or collision).
- `random_rollout(world, steps, seed)`: a uniform random policy in `NavEnv(mode="learn")`
  (fedjax_nav.env.random_rollout, re-exported here).
- `render_worlds(...)`: what `fedjax-nav render` calls: one PNG per world with a random
  trajectory, plus an overview of all of them.

No pyplot here: figures are `matplotlib.figure.Figure` objects saved with the Agg canvas, so
importing this module never changes the user's matplotlib backend (notebooks keep theirs).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from fedjax_nav import worlds as _worlds
from fedjax_nav.env.random_rollout import GOAL_RADIUS, random_rollout, split_episodes  # noqa: F401  (re-exported)
from fedjax_nav.worlds import World

ROBOT_RADIUS = 0.105  # TurtleBot3 Burger body, for drawing only
DPI = 90  # keeps the docs' PNGs small
# All shipped worlds fit these padded shapes, so one compiled rollout serves them all.

_WALL = "#3a3a3a"
_BOX = "#8c6d4f"
_CIRCLE = "#5f7f9f"
_START = "#1f77b4"
_GOAL = "#2ca02c"
_PATH = "#d62728"
_LABEL_FONTSIZE = 7  # the G<i> and S<i> labels


# ----------------------------------------------------------------------------- inputs


def _as_world(world_or_name: Any, meta: dict | None = None) -> tuple[World, dict]:
    """(World, meta) from a World, a (World, meta) pair, or a shipped name / file path."""
    if isinstance(world_or_name, World):
        return world_or_name, dict(meta or {})
    if isinstance(world_or_name, tuple) and len(world_or_name) == 2 and isinstance(world_or_name[0], World):
        w, m = world_or_name
        return w, {**(m or {}), **(meta or {})}
    if isinstance(world_or_name, (str, Path)):
        w, m = _worlds.load_with_meta(world_or_name)
        return w, {**m, **(meta or {})}
    raise TypeError(f"expected a World, a (World, meta) pair or a world name/path, got {type(world_or_name).__name__}")


def _numpy_world(world: World) -> dict[str, np.ndarray]:
    if np.ndim(world.size) != 1:
        raise ValueError("draw one world at a time (this World has a leading playground axis)")
    segs = np.asarray(world.segments, np.float64).reshape(-1, 4)
    circles = np.asarray(world.circles, np.float64).reshape(-1, 3)
    return {
        "segments": segs[np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]) > 0],
        "circles": circles[circles[:, 2] > 0],
        "starts": np.asarray(world.starts, np.float64)[: int(world.num_starts)],
        "goals": np.asarray(world.goals, np.float64)[: int(world.num_goals)],
        "size": np.asarray(world.size, np.float64),
    }


def _closed_quads(segs: np.ndarray, tol: float = 1e-4) -> tuple[list[np.ndarray], np.ndarray]:
    """Groups of 4 consecutive segments that form a closed loop (boxes): their corners, and a
    mask of the segments that are not part of such a group."""
    quads, rest = [], np.ones(len(segs), bool)
    i = 0
    while i + 4 <= len(segs):
        g = segs[i : i + 4]
        if all(np.allclose(g[k, 2:], g[(k + 1) % 4, :2], atol=tol) for k in range(4)):
            quads.append(g[:, :2])
            rest[i : i + 4] = False
            i += 4
        else:
            i += 1
    return quads, rest


# ----------------------------------------------------------------------------- drawing


def draw_world(
    ax,
    world: Any,
    meta: dict | None = None,
    *,
    title: str | bool | None = True,
    labels: bool = True,
    goal_radius: float = GOAL_RADIUS,
    robot_radius: float = ROBOT_RADIUS,
    margin: float = 0.4,
):
    """Draw one playground on a matplotlib Axes and return the Axes.

    world: a `World` (unstacked; padded rows are skipped), a `(World, meta)` pair as returned by
    `worlds.load_with_meta`, or a shipped name / file path. With the meta's boxes the boxes are
    filled polygons; with a bare World, closed groups of 4 segments after the 4 outer walls are
    filled (boxes become exactly such groups), other segments are drawn as thin walls.
    title: True for "name (W x H m)", a string, or False/None for none.
    """
    world, meta = _as_world(world, meta)
    w = _numpy_world(world)
    W, H = w["size"]
    hx, hy = W / 2, H / 2

    _draw_obstacles(ax, w, meta)
    _draw_goals(ax, w["goals"], goal_radius, labels)
    _draw_starts(ax, w["starts"], robot_radius, labels)

    ax.set_xlim(-hx - margin, hx + margin)
    ax.set_ylim(-hy - margin, hy + margin)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.tick_params(labelsize=7)
    if title is True:
        name = meta.get("name", "")
        title = f"{name} ({W:g} x {H:g} m)" if name else f"{W:g} x {H:g} m"
    if title:
        ax.set_title(title, fontsize=10)
    return ax


def _draw_obstacles(ax, w: dict, meta: dict) -> None:
    """The outer walls (a band), the boxes (filled), the other segments (thin walls) and the circles
    of the numpy world `w` (`_numpy_world`)."""
    from matplotlib.patches import Circle, Polygon, Rectangle

    W, H = w["size"]
    hx, hy = W / 2, H / 2
    # Outer walls: a grey band outside the inner free space (inner faces at +-size/2).
    band = 0.15
    ax.add_patch(
        Rectangle((-hx - band, -hy - band), W + 2 * band, H + 2 * band, facecolor=_WALL, edgecolor="none", zorder=0)
    )
    ax.add_patch(Rectangle((-hx, -hy), W, H, facecolor="white", edgecolor="none", zorder=0.5))

    segs = w["segments"]
    inner = segs
    walls = _worlds.wall_segments(w["size"])
    if len(segs) >= 4 and np.allclose(segs[:4], walls, atol=1e-4):
        inner = segs[4:]  # the square walls are drawn as the band above
    if meta.get("boxes"):
        for cx, cy, sx, sy, yaw in meta["boxes"]:
            corners = _worlds.box_segments(cx, cy, sx, sy, yaw)[:, :2]
            ax.add_patch(Polygon(corners, closed=True, facecolor=_BOX, edgecolor="black", lw=0.6, zorder=2))
        box_segs = (
            np.concatenate([_worlds.box_segments(*b) for b in meta["boxes"]]) if meta["boxes"] else np.zeros((0, 4))
        )
        # The boxes' edges are the last rows of the World's segments; the rest are thin walls.
        lines = inner[: max(len(inner) - len(box_segs), 0)]
    else:
        quads, rest = _closed_quads(inner)
        for q in quads:
            ax.add_patch(Polygon(q, closed=True, facecolor=_BOX, edgecolor="black", lw=0.6, zorder=2))
        lines = inner[rest]
    for x1, y1, x2, y2 in lines:
        ax.plot([x1, x2], [y1, y2], color=_WALL, lw=2.0, solid_capstyle="round", zorder=2)

    for cx, cy, r in w["circles"]:
        ax.add_patch(Circle((cx, cy), r, facecolor=_CIRCLE, edgecolor="black", lw=0.6, zorder=2))


def _draw_goals(ax, goals: np.ndarray, goal_radius: float, labels: bool) -> None:
    """Each goal: a star in a disc of the goal radius, labelled G<i> below it."""
    from matplotlib.patches import Circle

    for i, (gx, gy) in enumerate(goals):
        ax.add_patch(Circle((gx, gy), goal_radius, facecolor=_GOAL, alpha=0.25, edgecolor=_GOAL, lw=1.0, zorder=1))
        ax.plot([gx], [gy], marker="*", color=_GOAL, ms=8, zorder=4)
        if labels:
            ax.annotate(
                f"G{i}",
                (gx, gy),
                xytext=(0, -11),
                textcoords="offset points",
                ha="center",
                va="top",
                fontsize=_LABEL_FONTSIZE,
                color="darkgreen",
                zorder=5,
            )


def _draw_starts(ax, starts: np.ndarray, robot_radius: float, labels: bool) -> None:
    """Each start: the robot's disc with an arrow along its heading, labelled S<i> behind it."""
    from matplotlib.patches import Circle, FancyArrow

    L = 0.45
    for i, (sx, sy, th) in enumerate(starts):
        ax.add_patch(Circle((sx, sy), robot_radius, facecolor="white", edgecolor=_START, lw=1.2, zorder=4))
        ax.add_patch(
            FancyArrow(
                sx,
                sy,
                L * math.cos(th),
                L * math.sin(th),
                width=0.03,
                head_width=0.16,
                head_length=0.14,
                length_includes_head=True,
                color=_START,
                zorder=5,
            )
        )
        if labels:
            # behind the robot, away from its arrow
            ax.annotate(
                f"S{i}",
                (sx, sy),
                xytext=(-11 * math.cos(th), -11 * math.sin(th)),
                textcoords="offset points",
                ha="center",
                va="center",
                fontsize=_LABEL_FONTSIZE,
                color=_START,
                zorder=5,
            )


def draw_trajectories(
    ax,
    xy: Any,
    mask: Any = None,
    colors: Any = None,
    outcomes: Sequence[str | None] | None = None,
    *,
    lw: float = 1.0,
    alpha: float = 0.85,
    label: str | None = None,
):
    """Draw paths on an Axes and return the Axes.

    xy: one path f[T, 2] (or [T, >=2], e.g. poses), a batch f[N, T, 2], or a list of paths of
    different lengths. mask: bool[T] / bool[N, T] / list, the valid steps of each path (a path is
    drawn up to its last valid step). colors: one colour or one per path. outcomes: one per path,
    "success" (green star), "collision" (red cross), anything else (small dot) at its end.
    """
    if isinstance(xy, (list, tuple)):
        paths = [np.asarray(p, np.float64) for p in xy]
    else:
        arr = np.asarray(xy, np.float64)
        paths = [arr] if arr.ndim == 2 else list(arr)
    if mask is not None:
        masks = [
            np.asarray(m, bool)
            for m in (
                mask if isinstance(mask, (list, tuple)) else ([mask] if np.ndim(mask) == 1 else list(np.asarray(mask)))
            )
        ]
        if len(masks) != len(paths):
            raise ValueError(f"mask has {len(masks)} rows for {len(paths)} paths")
        paths = [p[m] for p, m in zip(paths, masks)]
    if (
        colors is None
        or isinstance(colors, str)
        or (np.ndim(colors) == 1 and len(colors) in (3, 4) and not isinstance(colors[0], str))
    ):
        colors = [colors or _PATH] * len(paths)
    if outcomes is not None and len(outcomes) != len(paths):
        raise ValueError(f"{len(outcomes)} outcomes for {len(paths)} paths")
    for k, (p, c) in enumerate(zip(paths, colors)):
        if len(p) == 0:
            continue
        ax.plot(p[:, 0], p[:, 1], color=c, lw=lw, alpha=alpha, zorder=3, label=label if k == 0 else None)
        end = outcomes[k] if outcomes is not None else None
        x, y = p[-1, 0], p[-1, 1]
        if end == "success":
            ax.plot([x], [y], marker="*", color="gold", mec="black", mew=0.5, ms=10, zorder=6)
        elif end == "collision":
            ax.plot([x], [y], marker="X", color=_PATH, mec="black", mew=0.5, ms=7, zorder=6)
        elif outcomes is not None:
            ax.plot([x], [y], marker="o", color=c, ms=3, zorder=6)
    return ax


# ----------------------------------------------------------------------------- files


def _draw_one(ax, world: World, meta: dict, episodes) -> None:
    draw_world(ax, world, meta)
    if episodes is not None:
        paths, outcomes = episodes
        draw_trajectories(ax, paths, outcomes=outcomes, lw=0.9)


def _figure(w_in: float, h_in: float):
    from matplotlib.figure import Figure

    return Figure(figsize=(w_in, h_in), layout="constrained")


def panel_inches(size, area: float = 13.0, short: float = 2.6, long: float = 11.0) -> tuple[float, float]:
    """(width, height) in inches of a panel drawing a room of `size` (W, H) m at equal aspect:
    about `area` square inches, its shorter side at least `short` and its longer side at most
    `long` (a 5 x 16.6 m map: 2.6 x 8.6 in, not a 1 in wide strip), so that a room of any shape
    reads at a glance."""
    W, H = (max(float(v), 1e-3) for v in np.asarray(size, float)[:2])
    aspect = W / H
    w, h = math.sqrt(area * aspect), math.sqrt(area / aspect)
    grow = max(1.0, short / min(w, h))
    w, h = w * grow, h * grow
    cut = min(1.0, long / max(w, h))
    return w * cut, h * cut


def wrapped(text: str, width_in: float, fontsize: float = 9.0) -> str:
    """`text` wrapped to a figure `width_in` inches wide (a title never runs off a narrow figure)."""
    import textwrap

    return textwrap.fill(text, max(20, int(width_in * 144 / fontsize)))


def render_worlds(
    names_or_paths: Sequence[str | Path] | str | Path | None = None,
    out_dir: str | Path = "runs/render",
    steps: int = 300,
    seed: int = 0,
    dpi: int = DPI,
) -> list[Path]:
    """One PNG per world (`<name>.png`) with a random-policy trajectory drawn on it, plus
    `overview.png` with all of them in a grid when there is more than one. Default: every
    shipped world (`fedjax_nav.worlds.SHIPPED`). Returns the paths written; prints nothing.

    Each trajectory runs start 0 towards goal 0 for `steps` steps (seed `seed`); a red cross
    marks a collision, a gold star a goal reached, after which the robot restarts at start 0.
    Raises `WorldError` for a missing or malformed world file.
    """
    if names_or_paths is None:
        names_or_paths = list(_worlds.SHIPPED)
    elif isinstance(names_or_paths, (str, Path)):
        names_or_paths = [names_or_paths]
    if steps < 0:
        raise ValueError(f"steps must be >= 0, got {steps}")
    loaded = [_worlds.load_with_meta(n) for n in names_or_paths]  # validate all before drawing
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)

    episodes = [
        split_episodes(world, *random_rollout(world, steps, seed)) if steps > 0 else None for world, _ in loaded
    ]
    written: list[Path] = []
    used = {"overview"}
    for (world, meta), src, ep in zip(loaded, names_or_paths, episodes):
        stem = _safe_stem(str(meta.get("name") or Path(str(src)).stem))
        name, k = stem, 1
        while name in used:
            k += 1
            name = f"{stem}-{k}"
        used.add(name)
        w_in, h_in = panel_inches(np.asarray(world.size, float) + 0.8)
        fig = _figure(w_in + 0.7, h_in + 0.8)
        _draw_one(fig.add_subplot(), world, meta, ep)
        path = out / f"{name}.png"
        fig.savefig(path, dpi=dpi)
        written.append(path)

    if len(loaded) > 1:
        n = len(loaded)
        cols = min(4, n)
        rows = -(-n // cols)
        fig = _figure(3.4 * cols, 3.4 * rows)
        for i, ((world, meta), ep) in enumerate(zip(loaded, episodes)):
            _draw_one(fig.add_subplot(rows, cols, i + 1), world, meta, ep)
        if steps > 0:
            fig.suptitle(f"random policy, {steps} steps, seed {seed}: x collision, * goal", fontsize=10)
        path = out / "overview.png"
        fig.savefig(path, dpi=dpi)
        written.append(path)
    return written


def _safe_stem(name: str) -> str:
    keep = "".join(c if (c.isalnum() or c in "-_.") else "_" for c in name).strip("._")
    return keep or "world"
