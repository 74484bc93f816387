"""The env's defaults are written in three places beside the config (EnvParams' fields, NavEnv's
and evaluate_policy's arguments); this test keeps every one that has a config field of the same
name equal to the config's default (`config.EnvConfig`, `robots.RobotConfig`), so that a default
changed in the config cannot leave the simulator's behind."""

import dataclasses
import inspect

import numpy as np

from fedjax_nav.config import EnvConfig, RobotConfig
from fedjax_nav.env.nav import EnvParams, NavEnv
from fedjax_nav.evaluation.rollout import evaluate_policy

# a robot field whose default is None takes the preset's value: not a number to compare
CONFIG = {
    f.name: f.default
    for cls in (EnvConfig, RobotConfig)
    for f in dataclasses.fields(cls)
    if f.default is not None and f.default is not dataclasses.MISSING
}
# evaluate_policy's episode length is called max_steps
RENAMED = {"max_steps": "episode_length"}


def _argument_defaults(fn) -> dict:
    return {
        RENAMED.get(n, n): p.default
        for n, p in inspect.signature(fn).parameters.items()
        if p.default is not inspect.Parameter.empty
    }


def test_env_params_defaults_are_the_configs():
    checked = 0
    for f in dataclasses.fields(EnvParams):
        if f.name in CONFIG and f.default_factory is not dataclasses.MISSING:
            got = np.asarray(f.default_factory())
            assert got == np.asarray(CONFIG[f.name], got.dtype), f.name  # in the program's precision
            checked += 1
    assert checked >= 8  # dt, v_max, omega_max, goal_radius, collision_distance, the rewards


def test_nav_env_and_evaluate_policy_defaults_are_the_configs():
    for fn in (NavEnv.__init__, evaluate_policy):
        shared = {n: v for n, v in _argument_defaults(fn).items() if n in CONFIG}
        assert {"num_beams", "max_range", "collision_test", "episode_length"} <= set(shared), fn.__qualname__
        for name, value in shared.items():
            assert value == CONFIG[name], (fn.__qualname__, name, value, CONFIG[name])
