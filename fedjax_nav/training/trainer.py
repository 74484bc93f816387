"""The scanned trainer: every method, every robot and every seed in one jitted program.

    chunk(states[seed], hp, first_episode):
      vmap over seeds:
        scan over episodes {
          reset every environment (robots x env.envs_per_robot)
          scan over steps { act (the learner's exploration) ; env step (vmap environments) ; store ;
                            when the learner is due: update (vmap nets) ; [DDPG: every T_target targets] ;
                            [every T_update steps: federated step] }
          [every E_update episodes: federated step]
        }

The learner (`cfg.learner`: DDPG, TD3, SAC, PPO) is data, `agents.learners.LEARNERS[cfg.learner]`:
the trainer calls its functions (explore, store, due, update, shared, ...) and never branches on
its name. A robot (a federated client) steps env.envs_per_robot environments at once, rows
robot-major in every per-environment array (environment j of robot i is row i * N + j); all of them
feed that robot's learner: an off-policy buffer receives N rows per step, a PPO rollout is
[T_roll, N]. With N = 1 and `learner: ddpg` this is the thesis's program, bit for bit.

The step and episode counters enter as scan inputs that are *not* batched over seeds, so the
"every T_train steps" gates are real `lax.cond`s (under vmap a cond on a batched predicate would
compute the update every step; a batched period, swept, makes its gate a select: correct, slower).

`TrainState` is one seed's state; `HParams` (fedjax_nav.training.hparams) holds every traced
config value, env constants included (each leaf a scalar, or [S] when swept over seeds/grid
points): the env's `EnvParams` are built from it inside the program, so a sweep over
`env.v_max` compiles once.

Per-step values (`StepMetrics`) are summed in the step scan's carry, then made episode metrics
(`EPISODE_METRICS`: one line per metric; training/step_metrics.py). Shared rooms: env/shared.py.

This module holds the run's description and its entry points (init, chunk, compiled_chunk); the
step and the episode's scan are training/episode.py's functions of it.
"""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from fedjax_nav import methods, worlds
from fedjax_nav.agents import learners
from fedjax_nav.config import Config, envs, values
from fedjax_nav.env import shared
from fedjax_nav.env.nav import EnvParams
from fedjax_nav.training import episode, federation, slices
from fedjax_nav.training.hparams import HParams, hp_axes, hparams_from_config
from fedjax_nav.training.metrics import Facts
from fedjax_nav.training.probe import Probe
from fedjax_nav.training.rooms import TrainRooms
from fedjax_nav.training.rooms import density as room_density  # the curriculum's, not an env field
from fedjax_nav.training.state import TrainState


@dataclass(frozen=True, eq=False, init=False)
class Trainer:
    """A run's program: the frozen description of its structure, built once from the config
    (padded with the mesh's masked clients), and the pure functions over it that make the compiled
    program (`init`, `episode` (training/episode.py), `chunk`; `compiled_chunk` jits a chunk).
    Nothing here changes after `__init__`; the federated round and the host's tables take only what they need of it
    (`round`: a `federation.Round`; `facts()`: a `metrics.Facts`)."""

    cfg: Config  # the padded config: env.worlds holds the padding clients' rooms too
    n_real: int  # clients of the user's config; the rest (`pad`) are masked copies of the last robot
    pad: int
    method: methods.Method
    learner: learners.Learner
    env: Any  # the NavEnv of the ideal robot (noise off: the thesis's program)
    env_step: Any  # every environment's step: vmap(env.step), or a shared room's (env/shared.py)
    rooms: TrainRooms  # fixed playgrounds, or procedural rooms drawn in the program
    world: worlds.World  # the fixed rooms, one per environment
    nets: Any  # the learner's static networks and sizes (`Learner.make_nets`)
    probe: Probe | None  # run.eval_every: the held-out probe
    num_robots: int  # clients, padding included
    envs_per_robot: int
    num_envs: int
    n_nets: int  # 1 for a shared-network method
    n_bufs: int  # 1 for a shared-buffer method
    writes: int  # rows each buffer receives per step
    obs_size: int
    T: int  # steps per episode
    real: np.ndarray  # bool[clients]: not padding
    byzantine: np.ndarray  # bool[clients]: the last fed.byzantine real clients
    round: federation.Round  # what a federated round needs
    fleet: tuple[int, int]  # (first, total): robots first.. of a run of `total` (training.slices)
    rounds: bool  # the federated round is in the program (not held outside it: `fleet` given)

    def __init__(self, cfg: Config, pad: int = 0, fleet: tuple[int, int] | None = None):
        """`pad` > 0 appends that many permanently masked clients (copies of the last robot's
        room) so that the client axis divides over a mesh's devices: they never take part in a
        federated round, their metrics are dropped, and the real robots' numbers equal the
        unpadded run's to float32 round-off (their PRNG keys are the same: split(k, n + pad)
        begins with split(k, n)). `fleet`: see the field (its rounds are held outside, docs/fleet.md)."""
        method = methods.get(cfg.method)
        # one shared network or buffer cannot be split over devices: no padding (check_mesh says so)
        n_real, pad = cfg.num_robots, 0 if method.shared_network or method.shared_buffer else int(pad)
        if pad:
            env = dataclasses.replace(cfg.env, worlds=cfg.env.worlds + (cfg.env.worlds[-1],) * pad)
            cfg = dataclasses.replace(cfg, env=env)
        learner = learners.get(cfg.learner)
        nets = learner.make_nets(values(cfg))
        n = cfg.num_robots
        env = envs.make_env(cfg, "learn")
        rooms = TrainRooms(cfg)
        n_envs = n * cfg.env.envs_per_robot
        real = np.arange(n) < n_real
        byzantine = real & (np.arange(n) >= n_real - cfg.fed.byzantine)
        n_bufs = 1 if method.shared_buffer else n
        fields = dict(
            cfg=cfg,
            n_real=n_real,
            pad=pad,
            method=method,
            learner=learner,
            env=env,
            env_step=shared.fleet_step(env, real, cfg.env.envs_per_robot) if rooms.shared else jax.vmap(env.step),
            rooms=rooms,
            world=rooms.world,
            nets=nets,
            probe=Probe(cfg, learner, nets, cfg.run.eval_suite) if cfg.run.eval_every else None,
            num_robots=n,
            envs_per_robot=cfg.env.envs_per_robot,
            num_envs=n_envs,
            n_nets=1 if method.shared_network else n,
            n_bufs=n_bufs,
            writes=n_envs // n_bufs,
            obs_size=env.obs_size,
            T=cfg.env.episode_length,
            real=real,
            byzantine=byzantine,
            round=federation.describe(cfg.fed, method, learner, real, byzantine),
            fleet=(0, n) if fleet is None else (int(fleet[0]), int(fleet[1])),
            rounds=method.aggregator != "none" and fleet is None,
        )
        for name, value in fields.items():
            object.__setattr__(self, name, value)

    def robot(self, first) -> Trainer:
        """This program for robots first.. of its run (`fleet`); `first` may be traced (one compiled
        program for every robot that drives the same rooms, docs/fleet.md)."""
        twin = copy.copy(self)
        object.__setattr__(twin, "fleet", (first, self.fleet[1]))
        return twin

    def facts(self) -> Facts:
        """What the host's tables (training.metrics) need of this run."""
        return Facts(
            method=self.method,
            n_real=self.n_real,
            n_nets=self.n_nets,
            num_params=self.num_params(),
            loss_names=self.learner.metrics,
            bounds=self.learner.bounds,
            byzantine=self.byzantine,
        )

    def env_params(self, hp: HParams, world: worlds.World | None = None) -> EnvParams:
        """The environments' EnvParams [environments] in `world` (default: the run's fixed rooms)."""
        return envs.env_params(self.world if world is None else world, hp, self.method.random_starts)

    def aggregator(self, hp: HParams):
        """The run's aggregator with its traced hyperparameters (`training.federation.aggregator`)."""
        return federation.aggregator(self.round, hp)

    def shared(self, agents) -> dict:
        """What a client sends in a federated round (`federation.Round.shared`)."""
        return self.round.shared(agents)

    def policy(self, agents):
        """The greedy policies' parameters (leaves [n_nets, ...]): what the probe drives."""
        return self.learner.policy(agents)

    def robot_rows(self, key: jax.Array, per_robot: int, draw=None) -> jax.Array:
        """Our robots' rows of a per-robot draw (`slices.rows`; split(key, rows) by default)."""
        draw = draw or (lambda n: jax.random.split(key, n))
        return slices.rows(draw, per_robot, self.num_robots, self.fleet) if per_robot else draw(1)

    # ------------------------------------------------------------------ init

    def init_agents(self, key: jax.Array, hp: HParams):
        """One seed's initial agents (`init`'s): every agent its own initialisation key."""
        k_nets = jax.random.split(key, 3)[0]
        init = lambda k: self.learner.init(self.nets, k, self.obs_size, hp)
        return jax.vmap(init)(self.robot_rows(k_nets, not self.method.shared_network))

    def init_agg_state(self, agents, hp: HParams):
        """The aggregator's initial state over the initial agents (the padding clients left out)."""
        return self.aggregator(hp).init(self.real_rows(self.shared(agents)))

    def init(self, key: jax.Array, hp: HParams) -> TrainState:
        """One seed's initial state. Every agent gets its own initialisation key."""
        L = self.learner
        agents, (_, k_env, k_run) = self.init_agents(key, hp), jax.random.split(key, 3)
        buffers = jax.vmap(lambda _: L.storage(self.nets, self.obs_size, self.writes))(jnp.arange(self.n_bufs))
        optional = {}  # the fields that are None unless the run has procedural rooms / a learner memory
        if self.rooms.procedural:
            stream = self.rooms.stream(key)
            optional = {"room_stream": stream, "world": self.rooms.draw(stream, 0, room_density(hp, 0))}
            if self.rooms.learnability:  # its slot 0 holds block 0's room: the world just drawn
                optional["bank"] = self.rooms.init_bank(stream)
        params = self.env_params(hp, optional.get("world"))
        obs, env_state = jax.vmap(self.env.reset)(self.robot_rows(k_env, self.envs_per_robot), params)
        memory = L.memory(self.nets)
        if memory is not None:
            optional["memory"] = jax.tree.map(lambda x: jnp.broadcast_to(x, (self.num_envs, *x.shape)), memory)
            optional["first"] = jnp.ones(self.num_envs, bool)
        return TrainState(
            **optional,
            agents=agents,
            buffers=buffers,
            env_state=env_state,
            obs=obs,
            explore=self.learner.explore_init(hp),
            agg_state=self.init_agg_state(agents, hp),
            reward_sum=jnp.zeros(self.num_robots),
            reward_steps=jnp.float32(0),
            key=k_run,
        )

    def init_seeds(self, seeds: jax.Array, hp: HParams, mesh=None) -> TrainState:
        """Stacked states for integer seeds i32[S] (hp leaves scalar or [S]); with a `mesh`
        (`fedjax_nav.training.parallel`), created already sharded over it."""
        init = jax.vmap(lambda s, h: self.init(jax.random.key(s), h), in_axes=(0, hp_axes(hp)))
        if mesh is None:
            return jax.jit(init)(seeds, hp)  # jit: op-by-op init of the buffers took ~20 s under load
        from fedjax_nav.training.parallel import init_placed

        return self.check_mesh(mesh, len(seeds)) or init_placed(init, mesh, np.asarray(seeds), hp)

    # ------------------------------------------------------------------ pieces

    def by_net(self, fn, agents, *per_env):
        """fn(agent, *rows) for every environment row with its robot's network (the one network
        of a shared-network method); per_env leaves [environments, ...], and so are the outputs."""
        in_axes = (None,) + (0,) * len(per_env)
        if self.method.shared_network:
            return jax.vmap(fn, in_axes=in_axes)(jax.tree.map(lambda p: p[0], agents), *per_env)
        if self.envs_per_robot == 1:
            return jax.vmap(fn)(agents, *per_env)
        n = self.envs_per_robot
        split = jax.tree.map(lambda x: x.reshape(self.n_nets, n, *x.shape[1:]), per_env)
        out = jax.vmap(jax.vmap(fn, in_axes=in_axes))(agents, *split)
        return jax.tree.map(lambda x: x.reshape(self.num_envs, *x.shape[2:]), out)

    def _act(self, state: TrainState, key: jax.Array, hp: HParams | None = None) -> jax.Array:
        """The exploration actions f32[environments, 2] (hp: default the config's)."""
        return episode.explore(self, state, key, hparams_from_config(self.cfg) if hp is None else hp)[0]

    def per_robot(self, x: jax.Array, reduce=jnp.sum) -> jax.Array:
        """[environments] -> [robots]: `reduce` over each robot's environments (x itself when 1)."""
        return x if self.envs_per_robot == 1 else reduce(x.reshape(self.num_robots, self.envs_per_robot), axis=1)

    def _update(self, agents, buffers, key, g, hp: HParams):
        """One update event of every network, each on its own storage (or all on the shared one)."""
        return episode.update(self, agents, buffers, key, g, hp)

    def federated_round(self, state: TrainState, hp: HParams) -> tuple[TrainState, dict]:
        """One federated round: the state and its stats (`training.federation.federated_round`)."""
        return federation.federated_round(self.round, state, hp)

    def episode(self, state: TrainState, hp: HParams, ep: jax.Array) -> tuple[TrainState, dict]:
        """One episode of T steps for one seed (training/episode.py); ep must be unbatched."""
        return episode.episode(self, state, hp, ep)

    def real_rows(self, tree):
        """Leaves [clients, ...] without the padding clients (`pad`)."""
        return jax.tree.map(lambda x: x[: self.n_real], tree) if self.pad else tree

    def chunk(self, states: TrainState, hp: HParams, first_episode: jax.Array, num_episodes: int):
        """`num_episodes` episodes for every seed. Metrics leaves: [seeds, num_episodes, ...]."""

        def one_seed(state, h):
            eps = first_episode + jnp.arange(num_episodes)
            return jax.lax.scan(lambda s, e: self.episode(s, h, e), state, eps)

        return jax.vmap(one_seed, in_axes=(0, hp_axes(hp)))(states, hp)

    def compiled_chunk(
        self, num_episodes: int | None = None, mesh=None, states=None, hp: HParams | None = None, on_trace=None
    ):
        """jit(chunk) with the states donated (the replay buffers are updated in place).

        With a `mesh` (see `fedjax_nav.training.parallel`), `states` and `hp` (templates: arrays or
        ShapeDtypeStructs) fix the in/out shardings: the states keep their placement, the
        metrics come back replicated (every process can read them). `on_trace()` is called each
        time jit traces the chunk (sweeps count their compilations with it)."""
        n = num_episodes or self.cfg.run.chunk_episodes

        def fn(states, hp, first_episode):
            if on_trace is not None:
                on_trace()
            return self.chunk(states, hp, first_episode, n)

        if mesh is None:
            return jax.jit(fn, donate_argnums=0)
        from fedjax_nav.training.parallel import jit_chunk

        if states is None or hp is None:
            raise ValueError("compiled_chunk(mesh=...) needs the states and hp templates")
        return self.check_mesh(mesh, states.reward_steps.shape[0]) or jit_chunk(fn, mesh, states, hp)

    def check_mesh(self, mesh, num_seeds: int) -> None:
        """Raise `parallel.ShardingError` if this run cannot be placed on `mesh`."""
        from fedjax_nav.training.parallel import check_placement

        check_placement(mesh, num_seeds, self.num_robots, self.method.shared_network, self.method.shared_buffer)

    def num_params(self) -> int:
        """Parameters of one agent's SHARED fields (DDPG: actor + critic), what one client sends
        per federated round (targets aside)."""
        hp = hparams_from_config(self.cfg)
        st = jax.eval_shape(lambda k: self.learner.init(self.nets, k, self.obs_size, hp), jax.random.key(0))
        return int(sum(np.prod(x.shape) for x in jax.tree.leaves(self.learner.shared(st))))
