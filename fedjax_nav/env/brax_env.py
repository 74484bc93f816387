"""A `brax.envs.Env` over the navigation task, for brax's trainers (PPO, SAC) and wrappers.

This is the only module of the package that imports brax, so import it only where you use it
(brax's import is slow). mujoco's mjx prints two "Failed to import warp" lines when brax imports
it; this module swallows exactly those two lines of its brax import (any other output is passed on).

    import fedjax_nav.env.brax_env  # noqa: F401  (registers "fedjax_nav", installs the jax shim)
    from brax import envs
    from brax.training.agents.ppo import train as ppo

    env = envs.get_environment("fedjax_nav", worlds=["train-0", "train-2"])  # a BraxNavEnv
    make_policy, params, metrics = ppo.train(env, num_timesteps=..., episode_length=1024, ...)

Importing this module registers the env with brax's registry as `"fedjax_nav"` (`ENV_NAME`), so
`brax.envs.get_environment("fedjax_nav", worlds=[...], **kwargs)` builds a `BraxNavEnv` and
`brax.envs.create("fedjax_nav", episode_length=..., batch_size=..., **kwargs)` wraps it in brax's
training wrappers, as for brax's own environments. The same import (`register`) installs
`fedjax_nav.env.brax_compat`'s `jax.device_put_replicated` if jax lacks it, which brax 0.14.2's
`ppo.train` and `sac.train` need on jax >= 0.10: they then train the env as they are.

Semantics (those of `NavEnv(mode="eval")`):
- `reset(rng)` picks a playground uniformly at random (or the fixed `playground`), puts the robot
  at its start and returns a `State` whose `pipeline_state` is a `NavPipelineState` (the
  `EnvState` and the playground index): brax's `AutoResetWrapper` restores only
  `pipeline_state` and `obs`, so everything needed to step lives there.
- `step(state, action)`: brax actions are in [-1, 1]^2 and map to NavEnv's units as
  `v / v_max = (a0 + 1) / 2` in [0, 1] and `omega / omega_max = a1` in [-1, 1] (clipped first).
  `done = terminated | truncated` (goal or collision, or the env's own time limit). Nothing is
  reset inside the env: auto-reset is the wrapper's job.
- `info["truncation"]` (1.0 when the episode ended by the time limit and not by goal/collision,
  brax's convention) and `info["time_out"]` (the same, for ppo's `bootstrap_on_timeout=True`);
  `info["rng"]` holds the key for the next step (advanced every step).
- `metrics["goal"]`, `metrics["collision"]` (0./1. on the step), updated by key so that keys
  added by wrappers survive.

Time limits and brax's EpisodeWrapper: the trainers wrap the env in `EpisodeWrapper`, which sets
`done` at its own `episode_length` and OVERWRITES `info["truncation"]` every step (1 only where
its own limit fires and the env is not done). If the env's own limit fired at the same step, that
step would count as a termination. So for brax training leave `episode_length=None` (the default:
no time limit in the env) and give the limit to the trainer; set `episode_length` only to use
the env unwrapped (or with ppo's `bootstrap_on_timeout=True`, which reads `info["time_out"]`).

Playgrounds under auto-reset: `AutoResetWrapper` restores the state from the *first* reset of
each parallel env, so each env slot keeps the playground (and start) drawn at that reset for the
whole run (brax re-resets only every `num_resets_per_eval` in ppo). Use `num_envs` well above the
number of playgrounds, or `random_starts`, for variety.

Keys: brax's wrappers expect old-style `jax.random.PRNGKey` keys (uint32[2]); `reset` also takes a
new-style typed key when used unwrapped.
"""

from __future__ import annotations

import contextlib
import io
import sys
from pathlib import Path
from typing import Any, Sequence, Union

import jax
import jax.numpy as jnp
from flax import struct

from fedjax_nav.env.brax_compat import ensure_device_put_replicated
from fedjax_nav.env.nav import EnvParams, EnvState, NavEnv, make_params
from fedjax_nav.worlds import World, load_many, stack

# What mujoco's mjx prints (with print, to stdout) when brax imports it and the optional `warp`
# package is missing: "Failed to import warp: ..." and "Failed to import mujoco_warp: ...".
_WARP_NOISE = ("Failed to import warp:", "Failed to import mujoco_warp:")


def _echo_unless_warp_noise(captured: str) -> None:
    """Print what the brax import printed, less mjx's two warp lines."""
    kept = [line for line in captured.splitlines(keepends=True) if not line.startswith(_WARP_NOISE)]
    if kept:
        sys.stdout.write("".join(kept))


# Only the brax import runs with stdout captured (a no-op when brax is already imported).
with contextlib.redirect_stdout(io.StringIO()) as _captured:
    from brax import envs as brax_envs
    from brax.envs.base import Env, State
_echo_unless_warp_noise(_captured.getvalue())
del _captured

WorldsLike = Union[str, Path, Sequence[Union[str, Path]], World]

ENV_NAME = "fedjax_nav"  # the name in brax's environment registry

# "No time limit": NavEnv counts steps in int32; this is never reached in practice.
_NO_LIMIT = 2**30


@struct.dataclass
class NavPipelineState:
    """What brax's AutoResetWrapper restores on done: the robot state and its playground."""

    nav: EnvState
    playground: jax.Array  # i32[] index into the env's stacked worlds


def _as_stacked_world(worlds: WorldsLike) -> World:
    if isinstance(worlds, World):
        if worlds.segments.ndim == 2:
            return stack([worlds])
        if worlds.segments.ndim == 3:
            return worlds
        raise ValueError(
            f"worlds: a World with segments of shape {tuple(worlds.segments.shape)}; expected "
            "[M, 4] (one playground) or [P, M, 4] (stacked playgrounds)"
        )
    if isinstance(worlds, (str, Path)):
        worlds = [worlds]
    worlds = list(worlds)
    if not worlds:
        raise ValueError("worlds: at least one playground name or file is needed")
    return load_many(worlds)


class BraxNavEnv(Env):
    """The navigation task as a brax `Env` over one or several playgrounds (see module doc).

    Args:
      worlds: a shipped world name or a world file, a list of them, or a `World` (one playground,
        or a stacked World with a leading playground axis as from `worlds.load_many`).
      playground: None to draw a playground uniformly at each reset, or a fixed index.
      episode_length: the env's own time limit in steps; None (default) for none, which is what
        brax's trainers want (they add an EpisodeWrapper with their `episode_length`).
      num_beams: lidar beams, as in `NavEnv`.
      max_range: lidar range in m, as in `NavEnv`.
      collision_test: "exact" or "lidar", as in `NavEnv`.
      noise: sensor and actuation noise on, as in `NavEnv`.
      plan: the global plan's waypoint in the observation, as in `NavEnv` (docs/planning.md;
        its lookahead is the `EnvParams` field `plan_lookahead`).
      plan_cells: the plan's grid cells per side, as in `NavEnv`.
      **param_overrides: `EnvParams` fields (e.g. `goal_index=1`, `random_starts=True`,
        `v_max=0.3`), scalars or arrays with one entry per playground.
    """

    def __init__(
        self,
        worlds: WorldsLike = "train-0",
        *,
        playground: int | None = None,
        episode_length: int | None = None,
        num_beams: int = 24,
        max_range: float = 3.5,
        collision_test: str = "exact",
        noise: bool = False,
        plan: bool = False,
        plan_cells: int = 64,
        **param_overrides: Any,
    ):
        world = _as_stacked_world(worlds)
        self.num_playgrounds = int(world.segments.shape[0])
        if playground is not None:
            playground = int(playground)
            if not 0 <= playground < self.num_playgrounds:
                raise ValueError(f"playground must be None or in [0, {self.num_playgrounds - 1}], got {playground}")
        if episode_length is not None and int(episode_length) < 1:
            raise ValueError(f"episode_length must be None or >= 1, got {episode_length}")
        self.playground = playground
        self.episode_length = None if episode_length is None else int(episode_length)
        self.nav = NavEnv(
            num_beams=num_beams,
            max_range=max_range,
            episode_length=_NO_LIMIT if episode_length is None else int(episode_length),
            mode="eval",
            collision_test=collision_test,
            noise=noise,
            plan=plan,
            plan_cells=plan_cells,
        )
        self.params: EnvParams = make_params(world, **param_overrides)  # leaves [P, ...]

    # ----------------------------------------------------------------- brax API

    @property
    def observation_size(self) -> int:
        return self.nav.obs_size

    @property
    def action_size(self) -> int:
        return 2

    @property
    def backend(self) -> str:
        return "jax"

    def params_at(self, playground: jax.Array | int) -> EnvParams:
        """EnvParams of one playground (a static slice for a fixed index, else a gather)."""
        return jax.tree.map(lambda x: x[playground], self.params)

    def reset(self, rng: jax.Array) -> State:
        k_pg, k_reset, k_next = jax.random.split(rng, 3)
        if self.playground is None:
            idx = jax.random.randint(k_pg, (), 0, self.num_playgrounds, dtype=jnp.int32)
            params = self.params_at(idx)
        else:
            idx = jnp.int32(self.playground)
            params = self.params_at(self.playground)
        obs, nav_state = self.nav.reset(k_reset, params)
        zero = jnp.zeros((), jnp.float32)
        return State(
            pipeline_state=NavPipelineState(nav=nav_state, playground=idx),
            obs=obs,
            reward=zero,
            done=zero,
            metrics={"goal": zero, "collision": zero},
            info={"rng": k_next, "truncation": zero, "time_out": zero},
        )

    def step(self, state: State, action: jax.Array) -> State:
        key, k_step = jax.random.split(state.info["rng"])
        a = jnp.clip(action, -1.0, 1.0)
        nav_action = jnp.stack([(a[0] + 1.0) * 0.5, a[1]])
        ps: NavPipelineState = state.pipeline_state
        params = self.params_at(ps.playground if self.playground is None else self.playground)
        obs, nav_state, reward, terminated, truncated, info = self.nav.step(k_step, ps.nav, nav_action, params)
        # NavEnv(mode="eval") already has truncated = time limit & ~terminated (brax's convention).
        done = (terminated | truncated).astype(jnp.float32)
        trunc = truncated.astype(jnp.float32)
        metrics = dict(state.metrics)
        metrics.update(goal=info["goal"].astype(jnp.float32), collision=info["collision"].astype(jnp.float32))
        new_info = dict(state.info)
        new_info.update(rng=key, truncation=trunc, time_out=trunc)
        return state.replace(
            pipeline_state=ps.replace(nav=nav_state),
            obs=obs,
            reward=reward.astype(jnp.float32),
            done=done,
            metrics=metrics,
            info=new_info,
        )


def register() -> None:
    """Register `BraxNavEnv` in brax's environment registry as `ENV_NAME` (done on import).

    `brax.envs.get_environment(ENV_NAME, **kwargs)` then calls `BraxNavEnv(**kwargs)`
    (`worlds=...`, `playground=...`, EnvParams overrides, ...). Registering again is harmless.
    Also installs `brax_compat.device_put_replicated` as `jax.device_put_replicated` when jax
    lacks it (jax >= 0.10), so that brax's `ppo.train` / `sac.train` run on the registered env
    without the caller doing anything; idempotent, and a jax that has the function keeps its own.
    """
    ensure_device_put_replicated()
    brax_envs.register_environment(ENV_NAME, BraxNavEnv)


register()
