"""A run's agents with K robots per room (`fedjax-nav evaluate RUN --suite NAME --robots-per-room
1,2,4,8`; docs/shared_rooms.md, "Evaluation").

Every agent of the run drives a fleet of K copies of itself in every room of the suite: the K
robots are placed together (`env.shared.place_fleet`: robot 0 at the room's own start 0 and goal
0, the others drawn apart), each drives to its own goal with the greedy actor under the
evaluation's noise (`rollout.py`'s protocol), and sees the others in its lidar. A robot's episode
ends at its goal (success), at a collision with an obstacle or with another robot, or at the
time-out T; a robot whose episode ended leaves the room (the others no longer see it). A
deadlock: a robot timed out within DEADLOCK_DISTANCE of another timed-out robot.

Results per K and family (shared_families.csv): the success with its 95 % bootstrap interval
over rooms, the worst 10 % of rooms, and the shares of robot-episodes ending in an obstacle
collision, a robot-robot collision, a time-out, a deadlock. Written to
RUN/eval/<suite folder>-shared/ through fedjax_nav.rundir; a figure of the K robots' trajectories
in the suite's first room for the largest K.
"""

from __future__ import annotations

import functools
import json
import time
from dataclasses import dataclass
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from fedjax_nav import rundir
from fedjax_nav import worlds as _worlds
from fedjax_nav.config import envs
from fedjax_nav.env.nav import NavEnv, make_params
from fedjax_nav.env.shared import fixed_fleet, fleet_move, fleet_others, place_fleet
from fedjax_nav.evaluation.limits import EvalError
from fedjax_nav.evaluation.policies import as_memory_policy
from fedjax_nav.evaluation.rollout import ACTION_NOISE, RANGE_NOISE
from fedjax_nav.evaluation.run_data import run_name
from fedjax_nav.evaluation.runs import load_run, run_policy
from fedjax_nav.evaluation.suite_files import suite_folder, suite_world
from fedjax_nav.evaluation.suite_stats import bootstrap_ci, worst_mean

DEADLOCK_DISTANCE = 1.0  # m between two timed-out robots' centres (two discs of 0.25 m and a robot's length)
MAX_ROBOTS = 16  # robots per room (placement candidates are shared by 2 K points)
ROBOT_DISC = 0.25  # m, a start's disc in the figure (D_c)
OUTCOMES = ("success", "collision", "robot_collision", "timeout", "deadlock")


@functools.lru_cache(maxsize=8)
def fleet_program(settings: tuple, policy, k: int, trajectories: bool = False, fixed: bool = False):
    """(one agent's actor params, one room's EnvParams, key) -> per robot [k] (`fixed`: robot i
    from the room's start i to its goal i, else `place_fleet`): success,
    collision (an obstacle), robot_collision, timeout, steps, final poses [k, 3] (and with
    `trajectories` the poses [T + 1, k, 3])."""
    env = NavEnv(**dict(settings))
    pol = as_memory_policy(policy)
    T = env.episode_length

    def run(actor, room, key):
        k_place, k_reset, k_steps = jax.random.split(key, 3)
        fleet = fixed_fleet(room.world, k) if fixed else place_fleet(room.world, k_place, k, keep_first=True)
        params = jax.vmap(lambda w: room.replace(world=w))(fleet)
        obs, states = jax.vmap(env.reset)(jax.random.split(k_reset, k), params)
        memory = jax.tree.map(lambda x: jnp.broadcast_to(x, (k, *x.shape)), pol.init())
        false = jnp.zeros(k, bool)
        flags = {name: false for name in ("done", "success", "collision", "robot_collision", "timeout")}
        carry = (states, obs, memory, jnp.ones(k, bool), flags, jnp.zeros(k, jnp.int32))

        def body(carry, key_t):
            states, obs, memory, first, f, steps = carry
            act, memory = jax.vmap(pol.step, in_axes=(None, 0, 0, 0))(actor, obs, memory, first)
            ks = jax.random.split(key_t, k)
            moved = fleet_move(env, ks, states, act, params, ~f["done"], 1)
            around = fleet_others(moved.pose, jax.vmap(env.radius)(params), ~f["done"], 1)
            obs2, states2, _, term, trunc, info = jax.vmap(env.settle)(ks, states, moved, params, around)
            live = ~f["done"]
            robot = info["robot_collision"]
            f = {
                "done": f["done"] | term | trunc,
                "success": f["success"] | (live & info["goal"] & ~info["collision"]),  # as rollout.py
                "collision": f["collision"] | (live & info["collision"] & ~robot),
                "robot_collision": f["robot_collision"] | (live & robot),
                "timeout": f["timeout"] | (live & trunc),
            }
            keep = lambda new, old: jnp.where(live.reshape(-1, *[1] * (new.ndim - 1)), new, old)  # noqa: E731
            states, obs = jax.tree.map(keep, states2, states), keep(obs2, obs)
            return (states, obs, memory, false, f, steps + live.astype(jnp.int32)), states.pose

        start = states.pose
        (states, _, _, _, f, steps), poses = jax.lax.scan(body, carry, jax.random.split(k_steps, T))
        out = {name: f[name] for name in ("success", "collision", "robot_collision", "timeout")}
        out |= {"steps": steps, "final": states.pose}
        if trajectories:
            out["poses"] = jnp.concatenate([start[None], poses])  # [T + 1, k, 3]
            out["goals"] = fleet.goals[:, 0]  # [k, 2]
        return out

    return jax.jit(jax.vmap(jax.vmap(run, (0, None, 0)), (None, 0, 0)))  # [rooms, agents, k]


def deadlocks(final: np.ndarray, timeout: np.ndarray, distance: float = DEADLOCK_DISTANCE) -> np.ndarray:
    """bool[..., k]: a robot timed out within `distance` of another timed-out robot of its room
    (final poses [..., k, 3], timeout bool[..., k])."""
    xy = np.asarray(final, np.float64)[..., :2]
    d = np.linalg.norm(xy[..., :, None, :] - xy[..., None, :, :], axis=-1)
    k = xy.shape[-2]
    both = timeout[..., :, None] & timeout[..., None, :] & ~np.eye(k, dtype=bool)
    return (both & (d < distance)).any(axis=-1)


def rooms_of(suite: str | None, world: str | None, attempts: int, ks) -> tuple:
    """(stacked World [rooms], families, room seeds, fixed): the rooms of `suite`, or `world`
    repeated `attempts` times with its own starts and goals (robot i: start i, goal i; a world
    with fewer than the largest K of either is refused in one line)."""
    ks = sorted({int(k) for k in ks})
    if not ks or ks[0] < 1 or ks[-1] > MAX_ROBOTS:
        raise EvalError(f"--robots-per-room: each K must be in [1, {MAX_ROBOTS}], got {list(ks)}")
    if world is None:
        return (*suite_world(suite), False)
    try:
        w = _worlds.load(world)
    except _worlds.WorldError as e:
        raise EvalError(str(e)) from None
    starts, goals = int(w.num_starts), int(w.num_goals)
    if min(starts, goals) < ks[-1]:
        raise EvalError(
            f"--robots-per-room: world '{world}' has {starts} start(s) and {goals} goal(s) for {ks[-1]} robots "
            "(robot i drives from start i to goal i; eval-crossing has 4 of each, or use --suite)"
        )
    stacked = jax.tree.map(lambda x: jnp.repeat(jnp.asarray(x)[None], attempts, axis=0), w)
    return stacked, np.array([rundir.world_slug(world)] * attempts), np.full(attempts, -1), True


@dataclass
class SharedProtocol:
    """What `evaluate_shared` and `shared_figure` run: the rooms (`rooms_of`), the run's env
    values with the protocol's noise, NavEnv's settings (T the time-out) and each K's keys."""

    run: object  # RunAgents
    world: object  # World [rooms]
    families: np.ndarray
    room_seeds: np.ndarray
    fixed: bool
    T: int
    values: dict
    settings: tuple

    @property
    def rooms(self):
        return make_params(self.world, **self.values)

    def keys(self, seed: int, k: int) -> jax.Array:
        """Room r, agent a's key [rooms, agents] for K = k."""
        R, A = int(self.world.goals.shape[0]), self.run.num_agents
        return jax.random.split(jax.random.fold_in(jax.random.key(seed), k), R * A).reshape(R, A)

    def program(self, k: int, trajectories: bool = False):
        return fleet_program(self.settings, run_policy(self.run), k, trajectories, self.fixed)


def shared_protocol(run_dir, suite, world, attempts, ks, range_noise, action_noise, max_steps) -> SharedProtocol:
    """`run_dir`: a run's folder, or its `RunAgents` (a run under changed values, a scripted
    baseline's: as `evaluate_suite` takes)."""
    world_rows, families, room_seeds, fixed = rooms_of(suite, world, attempts, ks)
    run = load_run(run_dir)
    T = int(max_steps or run.cfg.env.episode_length)
    values = envs.eval_values(run.cfg, range_noise, action_noise)
    settings = tuple(sorted(envs.env_settings(run.cfg, "eval", noise=True, episode_length=T).items()))
    return SharedProtocol(run, world_rows, np.asarray(families), np.asarray(room_seeds), fixed, T, values, settings)


def evaluate_shared(
    run_dir,
    suite: str | None = "heldout",
    robots_per_room=(1, 2, 4, 8),
    range_noise: float = RANGE_NOISE,
    action_noise: float = ACTION_NOISE,
    seed: int = 0,
    max_steps: int | None = None,
    world: str | None = None,
    attempts: int = 4,
) -> dict:
    """The run's agents on every room of `suite` (or `world`, `attempts` times: `rooms_of`) with K
    robots per room for each K; returns {"summary", "families", "episodes"} (the episodes: one row
    per room x agent x K x robot)."""
    ks = sorted({int(k) for k in robots_per_room})
    pr = shared_protocol(run_dir, suite, world, attempts, ks, range_noise, action_noise, max_steps)
    run, cfg, families, room_seeds = pr.run, pr.run.cfg, pr.families, pr.room_seeds
    rooms = pr.rooms
    R, A = int(pr.world.goals.shape[0]), run.num_agents
    frames, t0 = [], time.time()
    for k in ks:
        out = jax.device_get(pr.program(k)(run.actor_params, rooms, pr.keys(seed, k)))
        out["deadlock"] = deadlocks(out["final"], out["timeout"])
        r, a, i = np.meshgrid(np.arange(R), np.arange(A), np.arange(k), indexing="ij")
        frame = {
            "robots_per_room": k,
            "room": r.ravel(),
            "family": families[r.ravel()],
            "room_seed": room_seeds[r.ravel()],
            "seed": run.agent_seed[a.ravel()],
            "net": run.agent_net[a.ravel()],
            "robot": i.ravel(),
            "steps": out["steps"].ravel(),
        }
        frames.append(pd.DataFrame(frame | {name: out[name].ravel().astype(int) for name in OUTCOMES}))
    ep = pd.concat(frames, ignore_index=True)
    fams = pd.DataFrame(
        [
            shared_row(k, name, part)
            for k in ks
            for name, part in [
                *((f, ep[(ep.robots_per_room == k) & (ep.family == f)]) for f in dict.fromkeys(families)),
                ("all", ep[ep.robots_per_room == k]),
            ]
        ]
    )
    summary = {
        "run_dir": str(run.run_dir),
        "method": cfg.method,
        "suite": None if pr.fixed else suite,
        "world": world,
        "robots_per_room": ks,
        "rooms": R,
        "agents": A,
        "max_steps": pr.T,
        "eval_seed": int(seed),
        "trained_in_shared_rooms": bool(cfg.env.shared_rooms),
        "noise": {"range_noise": float(pr.values["range_noise"]), "action_noise": float(action_noise)},
        "deadlock_distance": DEADLOCK_DISTANCE,
        "families": fams.to_dict(orient="records"),
        "wall_s": time.time() - t0,
    }
    return {"summary": summary, "families": fams, "episodes": ep}


def shared_row(k: int, name: str, ep: pd.DataFrame) -> dict:
    """One K and family: success with its interval over rooms and its worst 10 % of rooms, and the
    shares of robot-episodes by outcome."""
    per_room = ep.groupby("room")["success"].mean().to_numpy()
    lo, hi = bootstrap_ci(per_room)
    return {
        "robots_per_room": k,
        "family": name,
        "rooms": int(len(per_room)),
        "robot_episodes": int(len(ep)),
        "success": float(ep["success"].mean()),
        "ci_rooms_low": lo,
        "ci_rooms_high": hi,
        "worst10": float(worst_mean(per_room)) if len(per_room) else float("nan"),
        **{name_: float(ep[name_].mean()) for name_ in OUTCOMES[1:]},
    }


def write_shared(result: dict, out: str | Path) -> list[Path]:
    """shared_episodes.csv, shared_families.csv, then shared.json (the marker of a complete one)."""
    from fedjax_nav.evaluation.report import json_safe

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / rundir.SHARED_EPISODES, out / rundir.SHARED_FAMILIES, out / rundir.SHARED_JSON]
    rundir.atomic_write(paths[0], lambda p: result["episodes"].to_csv(p, index=False))
    rundir.atomic_write(paths[1], lambda p: result["families"].to_csv(p, index=False))
    rundir.write_json(paths[2], json_safe(result["summary"]))
    return paths


def shared_dir(run_dir, suite: str | None, world: str | None = None) -> Path:
    """RUN/eval/<suite folder or world>-shared/."""
    name = rundir.world_slug(world) if world is not None else suite_folder(suite)
    return rundir.eval_dir(run_dir, f"{name}{rundir.SHARED_SUFFIX}")


def evaluate_shared_runs(
    run_dirs, suite: str | None, robots_per_room, echo=print, figures: bool = True, out=None, **kw
):
    """`evaluate_shared` of every run, written to RUN/eval/<suite or world>-shared/ (or `out`, for
    one run), a line per K."""
    done = []
    for run_dir in run_dirs:
        result = evaluate_shared(run_dir, suite, robots_per_room, **kw)
        folder = Path(out) if out is not None else shared_dir(run_dir, suite, kw.get("world"))
        write_shared(result, folder)
        for row in result["families"].to_dict(orient="records"):
            if row["family"] == "all":
                echo(
                    f"{run_name(run_dir)}: {row['robots_per_room']} robot(s) per room: success {row['success']:.3f} "
                    f"[{row['ci_rooms_low']:.3f}, {row['ci_rooms_high']:.3f}], worst10 {row['worst10']:.3f}, "
                    f"obstacle {row['collision']:.3f}, robot-robot {row['robot_collision']:.3f}, "
                    f"time-out {row['timeout']:.3f}, deadlock {row['deadlock']:.3f}"
                )
        if figures:
            shared_figure(run_dir, suite, max(result["summary"]["robots_per_room"]), folder, **kw)
        echo(f"wrote {folder}/ ({json.dumps(result['summary']['robots_per_room'])} robots per room)")
        done.append(result["summary"])
    return done


def shared_figure(
    run_dir,
    suite: str | None,
    k: int,
    out: str | Path,
    range_noise: float = RANGE_NOISE,
    action_noise: float = ACTION_NOISE,
    seed: int = 0,
    max_steps: int | None = None,
    world: str | None = None,
    attempts: int = 4,
) -> Path:
    """The first agent's fleet of `k` robots in the suite's first room: each robot's path from its
    start (a disc) to where its episode ended (a star at its goal, a cross at a collision), its
    goal a ring of its colour; the protocol of `evaluate_shared` (that room's key for K = k)."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle

    from fedjax_nav.env.render import draw_trajectories, draw_world, panel_inches

    pr = shared_protocol(run_dir, suite, world, attempts, [k], range_noise, action_noise, max_steps)
    first = lambda tree: jax.tree.map(lambda x: x[:1], tree)  # noqa: E731  room 0, agent 0
    out_ = jax.device_get(
        pr.program(k, trajectories=True)(first(pr.run.actor_params), first(pr.rooms), pr.keys(seed, k)[:1, :1])
    )
    poses, steps = out_["poses"][0, 0], out_["steps"][0, 0]  # [T + 1, k, 3], [k]
    room = jax.tree.map(lambda x: x[0], pr.world)
    fig = Figure(figsize=tuple(1.3 * v for v in panel_inches(room.size)), layout="constrained")
    ax = fig.add_subplot()
    room = room.replace(
        starts=jnp.zeros_like(room.starts[:1]),
        goals=jnp.zeros_like(room.goals[:1]),
        num_starts=jnp.int32(0),
        num_goals=jnp.int32(0),
    )
    draw_world(ax, room, title=f"{pr.families[0]} room, {k} robots (discs: starts; rings: goals)", labels=False)
    colors = [f"C{i % 10}" for i in range(k)]
    crashed = out_["collision"][0, 0] | out_["robot_collision"][0, 0]
    ends = ["success" if out_["success"][0, 0, i] else "collision" if crashed[i] else None for i in range(k)]
    draw_trajectories(ax, [poses[: steps[i] + 1, i, :2] for i in range(k)], colors=colors, outcomes=ends)
    for i in range(k):
        ax.add_patch(Circle(tuple(poses[0, i, :2]), ROBOT_DISC, color=colors[i], zorder=5))
        gx, gy = out_["goals"][0, 0, i]
        ax.add_patch(Circle((gx, gy), float(pr.values["goal_radius"]), fill=False, ec=colors[i], lw=1.2))
    path = Path(out) / rundir.SHARED_FIGURE
    return rundir.save_figure(fig, path, 110)
