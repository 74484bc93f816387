"""The rooms of a training run (docs/generalization.md): the fixed playgrounds of `env.worlds`,
procedural rooms drawn inside the compiled program, and random start/goal placement.

    env.rooms = "fixed"        every robot keeps its `env.worlds` playground (today's program)
    env.rooms = "procedural"   robot i gets a fresh room of family `env.room_families[i]` (one
                               entry: every robot) every `env.room_every` episodes; the family
                               "fixed" keeps that robot's `env.worlds` playground (mixed fleets)
    env.placement = "random"   at every episode's reset, a random start pose and goal are drawn
                               in the free space of each robot's room (clearance > D_c + 0.05 m)
    env.room_density_start,    a curriculum, sparse to dense: the rooms drawn at episode ep keep
    env.room_curriculum_episodes   `density(hp, ep)` of their obstacles (traced; default none)

With env.envs_per_robot = N > 1 each robot steps N environments: there is one room per
environment (rows robot-major: environment j of robot i is row i * N + j), each drawn on its own
(procedural rooms) and placed on its own (random placement); fixed playgrounds are repeated N times.
Below, "robot" reads "environment" then; N = 1 is exactly the program described.

State: a procedural run's `TrainState` holds the robots' current rooms (`world`: World [robots],
every robot padded to one shape that fits every family's rooms and every fixed playground) and
`room_stream` (u32[], drawn once per seed at init). The rooms of block b = episode // room_every
come from `train_room_key(room_stream + b * robots + robot)`: the training half of the room
seeds, disjoint from every held-out test suite (`fedjax_nav.worlds.suites`). Drawing happens at
the episode's reset, on the device, in the same compiled program (no recompilation, no host
round trip). A fixed run's state has neither field (`None`): its program is unchanged.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from fedjax_nav import worlds
from fedjax_nav.env.gym_task import place  # random placement: the gymnasium adapters' own draw
from fedjax_nav.worlds import World, WorldError
from fedjax_nav.worlds.procedural import generate
from fedjax_nav.worlds.rooms import make_spec, parse_overrides
from fedjax_nav.worlds.suites import common_shape, padded_spec, train_room_key

FIXED = "fixed"
ROOM_STREAM = 0x8007  # fold_in tag: the seed's room stream and placement draws (the run's key stream is untouched)


def parse_room_spec(text: str) -> dict:
    """`env.room_spec` ("cylinders_max=4, goals_max=4") -> RoomSpec overrides (WorldError on a bad one)."""
    items = [x.strip() for x in str(text or "").split(",") if x.strip()]
    try:
        return parse_overrides(items)
    except WorldError as e:
        raise WorldError(f"env.room_spec: {e}") from None


class TrainRooms:
    """Static description of a run's rooms, built from the Config (no traced values)."""

    def __init__(self, cfg):
        e = cfg.env
        n, per = cfg.num_robots, e.envs_per_robot
        self.num_robots = n
        self.num_rooms = n * per  # one per environment
        self.procedural = e.rooms == "procedural"
        self.random_placement = e.placement == "random"
        fixed = [worlds.load(w) for w in e.worlds]
        if not self.procedural:
            self.world = _per_env(worlds.load_many(e.worlds), per)  # N = 1: exactly the fixed program's World
            self.families, self.groups = (FIXED,) * n, []
            return
        fams = tuple(e.room_families)
        if 1 < len(fams) < n and len(e.worlds) == n:  # clients padded for a mesh (Trainer pad): copies of the last
            fams = fams + (fams[-1],) * (n - len(fams))
        if len(fams) not in (1, n):
            raise WorldError(
                f"env.room_families has {len(fams)} entries; give one (every robot) or one per robot ({n}, env.worlds)"
            )
        self.families = fams * n if len(fams) == 1 else fams
        overrides = parse_room_spec(e.room_spec)
        try:
            specs = {f: make_spec(f, **overrides) for f in dict.fromkeys(self.families) if f != FIXED}
        except WorldError as err:
            raise WorldError(f"env.room_spec: {err}") from None
        shapes = [(w.segments.shape[0], w.circles.shape[0], w.starts.shape[0], w.goals.shape[0]) for w in fixed]
        self.shape = common_shape(specs.values(), shapes)
        self.specs = {f: padded_spec(s, self.shape) for f, s in specs.items()}
        self.world = _per_env(worlds.stack([worlds.pad(w, *self.shape) for w in fixed]), per)  # "fixed" rows
        room_families = [f for f in self.families for _ in range(per)]
        self.groups = [
            (self.specs[f], np.array([i for i, g in enumerate(room_families) if g == f])) for f in self.specs
        ]

    def stream(self, key: jax.Array) -> jax.Array:
        """A seed's room stream u32[] (from its init key, without consuming it)."""
        return jax.random.bits(jax.random.fold_in(key, ROOM_STREAM), (), jnp.uint32)

    def draw(self, stream: jax.Array, block: jax.Array, density=1.0) -> World:
        """The robots' rooms of block `block` (World [robots]), thinned to `density` (see
        `density`); pure JAX, jit/vmap-able."""
        world = self.world
        base = stream + jnp.asarray(block, jnp.uint32) * jnp.uint32(self.num_rooms)
        for spec, idx in self.groups:
            keys = jax.vmap(train_room_key)(base + jnp.asarray(idx, jnp.uint32))
            rooms = jax.vmap(lambda k, spec=spec: generate(k, spec, density))(keys)
            world = jax.tree.map(lambda a, b, idx=idx: a.at[idx].set(b.astype(a.dtype)), world, rooms)
        return world

    def episode_world(self, state, hp, ep) -> tuple[object, World]:
        """At an episode's reset: (state with its rooms renewed when due, the robots' World)."""
        world = self.world
        if self.procedural:
            every = hp["env.room_every"]
            world = jax.lax.cond(
                ep % every == 0,
                lambda: self.draw(state.room_stream, ep // every, density(hp, ep)),
                lambda: state.world,
            )
            state = state.replace(world=world)
        if self.random_placement:
            keys = jax.random.split(jax.random.fold_in(state.key, ROOM_STREAM), self.num_rooms)
            world = jax.vmap(place)(world, keys)
        return state, world


def _per_env(world: World, per: int) -> World:
    """Each robot's row repeated for its `per` environments (robot-major); `world` itself when 1."""
    return world if per == 1 else jax.tree.map(lambda x: jnp.repeat(x, per, axis=0), world)


def density(hp, ep) -> jax.Array:
    """The curriculum's obstacle density at episode `ep`: env.room_density_start rising linearly
    to 1 over env.room_curriculum_episodes episodes; 1 without a curriculum (0 episodes). Both
    are traced: a sweep over them compiles once."""
    n = hp["env.room_curriculum_episodes"]
    start = jnp.asarray(hp["env.room_density_start"], jnp.float32)
    ramp = start + (1.0 - start) * jnp.minimum(jnp.asarray(ep, jnp.float32) / jnp.maximum(n, 1), 1.0)
    return jnp.where(n > 0, ramp, jnp.float32(1.0))
