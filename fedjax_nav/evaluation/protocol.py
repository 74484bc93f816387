"""The evaluation protocol (SCENARIO.md sections 2 and 5, thesis 4.2) as one jitted program.

Every agent drives one robot in an evaluation world from start 0 to each goal, `attempts` times,
with its greedy (deterministic) actor action, in `NavEnv(mode="eval", noise=True)`: small
Gaussian noise on the ranges and on the executed action is the only thing that makes attempts
differ. An episode ends at the goal (success), at a collision (failure) or after `T` steps
(a time-out, failure). All agents x goals x attempts run in one `vmap`; an outer `while_loop`
over chunks of steps stops as soon as every episode has ended.

Per episode: success, collision, timeout, steps, time = steps * dt (s), path length (m, the sum
of the distances between consecutive poses), the straight-line distance and the efficiency, and
the trajectory (poses; frozen at the last pose after the episode ended).

Straight-line convention. The episode succeeds as soon as the robot is within the goal radius
`D_g`, so the shortest possible path is `|goal - start| - D_g`, not `|goal - start|`. As in the
thesis's analysis, `straight_line = |goal - start| - D_g` and
`efficiency = straight_line / path_length`, over successful episodes only: a straight drive at
the goal gives 1 (up to the overshoot of the last step, at most `v_max * dt`). The raw
start-goal distance is recorded beside it (`start_goal_distance`).

Public entry points:
    evaluate_policy(policy, world, params, ...) -> EvalResult   any policy function
    load_run(run_dir) -> RunAgents                              agents of a training run
    evaluate_run(run_dir, ...) -> RunEvaluation                 the protocol on a run
    episodes_frame(result, ...) / summarize(frame, ...)         the metrics
    write_run(evaluation) -> paths                              eval.json, eval_episodes.csv, ...
"""
from __future__ import annotations

import functools
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
from flax import struct

from fedjax_nav import worlds as _worlds
from fedjax_nav.env.nav import EnvState, NavEnv, make_params
from fedjax_nav.worlds import World

# Defaults of the evaluation noise (std of Gaussian noise): ranges in m, actions in the network's
# units (v / v_max in [0, 1], omega / omega_max in [-1, 1]).
RANGE_NOISE = 0.01
ACTION_NOISE = 0.01
ATTEMPTS = 4
CHUNK = 64  # steps per inner scan; the outer while_loop exits once every episode is over
SELECTED_NOTE = "selected on evaluation data (best agent per seed by evaluation success rate)"
STRAIGHT_LINE_NOTE = (
    "straight_line = |goal - start| - goal_radius (the episode succeeds on entering the goal "
    "radius); efficiency = straight_line / path_length, successful episodes only"
)


class EvalError(ValueError):
    """An evaluation input (run directory, params file, setting) is invalid; the message says which."""


# ----------------------------------------------------------------------------- the program


@struct.dataclass
class _Episode:
    """One episode's running state (vmapped over agents x episodes)."""

    env_state: EnvState
    obs: jax.Array  # f32[obs]
    key: jax.Array
    done: jax.Array  # bool[]
    success: jax.Array  # bool[]
    collision: jax.Array  # bool[]
    timeout: jax.Array  # bool[]
    steps: jax.Array  # i32[] steps taken until (and including) the terminal one
    path: jax.Array  # f32[] m travelled


@dataclass
class EvalResult:
    """Everything the program measured; arrays are numpy, axes [agent, goal, attempt, ...]."""

    success: np.ndarray  # bool[A, G, K]
    collision: np.ndarray  # bool[A, G, K]
    timeout: np.ndarray  # bool[A, G, K]
    steps: np.ndarray  # i32[A, G, K]
    path_length: np.ndarray  # f32[A, G, K] m
    poses: np.ndarray  # f32[A, G, K, T + 1, 3]; poses[..., 0, :] is the start; frozen after the end
    goals: np.ndarray  # f32[G, 2] the goals evaluated (world coordinates)
    goal_index: np.ndarray  # i32[G] their rows in the world
    start: np.ndarray  # f32[3] start 0
    dt: float
    goal_radius: float
    max_steps: int  # T
    range_noise: float
    action_noise: float
    seed: int
    wall_s: float = 0.0  # seconds of the call (compile included when it compiled)

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.success.shape)  # type: ignore[return-value]

    @property
    def time_s(self) -> np.ndarray:
        return self.steps.astype(np.float64) * self.dt

    @property
    def start_goal_distance(self) -> np.ndarray:
        """f64[G] |goal - start| in m."""
        return np.linalg.norm(self.goals.astype(np.float64) - self.start[None, :2].astype(np.float64), axis=-1)

    @property
    def straight_line(self) -> np.ndarray:
        """f64[G] |goal - start| - goal_radius (the shortest successful path), at least 0."""
        return np.maximum(self.start_goal_distance - self.goal_radius, 0.0)

    @property
    def efficiency(self) -> np.ndarray:
        """f64[A, G, K] straight_line / path_length on successful episodes, NaN elsewhere."""
        path = self.path_length.astype(np.float64)
        eff = self.straight_line[None, :, None] / np.where(path > 0, path, np.nan)
        return np.where(self.success, eff, np.nan)


@functools.lru_cache(maxsize=16)
def _program(env_settings: tuple, policy: Callable, chunk: int):
    """jit(run) for one env configuration (static: num_beams, max_range, T, collision_test) and
    one policy function (static; cached by identity, so the same function reuses the program).

    run(agent_params [A, ...], env_params, goal_index i32[G], keys [A, G*K]) with K = keys' second
    axis // G.
    """
    num_beams, max_range, T, collision_test = env_settings
    env = NavEnv(num_beams, max_range, T, mode="eval", collision_test=collision_test, noise=True)
    n_chunks = -(-T // chunk)

    def init_one(key, g, env_params):
        k_reset, k_run = jax.random.split(key)
        obs, state = env.reset(k_reset, env_params.replace(goal_index=g))
        f, i = jnp.bool_(False), jnp.int32(0)
        return _Episode(state, obs, k_run, f, f, f, f, i, jnp.float32(0.0))

    def step_one(params, ep: _Episode, env_params):
        key, k_step = jax.random.split(ep.key)
        action = policy(params, ep.obs)
        obs, state, _, terminated, truncated, info = env.step(k_step, ep.env_state, action, env_params)
        moved = jnp.linalg.norm(info["pose"][:2] - ep.env_state.pose[:2])
        goal, collision = info["goal"], info["collision"]
        new = ep.replace(
            env_state=state, obs=obs, key=key, done=terminated | truncated,
            success=goal & ~collision, collision=collision, timeout=truncated & ~terminated,
            steps=ep.steps + 1, path=ep.path + moved,
        )
        # Freeze after the end: a finished episode keeps its last state (and pose) for good.
        return jax.tree.map(lambda n, o: jnp.where(ep.done, o, n), new, ep)

    def run(agent_params, env_params, goal_index, keys):
        A, E = keys.shape[:2]
        G = goal_index.shape[0]
        goals_e = jnp.tile(goal_index, E // G)  # episode e = attempt * G + goal  (reordered below)
        ep = jax.vmap(jax.vmap(init_one, (0, 0, None)), (0, None, None))(keys, goals_e, env_params)
        start_pose = ep.env_state.pose  # [A, E, 3]
        # agents x episodes: params vary over agents only
        step_all = jax.vmap(jax.vmap(step_one, (None, 0, None)), (0, 0, None))

        def inner(ep, _):
            ep = step_all(agent_params, ep, env_params)
            return ep, ep.env_state.pose

        buf = jnp.zeros((n_chunks, chunk, A, E, 3), jnp.float32)

        def cond(carry):
            c, ep, _ = carry
            return (c < n_chunks) & jnp.any(~ep.done)

        def body(carry):
            c, ep, buf = carry
            ep, poses = jax.lax.scan(inner, ep, None, length=chunk)
            return c + 1, ep, jax.lax.dynamic_update_index_in_dim(buf, poses, c, 0)

        _, ep, buf = jax.lax.while_loop(cond, body, (jnp.int32(0), ep, buf))
        poses = buf.reshape(n_chunks * chunk, A, E, 3)[:T]
        # Chunks skipped by the early exit are zeros: every pose at or after an episode's end is
        # its final pose (frozen), so fill those from the final state.
        t = jnp.arange(1, T + 1)[:, None, None, None]
        poses = jnp.where(t <= ep.steps[None, :, :, None], poses, ep.env_state.pose[None])
        poses = jnp.concatenate([start_pose[None], poses], axis=0)  # [T + 1, A, E, 3]
        poses = jnp.moveaxis(poses, 0, 2)  # [A, E, T + 1, 3]
        out = {"success": ep.success, "collision": ep.collision, "timeout": ep.timeout,
               "steps": ep.steps, "path": ep.path, "poses": poses}
        # [A, E] -> [A, K, G] -> [A, G, K]
        return jax.tree.map(lambda x: jnp.swapaxes(x.reshape(A, E // G, G, *x.shape[2:]), 1, 2), out)

    return jax.jit(run)


@functools.lru_cache(maxsize=32)
def _wrap_obs_only(policy: Callable) -> Callable:
    def wrapped(_params, obs):
        return policy(obs)

    return wrapped


def evaluate_policy(
    policy: Callable,
    world: World | str | Path,
    params: Any = None,
    *,
    num_agents: int | None = None,
    goals: list[int] | None = None,
    attempts: int = ATTEMPTS,
    max_steps: int = 1024,
    range_noise: float = RANGE_NOISE,
    action_noise: float = ACTION_NOISE,
    seed: int = 0,
    num_beams: int = 24,
    max_range: float = 3.5,
    collision_test: str = "exact",
    chunk: int = CHUNK,
    **env_overrides,
) -> EvalResult:
    """Run the protocol for any policy: every agent x goal x attempt, one jitted program.

    policy: `policy(agent_params, obs) -> action` when `params` is given, with `params` a pytree
        whose leaves have a leading agent axis [A]; `policy(obs) -> action` when `params` is None
        (one agent unless `num_agents` says otherwise, all identical). `obs` is the env's
        observation f32[num_beams + 4] (ranges, goal distance, goal bearing, previous action);
        the action is in the env's units (v / v_max, omega / omega_max). The policy is traced
        once per (policy, env settings): pass the same function object to reuse the compilation.
    world: a World (unstacked), a shipped name or a world file. goals: rows of the world's goals
        (default: all of them). Start 0 is always the start.
    max_steps: T, the time-out. range_noise / action_noise: Gaussian stds (m; action units).
    env_overrides: EnvParams fields (dt, v_max, omega_max, goal_radius, collision_distance, ...).
    """
    if not isinstance(world, World):
        world = _worlds.load(world)
    if attempts < 1:
        raise EvalError(f"attempts must be >= 1, got {attempts}")
    if max_steps < 1:
        raise EvalError(f"max_steps must be >= 1, got {max_steps}")
    if range_noise < 0 or action_noise < 0:
        raise EvalError(f"noise stds must be >= 0, got range_noise={range_noise}, action_noise={action_noise}")
    n_goals = int(world.num_goals)
    goal_rows = list(range(n_goals)) if goals is None else [int(g) for g in goals]
    bad = [g for g in goal_rows if not 0 <= g < n_goals]
    if bad or not goal_rows:
        raise EvalError(f"goals must be rows 0..{n_goals - 1} of the world's goals, got {goals}")

    if params is None:
        A = int(num_agents or 1)
        fn = _wrap_obs_only(policy)
        agent_params = jnp.zeros((A,))  # a dummy leaf carrying the agent axis
    else:
        leaves = jax.tree.leaves(params)
        if not leaves:
            raise EvalError("params has no leaves")
        A = int(leaves[0].shape[0])
        if num_agents is not None and num_agents != A:
            raise EvalError(f"num_agents={num_agents} but params have {A} agents on their leading axis")
        fn, agent_params = policy, params

    settings = (int(num_beams), float(max_range), int(max_steps), str(collision_test))
    env_params = make_params(world, range_noise=range_noise, action_noise=action_noise, **env_overrides)
    G, K = len(goal_rows), int(attempts)
    keys = jax.random.split(jax.random.key(seed), A * G * K).reshape(A, G * K)
    t0 = time.time()
    program = _program(settings, fn, min(int(chunk), int(max_steps)))
    out = program(agent_params, env_params, jnp.asarray(goal_rows, jnp.int32), keys)
    out = jax.device_get(out)
    wall = time.time() - t0
    return EvalResult(
        success=np.asarray(out["success"]), collision=np.asarray(out["collision"]),
        timeout=np.asarray(out["timeout"]), steps=np.asarray(out["steps"]),
        path_length=np.asarray(out["path"]), poses=np.asarray(out["poses"]),
        goals=np.asarray(world.goals)[goal_rows], goal_index=np.asarray(goal_rows, np.int32),
        start=np.asarray(world.starts[0]), dt=round(float(env_params.dt), 7),
        goal_radius=round(float(env_params.goal_radius), 7),
        max_steps=int(max_steps), range_noise=float(range_noise), action_noise=float(action_noise),
        seed=int(seed), wall_s=wall,
    )


# ----------------------------------------------------------------------------- metrics


def episodes_frame(result: EvalResult, agent_seed: np.ndarray | None = None,
                   agent_net: np.ndarray | None = None) -> pd.DataFrame:
    """One row per episode: agent, seed, net, goal, attempt and the per-episode measurements."""
    A, G, K = result.shape
    a, g, k = np.meshgrid(np.arange(A), np.arange(G), np.arange(K), indexing="ij")
    seed = np.zeros(A, int) if agent_seed is None else np.asarray(agent_seed)
    net = np.arange(A) if agent_net is None else np.asarray(agent_net)
    goal_row = result.goal_index[g.ravel()]
    outcome = np.where(result.success, "success", np.where(result.collision, "collision",
                                                           np.where(result.timeout, "timeout", "other")))
    return pd.DataFrame({
        "agent": a.ravel(), "seed": seed[a.ravel()], "net": net[a.ravel()], "goal": goal_row,
        "attempt": k.ravel(),
        "goal_x": result.goals[g.ravel(), 0], "goal_y": result.goals[g.ravel(), 1],
        "success": result.success.ravel().astype(int), "collision": result.collision.ravel().astype(int),
        "timeout": result.timeout.ravel().astype(int), "outcome": outcome.ravel(),
        "steps": result.steps.ravel(), "time_s": result.time_s.ravel(),
        "path_length": result.path_length.ravel().astype(np.float64),
        "start_goal_distance": result.start_goal_distance[g.ravel()],
        "straight_line": result.straight_line[g.ravel()],
        "efficiency": result.efficiency.ravel(),
    })


def _stats(df: pd.DataFrame) -> dict:
    """Success rate; time and efficiency mean/std (ddof=0) over successful episodes."""
    ok = df[df["success"] == 1]
    n, s = len(df), len(ok)

    def ms(col):
        if s == 0:
            return None, None
        x = ok[col].to_numpy(np.float64)
        return float(np.mean(x)), float(np.std(x))

    tm, ts = ms("time_s")
    em, es = ms("efficiency")
    return {
        "episodes": int(n), "successes": int(s),
        "collisions": int(df["collision"].sum()), "timeouts": int(df["timeout"].sum()),
        "success_rate": float(s / n) if n else None,
        "time_mean": tm, "time_std": ts, "efficiency_mean": em, "efficiency_std": es,
    }


def _block(df: pd.DataFrame) -> dict:
    per_goal = []
    for g, sub in df.groupby("goal", sort=True):
        per_goal.append({"goal": int(g), "xy": [float(sub["goal_x"].iloc[0]), float(sub["goal_y"].iloc[0])],
                         **_stats(sub)})
    per_seed = df.groupby("seed")["success"].mean()
    out = {"overall": _stats(df), "per_goal": per_goal,
           "success_per_seed": {str(int(k)): float(v) for k, v in per_seed.items()}}
    out["overall"]["success_seed_std"] = float(np.std(per_seed.to_numpy())) if len(per_seed) else None
    return out


def best_agents(df: pd.DataFrame) -> list[int]:
    """The best agent of each seed: highest success rate, then shortest mean successful time,
    then lowest index. Chosen on the evaluation episodes themselves (see SELECTED_NOTE)."""
    per = df.groupby("agent").agg(seed=("seed", "first"), success=("success", "mean"))
    t = df[df["success"] == 1].groupby("agent")["time_s"].mean()
    per["time"] = t.reindex(per.index).fillna(np.inf)
    per = per.reset_index().sort_values(["seed", "success", "time", "agent"], ascending=[True, False, True, True])
    return [int(a) for a in per.groupby("seed")["agent"].first()]


def summarize(df: pd.DataFrame) -> dict:
    """The two aggregations: every agent (the headline) and the best agent per seed."""
    best = best_agents(df)
    per_agent = df.groupby("agent").agg(seed=("seed", "first"), net=("net", "first"), success_rate=("success", "mean"))
    return {
        "all_agents": _block(df),
        "best_agent_per_seed": {"note": SELECTED_NOTE, "agents": best, **_block(df[df["agent"].isin(best)])},
        "per_agent": [{"agent": int(a), "seed": int(r.seed), "net": int(r.net), "success_rate": float(r.success_rate)}
                      for a, r in per_agent.iterrows()],
    }


# ----------------------------------------------------------------------------- runs


@dataclass
class RunAgents:
    """The trained actors of a run, flattened to one agent axis [A = seeds x nets]."""

    run_dir: Path
    cfg: Any  # fedjax_nav.config.Config
    actor_params: dict  # leaves [A, ...]
    agent_seed: np.ndarray  # i64[A] the run's PRNG seed of each agent
    agent_net: np.ndarray  # i64[A] the network index within its seed
    n_nets: int
    num_robots: int

    @property
    def num_agents(self) -> int:
        return len(self.agent_seed)


@functools.lru_cache(maxsize=16)
def actor_policy(hidden: int, depth: int, activation: str) -> Callable:
    """The greedy actor as `policy(actor_params, obs)` (one function object per architecture,
    so that runs with the same networks share one compiled evaluation)."""
    from fedjax_nav.agents import ddpg

    nets = ddpg.make_nets(hidden, depth, activation)

    def policy(params, obs):
        return ddpg.act(nets, params, obs)

    return policy


def _unflatten(flat: dict[str, np.ndarray]) -> dict:
    tree: dict = {}
    for key, value in flat.items():
        node = tree
        parts = key.split("/")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        node[parts[-1]] = value
    return tree


def load_run(run_dir: str | Path) -> RunAgents:
    """Read config.yaml and params.npz (actor leaves [seed, net, ...]) of a training run."""
    from fedjax_nav.agents import ddpg
    from fedjax_nav.config import ConfigError, load_config
    from fedjax_nav.env import NavEnv as _Env
    from fedjax_nav import methods

    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise EvalError(f"{run_dir}: no such run directory")
    for name in ("config.yaml", "params.npz"):
        if not (run_dir / name).exists():
            raise EvalError(f"{run_dir}: missing {name} (is this a finished training run directory?)")
    try:
        cfg = load_config(run_dir / "config.yaml")
    except ConfigError as e:
        raise EvalError(str(e)) from None
    try:
        with np.load(run_dir / "params.npz") as z:
            flat = {k[len("actor/"):]: np.asarray(z[k]) for k in z.files if k.startswith("actor/")}
    except Exception as e:  # a truncated or foreign file
        raise EvalError(f"{run_dir / 'params.npz'}: cannot be read as a params file ({e})") from None
    if not flat:
        raise EvalError(f"{run_dir / 'params.npz'}: no 'actor/...' arrays")
    actor = _unflatten(flat)

    method = methods.get(cfg.method)
    n_robots = cfg.num_robots
    n_nets = 1 if method.shared_network else n_robots
    d = cfg.ddpg
    nets = ddpg.make_nets(d.hidden, d.depth, d.activation)
    obs_size = _Env(cfg.env.num_beams).obs_size
    expected = jax.eval_shape(nets.actor.init, jax.random.key(0), jnp.zeros((obs_size,)))
    exp_flat = {"/".join(str(getattr(k, "key", k)) for k in kp): v.shape
                for kp, v in jax.tree_util.tree_flatten_with_path(expected)[0]}
    if set(exp_flat) != set(flat):
        raise EvalError(
            f"{run_dir / 'params.npz'}: actor arrays {sorted(flat)} do not match the network of "
            f"config.yaml (ddpg.hidden={d.hidden}, depth={d.depth}): expected {sorted(exp_flat)}"
        )
    lead = None
    for k, shape in exp_flat.items():
        got = flat[k].shape
        if len(got) != len(shape) + 2 or tuple(got[2:]) != tuple(shape) or got[1] != n_nets:
            raise EvalError(
                f"{run_dir / 'params.npz'}: actor/{k} has shape {list(got)}, expected "
                f"[seeds, {n_nets}, {', '.join(map(str, shape))}] for {cfg.method} with "
                f"ddpg.hidden={d.hidden}, depth={d.depth}"
            )
        lead = got[:2] if lead is None else lead
        if got[:2] != lead:
            raise EvalError(f"{run_dir / 'params.npz'}: inconsistent leading axes {list(got[:2])} vs {list(lead)}")
    S = int(lead[0])
    actor = jax.tree.map(lambda x: jnp.asarray(x.reshape(S * n_nets, *x.shape[2:]), jnp.float32), actor)
    seeds = np.repeat(np.arange(S) + cfg.run.seed, n_nets)
    nets_idx = np.tile(np.arange(n_nets), S)
    return RunAgents(run_dir, cfg, actor, seeds, nets_idx, n_nets, n_robots)


@dataclass
class RunEvaluation:
    run: RunAgents
    result: EvalResult
    frame: pd.DataFrame
    summary: dict  # what eval.json holds
    world: World
    world_meta: dict = field(default_factory=dict)


def evaluate_run(
    run_dir: str | Path | RunAgents,
    world: str | Path = "eval",
    attempts: int = ATTEMPTS,
    range_noise: float = RANGE_NOISE,
    action_noise: float = ACTION_NOISE,
    seed: int = 0,
    max_steps: int | None = None,
) -> RunEvaluation:
    """The protocol on a run: its agents, the run's env settings (dt, speeds, radii, beams,
    collision test, T = env.episode_length unless `max_steps`), on `world` and its goals.

    `attempts` is per agent of a per-robot method; a shared-network method (SNDDPG, one agent per
    seed) gets attempts * num_robots so that the total number of episodes is the same.
    """
    run = run_dir if isinstance(run_dir, RunAgents) else load_run(run_dir)
    cfg = run.cfg
    w, meta = _worlds.load_with_meta(world)
    k_eff = int(attempts) * run.num_robots // run.n_nets
    e, d = cfg.env, cfg.ddpg
    T = int(max_steps or e.episode_length)
    result = evaluate_policy(
        actor_policy(d.hidden, d.depth, d.activation), w, run.actor_params,
        attempts=k_eff, max_steps=T, range_noise=range_noise, action_noise=action_noise, seed=seed,
        num_beams=e.num_beams, max_range=e.max_range, collision_test=e.collision_test,
        dt=e.dt, v_max=e.v_max, omega_max=e.omega_max, goal_radius=e.goal_radius,
        collision_distance=e.collision_distance,
    )
    frame = episodes_frame(result, run.agent_seed, run.agent_net)
    summary = {
        "run_dir": str(run.run_dir),
        "method": cfg.method,
        "world": str(meta.get("name", world)),
        "world_source": str(meta.get("source", world)),
        "start": [float(x) for x in result.start],
        "goals": [[float(x) for x in g] for g in result.goals],
        "agents": run.num_agents,
        "seeds": sorted({int(s) for s in run.agent_seed}),
        "nets_per_seed": run.n_nets,
        "attempts_requested": int(attempts),
        "attempts_per_agent": k_eff,
        "episodes": int(result.success.size),
        "max_steps": T,
        "dt": result.dt,
        "goal_radius": result.goal_radius,
        "v_max": float(e.v_max),
        "noise": {"range_noise": float(range_noise), "action_noise": float(action_noise),
                  "units": "range_noise in m; action_noise in action units (v/v_max, omega/omega_max)"},
        "eval_seed": int(seed),
        "policy": "greedy actor (no exploration)",
        "straight_line": STRAIGHT_LINE_NOTE,
        "std": "population std (ddof=0) over successful episodes; success_seed_std over seeds",
        **summarize(frame),
        "wall_s": result.wall_s,
        "jax_backend": jax.default_backend(),
    }
    return RunEvaluation(run, result, frame, summary, w, meta)


def _atomic(path: Path, write) -> None:
    from fedjax_nav.training.run import atomic_write

    atomic_write(path, write)


def write_run(ev: RunEvaluation, out_dir: str | Path | None = None, figures: bool = True) -> list[Path]:
    """eval.json, eval_episodes.csv, eval_trajectories.npz (+ eval_bars.png,
    eval_trajectories.png) into the run directory (or out_dir). Returns the paths written."""
    out = Path(out_dir or ev.run.run_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "eval.json", out / "eval_episodes.csv", out / "eval_trajectories.npz"]
    _atomic(paths[0], lambda p: Path(p).write_text(json.dumps(_jsonable(ev.summary), indent=1)))
    _atomic(paths[1], lambda p: ev.frame.to_csv(p, index=False))
    r = ev.result
    last = int(r.steps.max()) + 1  # poses after the longest episode are all frozen copies
    _atomic(paths[2], lambda p: np.savez_compressed(
        open(p, "wb"), poses=r.poses[..., :last, :], steps=r.steps, success=r.success,
        collision=r.collision, goals=r.goals, start=r.start, agent_seed=ev.run.agent_seed,
        agent_net=ev.run.agent_net))
    if figures:
        from fedjax_nav.evaluation import figures as figs

        paths.append(figs.bars({ev.summary["method"]: ev.summary}, out / "eval_bars.png", per_goal=True,
                               title=f"{ev.summary['method']} on {ev.summary['world']}"))
        paths.append(figs.trajectories(ev, out / "eval_trajectories.png"))
    return paths


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.floating, float)):
        return None if not math.isfinite(float(x)) else float(x)
    return x


# ----------------------------------------------------------------------------- tables


def _fmt(mean, std, digits=2):
    if mean is None:
        return "-"
    return f"{mean:.{digits}f} +- {std:.{digits}f}"


def summary_table(summary: dict) -> str:
    """A plain-text table of one run's evaluation: per goal and overall, then the best agents."""
    s = summary
    noise = s["noise"]
    lines = [
        f"{s['method']} ({s['run_dir']}): {s['agents']} agent(s) x {len(s['goals'])} goals x "
        f"{s['attempts_per_agent']} attempts = {s['episodes']} episodes on '{s['world']}', "
        f"T = {s['max_steps']} steps ({s['max_steps'] * s['dt']:g} s)",
        f"noise: range {noise['range_noise']:g} m, action {noise['action_noise']:g} (std, action units); "
        f"eval seed {s['eval_seed']}",
        f"{'goal':<16}{'success':>9}{'n':>6}{'time (s)':>18}{'efficiency':>18}",
    ]

    def row(name, st):
        time_s = _fmt(st["time_mean"], st["time_std"])
        eff = _fmt(st["efficiency_mean"], st["efficiency_std"], 3)
        return f"{name:<16}{st['success_rate']:>9.3f}{st['episodes']:>6}{time_s:>18}{eff:>18}"

    for g in s["all_agents"]["per_goal"]:
        lines.append(row(f"G{g['goal']} ({g['xy'][0]:g}, {g['xy'][1]:g})", g))
    lines.append(row("all agents", s["all_agents"]["overall"]))
    lines.append(row("best per seed*", s["best_agent_per_seed"]["overall"]))
    lines.append(f"* {SELECTED_NOTE}; agents {s['best_agent_per_seed']['agents']}")
    return "\n".join(lines)


def comparison_frame(summaries: dict[str, dict]) -> pd.DataFrame:
    """One row per run (label -> eval.json dict): the headline and the best-per-seed numbers."""
    rows = []
    for label, s in summaries.items():
        o, b = s["all_agents"]["overall"], s["best_agent_per_seed"]["overall"]
        rows.append({
            "run": label, "method": s["method"], "agents": s["agents"], "seeds": len(s["seeds"]),
            "episodes": s["episodes"], "success": o["success_rate"], "success_seed_std": o["success_seed_std"],
            "time_mean": o["time_mean"], "time_std": o["time_std"],
            "efficiency_mean": o["efficiency_mean"], "efficiency_std": o["efficiency_std"],
            "best_per_seed_success": b["success_rate"], "world": s["world"],
            "range_noise": s["noise"]["range_noise"], "action_noise": s["noise"]["action_noise"],
        })
    return pd.DataFrame(rows)


def comparison_markdown(df: pd.DataFrame) -> str:
    def f(x, d=3):
        return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{d}f}"

    def pm(m, s, d=3):
        m, s = f(m, d), f(s, d)
        return m if m == "-" else f"{m} +- {s}"

    lines = ["| run | method | agents | episodes | success (+- std over seeds) | time (s) | efficiency | "
             "best agent per seed success* |", "|---|---|---|---|---|---|---|---|"]
    for r in df.itertuples():
        lines.append(
            f"| {r.run} | {r.method} | {r.agents} | {r.episodes} | {pm(r.success, r.success_seed_std)} | "
            f"{pm(r.time_mean, r.time_std, 2)} | {pm(r.efficiency_mean, r.efficiency_std)} | "
            f"{f(r.best_per_seed_success)} |")
    lines.append(f"\n\\* {SELECTED_NOTE}.")
    return "\n".join(lines)


# ----------------------------------------------------------------------------- the command


def evaluate_runs(
    run_dirs: list[str | Path],
    world: str | Path = "eval",
    attempts: int = ATTEMPTS,
    range_noise: float = RANGE_NOISE,
    action_noise: float = ACTION_NOISE,
    seed: int = 0,
    max_steps: int | None = None,
    out: str | Path | None = None,
    figures: bool = True,
    echo: Callable[[str], None] = print,
) -> dict[str, Any]:
    """What `fedjax-nav evaluate` does: evaluate each run (files into its directory), print its
    table; with several runs also a comparison table (CSV + markdown) and figure, written to
    `out` or next to the first run (its parent directory). Returns {label: summary, "_paths": [...]}.

    Every run is loaded and checked before any evaluation starts (a bad path fails early).
    """
    runs = [load_run(d) for d in run_dirs]
    w_check = _worlds.load_with_meta(world)  # a bad world fails before any compilation
    del w_check
    echo(f"evaluating on '{world}': noise std range {range_noise:g} m, action {action_noise:g} "
         f"(action units); {attempts} attempts per agent and goal (x num_robots for a shared network)")
    summaries: dict[str, dict] = {}
    written: list[Path] = []
    for run in runs:
        ev = evaluate_run(run, world, attempts, range_noise, action_noise, seed, max_steps)
        paths = write_run(ev, figures=figures)
        written += paths
        echo("")
        echo(summary_table(ev.summary))
        echo(f"{ev.summary['episodes']} episodes in {ev.result.wall_s:.1f} s; wrote "
             + ", ".join(str(p) for p in paths))
        label = ev.summary["method"]
        if label in summaries:
            label = f"{label} ({run.run_dir.name})"
        summaries[label] = ev.summary
    if len(runs) > 1:
        out_dir = Path(out) if out else Path(run_dirs[0]).resolve().parent
        out_dir.mkdir(parents=True, exist_ok=True)
        df = comparison_frame(summaries)
        md = comparison_markdown(df)
        paths = [out_dir / "eval_comparison.csv", out_dir / "eval_comparison.md"]
        _atomic(paths[0], lambda p: df.to_csv(p, index=False))
        _atomic(paths[1], lambda p: Path(p).write_text(md + "\n"))
        if figures:
            from fedjax_nav.evaluation import figures as figs

            paths.append(figs.bars(summaries, out_dir / "eval_comparison.png", title=f"evaluation on {world}"))
        written += paths
        echo("")
        echo(md)
        echo("wrote " + ", ".join(str(p) for p in paths))
    return {**summaries, "_paths": written}
