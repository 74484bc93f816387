"""A `gymnasium.Env` for one robot (optional extra: `pip install fedjax_nav[gym]`).

For single-agent libraries (Stable-Baselines3, CleanRL and the like) that step one environment
from Python. It runs `fedjax_nav.env.gym_task` (NavEnv in "eval" mode) with a jitted `reset`
and `step` compiled once per set of settings and shared by every instance; each call crosses to
the host once. For many environments at once use the vmap vector env (`gym_vector`), which
`gymnasium.make_vec(ENV_ID, n)` builds by default.

- observation: Box(num_beams + 4,) float32, as NavEnv's: ranges in [0, max_range], goal distance
  (m, >= 0), goal bearing in [-pi, pi], previous action in the network's units. `plan=True`
  (docs/planning.md): Box(num_beams + 5,), the waypoint's distance and bearing for the goal's,
  the goal's distance last.
- action: Box([0, -1], [1, 1]) float32, (v / v_max, omega / omega_max), the actor's output units.
- `terminated`: goal reached or collision (nothing is reset inside the env: the caller calls
  `reset`); `truncated`: `episode_length` steps without terminating. Never both.
- info: `goal`, `collision` (bool), `pose` (x, y, theta after the move), `clearance` (m).
- seeds: `reset(seed=s)` seeds the episode's draws. With the defaults (the world's start 0 and
  goal 0, no noise) every episode is the same one; `placement="random"` (start pose and goal
  drawn in the free space), `rooms="procedural"` (a fresh generated room per reset),
  `random_starts=True` (one of the world's starts) or `noise=True` with a `range_noise` /
  `action_noise` above 0 make seeds matter.
- render: `render_mode="rgb_array"` gives `render()` -> uint8[render_size, render_size, 3]
  (`gym_task.frame`); `render_fps` = 1 / dt.
- pickling (and `copy.deepcopy`) keeps the settings, the episode and the random stream.
- fork: JAX deadlocks in a process forked after JAX started, so constructing the env in such a
  process raises a RuntimeError at once (gymnasium's `AsyncVectorEnv` forks by default, after
  building one env in the parent): use `vector_kwargs={"context": "spawn"}` or the vmap env.

`import fedjax_nav` registers `"fedjax_nav/Nav-v0"` (`ENV_ID`) with gymnasium, with the vmap
`NavVectorEnv` as its vector entry point (importing neither gymnasium nor jax: see
`fedjax_nav.register_gymnasium`); keyword arguments of `gymnasium.make` (and `make_vec`) go to
`NavGymEnv` (and `NavVectorEnv`):

    import gymnasium
    import fedjax_nav

    gymnasium.register_envs(fedjax_nav)  # gymnasium's convention (the import registered it)

    env = gymnasium.make("fedjax_nav/Nav-v0", world="train-2", episode_length=512)
    envs = gymnasium.make_vec("fedjax_nav/Nav-v0", num_envs=64, placement="random")

or, without importing fedjax_nav first: `gymnasium.make("fedjax_nav:fedjax_nav/Nav-v0")` (gymnasium
imports the module named before the colon).
No `max_episode_steps` is registered: the env truncates at its own `episode_length`.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np

from fedjax_nav import GYM_ENV_ID, GYM_VECTOR_ENTRY_POINT, register_gymnasium
from fedjax_nav.env import gym_task

# the id and entry points are the package's (`import fedjax_nav` registers them, gymnasium unimported)
ENV_ID = GYM_ENV_ID
VECTOR_ENTRY_POINT = GYM_VECTOR_ENTRY_POINT

# ----------------------------------------------------------------------------- fork guard
#
# A child forked after JAX started in its parent inherits JAX's locks but not its threads: its
# first JAX call hangs for ever. Refusing to build the env there turns that hang into an error.

_jax_started = False  # set by every env built in this process
_forked_after_jax = False


def _note_fork_in_child() -> None:
    """Runs in every child of os.fork (only Python-level forks: subprocess's fork-exec does not).
    Takes no lock: a lock held by another thread at the fork would never be released here."""
    global _forked_after_jax
    # Also JAX started by the user's own code: jax's table of initialised backends, read without
    # its lock (a private name, so best effort; our own flag covers the envs built here).
    backends = getattr(sys.modules.get("jax._src.xla_bridge"), "_backends", None)
    _forked_after_jax = _forked_after_jax or _jax_started or bool(backends)


os.register_at_fork(after_in_child=_note_fork_in_child)


def refuse_forked_child(what: str) -> None:
    """RuntimeError if this process was forked after JAX started (where JAX would hang); else
    note that JAX is in use in this process."""
    global _jax_started
    if _forked_after_jax:
        raise RuntimeError(
            f"{what}: this process was forked after JAX had started in its parent, and JAX hangs after a fork; "
            "build the async vector env with vector_kwargs={'context': 'spawn'} (or 'forkserver'), "
            f"or use the vmap vector env: gymnasium.make_vec('{ENV_ID}', num_envs)"
        )
    _jax_started = True


# ----------------------------------------------------------------------------- the env


class NavGymEnv(gymnasium.Env):
    """One robot in one world (a shipped name such as "train-0", or a world file's path).

    placement: "world" (start 0, or with `random_starts=True` one of the world's starts; goal
    `goal_index`) or "random" (start pose and goal drawn in the free space at every reset).
    rooms: "world" or "procedural" (a new room of `room_family` per reset, `room_spec`: RoomSpec
    overrides; leave `world` unset). noise: range and action noise with the stds `range_noise`,
    `action_noise` (both 0 unless given). Other keyword arguments are EnvParams fields (v_max, omega_max, dt,
    goal_radius, reward_goal, ...).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        world: str | Path | None = None,
        *,
        num_beams: int = 24,
        max_range: float = 3.5,
        episode_length: int = 1024,
        collision_test: str = "exact",
        random_starts: bool = False,
        goal_index: int = 0,
        placement: str = "world",
        rooms: str = "world",
        room_family: str = "mixture",
        room_spec: dict | None = None,
        noise: bool = False,
        render_mode: str | None = None,
        render_size: int = 256,
        **param_overrides: Any,
    ):
        refuse_forked_child(type(self).__name__)
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if int(render_size) < 16:
            raise ValueError(f"render_size must be >= 16 pixels, got {render_size}")
        self._kwargs = dict(
            world=world,
            num_beams=num_beams,
            max_range=max_range,
            episode_length=episode_length,
            collision_test=collision_test,
            random_starts=random_starts,
            goal_index=goal_index,
            placement=placement,
            rooms=rooms,
            room_family=room_family,
            room_spec=room_spec,
            noise=noise,
            render_mode=render_mode,
            render_size=render_size,
            **param_overrides,
        )
        self.task, self.params, self.world_name = gym_task.make_task(
            world,
            num_beams=num_beams,
            max_range=max_range,
            episode_length=episode_length,
            collision_test=collision_test,
            noise=noise,
            placement=placement,
            rooms=rooms,
            room_family=room_family,
            room_spec=room_spec,
            random_starts=random_starts,
            goal_index=goal_index,
            **param_overrides,
        )
        self.nav = self.task.nav
        self.render_mode = render_mode
        self.render_size = int(render_size)
        self.metadata = {**self.metadata, "render_fps": 1.0 / float(self.params.dt)}
        self.observation_space, self.action_space = gym_task.gym_spaces(self.task, self.params)
        self._state = None  # (EnvState, this episode's EnvParams, last obs) once reset
        self._key: jax.Array | None = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if self._key is None or seed is not None:
            self._key = jax.random.key(int(self.np_random.integers(0, 2**31 - 1)))
        obs, state, params, self._key = gym_task.jit_reset(self.task, self._key, self.params)
        self._state = (state, params, obs)
        return np.asarray(obs, np.float32), {}

    def step(self, action):
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        a = jnp.asarray(np.asarray(action, np.float32).reshape(2))
        state, params, _ = self._state
        out, state, self._key = gym_task.jit_step(self.task, self._key, state, a, params)
        self._state = (state, params, out[0])
        obs, reward, term, trunc, info = jax.device_get(out)
        info = {
            "goal": bool(info["goal"]),
            "collision": bool(info["collision"]),
            "pose": np.asarray(info["pose"]),
            "clearance": float(info["clearance"]),
        }
        return np.asarray(obs, np.float32), float(reward), bool(term), bool(trunc), info

    def render(self):
        """render_mode="rgb_array": uint8[render_size, render_size, 3] of the current state; else None."""
        if self.render_mode is None:
            return None
        if self._state is None:
            raise RuntimeError("call reset() before render()")
        return np.asarray(gym_task.jit_frame(self.task, *self._state, self.render_size))

    # ------------------------------------------------------------------ pickling
    # The jitted functions are module-level (never pickled); an instance is its settings, its
    # episode state and its random streams, rebuilt with __init__ on loading.

    def __getstate__(self) -> dict:
        key = None if self._key is None else np.asarray(jax.random.key_data(self._key))
        return {
            "kwargs": self._kwargs,
            "state": None if self._state is None else jax.device_get(self._state),
            "key": key,
            "np_random": self._np_random,
            "np_random_seed": self._np_random_seed,
        }

    def __setstate__(self, d: dict) -> None:
        self.__init__(**d["kwargs"])
        self._state = None if d["state"] is None else jax.tree.map(jnp.asarray, d["state"])
        self._key = None if d["key"] is None else jax.random.wrap_key_data(jnp.asarray(d["key"]))
        self._np_random, self._np_random_seed = d["np_random"], d["np_random_seed"]


def register() -> None:
    """Register `NavGymEnv` with gymnasium as `ENV_ID`, with `NavVectorEnv` as its vector entry
    point (done on import; a second call is a no-op). No `max_episode_steps`: the env's own
    `episode_length` truncates. `import fedjax_nav` has already done it (`fedjax_nav.register_gymnasium`)."""
    register_gymnasium()


register()
