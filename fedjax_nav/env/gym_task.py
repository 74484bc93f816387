"""The pure-JAX task behind the gymnasium adapters (`NavGymEnv` and the vmap `NavVectorEnv`).

One robot, `NavEnv(mode="eval")`: nothing is reset inside the env; the adapter calls `reset`.
What a reset draws is set by two static options:

- `placement="world"`: the room's own start (start 0, or one drawn from its starts with
  `random_starts=True`) and goal `goal_index`. `placement="random"`: a start pose and a goal
  drawn uniformly in the room's free space at every reset (`place`, the same draw as
  `env.placement: random` in training).
- `rooms="world"`: the given world file every episode. `rooms="procedural"`: a fresh room of
  `room_family` (`worlds.procedural.generate`, solvable by construction) at every reset, from
  the training half of the room seeds (never a held-out test room).

Everything is a function of a `TaskSpec` (static, hashable: it fixes the program) and arrays, so
every adapter instance with equal settings shares one compiled `reset` / `step` / `frame`
(the jitted functions at the bottom; a vector env of 64 gymnasium envs compiles once).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from fedjax_nav import worlds
from fedjax_nav.env.geometry import nearest_distance
from fedjax_nav.env.nav import COLLISION_TESTS, EnvParams, EnvState, NavEnv, make_params
from fedjax_nav.worlds import World
from fedjax_nav.worlds.procedural import generate
from fedjax_nav.worlds.rooms import RoomSpec, make_spec
from fedjax_nav.worlds.suites import train_room_key

PLACEMENTS = ("world", "random")
ROOMS = ("world", "procedural")
EPISODE_TAG = 0x6570  # fold_in tag of a reset's room / placement draws (the start key stays what it was)
# Random placement: `place` below, also training's `env.placement: random` (fedjax_nav.training.rooms).
PLACEMENT_TRIES = 64  # candidates per start / goal
PLACEMENT_MARGIN = 0.05  # m over D_c that a random start or goal keeps from every obstacle
MIN_START_GOAL = 1.0  # m, best effort: the first candidate goal this far from the start
ROBOT_RADIUS = 0.105  # m, TurtleBot3 Burger body (drawing only, as fedjax_nav.env.render)


@dataclasses.dataclass(frozen=True)
class TaskSpec:
    """The static settings of the task (hashable: a jit static argument)."""

    num_beams: int = 24
    max_range: float = 3.5
    episode_length: int = 1024
    collision_test: str = "exact"
    noise: bool = False
    placement: str = "world"
    rooms: str = "world"
    room: RoomSpec | None = None  # rooms="procedural" only
    plan: bool = False  # the global plan's waypoint in the observation (NavEnv's, docs/planning.md)
    plan_cells: int = 64

    @property
    def nav(self) -> NavEnv:
        return NavEnv(
            self.num_beams,
            self.max_range,
            self.episode_length,
            "eval",
            self.collision_test,
            noise=self.noise,
            plan=self.plan,
            plan_cells=self.plan_cells,
        )


def make_task(
    world: str | Path | None = None,
    *,
    num_beams: int = 24,
    max_range: float = 3.5,
    episode_length: int = 1024,
    collision_test: str = "exact",
    noise: bool = False,
    placement: str = "world",
    rooms: str = "world",
    room_family: str = "mixture",
    room_spec: dict | None = None,
    plan: bool = False,
    plan_cells: int = 64,
    **param_overrides: Any,
) -> tuple[TaskSpec, EnvParams, str]:
    """(spec, base params, world name). `world` (default "train-0") is a shipped name or a world
    file; not with rooms="procedural". `room_spec`: RoomSpec overrides ({"cylinders_max": 4}).
    `plan`, `plan_cells`: NavEnv's global plan (docs/planning.md; its lookahead is the EnvParams
    field `plan_lookahead`).
    Other keyword arguments are EnvParams fields (random_starts, goal_index, v_max, ...)."""
    if placement not in PLACEMENTS:
        raise ValueError(f"placement must be one of {PLACEMENTS}, got {placement!r}")
    if rooms not in ROOMS:
        raise ValueError(f"rooms must be one of {ROOMS}, got {rooms!r}")
    if collision_test not in COLLISION_TESTS:
        raise ValueError(f"collision_test must be one of {COLLISION_TESTS}, got {collision_test!r}")
    room = None
    if rooms == "procedural":
        if world is not None:
            raise ValueError("world: rooms='procedural' draws a new room at every reset; leave world unset")
        room = make_spec(room_family, **(room_spec or {}))  # WorldError (a ValueError) names a bad field
        shapes = jax.eval_shape(lambda k: generate(k, room), jax.random.key(0))
        template = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)
        # the largest room the family draws bounds the goal distance (the observation space)
        world = template.replace(size=jnp.array([room.width_max, room.height_max], jnp.float32))
        name = f"procedural:{room_family}"
    else:
        if room_spec is not None:
            raise ValueError("room_spec: only with rooms='procedural'")
        name = "train-0" if world is None else str(world)
        world = worlds.load(name)
    spec = TaskSpec(
        int(num_beams),
        float(max_range),
        int(episode_length),
        collision_test,
        bool(noise),
        placement,
        rooms,
        room,
        bool(plan),
        int(plan_cells),
    )
    return spec, make_params(world, **param_overrides), name


def gym_spaces(spec: TaskSpec, params: EnvParams):
    """(observation, action) as `gymnasium.spaces.Box` (NavEnv's gymnax-style spaces, converted)."""
    nav = spec.nav
    return nav.observation_space(params).to_gymnasium(), nav.action_space(params).to_gymnasium()


def place(world: World, key: jax.Array) -> World:
    """One room with a random start pose and goal in its free space: each the first of
    PLACEMENT_TRIES uniform candidates that keeps D_c + PLACEMENT_MARGIN from every obstacle
    (the goal also at least MIN_START_GOAL m from the start, best effort); if none fits, the
    room's own start 0 / goal 0. Every start / goal row becomes the drawn one. Training's random
    placement (`fedjax_nav.training.rooms`) is this function, so the two draw the same rooms."""
    c = worlds.CLEARANCE + PLACEMENT_MARGIN
    k_s, k_g, k_yaw = jax.random.split(key, 3)
    half = jnp.maximum(world.size / 2 - c, 0.0)

    def candidates(k):
        p = jax.random.uniform(k, (PLACEMENT_TRIES, 2), minval=-1.0, maxval=1.0) * half
        d = jax.vmap(lambda q: nearest_distance(world.segments, q, world.circles))(p)
        return p, d > c

    ps, ok_s = candidates(k_s)
    start_xy = jnp.where(jnp.any(ok_s), ps[jnp.argmax(ok_s)], world.starts[0, :2])
    pg, ok_g = candidates(k_g)
    far = ok_g & (jnp.linalg.norm(pg - start_xy, axis=-1) >= MIN_START_GOAL)
    pick = jnp.where(jnp.any(far), jnp.argmax(far), jnp.argmax(ok_g))
    goal = jnp.where(jnp.any(ok_g), pg[pick], world.goals[0])
    yaw = jax.random.uniform(k_yaw, (), minval=-jnp.pi, maxval=jnp.pi)
    start = jnp.where(jnp.any(ok_s), jnp.concatenate([start_xy, yaw[None]]), world.starts[0])
    return world.replace(
        starts=jnp.broadcast_to(start, world.starts.shape),
        num_starts=jnp.int32(1),
        goals=jnp.broadcast_to(goal, world.goals.shape),
        num_goals=jnp.int32(1),
    )


def episode_params(spec: TaskSpec, key: jax.Array, base: EnvParams) -> EnvParams:
    """The params of a new episode: a procedural room and / or a random placement (else `base`)."""
    k_room, k_place = jax.random.split(key)
    params = base
    if spec.rooms == "procedural":
        room = generate(train_room_key(jax.random.bits(k_room, (), jnp.uint32)), spec.room)
        params = params.replace(world=jax.tree.map(lambda a, b: b.astype(a.dtype), base.world, room))
    if spec.placement == "random":
        params = params.replace(world=place(params.world, k_place))
    return params


def _clip_bearing(spec: TaskSpec, obs: jax.Array) -> jax.Array:
    # the float32 bearing may round a hair past +-pi, outside the observation space
    i = spec.num_beams + 1
    return obs.at[i].set(jnp.clip(obs[i], -np.float32(np.pi), np.float32(np.pi)))


def reset(spec: TaskSpec, key: jax.Array, base: EnvParams) -> tuple[jax.Array, EnvState, EnvParams, jax.Array]:
    """A new episode: (obs f32[obs_size], state, this episode's params, the key for the
    next call). The params (room, start, goal) are `base` unless placement or rooms draw them."""
    k, k_next = jax.random.split(key)
    params = base
    if spec.rooms != "world" or spec.placement != "world":
        params = episode_params(spec, jax.random.fold_in(k, EPISODE_TAG), base)
    obs, state = spec.nav.reset(k, params)
    return _clip_bearing(spec, obs), state, params, k_next


def step(spec: TaskSpec, key: jax.Array, state: EnvState, action: jax.Array, params: EnvParams):
    """One step: ((obs, reward, terminated, truncated, info), state, the key for the next call).
    info: goal, collision (bool[]), pose (f32[3], after the move), clearance (f32[], m). The
    episode's params are an input only (returning them would copy the room every step)."""
    k, k_next = jax.random.split(key)
    obs, state, reward, term, trunc, info = spec.nav.step(k, state, action, params)
    info = {name: info[name] for name in ("goal", "collision", "pose", "clearance")}
    return (_clip_bearing(spec, obs), reward, term, trunc, info), state, k_next


def frame(spec: TaskSpec, state: EnvState, params: EnvParams, obs: jax.Array, size: int) -> jax.Array:
    """A top view, uint8[size, size, 3]: the room (grey outside its walls), obstacles (dark),
    the goal (green disc of the goal radius), the last scan (light red rays), the robot (blue
    disc, white heading). Rasterized in JAX with the env's own distance function, so the picture
    shows exactly the obstacles the robot collides with; the scale follows the room (+10 %)."""
    w, pose = params.world, state.pose
    extent = jnp.max(w.size) * 1.1 + 0.2
    m_px = extent / size
    c = (jnp.arange(size, dtype=jnp.float32) + 0.5) * m_px - extent / 2
    x, y = jnp.meshgrid(c, -c)  # row 0 at the top (+y)
    pts = jnp.stack([x.ravel(), y.ravel()], -1)  # [size * size, 2]
    d_obst = jax.vmap(lambda p: nearest_distance(w.segments, p, w.circles))(pts)

    # Rays in polar coordinates around the robot (one pass over the pixels, not one per beam):
    # a pixel is on the beam nearest its bearing if within 0.6 px of it and short of its range.
    rel = pts - pose[:2]
    to_robot = jnp.linalg.norm(rel, axis=-1)
    spacing = 2.0 * jnp.pi / spec.num_beams  # beam i at heading + i * spacing (geometry.beam_angles)
    phi = jnp.arctan2(rel[:, 1], rel[:, 0]) - pose[2]
    beam = jnp.round(phi / spacing).astype(jnp.int32)
    dphi = phi - beam * spacing
    along, across = to_robot * jnp.cos(dphi), to_robot * jnp.abs(jnp.sin(dphi))
    rays = (along >= 0) & (along <= obs[jnp.mod(beam, spec.num_beams)]) & (across < 0.6 * m_px)
    ahead, aside = to_robot * jnp.cos(phi), to_robot * jnp.abs(jnp.sin(phi))
    head = (ahead >= 0) & (ahead <= 0.9 * ROBOT_RADIUS) & (aside < 0.8 * m_px)
    to_goal = jnp.linalg.norm(pts - state.goal, axis=-1)
    inside = jnp.all(jnp.abs(pts) <= w.size / 2, -1)
    layers = [  # painted in this order
        (~inside, (200, 200, 200)),
        (to_goal < params.goal_radius, (205, 240, 205)),
        (rays, (250, 170, 170)),
        (to_goal < jnp.maximum(0.05, 1.5 * m_px), (40, 160, 40)),
        (d_obst < jnp.maximum(0.02, m_px), (60, 60, 60)),
        (to_robot < jnp.maximum(ROBOT_RADIUS, 2 * m_px), (31, 119, 180)),
        (head, (255, 255, 255)),
    ]
    img = jnp.full((size * size, 3), 255, jnp.uint8)
    for mask, rgb in layers:
        img = jnp.where(mask[:, None], jnp.array(rgb, jnp.uint8), img)
    return img.reshape(size, size, 3)


# One compilation per TaskSpec (and array shapes), shared by every adapter instance.
jit_reset = jax.jit(reset, static_argnums=0)
jit_step = jax.jit(step, static_argnums=0)
jit_frame = jax.jit(frame, static_argnums=(0, 4))
