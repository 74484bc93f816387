"""A uniform random policy driven through `NavEnv(mode="learn")`, and its cut into episodes: the
trajectories `fedjax-nav render` draws (fedjax_nav.env.render)."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from fedjax_nav import worlds as _worlds
from fedjax_nav.worlds import World

GOAL_RADIUS = 0.5  # D_g
_PAD = {"segments": 48, "circles": 24, "starts": 4, "goals": 4}  # bucket sizes of the rollout cache


@functools.lru_cache(maxsize=8)
def _rollout_fn(steps: int):
    import jax
    import jax.numpy as jnp

    from fedjax_nav.env.nav import NavEnv, make_params

    env = NavEnv(mode="learn", episode_length=steps + 1)

    @jax.jit
    def run(world: World, key: jax.Array):
        params = make_params(world)
        k_reset, k_act, k_env = jax.random.split(key, 3)
        _, state = env.reset(k_reset, params)
        actions = jax.random.uniform(k_act, (steps, 2), minval=jnp.array([0.0, -1.0]), maxval=1.0)

        def body(state, xs):
            a, k = xs
            _, state, _, terminated, _, info = env.step(k, state, a, params)
            return state, (info["pose"], terminated)

        _, (poses, terminated) = jax.lax.scan(body, state, (actions, jax.random.split(k_env, steps)))
        return poses, terminated

    return run


def random_rollout(world: World | str | Path, steps: int = 300, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Drive a uniform random policy (v/v_max in [0, 1], omega/omega_max in [-1, 1]) for `steps`
    steps in `NavEnv(mode="learn")` with default EnvParams (start 0, goal 0), in one jitted scan.

    Returns (poses f32[steps, 3], terminated bool[steps]): `poses[t]` is the pose after step t,
    before any reset, so a terminated step's pose is where the robot hit or reached the goal;
    the next pose continues from the start. World may be a name or path.
    """
    import jax

    if not isinstance(world, World):
        world = _worlds.load(world)
    steps = int(steps)
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    world = _pad_for_cache(world)
    poses, terminated = _rollout_fn(steps)(world, jax.random.PRNGKey(seed))
    return np.asarray(poses), np.asarray(terminated)


def _pad_for_cache(world: World) -> World:
    """Pad to shared bucket sizes so that worlds of similar size reuse one compiled rollout."""
    dims = []
    for field in ("segments", "circles", "starts", "goals"):
        n, b = getattr(world, field).shape[0], _PAD[field]
        dims.append(max(b, -(-n // b) * b))
    return _worlds.pad(world, *dims)


def split_episodes(
    world: World, poses: np.ndarray, terminated: np.ndarray, goal_radius: float = GOAL_RADIUS
) -> tuple[list[np.ndarray], list[str | None]]:
    """Cut a learn-mode rollout (start 0, goal 0) into pieces at its terminal steps.

    Returns the paths ([n, 2], each beginning at start 0) and their outcomes: "success",
    "collision", or None for the last, unfinished piece.
    """
    start = np.asarray(world.starts[0, :2], np.float64)
    goal = np.asarray(world.goals[0], np.float64)
    paths, outcomes, begin = [], [], 0
    xy = np.asarray(poses)[:, :2]
    for t in np.flatnonzero(np.asarray(terminated)):
        paths.append(np.concatenate([start[None], xy[begin : t + 1]]))
        outcomes.append("success" if np.linalg.norm(xy[t] - goal) < goal_radius else "collision")
        begin = t + 1
    if begin < len(xy):
        paths.append(np.concatenate([start[None], xy[begin:]]))
        outcomes.append(None)
    return paths, outcomes
