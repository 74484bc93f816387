"""The one place where a run's config becomes the simulator: `NavEnv` settings (static) and
`EnvParams` values (traced), for training, the probe during training, and both evaluations
(the arena and the held-out suites).

    env = make_env(cfg, "learn")                       # the trainer
    env = make_env(cfg, "eval", noise=False)           # the probe: the run's robot, noiseless
    env = make_env(cfg, "eval", noise=True, episode_length=T)   # evaluation protocol
    params = env_params(world, hp)                     # every traced env.* / robot.* value of HParams

Settings come from `env.*` (beams, range, T, collision test) and the robot model (`robot:`;
`RobotConfig.env_settings()`); values are every traced `env.*` and `robot.*` field that is an
`EnvParams` field, read from HParams (so a sweep over them compiles once). A value the trainer
keeps for itself (env.room_every, the curriculum) is not an EnvParams field and is left out by
construction, not by a list kept by hand.

It sits in the config layer (above the env, below training and evaluation) because both the
trainer and the evaluations build from it, and evaluation reads runs without importing training.
`import fedjax_nav.config` alone does not load it (nor jax).
"""

from __future__ import annotations

from fedjax_nav import worlds
from fedjax_nav.config.names import get, traced_fields
from fedjax_nav.config.schema import Config
from fedjax_nav.env.nav import EnvParams, NavEnv, make_params

ENV_PREFIXES = ("env.", "robot.")  # the sections whose traced fields may be EnvParams fields


def env_settings(cfg: Config, mode: str, noise: bool | None = None, episode_length: int | None = None) -> dict:
    """NavEnv's keyword arguments for this config: `mode` "learn" or "eval"; `noise` None = the
    robot model's own (on for a modelled robot, off for the ideal one); `episode_length` None =
    env.episode_length (an evaluation's time-out may differ)."""
    e = cfg.env
    settings = dict(cfg.robot.env_settings())
    if noise is not None:
        settings["noise"] = bool(noise)
    path = e.path_progress and mode == "learn"  # a reward shapes training only: evaluations read none, need no field
    return {
        "num_beams": e.num_beams,
        "max_range": e.max_range,
        "episode_length": int(episode_length or e.episode_length),
        "mode": mode,
        "collision_test": e.collision_test,
        **settings,
        **({"plan": True} if e.plan else {}),
        **({"path_progress": True} if path else {}),
        **({"plan_cells": e.plan_cells} if e.plan or path else {}),
    }


def make_env(cfg: Config, mode: str, noise: bool | None = None, episode_length: int | None = None) -> NavEnv:
    """The run's simulator (see `env_settings`)."""
    return NavEnv(**env_settings(cfg, mode, noise, episode_length))


def _is_env_field(name: str) -> bool:
    return name.startswith(ENV_PREFIXES) and name.split(".", 1)[1] in EnvParams.__dataclass_fields__


def env_values(hp) -> dict:
    """Every traced env.* / robot.* value of HParams (`config.traced`) that is an EnvParams
    field, by field name."""
    return {k.split(".", 1)[1]: v for k, v in hp.to_flat().items() if _is_env_field(k)}


def env_params(world: worlds.World, hp, random_starts: bool = False, **overrides) -> EnvParams:
    """EnvParams for `world` (one room, or stacked [robots]) with the run's traced values;
    `overrides` (EnvParams fields) replace them, e.g. an evaluation's noise."""
    return make_params(world, random_starts=random_starts, **(env_values(hp) | overrides))


def eval_values(cfg: Config, range_noise: float, action_noise: float) -> dict:
    """EnvParams values of an evaluation under `cfg` (its robot included): the run's traced
    values with the protocol's noise; a modelled robot's own range noise replaces the protocol's."""
    values = {name.split(".", 1)[1]: get(cfg, name) for name in traced_fields() if _is_env_field(name)}
    if not cfg.robot.enabled:
        values["range_noise"] = range_noise
    values["action_noise"] = action_noise
    return values
