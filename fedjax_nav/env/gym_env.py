"""A `gymnasium.Env` for one robot in one playground (optional extra: `pip install fedjax_nav[gym]`).

For single-agent libraries (Stable-Baselines3 and the like) that step one environment from Python.
It wraps `NavEnv` with a jitted `reset` and `step` (compiled once per instance on first use);
each call crosses to the host once. For speed, batch `NavEnv` with `jax.vmap` instead.

- observation: Box(num_beams + 4,) float32, as NavEnv's: ranges in [0, max_range], goal distance
  (m, >= 0), goal bearing in [-pi, pi], previous action in the network's units.
- action: Box([0, -1], [1, 1]) float32, (v / v_max, omega / omega_max), the actor's output units.
- `terminated`: goal reached or collision (NavEnv in "eval" mode: nothing is reset inside the
  env, the caller calls `reset`); `truncated`: `episode_length` steps without terminating.
  The two are never both true.
- info: `goal`, `collision` (bool), `pose` (x, y, theta after the move), `clearance` (m).
- render(): this wrapper draws nothing (`render_mode` must be None; `render()` returns None).
  Use `fedjax_nav.env.render` for pictures of rollouts.

Importing this module registers the env with gymnasium as `"fedjax_nav/Nav-v0"` (`ENV_ID`);
keyword arguments of `gymnasium.make` go to `NavGymEnv`:

    import gymnasium
    import fedjax_nav.env.gym_env  # noqa: F401  (registers fedjax_nav/Nav-v0)

    env = gymnasium.make("fedjax_nav/Nav-v0", world="train-2", episode_length=512)

or, without importing fedjax_nav first (gymnasium imports the module named before the colon):
`gymnasium.make("fedjax_nav.env.gym_env:fedjax_nav/Nav-v0", world="train-2")`. No
`max_episode_steps` is registered: the env truncates at its own `episode_length`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium import spaces

from fedjax_nav import worlds
from fedjax_nav.env.nav import NavEnv, make_params

ENV_ID = "fedjax_nav/Nav-v0"


class NavGymEnv(gymnasium.Env):
    """One robot in one world (a shipped name such as "train-0", or a world file's path).

    `random_starts`: draw the start from the world's starts at every reset (else start 0).
    `goal_index`: which of the world's goals. Other keyword arguments are EnvParams fields
    (v_max, omega_max, dt, goal_radius, reward_goal, ...).
    """

    metadata = {"render_modes": []}

    def __init__(
        self,
        world: str | Path = "train-0",
        *,
        num_beams: int = 24,
        max_range: float = 3.5,
        episode_length: int = 1024,
        collision_test: str = "exact",
        random_starts: bool = False,
        goal_index: int = 0,
        render_mode: str | None = None,
        **param_overrides: Any,
    ):
        if render_mode is not None:
            raise ValueError(f"NavGymEnv draws nothing: render_mode must be None, got {render_mode!r}")
        self.render_mode = None
        self.world_name = str(world)
        self.nav = NavEnv(num_beams, max_range, episode_length, mode="eval", collision_test=collision_test)
        self.params = make_params(
            worlds.load(world), random_starts=random_starts, goal_index=goal_index, **param_overrides
        )
        # the goal distance can never exceed the room's diagonal plus the longest possible drive
        w = self.params.world
        dmax = float(np.hypot(*np.asarray(w.size))) + float(self.params.v_max * self.params.dt) * episode_length
        low = np.array([0.0] * num_beams + [0.0, -np.pi, 0.0, -1.0], np.float32)
        high = np.array([max_range] * num_beams + [dmax, np.pi, 1.0, 1.0], np.float32)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self.action_space = spaces.Box(
            np.array([0.0, -1.0], np.float32), np.array([1.0, 1.0], np.float32), dtype=np.float32
        )
        nav = self.nav

        def reset(key, params):
            k, k_next = jax.random.split(key)
            obs, state = nav.reset(k, params)
            return obs, state, k_next

        def step(key, state, action, params):
            k, k_next = jax.random.split(key)
            obs, state, reward, term, trunc, info = nav.step(k, state, action, params)
            # observation bounds: the float32 bearing may round a hair past +-pi
            obs = obs.at[num_beams + 1].set(jnp.clip(obs[num_beams + 1], -np.float32(np.pi), np.float32(np.pi)))
            return (obs, reward, term, trunc, info), state, k_next

        self._reset = jax.jit(reset)
        self._step = jax.jit(step)
        self._state = None
        self._key = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if self._key is None or seed is not None:
            self._key = jax.random.key(int(self.np_random.integers(0, 2**31 - 1)))
        obs, self._state, self._key = self._reset(self._key, self.params)
        return np.asarray(obs, np.float32), {}

    def step(self, action):
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        a = jnp.asarray(np.asarray(action, np.float32).reshape(2))
        out, self._state, self._key = self._step(self._key, self._state, a, self.params)
        obs, reward, term, trunc, info = jax.device_get(out)
        info = {
            "goal": bool(info["goal"]),
            "collision": bool(info["collision"]),
            "pose": np.asarray(info["pose"]),
            "clearance": float(info["clearance"]),
        }
        return np.asarray(obs, np.float32), float(reward), bool(term), bool(trunc), info

    def render(self):
        return None


def register() -> None:
    """Register `NavGymEnv` with gymnasium as `ENV_ID` (done on import; a second call is a no-op).

    `gymnasium.make(ENV_ID, **kwargs)` passes `kwargs` to `NavGymEnv` (world, episode_length,
    random_starts, EnvParams overrides, ...). No `max_episode_steps`: the env's own
    `episode_length` truncates.
    """
    if ENV_ID not in gymnasium.registry:
        gymnasium.register(id=ENV_ID, entry_point="fedjax_nav.env.gym_env:NavGymEnv")


register()
