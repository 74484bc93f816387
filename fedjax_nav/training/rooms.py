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
    env.room_sampling =        the learnability curriculum (SFL): each environment keeps a bank of
      "learnability"           env.room_bank procedural rooms with their recent success p; a renewal
                               draws a fresh room with probability env.room_fresh, else a bank room
                               with weight p(1 - p) + env.room_floor (`RoomBank`, below)

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

The learnability curriculum ("sampling for learnability", Rutherford et al. 2024, as JaxNav's
SFL) adds `bank` (a `RoomBank`) to the state; a uniform run's `bank` is None and its program is
today's. The bank holds room counters, not rooms: bank room k of environment r is
`generate(train_room_key(rooms[r, k]), spec_r, density(hp, ep))`, regenerated when drawn (one
generation per environment per renewal, as a uniform run), so its rooms come from the training
half of the room seeds like every other training room, and a bank costs 8 bytes per room.
The bank starts as the rooms a uniform run draws in its blocks 0 .. B-1 (its block 0 is the
initial room, bitwise a uniform run's); the fresh room of block b is the uniform run's room of
block B + b. Outcome and update: at each episode's end every environment's goal share over the
attempts of that episode (goals / attempts, an attempt ending in a goal, a collision or the
episode's time-out) moves p of its current room by an EMA with rate env.room_ema
(`update_score`). Never-tried rooms have p = 0.5, where p(1 - p) is largest: they get tried.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from fedjax_nav import worlds
from fedjax_nav.env import shared
from fedjax_nav.env.gym_task import place  # random placement: the gymnasium adapters' own draw
from fedjax_nav.worlds import World, WorldError
from fedjax_nav.worlds.procedural import generate
from fedjax_nav.worlds.rooms import make_spec, parse_overrides
from fedjax_nav.worlds.suites import common_shape, padded_spec, train_room_key

FIXED = "fixed"
ROOM_STREAM = 0x8007  # fold_in tag: the seed's room stream and placement draws (the run's key stream is untouched)
ROOM_BANK = 0x8009  # fold_in tag: the learnability curriculum's draws (the run's key stream is untouched)
UNTRIED = 0.5  # p of a room never tried: p(1 - p) is largest there
# Rooms generated at once at a renewal (`jax.lax.map`'s batch): generating every environment's room
# in one vmap held ~230 KB of temporaries per room ('mixture', XLA:CPU), 9.6 GB at 5 x 8192
# environments, more than the run's state; in batches of ROOM_BATCH the generator's temporaries
# stay ~120 MB at any number of environments, and each room is the same (docs/reliability.md,
# "Memory for many environments").
ROOM_BATCH = 512
# XLA:CPU temporaries of generating one room (vmap of `generate`, 64 and 128 rooms): mixture 228 KB,
# cave 183 KB, forest 128 KB, office 110 KB, boxes 77 KB, corridors 51 KB, maze 45 KB, warehouse
# 35 KB, cylinders 29 KB, walls 27 KB; the memory estimate counts the largest for every family.
ROOM_TEMP_BYTES = 240_000


def generation_bytes(rooms: int) -> int:
    """Peak temporaries of generating `rooms` rooms at once (`generate_rooms`: at most ROOM_BATCH)."""
    return min(int(rooms), ROOM_BATCH) * ROOM_TEMP_BYTES


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
        self.learnability = self.procedural and e.room_sampling == "learnability"
        self.bank_size = e.room_bank
        self.shared, self.per = bool(e.shared_rooms), per  # env.shared_rooms: see `fleet`
        fixed = [worlds.load(w) for w in e.worlds]
        if self.shared:
            check_shared(e, fixed, n)
        elif e.reward_robot_near != 0:  # a reward that could never be paid: loud, not silently ignored
            raise WorldError(
                "env.reward_robot_near is paid between robots of a shared room: "
                "set env.shared_rooms: true, or leave it 0"
            )
        for name in ("give_way", "give_way_door"):  # the same: no other robot to give way to
            if getattr(e, name) != 0 and not self.shared:
                raise WorldError(
                    f"env.{name} keeps a robot from driving into another of a shared room: "
                    "set env.shared_rooms: true, or leave it 0"
                )
        if e.plan_keep_right != 0 and not (self.shared and e.plan):  # a rule no robot would follow: as loud
            raise WorldError(
                "env.plan_keep_right moves the plan's waypoint away from the other robots of a shared room: "
                "set env.shared_rooms: true and env.plan: true, or leave it 0"
            )
        if e.plan and e.rooms != "procedural" and e.placement == "fixed":
            check_plan(cfg, fixed)
        if not self.procedural:
            self.world = _per_env(worlds.load_many(e.worlds), per)  # N = 1: exactly the fixed program's World
            if self.shared and not self.random_placement:  # robot i: the room's start i and goal i
                self.world = _per_env(shared.fixed_fleet(fixed[0], n), per)
            self.families, self.groups = (FIXED,) * n, []
            self.banked = np.zeros(self.num_rooms, bool)
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
        if self.shared:  # room j of the fleet: generated once (robot 0's rows), every robot's row j
            room_families = room_families[:per]
        self.banked = np.array([f != FIXED for f in room_families])  # the rows whose rooms are generated
        self.groups = [
            (self.specs[f], np.array([i for i, g in enumerate(room_families) if g == f])) for f in self.specs
        ]

    def stream(self, key: jax.Array) -> jax.Array:
        """A seed's room stream u32[] (from its init key, without consuming it)."""
        return jax.random.bits(jax.random.fold_in(key, ROOM_STREAM), (), jnp.uint32)

    def draw(self, stream: jax.Array, block: jax.Array, density=1.0) -> World:
        """The robots' rooms of block `block` (World [robots]), thinned to `density` (see
        `density`); pure JAX, jit/vmap-able."""
        return self.rooms_at(self.block_counters(stream, block), density)

    def block_counters(self, stream: jax.Array, block) -> jax.Array:
        """The room counters u32[environments] of block `block`: stream + block * environments + row."""
        base = stream + jnp.asarray(block, jnp.uint32) * jnp.uint32(self.num_rooms)
        return base + jnp.arange(self.num_rooms, dtype=jnp.uint32)

    def rooms_at(self, counters: jax.Array, density=1.0) -> World:
        """Every environment's room from its counter u32[environments] (`train_room_key`: the
        training half of the room seeds); the rows of family "fixed" keep their playground."""
        world = jax.tree.map(lambda x: x[: self.per], self.world) if self.shared else self.world
        for spec, idx in self.groups:
            keys = jax.vmap(train_room_key)(counters[idx])
            rooms = generate_rooms(keys, spec, density)
            world = jax.tree.map(lambda a, b, idx=idx: a.at[idx].set(b.astype(a.dtype)), world, rooms)
        if self.shared:
            world = jax.tree.map(lambda x: jnp.tile(x, (self.num_robots,) + (1,) * (x.ndim - 1)), world)
        return world

    def episode_world(self, state, hp, ep) -> tuple[object, World]:
        """At an episode's reset: (state with its rooms renewed when due, the robots' World)."""
        world = self.world
        if self.learnability:
            state, world = self._bank_world(state, hp, ep)
        elif self.procedural:
            every = hp.env.room_every
            world = jax.lax.cond(
                ep % every == 0,
                lambda: self.draw(state.room_stream, ep // every, density(hp, ep)),
                lambda: state.world,
            )
            state = state.replace(world=world)
        if self.shared and (self.procedural or self.random_placement):
            world = self.fleet(world, jax.random.fold_in(state.key, ROOM_STREAM))
        elif self.random_placement:
            keys = jax.random.split(jax.random.fold_in(state.key, ROOM_STREAM), self.num_rooms)
            world = jax.vmap(place)(world, keys)
        return state, world

    def fleet(self, world: World, key: jax.Array) -> World:
        """Shared rooms (env/shared.py): every room's robots placed together (`place_fleet`, one key
        per room), each robot's row holding its own start and goal; rows robot-major, room j the
        same for every robot. With env.placement fixed robot 0 keeps the room's start 0 and goal 0."""
        rooms = jax.tree.map(lambda x: x[: self.per], world)  # robot 0's rows: the rooms
        keep = not self.random_placement
        place = lambda w, k: shared.place_fleet(w, k, self.num_robots, keep)  # noqa: E731
        placed = jax.vmap(place)(rooms, jax.random.split(key, self.per))
        return jax.tree.map(lambda x: x.swapaxes(0, 1).reshape(-1, *x.shape[2:]), placed)  # [per, R] -> [R * per]

    # ------------------------------------------------------------ the learnability curriculum

    def init_bank(self, stream: jax.Array) -> RoomBank:
        """A seed's initial bank: row r's rooms are those of blocks 0 .. B-1 (`block_counters`),
        all untried; every environment starts in slot 0 (block 0's room, the initial `world`)."""
        rooms = jax.vmap(lambda b: self.block_counters(stream, b), out_axes=1)(jnp.arange(self.bank_size))
        return RoomBank(
            rooms=rooms,
            p=jnp.full((self.num_rooms, self.bank_size), UNTRIED, jnp.float32),
            slot=jnp.zeros(self.num_rooms, jnp.int32),
            fresh=jnp.zeros(self.num_rooms, bool),
        )

    def draw_bank(self, bank: RoomBank, key: jax.Array, hp, stream: jax.Array, block) -> RoomBank:
        """Every environment's draw at the renewal of block `block` (`draw_room` per row); the rows of
        family "fixed" never draw fresh (their room is their playground)."""
        fresh_prob = jnp.where(self.banked, jnp.asarray(hp.env.room_fresh, jnp.float32), 0.0)
        fresh_counters = self.block_counters(stream, jnp.asarray(block, jnp.uint32) + jnp.uint32(self.bank_size))
        keys = jax.random.split(key, self.num_rooms)
        rooms, p, slot, fresh = jax.vmap(draw_room, in_axes=(0, 0, 0, 0, 0, None))(
            keys, bank.rooms, bank.p, fresh_counters, fresh_prob, hp.env.room_floor
        )
        return RoomBank(rooms=rooms, p=p, slot=slot, fresh=fresh)

    def _bank_world(self, state, hp, ep):
        """At an episode's reset: on a renewal (ep % env.room_every == 0) each environment draws
        from its bank and its room is generated; otherwise it keeps its room (and slot)."""
        every = hp.env.room_every
        key = jax.random.fold_in(state.key, ROOM_BANK)

        def renew():
            bank = self.draw_bank(state.bank, key, hp, state.room_stream, ep // every)
            return bank, self.rooms_at(bank.rooms[jnp.arange(self.num_rooms), bank.slot], density(hp, ep))

        def keep():
            return state.bank.replace(fresh=jnp.zeros_like(state.bank.fresh)), state.world

        bank, world = jax.lax.cond(ep % every == 0, renew, keep)
        return state.replace(bank=bank, world=world), world

    def score(self, bank: RoomBank, hp, goals: jax.Array, attempts: jax.Array) -> RoomBank:
        """At an episode's end: each environment's goal share (goals / attempts, i32[environments]
        each, summed over the episode) updates p of its current room (`update_score`)."""
        outcome = goals.astype(jnp.float32) / jnp.maximum(attempts, 1).astype(jnp.float32)
        rate = jnp.where(self.banked, jnp.asarray(hp.env.room_ema, jnp.float32), 0.0)
        return bank.replace(p=jax.vmap(update_score)(bank.p, bank.slot, outcome, rate))

    def bank_metrics(self, bank: RoomBank) -> dict:
        """Per environment f32[environments]: `room_p`, the mean p of its bank, and `fresh_rooms`,
        1 if it drew a fresh room at this episode's start; NaN on rows of family "fixed"."""
        nan = jnp.float32(jnp.nan)
        return {
            "room_p": jnp.where(self.banked, jnp.mean(bank.p, axis=1), nan),
            "fresh_rooms": jnp.where(self.banked, bank.fresh.astype(jnp.float32), nan),
        }


@struct.dataclass
class RoomBank:
    """The learnability curriculum's state of one seed (`TrainState.bank`). One bank per
    environment, so per robot with env.envs_per_robot = 1: p is a property of a room *and the
    policy that plays it*, so no bank is shared between robots (clients with their own networks
    and, in a mixed fleet, their own families); and per environment rather than per robot with N > 1,
    so that no two draws of one episode contend for one slot (a fresh room replacing a slot another
    environment is playing, two outcomes for one score): every operation is one vmap over rows."""

    rooms: jax.Array  # u32[environments, B] room counters (`TrainRooms.rooms_at`)
    p: jax.Array  # f32[environments, B] each room's recent goal share (EMA); UNTRIED = 0.5 never tried
    slot: jax.Array  # i32[environments] the slot of each environment's current room
    fresh: jax.Array  # bool[environments] its room was drawn fresh at this episode's start


def learnability_weights(p: jax.Array, floor) -> jax.Array:
    """The probabilities f32[B] of drawing each bank room: p(1 - p) + floor, normalised. The
    floor (env.room_floor > 0) keeps a bank whose rooms are all solved (p = 1) or all hopeless
    (p = 0) sampling, uniformly then."""
    w = p * (1.0 - p) + floor
    return w / jnp.sum(w)


def draw_room(key: jax.Array, rooms: jax.Array, p: jax.Array, fresh_counter: jax.Array, fresh_prob, floor):
    """One environment's draw from its bank (rooms u32[B], p f32[B]): with probability `fresh_prob`
    the fresh room `fresh_counter`, which replaces the bank's least learnable room (the lowest
    p(1 - p), ties to the lowest slot) with p = UNTRIED; else a bank room drawn with
    `learnability_weights(p, floor)`. Returns (rooms, p, slot i32[], fresh bool[]).

    Why the least learnable: SFL keeps the rooms of highest learnability; a solved or hopeless room
    teaches least. Untried rooms score highest (0.25), so a fresh room is not replaced before it
    was played once."""
    k_fresh, k_slot = jax.random.split(key)
    fresh = jax.random.uniform(k_fresh) < fresh_prob
    score = p * (1.0 - p)
    drawn = jax.random.categorical(k_slot, jnp.log(score + floor))
    slot = jnp.where(fresh, jnp.argmin(score), drawn).astype(jnp.int32)
    rooms = jnp.where(fresh, rooms.at[slot].set(fresh_counter), rooms)
    p = jnp.where(fresh, p.at[slot].set(UNTRIED), p)
    return rooms, p, slot, fresh


def update_score(p: jax.Array, slot: jax.Array, outcome: jax.Array, rate) -> jax.Array:
    """p f32[B] with p[slot] <- (1 - rate) p[slot] + rate * outcome (outcome in [0, 1]): a room
    solved every time rises to 1 as 1 - (1 - p0)(1 - rate)^n."""
    return p.at[slot].set((1.0 - rate) * p[slot] + rate * outcome)


def generate_rooms(keys: jax.Array, spec, density=1.0) -> World:
    """`generate` for every key (a World [keys]): one vmap up to ROOM_BATCH keys, above it
    `jax.lax.map` over batches of ROOM_BATCH, the keys padded to a whole batch (the padding rooms
    dropped): a room generated in a short remainder batch could round differently from the same
    room in a wide one (XLA:CPU picks its loops by width), so every batch has the one width."""
    n = keys.shape[0]
    if n <= ROOM_BATCH:
        return jax.vmap(lambda k: generate(k, spec, density))(keys)
    pad = -n % ROOM_BATCH
    keys = jnp.concatenate([keys, keys[:pad]]) if pad else keys
    rooms = jax.lax.map(lambda k: generate(k, spec, density), keys, batch_size=ROOM_BATCH)
    return jax.tree.map(lambda x: x[:n], rooms)


def _per_env(world: World, per: int) -> World:
    """Each robot's row repeated for its `per` environments (robot-major); `world` itself when 1."""
    return world if per == 1 else jax.tree.map(lambda x: jnp.repeat(x, per, axis=0), world)


def density(hp, ep) -> jax.Array:
    """The curriculum's obstacle density at episode `ep`: env.room_density_start rising linearly
    to 1 over env.room_curriculum_episodes episodes; 1 without a curriculum (0 episodes). Both
    are traced: a sweep over them compiles once."""
    n = hp.env.room_curriculum_episodes
    start = jnp.asarray(hp.env.room_density_start, jnp.float32)
    ramp = start + (1.0 - start) * jnp.minimum(jnp.asarray(ep, jnp.float32) / jnp.maximum(n, 1), 1.0)
    return jnp.where(n > 0, ramp, jnp.float32(1.0))


def check_shared(e, fixed: list, robots: int) -> None:
    """What shared rooms need of a config (`WorldError`, one line naming the field): one room for
    the fleet (one family; one world when the rooms are fixed), uniform room sampling (the
    learnability curriculum scores each environment's own room), and, with fixed rooms and fixed
    placement, a start and a goal per robot in the world."""
    if e.room_sampling == "learnability":
        raise WorldError(
            "env.room_sampling: learnability scores each environment's own room; shared rooms "
            "(env.shared_rooms) need uniform"
        )
    if e.rooms == "procedural" and len(e.room_families) > 1:
        raise WorldError(
            f"env.room_families has {len(e.room_families)} entries; shared rooms (env.shared_rooms) "
            "put the fleet in one room: give one family"
        )
    if e.rooms != "procedural" and len(set(e.worlds)) > 1:
        raise WorldError(
            f"env.worlds names {len(set(e.worlds))} different worlds; shared rooms (env.shared_rooms) "
            "put the fleet in one room: give the same world for every robot"
        )
    if e.rooms != "procedural" and e.placement == "fixed":
        w = fixed[0]
        starts, goals = int(w.num_starts), int(w.num_goals)
        if min(starts, goals) < robots:
            raise WorldError(
                f"env.worlds: '{e.worlds[0]}' has {starts} start(s) and {goals} goal(s) for {robots} "
                "robots in a shared room (env.shared_rooms); give a start and a goal per robot, "
                "or env.placement: random"
            )


def check_plan(cfg, fixed: list) -> None:
    """env.plan (docs/planning.md): every start row of each `env.worlds` room reaches the goal it
    drives to (goal 0; in a shared room robot i's start i its goal i) on the plan's grid, inflated
    by the robot's collision radius; else `WorldError`, one line naming the world and the field."""
    from fedjax_nav.env import plan

    e, r = cfg.env, cfg.robot
    radius = r.footprint if r.enabled and r.footprint > 0 else e.collision_distance
    reach = jax.jit(plan.reachable, static_argnums=4)
    for name, w in dict(zip(e.worlds, fixed)).items():
        # (goal row, the start rows driving to it)
        pairs = [(i, [i]) for i in range(cfg.num_robots)] if e.shared_rooms else [(0, range(int(w.num_starts)))]
        for g, rows in pairs:
            ok = np.asarray(reach(w, w.goals[g], radius, e.goal_radius, e.plan_cells))
            for i in (i for i in rows if not ok[i]):
                raise WorldError(
                    f"env.worlds: '{name}': start {i} {np.round(np.asarray(w.starts[i, :2]), 2).tolist()} cannot "
                    f"reach goal {g} {np.round(np.asarray(w.goals[g]), 2).tolist()} on the plan's grid (env.plan: "
                    f"true, env.plan_cells={e.plan_cells}, clearance {radius:g} m); give a start that can, or "
                    "env.plan: false"
                )
