"""The 2D navigation simulator: geometry, kinematics, reward, reset/step (and adapters)."""

from fedjax_nav.env.geometry import beam_angles, lidar, nearest_distance
from fedjax_nav.env.nav import EnvState, NavEnv, unicycle
from fedjax_nav.env.params import EnvParams, make_params
from fedjax_nav.env.registry import make
from fedjax_nav.env.spaces import Box

__all__ = [
    "lidar",
    "nearest_distance",
    "beam_angles",
    "NavEnv",
    "EnvParams",
    "EnvState",
    "make",
    "make_params",
    "unicycle",
    "Box",
]
