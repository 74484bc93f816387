"""Why detours fail (docs/clutter.md, "Why detours fail"): the episodes of a kept suite evaluation
whose goal needs a detour, replayed with the evaluation's protocol (`worst_rooms.replay`) in the
rooms with the most failed ones, each read where it went wrong (`read_episodes`, one row each):

- `outcome` (success, collision, timeout); `progress`: how much nearer the goal the robot came at
  its closest approach (m) than at its start, `closest` that step;
- `gave_back_m`: the most it ever moved away from the goal, the largest rise of its goal distance
  above the least it had reached before; `turned_back`: more than TURNED m;
- `stalled` (time-outs): the share of the steps after its closest approach in which it moved less
  than STALL x a full step (v_max dt), `last_100_m` how far it got in its last 100 steps;
- at the closest approach, what its ideal beams saw: `goal_blocked`, the beam nearest the goal's
  bearing reads less than the goal's distance (an obstacle on the straight way), `front_m` the
  nearest return within +-45 deg of its heading, `goal_bearing_deg` the goal's bearing;
- `crash_clearance_m` (collisions): the true clearance at the crash pose (exact geometry) and
  `crash_beam_m` the nearest of the ideal beams there; `unseen`: the beams read more than D_c +
  UNSEEN at the crash, an obstacle that sat between two beams;
- the learned value (`value_columns`, `evaluation.values`: PPO's V(s), an off-policy learner's
  Q(s, mu(s))) of the observations the policy acted on, recorded by the replay itself (the same
  noise keys: `rollout.observed_program`), step t's at pose t for t < steps: `v_start` (step 0),
  `v_closest` (at the closest approach, the last acted-on step where that is the final pose),
  `v_last_100` (the mean over its last 100 acted-on steps), `v_end` (the last one) and `v_fell`
  (v_end < v_start).

    python scripts/detour_probe.py RUN --suite dense-heldout     # needs `fedjax-nav evaluate RUN --suite ...`
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from fedjax_nav.env.geometry import lidar, nearest_distance
from fedjax_nav.evaluation.suite_stats import DETOUR
from fedjax_nav.evaluation.worst_rooms import kept_evaluation, rank_rooms, replay

TURNED = 0.3  # m farther from the goal than the nearest it had come before: it turned back
STALL = 0.2  # a step shorter than this share of v_max * dt is standing still
UNSEEN = 0.05  # m: a crash whose nearest beam reads more than D_c + this was not seen
FRONT = np.pi / 4  # the front sector's half-width


def needs_detour(episodes: pd.DataFrame) -> np.ndarray:
    """bool per row of suite_episodes.csv: the goal's shortest safe path is longer than DETOUR x
    the straight line (`suite_stats.detour_split`'s rule)."""
    return (episodes["shortest_path"] > DETOUR * episodes["straight_line"]).to_numpy()


def most_failed_detours(episodes: pd.DataFrame) -> pd.DataFrame:
    """`rank_rooms`' rows ordered by their failed detour episodes, most first (ties: lower success)."""
    failed = episodes[needs_detour(episodes) & ~episodes["success"].astype(bool)]
    count = failed.groupby("room").size().rename("failed_detours")
    ranked = rank_rooms(episodes).join(count, on="room").fillna({"failed_detours": 0})
    return ranked.sort_values(["failed_detours", "success"], ascending=[False, True], kind="stable")


def _seen(segments, circles, pose, goal, num_beams: int, max_range: float):
    """What the ideal beams see at `pose`: (goal_blocked, front_m, goal_bearing, nearest beam)."""
    ranges = lidar(segments, pose, num_beams, max_range, circles)
    rel = goal - pose[:2]
    bearing = jnp.arctan2(rel[1], rel[0]) - pose[2]
    bearing = jnp.arctan2(jnp.sin(bearing), jnp.cos(bearing))
    angles = jnp.arange(num_beams) * (2 * jnp.pi / num_beams)
    off = jnp.abs(jnp.arctan2(jnp.sin(angles - bearing), jnp.cos(angles - bearing)))
    ahead = jnp.abs(jnp.arctan2(jnp.sin(angles), jnp.cos(angles))) <= FRONT
    blocked = ranges[jnp.argmin(off)] < jnp.linalg.norm(rel)
    return blocked, jnp.min(jnp.where(ahead, ranges, max_range)), bearing, jnp.min(ranges)


def _episode_rows(w, episodes: pd.DataFrame) -> pd.DataFrame:
    """One row per replayed episode of a room's own goals: its indices and the suite's columns."""
    n, A, G, K = w.success.shape
    own = [(i, g) for i in range(n) for g in range(int(w.num_goals[i]))]
    idx = np.array([(i, a, g, k) for i, g in own for a in range(A) for k in range(K)])
    rows = pd.DataFrame(idx, columns=["i", "agent", "goal", "attempt"])
    rows["room"] = w.rooms["room"].to_numpy()[rows["i"]]
    rows["family"] = w.rooms["family"].to_numpy()[rows["i"]]
    rows["seed"], rows["net"] = w.agent_seed[rows["agent"]], w.agent_net[rows["agent"]]
    keys = ["room", "seed", "net", "goal", "attempt"]
    suite = episodes[keys + ["shortest_path", "straight_line"]].copy()
    suite["detour"] = needs_detour(episodes)
    return rows.merge(suite, on=keys, how="left", validate="one_to_one")


def value_columns(v: np.ndarray, steps: np.ndarray, closest: np.ndarray) -> dict:
    """The value readings of episodes: v f32[E, T + 1] the value at each pose's observation, steps
    i[E] the steps taken (the policy acted on observations 0 .. steps - 1), closest i[E] the step
    of the closest approach (at most steps)."""
    e, last = np.arange(len(steps)), np.maximum(steps - 1, 0)
    t = np.arange(v.shape[1])[None, :]
    tail = (t >= np.maximum(steps - 100, 0)[:, None]) & (t <= last[:, None])
    end = v[e, last]
    return {
        "v_start": v[:, 0],
        "v_closest": v[e, np.minimum(closest, last)],
        "v_last_100": (v * tail).sum(1) / tail.sum(1),
        "v_end": end,
        "v_fell": end < v[:, 0],
    }


def read_episodes(w, episodes: pd.DataFrame, env, values=None) -> pd.DataFrame:
    """`read`'s table from a replay `w` (`worst_rooms.WorstRooms`), the evaluation's episodes and
    the run's env config (`cfg.env`: v_max, dt, collision_distance, num_beams, max_range);
    `values` f32[n, A, G, k, T + 1] the learned value at each pose of `w` (`value_columns`), or None."""
    rows = _episode_rows(w, episodes)
    at = tuple(rows[c].to_numpy() for c in ("i", "agent", "goal", "attempt"))
    poses, steps = w.poses[at], w.steps[at]  # [E, T + 1, 3], [E]
    goals = np.asarray(w.world.goals)[rows["i"], rows["goal"]]
    dist = np.linalg.norm(poses[:, :, :2] - goals[:, None, :], axis=-1)
    T = np.arange(poses.shape[1])[None, :]
    live = T <= steps[:, None]
    closest = np.argmin(np.where(live, dist, np.inf), axis=1)
    e = np.arange(len(rows))
    end = poses[e, steps]
    moved = np.linalg.norm(np.diff(poses[:, :, :2], axis=1), axis=-1)  # [E, T]
    still = moved < STALL * env.v_max * env.dt
    after = (T[:, :-1] >= closest[:, None]) & (T[:, :-1] < steps[:, None])
    outcome = np.where(w.success[at], "success", np.where(w.collision[at], "collision", "timeout"))
    seen = jax.jit(jax.vmap(lambda s, c, p, g: _seen(s, c, p, g, env.num_beams, env.max_range)))
    seg, circ = np.asarray(w.world.segments)[rows["i"]], np.asarray(w.world.circles)[rows["i"]]
    blocked, front, bearing, _ = jax.device_get(seen(seg, circ, poses[e, closest], goals))
    _, _, _, beam = jax.device_get(seen(seg, circ, end, goals))
    clear = jax.device_get(jax.vmap(lambda s, c, p: nearest_distance(s, p, c))(seg, circ, end[:, :2]))
    back = np.maximum(steps - 100, 0)
    live_d = np.where(live, dist, -np.inf)
    gave_back = np.max(live_d - np.minimum.accumulate(np.where(live, dist, np.inf), axis=1), axis=1)
    more = {} if values is None else value_columns(np.asarray(values)[at], steps, closest)
    return rows.assign(
        outcome=outcome,
        steps=steps,
        closest=closest,
        progress=dist[:, 0] - dist[e, closest],
        gave_back_m=gave_back,
        turned_back=gave_back > TURNED,
        stalled=np.where(after.any(1), (still & after).sum(1) / np.maximum(after.sum(1), 1), np.nan),
        last_100_m=np.linalg.norm(end[:, :2] - poses[e, back, :2], axis=-1),
        goal_blocked=blocked,
        front_m=front,
        goal_bearing_deg=np.degrees(bearing),
        crash_clearance_m=np.where(outcome == "collision", clear, np.nan),
        crash_beam_m=np.where(outcome == "collision", beam, np.nan),
        unseen=(outcome == "collision") & (beam > env.collision_distance + UNSEEN),
        **more,
    )


def replay_values(run, params: dict, w) -> np.ndarray:
    """The learned value f32[n, A, G, k, T + 1] at every observation of a replay kept with its
    observations (`replay(..., observations=True)`), each episode from its start: `run` its
    `RunAgents`, `params` its `values.value_params`."""
    from fedjax_nav.evaluation.values import values_along

    obs = np.moveaxis(w.obs, 1, 0)  # [A, n, G, k, T + 1, obs]: the agent axis first
    v = values_along(run, params, obs.reshape(obs.shape[0], -1, *obs.shape[-2:]))
    return np.moveaxis(v.reshape(obs.shape[:-1]), 0, 1)


def read(run_dir, suite: str, rooms: int = 12, attempts: int = 1, folder=None, value: bool = True):
    """The episodes of the `rooms` rooms with the most failed detours of the kept evaluation of
    `run_dir` on `suite`, replayed and read: (`read_episodes`' table, the replay). `value`: with
    the learned value's columns (a learner without a value: an EvalError naming it, before the replay)."""
    from fedjax_nav.evaluation.runs import load_run
    from fedjax_nav.evaluation.values import value_params

    _, _, episodes = kept_evaluation(run_dir, suite, folder)
    run = load_run(run_dir)
    params = value_params(run) if value else None
    w = replay(run_dir, suite, rooms, attempts, folder, choose=most_failed_detours, observations=value)
    v = None if params is None else replay_values(run, params, w)
    return read_episodes(w, episodes, run.cfg.env, v), w


VALUES = ["v_start", "v_closest", "v_last_100", "v_end", "v_fell"]


def summary(table: pd.DataFrame) -> pd.DataFrame:
    """Per family (and all) and outcome, over the detour episodes: count and the mean of each
    reading (the value's too, where the table has them)."""
    t = table[table["detour"].astype(bool)]
    t = pd.concat([t, t.assign(family="all")])
    cols = ["progress", "gave_back_m", "turned_back", "stalled", "last_100_m", "goal_blocked", "front_m", "unseen"]
    cols += [c for c in VALUES if c in t]
    out = t.groupby(["family", "outcome"])[cols].mean()
    out.insert(0, "episodes", t.groupby(["family", "outcome"]).size())
    return out.reset_index()
