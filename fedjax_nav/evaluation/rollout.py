"""The evaluation program (docs/evaluation.md; thesis 4.2): every agent x goal x attempt of a
policy in one jitted program.

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

    evaluate_policy(policy, world, params, ...) -> EvalResult   any policy function

A policy with a memory (a recurrent one: PPO's GRU) is a `MemoryPolicy`: its memory starts at
`init()` in every episode (with `first` True at the episode's first step, False after) and is
carried step to step inside the program, as the trainer's probe carries it.

Memory: `evaluate_policy` refuses an evaluation whose trajectories and episode states would not
fit (`limits.check_eval_memory`) before anything is allocated or compiled.
"""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from fedjax_nav import worlds as _worlds
from fedjax_nav.env.nav import EnvState, NavEnv, make_params
from fedjax_nav.evaluation.limits import EvalError, check_counts, check_eval_memory
from fedjax_nav.evaluation.policies import MemoryPolicy, as_memory_policy, no_memory
from fedjax_nav.worlds import World

# Defaults of the evaluation noise (std of Gaussian noise): ranges in m, actions in the network's
# units (v / v_max in [0, 1], omega / omega_max in [-1, 1]).
RANGE_NOISE = 0.01
ACTION_NOISE = 0.01
ATTEMPTS = 4
CHUNK = 64  # steps per inner scan; the outer while_loop exits once every episode is over


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
    memory: Any = None  # the policy's memory before the next step (None: a policy without one)
    first: Any = None  # bool[]: the next step is the episode's first (None without a memory)


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


def eval_program(env_settings: dict, policy: Callable, chunk: int):
    """jit(run) for one env configuration (`NavEnv` keyword arguments, mode "eval": see
    `fedjax_nav.config.envs.env_settings`; its episode_length is the time-out T) and one policy
    function (static; cached by identity, so the same function reuses the program).

    run(agent_params [A, ...], env_params, goal_index i32[G], keys [A, G*K]) with K = keys' second
    axis // G. `policy`: `policy(params, obs) -> action`, or a `MemoryPolicy`.
    """
    return _cached_program(tuple(sorted(env_settings.items())), as_memory_policy(policy), int(chunk))


def observed_program(env_settings: dict, policy: Callable, chunk: int):
    """`eval_program` that also returns "obs" f32[A, G, K, T + 1, obs]: obs[..., t, :] is the
    observation at poses[..., t, :], the one the policy acted on at step t for t < steps (t = steps:
    the episode's last, which it never acted on; frozen after the end). The episodes are the same.
    For replays of a few rooms: `limits.eval_memory` counts the poses only (obs are obs_size / 3 x them)."""
    return _cached_program(tuple(sorted(env_settings.items())), as_memory_policy(policy), int(chunk), True)


def _init_one(env: NavEnv, memory_init: Callable, key, g, env_params) -> _Episode:
    """One episode's first state: reset at start 0 towards goal row `g`, the policy's memory at
    an episode's start."""
    k_reset, k_run = jax.random.split(key)
    obs, state = env.reset(k_reset, env_params.replace(goal_index=g))
    f, i = jnp.bool_(False), jnp.int32(0)
    memory = memory_init()
    first = None if memory is None else jnp.bool_(True)
    return _Episode(state, obs, k_run, f, f, f, f, i, jnp.float32(0.0), memory, first)


@functools.lru_cache(maxsize=16)
def _cached_program(env_settings: tuple, policy: MemoryPolicy, chunk: int, observations: bool = False):
    env = NavEnv(**dict(env_settings))
    T = env.episode_length
    n_chunks = -(-T // chunk)
    init_one = functools.partial(_init_one, env, policy.init)

    def step_one(params, ep: _Episode, env_params):
        key, k_step = jax.random.split(ep.key)
        action, memory = policy.step(params, ep.obs, ep.memory, ep.first)
        obs, state, _, terminated, truncated, info = env.step(k_step, ep.env_state, action, env_params)
        moved = jnp.linalg.norm(info["pose"][:2] - ep.env_state.pose[:2])
        goal, collision = info["goal"], info["collision"]
        new = ep.replace(
            env_state=state,
            obs=obs,
            key=key,
            done=terminated | truncated,
            success=goal & ~collision,
            collision=collision,
            timeout=truncated & ~terminated,
            steps=ep.steps + 1,
            path=ep.path + moved,
            memory=memory,
            first=None if ep.first is None else jnp.bool_(False),
        )
        # Freeze after the end: a finished episode keeps its last state (and pose) for good.
        return jax.tree.map(lambda n, o: jnp.where(ep.done, o, n), new, ep)

    def run(agent_params, env_params, goal_index, keys):
        A, E = keys.shape[:2]
        G = goal_index.shape[0]
        goals_e = jnp.tile(goal_index, E // G)  # episode e = attempt * G + goal  (reordered below)
        ep = jax.vmap(jax.vmap(init_one, (0, 0, None)), (0, None, None))(keys, goals_e, env_params)
        # what each step records: the pose (and the observation there, with `observations`)
        track = (lambda ep: (ep.env_state.pose, ep.obs)) if observations else (lambda ep: ep.env_state.pose)
        start = track(ep)  # [A, E, ...]
        # agents x episodes: params vary over agents only
        step_all = jax.vmap(jax.vmap(step_one, (None, 0, None)), (0, 0, None))

        def inner(ep, _):
            ep = step_all(agent_params, ep, env_params)
            return ep, track(ep)

        buf = jax.tree.map(lambda x: jnp.zeros((n_chunks, chunk, *x.shape), x.dtype), start)

        def cond(carry):
            c, ep, _ = carry
            return (c < n_chunks) & jnp.any(~ep.done)

        def body(carry):
            c, ep, buf = carry
            ep, rows = jax.lax.scan(inner, ep, None, length=chunk)
            return c + 1, ep, jax.tree.map(lambda b, r: jax.lax.dynamic_update_index_in_dim(b, r, c, 0), buf, rows)

        _, ep, buf = jax.lax.while_loop(cond, body, (jnp.int32(0), ep, buf))
        # Chunks skipped by the early exit are zeros: every row at or after an episode's end is
        # its final one (frozen), so fill those from the final state.
        t = jnp.arange(1, T + 1)[:, None, None, None]

        def trajectory(b, first, last):  # [T + 1, A, E, ...] -> [A, E, T + 1, ...]
            b = jnp.where(t <= ep.steps[None, :, :, None], b.reshape(n_chunks * chunk, *b.shape[2:])[:T], last[None])
            return jnp.moveaxis(jnp.concatenate([first[None], b], axis=0), 0, 2)

        rows = jax.tree.map(trajectory, buf, start, track(ep))
        out = {
            "success": ep.success,
            "collision": ep.collision,
            "timeout": ep.timeout,
            "steps": ep.steps,
            "path": ep.path,
            "poses": rows[0] if observations else rows,
            **({"obs": rows[1]} if observations else {}),
        }
        # [A, E] -> [A, K, G] -> [A, G, K]
        return jax.tree.map(lambda x: jnp.swapaxes(x.reshape(A, E // G, G, *x.shape[2:]), 1, 2), out)

    return jax.jit(run)


def episode_state(env_settings: dict, env_params, policy=None):
    """The shapes of one episode's running state (`jax.eval_shape`: nothing is allocated) under
    `env_settings` with one room's `env_params` (arrays or ShapeDtypeStructs), the policy's memory
    included (`policy`: a MemoryPolicy; None or a plain function: no memory), for
    `limits.check_eval_memory`."""
    memory_init = as_memory_policy(policy).init if policy is not None else no_memory
    init = functools.partial(_init_one, NavEnv(**env_settings), memory_init)
    return jax.eval_shape(init, jax.random.key(0), jnp.int32(0), env_params)


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
    robot: dict | None = None,
    env_settings: dict | None = None,
    memory_budget: int | None = None,
    **env_overrides,
) -> EvalResult:
    """Run the protocol for any policy: every agent x goal x attempt, one jitted program.

    policy: `policy(agent_params, obs) -> action` (or a `MemoryPolicy`, carrying its memory through
        each episode) when `params` is given, with `params` a pytree
        whose leaves have a leading agent axis [A]; `policy(obs) -> action` when `params` is None
        (one agent unless `num_agents` says otherwise, all identical). `obs` is the env's
        observation f32[num_beams + 4] (ranges, goal distance, goal bearing, previous action);
        the action is in the env's units (v / v_max, omega / omega_max). The policy is traced
        once per (policy, env settings): pass the same function object to reuse the compilation.
    world: a World (unstacked), a shipped name or a world file. goals: rows of the world's goals
        (default: all of them). Start 0 is always the start.
    max_steps: T, the time-out. range_noise / action_noise: Gaussian stds (m; action units).
    env_overrides: EnvParams fields (dt, v_max, omega_max, goal_radius, collision_distance, ...).
    robot: NavEnv's static robot-model settings (`RobotConfig.env_settings()` without `noise`; the
        model's traced values go in env_overrides); None: the ideal robot.
    env_settings: NavEnv's keyword arguments as a run builds them (`config.envs.env_settings`);
        when given they replace num_beams, max_range, collision_test and robot (and max_steps is
        its episode_length).
    memory_budget: bytes the evaluation may take (default: the memory available now); one whose
        estimate (`limits.eval_memory`) exceeds it is refused (EvalError) before anything is allocated.
    """
    if not isinstance(world, World):
        world = _worlds.load(world)
    goal_rows = _checked_goal_rows(world, goals, attempts, max_steps, range_noise, action_noise)
    A, fn, agent_params = _policy_agents(policy, params, num_agents)

    settings = _eval_settings(env_settings, num_beams, max_range, collision_test, robot, max_steps)
    env_params = make_params(world, range_noise=range_noise, action_noise=action_noise, **env_overrides)
    G, K = len(goal_rows), int(attempts)
    state = episode_state(settings, env_params, fn)
    check_eval_memory(settings, state, (A, G, K), chunk, budget=memory_budget)
    keys = jax.random.split(jax.random.key(seed), A * G * K).reshape(A, G * K)
    t0 = time.time()
    program = eval_program(settings, fn, min(int(chunk), int(max_steps)))
    out = program(agent_params, env_params, jnp.asarray(goal_rows, jnp.int32), keys)
    out = jax.device_get(out)
    wall = time.time() - t0
    return EvalResult(
        success=np.asarray(out["success"]),
        collision=np.asarray(out["collision"]),
        timeout=np.asarray(out["timeout"]),
        steps=np.asarray(out["steps"]),
        path_length=np.asarray(out["path"]),
        poses=np.asarray(out["poses"]),
        goals=np.asarray(world.goals)[goal_rows],
        goal_index=np.asarray(goal_rows, np.int32),
        start=np.asarray(world.starts[0]),
        dt=round(float(env_params.dt), 7),
        goal_radius=round(float(env_params.goal_radius), 7),
        max_steps=int(max_steps),
        range_noise=float(range_noise),
        action_noise=float(action_noise),
        seed=int(seed),
        wall_s=wall,
    )


def _eval_settings(env_settings, num_beams, max_range, collision_test, robot, max_steps) -> dict:
    """NavEnv's settings of an evaluation: `env_settings` (else the sensor's and robot's), eval mode, noise on."""
    if env_settings is None:
        sensor = {"num_beams": int(num_beams), "max_range": float(max_range), "collision_test": str(collision_test)}
        env_settings = {**sensor, **(robot or {})}
    return {**env_settings, "episode_length": int(max_steps), "mode": "eval", "noise": True}


def _checked_goal_rows(world: World, goals, attempts, max_steps, range_noise, action_noise) -> list[int]:
    """The world's goal rows to evaluate, the counts and noise stds checked (EvalError otherwise)."""
    check_counts(attempts, max_steps)
    if not (0 <= range_noise < float("inf") and 0 <= action_noise < float("inf")):  # NaN fails too
        raise EvalError(
            f"noise stds must be finite and >= 0, got range_noise={range_noise}, action_noise={action_noise}"
        )
    n_goals = int(world.num_goals)
    goal_rows = list(range(n_goals)) if goals is None else [int(g) for g in goals]
    bad = [g for g in goal_rows if not 0 <= g < n_goals]
    if bad or not goal_rows:
        raise EvalError(f"goals must be rows 0..{n_goals - 1} of the world's goals, got {goals}")
    return goal_rows


def _policy_agents(policy: Callable, params: Any, num_agents: int | None) -> tuple[int, Callable, Any]:
    """(A, the policy as `fn(agent_params, obs)`, the agent params with their leading axis [A])."""
    if params is None:
        A = int(num_agents or 1)
        return A, _wrap_obs_only(policy), jnp.zeros((A,))  # a dummy leaf carrying the agent axis
    leaves = jax.tree.leaves(params)
    if not leaves:
        raise EvalError("params has no leaves")
    A = int(leaves[0].shape[0])
    if num_agents is not None and num_agents != A:
        raise EvalError(f"num_agents={num_agents} but params have {A} agents on their leading axis")
    return A, policy, params
