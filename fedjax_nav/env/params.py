"""The navigation task's data for one robot: `EnvParams` (every leaf traced: vmap it, sweep it,
stack playgrounds in it) and `make_params`, which builds it for one world or a stack of them;
`env/nav.py` is what the task does with it (`NavEnv.reset` / `step`)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from flax import struct

from fedjax_nav import worlds as _worlds
from fedjax_nav.worlds import World


@struct.dataclass
class EnvParams:
    """Per-robot task data. Every leaf is traced: vmap it, sweep it, or stack playgrounds in it."""

    world: World
    goal_index: jax.Array = struct.field(default_factory=lambda: jnp.int32(0))  # which goal row
    random_starts: jax.Array = struct.field(default_factory=lambda: jnp.bool_(False))  # FLS
    dt: jax.Array = struct.field(default_factory=lambda: jnp.float32(0.1))  # s per control step
    v_max: jax.Array = struct.field(default_factory=lambda: jnp.float32(0.25))  # m/s
    omega_max: jax.Array = struct.field(default_factory=lambda: jnp.float32(1.0))  # rad/s
    goal_radius: jax.Array = struct.field(default_factory=lambda: jnp.float32(0.5))  # m, D_g
    collision_distance: jax.Array = struct.field(default_factory=lambda: jnp.float32(0.25))  # m, D_c
    reward_goal: jax.Array = struct.field(default_factory=lambda: jnp.float32(100.0))  # R_g
    reward_collision: jax.Array = struct.field(default_factory=lambda: jnp.float32(-10.0))  # R_c
    progress_scale: jax.Array = struct.field(default_factory=lambda: jnp.float32(40.0))  # R_d factor
    range_noise: jax.Array = struct.field(default_factory=lambda: jnp.float32(0.0))  # m, std
    action_noise: jax.Array = struct.field(default_factory=lambda: jnp.float32(0.0))  # std, action units
    # The robot model (read only when NavEnv(robot=True); docs/robot.md). 0 = off for each.
    accel_lin: jax.Array = struct.field(default_factory=lambda: jnp.float32(0.0))  # m/s^2, 0 = unlimited
    accel_ang: jax.Array = struct.field(default_factory=lambda: jnp.float32(0.0))  # rad/s^2, 0 = unlimited
    delay_steps: jax.Array = struct.field(default_factory=lambda: jnp.int32(0))  # <= NavEnv.max_delay
    range_resolution: jax.Array = struct.field(default_factory=lambda: jnp.float32(0.0))  # m, 0 = exact
    range_min: jax.Array = struct.field(default_factory=lambda: jnp.float32(0.0))  # m, nearer reads 0
    dropout: jax.Array = struct.field(default_factory=lambda: jnp.float32(0.0))  # probability per sample
    footprint: jax.Array = struct.field(default_factory=lambda: jnp.float32(0.0))  # m, 0 = collision_distance
    lidar_offset: jax.Array = struct.field(default_factory=lambda: jnp.float32(0.0))  # m ahead of the centre
    plan_lookahead: jax.Array = struct.field(default_factory=lambda: jnp.float32(1.0))  # m; NavEnv(plan=True) only
    plan_margin: jax.Array = struct.field(default_factory=lambda: jnp.float32(0.0))  # m; NavEnv(plan=True) only
    # Shared rooms only (docs/shared_rooms.md, "Keeping apart"): a reward on every step another robot's
    # disc is nearer than robot_clearance to the robot's own. 0 = off.
    reward_robot_near: jax.Array = struct.field(default_factory=lambda: jnp.float32(0.0))  # per step
    robot_clearance: jax.Array = struct.field(default_factory=lambda: jnp.float32(0.3))  # m between two discs
    # Shared rooms (docs/shared_rooms.md, "Giving way"): m between two robots' discs within which a
    # robot stops and turns right in place when driving on would bring it nearer to another. 0 = off.
    give_way: jax.Array = struct.field(default_factory=lambda: jnp.float32(0.0))  # m between two discs
    # Shared rooms (docs/shared_rooms.md, "Waiting at doors"): m across under which a place counts as a
    # door; a robot not in one stops while another robot in sight, ahead and within give_way_reach of
    # its centre stands in one. 0 = off.
    give_way_door: jax.Array = struct.field(default_factory=lambda: jnp.float32(0.0))  # m across
    give_way_reach: jax.Array = struct.field(default_factory=lambda: jnp.float32(1.5))  # m between centres
    # Shared rooms with NavEnv(plan=True) (docs/shared_rooms.md, "Keeping right"): m the waypoint moves
    # to the right while another robot's centre is within plan_keep_right_reach and ahead. 0 = off.
    plan_keep_right: jax.Array = struct.field(default_factory=lambda: jnp.float32(0.0))  # m
    plan_keep_right_reach: jax.Array = struct.field(default_factory=lambda: jnp.float32(1.5))  # m


def make_params(world: World, **overrides) -> EnvParams:
    """EnvParams for one world, or for a stacked World (leading playground axis), in which case
    scalar fields are broadcast to that axis (pass arrays of that length to vary them)."""
    base = EnvParams(world=world)
    batch = world.segments.shape[:-2]
    fields = {}
    for name in EnvParams.__dataclass_fields__:
        if name == "world":
            continue
        default = getattr(base, name)
        value = jnp.asarray(overrides.pop(name, default), default.dtype)
        fields[name] = jnp.broadcast_to(value, batch) if value.ndim == 0 else value
    if overrides:
        raise TypeError(f"EnvParams has no field '{sorted(overrides)[0]}'")
    return base.replace(**fields)


# ----------------------------------------------------------------------------- the default world

DEFAULT_WORLD = "train-0"  # the world of `NavEnv.default_params` and of `env.make` without `world=`


@functools.lru_cache(maxsize=1)
def default_world() -> World:
    """The World of `DEFAULT_WORLD`, loaded once."""
    return _worlds.load(DEFAULT_WORLD)
