"""The exported policy's inputs: a robot's LaserScan, pose and goal -> the policy's observation.

numpy and the standard library only. `fedjax-nav export` copies this file beside policy.py
(policy_template.py), which loads it by its path and re-exports every name below; in the project it
is `fedjax_nav/deploy/policy_inputs.py`. Conventions (the simulator's, fedjax_nav.env.nav and
fedjax_nav.env.geometry; docs/export.md, "Observation conventions"):

- Beams: beam i points at heading + 2 pi i / num_beams (counter-clockwise, beam 0 straight ahead),
  and reads the distance to the nearest obstacle along it, `max_range` when nothing is within
  `max_range`.
- Observation, float32[num_beams + 4]: the ranges (m, clipped to [0, max_range]), the goal
  distance (m), the goal bearing relative to the heading (rad, wrapped to [-pi, pi],
  counter-clockwise positive), and the previous action in network units. A policy trained with
  the plan (env.plan: true): float32[num_beams + 5], the waypoint's distance and bearing in place
  of the goal's, the goal's distance last (meta.json's "observation_layout"; `path_waypoint`).
- Scan pooling (`pool_scan`): a scan with more samples than beams is reduced to one range per
  beam, the sector minimum (mode="min", default: never longer than the exact beam, but shorter
  than the simulator's ray where the range changes within the sector: median 4-7 cm, the 10 %
  worst beams 0.8-1.1 m or more on three shipped worlds) or the valid sample nearest the beam's
  angle (mode="nearest", a thin ray like the simulator's); invalid samples: `pool_scan`.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "MAPLESS_LAYOUT",
    "pool_scan",
    "wrap_angle",
    "goal_features",
    "build_observation",
    "path_waypoint",
    "yaw_from_quaternion",
]


def pool_scan(
    ranges,
    angle_min: float,
    angle_increment: float,
    num_beams: int = 24,
    max_range: float = 3.5,
    range_min: float = 0.0,
    range_max: float = math.inf,
    angle_offset: float = 0.0,
    invalid: float | None = None,
    mode: str = "min",
) -> np.ndarray:
    """A LaserScan's ranges -> the policy's `num_beams` ranges, float32[num_beams] in [0, max_range].

    Sample j is at angle_min + j * angle_increment (+ angle_offset: the laser's yaw in the robot's
    base frame, 0 when the scan's frame faces forward, as TurtleBot3's base_scan does). Beam i's
    sector holds the samples in [2 pi i / n - pi / n, 2 pi i / n + pi / n), n = num_beams.
    mode="min": the beam reads the minimum of its sector (default; conservative: an obstacle
    between two beams is seen). mode="nearest": the beam reads the valid sample nearest its angle
    (a thin ray, like the simulator's own beams; equal to them when the scan has a sample at each
    beam angle). Either way the reading is clipped to max_range, and a sector with no valid sample
    reads max_range. Invalid samples: +inf or above range_max is no return (max_range); NaN, -inf,
    0, negative or below range_min is no information (a dropout, the robot's body: the simulated
    robot never comes within 0.25 m), left out (`invalid=None`) or read as the range `invalid`.
    """
    if mode not in ("min", "nearest"):
        raise ValueError(f"mode must be 'min' or 'nearest', got {mode!r}")
    r = np.asarray(ranges, np.float64).reshape(-1)
    n = int(num_beams)
    max_range = float(max_range)
    rmin = max(float(range_min), 0.0)
    rmax = float(range_max) if range_max is not None and float(range_max) > 0 else math.inf
    with np.errstate(invalid="ignore"):
        no_return = (r == np.inf) | (np.isfinite(r) & (r > rmax))
        bad = ~no_return & (~np.isfinite(r) | (r <= 0.0) | (r < rmin))
    vals = np.where(no_return, max_range, r)
    if invalid is None:
        vals = np.where(bad, np.inf, vals)  # left out (reads as "nothing here")
    else:
        vals = np.where(bad, float(invalid), vals)
        bad = np.zeros_like(bad)
    two_pi = 2.0 * math.pi
    width = two_pi / n
    ang = float(angle_min) + float(angle_offset) + np.arange(r.size, dtype=np.float64) * float(angle_increment)
    shifted = np.mod(ang + 0.5 * width, two_pi)
    sector = np.floor(shifted / width).astype(np.int64) % n
    out = np.full(n, np.inf)
    if mode == "min":
        np.minimum.at(out, sector, vals)
    else:  # per sector, the valid sample nearest the beam angle (ties: the first sample)
        offset = np.abs(shifted - (sector + 0.5) * width)
        order = np.lexsort((np.arange(r.size), offset, bad, sector))
        first = np.ones(order.size, bool)
        first[1:] = sector[order][1:] != sector[order][:-1]
        out[sector[order][first]] = vals[order][first]
    out = np.where(np.isfinite(out), out, max_range)  # empty or all-invalid sectors: no return
    return np.clip(out, 0.0, max_range).astype(np.float32)


def wrap_angle(a):
    """To [-pi, pi], as the simulator does: atan2(sin a, cos a)."""
    return np.arctan2(np.sin(a), np.cos(a))


def goal_features(pose, goal) -> np.ndarray:
    """(goal distance in m, goal bearing relative to the heading in rad, wrapped to [-pi, pi]).

    pose: (x, y, yaw) in the odometry frame; goal: (x, y) in the same frame. Batched over leading
    axes. float32[..., 2].
    """
    pose = np.asarray(pose, np.float64)
    goal = np.asarray(goal, np.float64)
    rel = goal[..., :2] - pose[..., :2]
    dist = np.hypot(rel[..., 0], rel[..., 1])
    bearing = wrap_angle(np.arctan2(rel[..., 1], rel[..., 0]) - pose[..., 2])
    return np.stack([dist, bearing], axis=-1).astype(np.float32)


# The entries after the ranges of an export whose meta.json names none (exported before the plan):
# the env's mapless layout, fedjax_nav/env/plan.py's MAPLESS (tests/test_export_plan.py checks it).
MAPLESS_LAYOUT = ("goal_distance", "goal_bearing", "previous_v", "previous_omega")


def build_observation(ranges, pose, goal, prev_action, waypoint=None, layout=MAPLESS_LAYOUT) -> np.ndarray:
    """The policy's observation float32[..., num_beams + len(layout)], as NavEnv.observe builds it:
    concat(ranges, the entries of `layout` in its order).

    ranges: the pooled ranges (`pool_scan`), m; pose: (x, y, yaw); goal: (x, y);
    prev_action: the last action sent, in network units (v / v_max, omega / omega_max), clipped
    to [0, 1] x [-1, 1] as the simulator stores it; (0, 0) at the start of an episode;
    waypoint: (x, y), the plan's waypoint (`path_waypoint`), for a policy trained with the plan;
    layout: the entries' names, meta.json's "observation_layout" (goal_distance, goal_bearing,
    waypoint_distance, waypoint_bearing, previous_v, previous_omega); the mapless one by default.
    """
    ranges = np.asarray(ranges, np.float32)
    prev = np.clip(np.asarray(prev_action, np.float32), [0.0, -1.0], [1.0, 1.0]).astype(np.float32)
    goal_f = goal_features(pose, goal)
    entries = {"goal_distance": goal_f[..., 0], "goal_bearing": goal_f[..., 1]}
    entries.update(previous_v=prev[..., 0], previous_omega=prev[..., 1])
    if waypoint is not None:
        way_f = goal_features(pose, waypoint)
        entries.update(waypoint_distance=way_f[..., 0], waypoint_bearing=way_f[..., 1])
    missing = [k for k in layout if k not in entries]
    if missing:
        raise ValueError(
            f"the observation's layout has {', '.join(missing)}: the policy was trained with the plan, pass its "
            'waypoint (path_waypoint; docs/export.md, "Exporting a plan run")'
        )
    feats = np.stack(np.broadcast_arrays(*(entries[k] for k in layout)), axis=-1)
    lead = np.broadcast_shapes(ranges.shape[:-1], feats.shape[:-1])
    parts = [np.broadcast_to(p, lead + p.shape[-1:]) for p in (ranges, feats)]
    return np.concatenate(parts, axis=-1).astype(np.float32)


def path_waypoint(path, position, lookahead: float, search: float = 2.0) -> np.ndarray | None:
    """The plan's waypoint on a planner's path, as fedjax_nav/env/plan.py's walk takes it
    (docs/export.md, "Exporting a plan run"): float32[2], the first pose at least `lookahead` m
    along the path from the robot's place on it, else the path's last pose (the goal's end; the
    simulator's waypoint is the goal within `lookahead` of it). None for an empty path.

    path: float[n, 2], the poses' (x, y) (nav2's nav_msgs/Path on /plan), in the frame of
    `position` (x, y[, yaw]). The robot's place: the pose nearest `position` among those within
    the path's first `search` m (a planner replans from the robot, nav2's about once a second; a
    path that folds back near the robot further on is not taken for where it stands). A NaN or an
    infinity in the path gives a NaN waypoint: the observation is then unsafe and `Policy` stops
    (docs/export.md, "Unsafe observations")."""
    p = np.asarray(path, np.float64).reshape(-1, 2)
    if p.shape[0] == 0:
        return None
    if not np.all(np.isfinite(p)):
        return np.full(2, np.nan, np.float32)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))])
    xy = np.asarray(position, np.float64).reshape(-1)[:2]
    with np.errstate(invalid="ignore"):
        start = int(np.argmin(np.where(arc <= search, np.hypot(*(p - xy).T), np.inf)))
    ahead = np.flatnonzero(arc - arc[start] >= lookahead)
    return p[ahead[0] if ahead.size else -1].astype(np.float32)


def yaw_from_quaternion(x: float, y: float, z: float, w: float) -> float:
    """Yaw (rad, about z) of an orientation quaternion, e.g. nav_msgs/Odometry pose.orientation."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
