"""A `gymnasium.vector.VectorEnv` of many robots stepped by one jitted, vmapped program.

`gymnasium.make_vec("fedjax_nav/Nav-v0", num_envs)` builds it (it is the id's vector entry point,
which make_vec uses by default). Each sub-environment is exactly a `NavGymEnv` with the same
settings: the same task (`gym_task`), the same seeding (sub-env i of `reset(seed=s)` is
`NavGymEnv.reset(seed=s + i)`) and the same key use per step, so its episodes equal those of
gymnasium's `SyncVectorEnv` over `NavGymEnv`s (tests/test_gym.py checks it) while one `step`
is one compiled call and one host transfer for all `num_envs` robots (docs/gym.md: speed).

- observations f32[num_envs, num_beams + 4]; actions f32[num_envs, 2] in [0, 1] x [-1, 1];
  rewards f64[num_envs] (as SyncVectorEnv), terminations / truncations bool[num_envs].
- infos: `goal`, `collision`, `pose`, `clearance` as arrays with gymnasium's `_name` masks.
- autoreset_mode: NEXT_STEP (gymnasium's default: the step after an episode's end resets that
  sub-env, ignores its action and reports reward 0), SAME_STEP (the reset happens in the same
  step; `infos["final_obs"]` / `infos["final_info"]` hold the last observation and info) or
  DISABLED (the caller resets with `reset(options={"reset_mask": mask})`).
- render_mode="rgb_array": `render()` -> a tuple of num_envs uint8[render_size, render_size, 3].
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from fedjax_nav.env import gym_task
from fedjax_nav.env.gym_env import refuse_forked_child

INFO_KEYS = ("goal", "collision", "pose", "clearance")


def _select(mask: jax.Array, a, b):
    """Per sub-env choice between two batched pytrees (mask bool[n])."""
    return jax.tree.map(lambda x, y: jnp.where(mask.reshape(mask.shape + (1,) * (x.ndim - 1)), x, y), a, b)


def _reset_all(spec, kd, base):
    """Every sub-env reset from its key data kd u32[n, 2]: (obs, (EnvState, EnvParams), key data)."""
    reset = jax.vmap(functools.partial(gym_task.reset, spec), in_axes=(0, None))
    obs, state, params, k = reset(jax.random.wrap_key_data(kd), base)
    return obs, (state, params), jax.random.key_data(k)


@functools.partial(jax.jit, static_argnums=0)
def reset_envs(spec, kd, base, mask, old):
    """Reset the sub-envs where `mask` (all of them when `old` is None): (obs, state, key data)."""
    new = _reset_all(spec, kd, base)
    return new if old is None else _select(mask, new, old)


@functools.partial(jax.jit, static_argnums=(0, 1))
def step_envs(spec, mode: AutoresetMode, kd, state, action, autoreset, base):
    """One step of every sub-env with gymnasium's autoreset `mode`. kd: u32[n, 2] key data; state:
    (EnvState, EnvParams) [n]. Returns ((obs, reward, terminated, truncated, info, final_obs or
    None), state, key data). A reset replaces the sub-env's params (its room, start and goal)."""
    nav_state, params = state
    step = jax.vmap(functools.partial(gym_task.step, spec))
    (obs, rew, term, trunc, info), nav_state, k_s = step(jax.random.wrap_key_data(kd), nav_state, action, params)
    stepped, final_obs = (obs, (nav_state, params), jax.random.key_data(k_s)), None
    if mode == AutoresetMode.NEXT_STEP:  # the ended sub-envs reset now, from the key they had
        fresh = jax.lax.cond(jnp.any(autoreset), lambda: _reset_all(spec, kd, base), lambda: stepped)
        obs, state, kd = _select(autoreset, fresh, stepped)
        rew, term, trunc = jnp.where(autoreset, 0.0, rew), term & ~autoreset, trunc & ~autoreset
    elif mode == AutoresetMode.SAME_STEP:  # the ended sub-envs reset in this step, from the next key
        done = term | trunc
        fresh = jax.lax.cond(jnp.any(done), lambda: _reset_all(spec, stepped[2], base), lambda: stepped)
        final_obs = obs
        obs, state, kd = _select(done, fresh, stepped)
    else:
        _, state, kd = stepped
    return (obs, rew, term, trunc, info, final_obs), state, kd


_frames = jax.jit(jax.vmap(gym_task.frame, in_axes=(None, 0, 0, 0, None)), static_argnums=(0, 4))


def _masked(values: dict[str, np.ndarray], mask: np.ndarray) -> dict[str, Any]:
    """gymnasium's vector infos: each key with its `_key` mask; no keys when no sub-env has them."""
    out: dict[str, Any] = {}
    if not mask.any():
        return out
    for name in INFO_KEYS:
        out[name], out[f"_{name}"] = values[name], mask.copy()
    return out


def _autoreset_mode(mode: AutoresetMode | str) -> AutoresetMode:
    """An AutoresetMode from itself, its value ("NextStep") or its name in any case ("next_step")."""
    if isinstance(mode, AutoresetMode):
        return mode
    for m in AutoresetMode:
        if str(mode) == m.value or str(mode).upper() == m.name:
            return m
    raise ValueError(f"autoreset_mode must be one of {[m.value for m in AutoresetMode]}, got {mode!r}")


def _key_data(seed: int) -> np.ndarray:
    """NavGymEnv's key after `reset(seed=seed)` (gymnasium's seeding, then one draw)."""
    rng, _ = seeding.np_random(seed)
    return np.asarray(jax.random.key_data(jax.random.key(int(rng.integers(0, 2**31 - 1)))))


class NavVectorEnv(VectorEnv):
    """`num_envs` NavGymEnvs in one vmapped program. Keyword arguments: those of `NavGymEnv`
    (world, episode_length, placement, rooms, noise, EnvParams fields, render_mode, ...), plus
    `autoreset_mode` (an `AutoresetMode` or its value, default NEXT_STEP)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10, "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(
        self,
        num_envs: int = 1,
        *,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        render_mode: str | None = None,
        render_size: int = 256,
        **task_kwargs: Any,
    ):
        refuse_forked_child(type(self).__name__)
        if int(num_envs) < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self._kwargs = dict(
            num_envs=num_envs, autoreset_mode=autoreset_mode, render_mode=render_mode, render_size=render_size
        )
        self._kwargs.update(task_kwargs)
        self.num_envs = int(num_envs)
        self.autoreset_mode = _autoreset_mode(autoreset_mode)
        self.task, self.params, self.world_name = gym_task.make_task(**task_kwargs)
        self.render_mode, self.render_size = render_mode, int(render_size)
        self.metadata = {
            **self.metadata,
            "autoreset_mode": self.autoreset_mode,
            "render_fps": 1.0 / float(self.params.dt),
        }
        self.single_observation_space, self.single_action_space = gym_task.gym_spaces(self.task, self.params)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._kd: jax.Array | None = None  # u32[n, 2] each sub-env's key data
        self._state = None  # (EnvState, EnvParams) [n] once reset
        self._autoreset = np.zeros(self.num_envs, np.bool_)

    def reset(self, *, seed: int | list[int | None] | None = None, options: dict | None = None):
        """Reset every sub-env, or those of `options["reset_mask"]` (bool[num_envs]). `seed`: None,
        an int s (sub-env i gets s + i) or one seed (or None) per sub-env."""
        n = self.num_envs
        seeds = [None] * n if seed is None else [seed + i for i in range(n)] if isinstance(seed, int) else list(seed)
        if len(seeds) != n:
            raise ValueError(f"seed: a list of {n} seeds (one per sub-env) is needed, got {len(seeds)}")
        mask = np.ones(n, np.bool_)
        if options and "reset_mask" in options:
            mask = np.asarray(options["reset_mask"])
            if mask.shape != (n,) or mask.dtype != np.bool_ or not mask.any():
                raise ValueError(f"options['reset_mask']: a bool array of shape ({n},) with a True entry is needed")
            if self._state is None:
                raise RuntimeError("call reset() without reset_mask first")
        kd = np.array(self._kd) if self._kd is not None else np.zeros((n, 2), np.uint32)
        for i, s in enumerate(seeds):
            if s is not None:
                kd[i] = _key_data(s)
            elif self._kd is None:  # unseeded and new: fresh entropy, as an unseeded NavGymEnv
                kd[i] = _key_data(int(np.random.SeedSequence().generate_state(1)[0]))
        old = None if self._state is None or mask.all() else (self._obs, self._state, self._kd)
        self._obs, self._state, self._kd = reset_envs(self.task, jnp.asarray(kd), self.params, jnp.asarray(mask), old)
        self._autoreset = self._autoreset & ~mask
        return np.asarray(self._obs, np.float32), {}

    def step(self, actions):
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        a = jnp.asarray(np.asarray(actions, np.float32).reshape(self.num_envs, 2))
        if self.autoreset_mode == AutoresetMode.DISABLED and self._autoreset.any():
            raise RuntimeError(
                "autoreset_mode=DISABLED: reset the ended sub-envs with reset(options={'reset_mask': ...})"
            )
        out, self._state, self._kd = step_envs(
            self.task, self.autoreset_mode, self._kd, self._state, a, jnp.asarray(self._autoreset), self.params
        )
        self._obs = out[0]
        obs, rew, term, trunc, info, final_obs = jax.device_get(out)
        done = term | trunc
        if self.autoreset_mode == AutoresetMode.NEXT_STEP:
            infos = _masked(info, ~self._autoreset)
        elif self.autoreset_mode == AutoresetMode.SAME_STEP:
            infos = _masked(info, ~done)
            if done.any():
                fo = np.full(self.num_envs, None, dtype=object)
                for i in np.flatnonzero(done):
                    fo[i] = final_obs[i]
                infos.update(
                    final_obs=fo, _final_obs=done.copy(), final_info=_masked(info, done), _final_info=done.copy()
                )
        else:
            infos = _masked(info, np.ones(self.num_envs, np.bool_))
        self._autoreset = done
        return np.asarray(obs, np.float32), np.asarray(rew, np.float64), term, trunc, infos

    def render(self):
        """render_mode="rgb_array": a tuple of num_envs frames uint8[render_size, render_size, 3]."""
        if self.render_mode is None:
            return None
        if self._state is None:
            raise RuntimeError("call reset() before render()")
        return tuple(np.asarray(_frames(self.task, *self._state, self._obs, self.render_size)))

    # ------------------------------------------------------------------ pickling (as NavGymEnv)

    def __getstate__(self) -> dict:
        live = self._state is not None
        return {
            "kwargs": self._kwargs,
            "live": jax.device_get((self._obs, self._state, self._kd)) if live else None,
            "autoreset": self._autoreset,
        }

    def __setstate__(self, d: dict) -> None:
        self.__init__(**d["kwargs"])
        if d["live"] is not None:
            self._obs, self._state, self._kd = jax.tree.map(jnp.asarray, d["live"])
        self._autoreset = d["autoreset"]
