"""gymnax's `make` for this package: `env, params = make("Nav-v0", world=..., **settings)`
(docs/gym.md). The env itself is fedjax_nav/env/nav.py's."""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import Sequence

from fedjax_nav import worlds as _worlds
from fedjax_nav.env.nav import NavEnv
from fedjax_nav.env.params import DEFAULT_WORLD, EnvParams, make_params
from fedjax_nav.worlds import World

ENV_IDS = ("Nav-v0", "fedjax_nav/Nav-v0")  # the names `make` knows (the second is the gymnasium id)
_NAVENV_ARGS = tuple(inspect.signature(NavEnv.__init__).parameters)[1:]


def make(
    env_id: str = "Nav-v0", *, world: str | Path | Sequence[str | Path] | World = DEFAULT_WORLD, **kwargs
) -> tuple[NavEnv, EnvParams]:
    """`env, params = make("Nav-v0", ...)`, as `gymnax.make`.

    world: a shipped name or a world file, a list of them (stacked: params with a leading
    playground axis, to `vmap` over), or a `World`. The other keyword arguments go to `NavEnv`
    when they are its arguments (num_beams, max_range, episode_length, mode, collision_test,
    noise, robot, ...) and to `make_params` otherwise (EnvParams fields: goal_index, v_max, ...).
    """
    if env_id not in ENV_IDS:
        raise ValueError(f"unknown environment {env_id!r}; known: {', '.join(ENV_IDS)}")
    env = NavEnv(**{k: kwargs.pop(k) for k in list(kwargs) if k in _NAVENV_ARGS})
    if isinstance(world, World):
        w = world
    elif isinstance(world, (str, Path)):
        w = _worlds.load(world)
    else:
        w = _worlds.load_many(list(world))
    return env, make_params(w, **kwargs)
