"""The scanned trainer: every method, every robot and every seed in one jitted program.

    chunk(states[seed], hp, first_episode):
      vmap over seeds:
        scan over episodes {
          reset every robot
          scan over steps { act (epsilon-greedy) ; env step (vmap robots) ; store ;
                            every T_train: DDPG update (vmap nets) ; every T_target: targets ;
                            [every T_update steps: federated step] }
          [every E_update episodes: federated step]
        }

The step and episode counters enter as scan inputs that are *not* batched over seeds, so the
"every T_train steps" gates are real `lax.cond`s (under vmap a cond on a batched predicate
would compute the update every step). A hyperparameter that is batched (a sweep over periods)
turns its gate into a select, which is correct but slower.

`TrainState` is one seed's state; `HParams` (fedjax_nav.training.hparams) holds every traced
config value, env constants included (each leaf a scalar, or [S] when swept over seeds/grid
points): the env's `EnvParams` are built from it inside the program, so a sweep over
`env.v_max` compiles once.

Per-step values (`StepMetrics`) are summed over the episode in the step scan's carry and turned
into episode metrics by `EPISODE_METRICS`: adding a metric is one line in that table (and a field
when it needs a new per-step value).
"""

from __future__ import annotations

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from fedjax_nav import methods, worlds
from fedjax_nav.agents import buffer as rb
from fedjax_nav.agents import ddpg
from fedjax_nav.config import Config, envs
from fedjax_nav.env.nav import EnvParams, EnvState
from fedjax_nav.training import federation
from fedjax_nav.training.hparams import HParams, hp_axes
from fedjax_nav.training.probe import Probe
from fedjax_nav.training.rooms import TrainRooms
from fedjax_nav.training.rooms import density as room_density  # the curriculum's, not an env field
from fedjax_nav.training.step_metrics import EPISODE_METRICS, NO_ROUND, StepMetrics, all_finite


@struct.dataclass
class TrainState:
    """One seed. Leading axes: agents [n_nets], buffers [n_bufs], env_state/obs [robots]."""

    agents: ddpg.AgentState
    buffers: rb.Transition
    env_state: EnvState
    obs: jax.Array  # f32[robots, obs]
    epsilon: jax.Array  # f32[]
    agg_state: Any  # the aggregator's state (a NamedTuple of fedjax_nav.federated.aggregators; no client axis)
    reward_sum: jax.Array  # f32[robots] since the last federated step
    reward_steps: jax.Array  # f32[]
    key: jax.Array
    # procedural rooms only (env.rooms = procedural; training/rooms.py), None otherwise:
    world: worlds.World | None = None  # the robots' current rooms [robots]
    room_stream: jax.Array | None = None  # u32[] this seed's offset in the training room stream


class Trainer:
    """Static structure of a run (shapes, method flags, networks, worlds) built from a Config."""

    def __init__(self, cfg: Config, pad: int = 0):
        """`pad` > 0 appends that many permanently masked clients (copies of the last robot's
        room) so that the client axis divides over a mesh's devices: they never take part in a
        federated round, their metrics are dropped, and the real robots' numbers equal the
        unpadded run's to float32 round-off (their PRNG keys are the same: split(k, n + pad)
        begins with split(k, n))."""
        self.cfg = cfg
        self.method = methods.get(cfg.method)
        # one shared network or buffer cannot be split over devices: no padding (check_mesh says so)
        shared = self.method.shared_network or self.method.shared_buffer
        self.n_real, self.pad = cfg.num_robots, 0 if shared else int(pad)
        if self.pad:
            import dataclasses

            cfg = dataclasses.replace(
                cfg, env=dataclasses.replace(cfg.env, worlds=cfg.env.worlds + (cfg.env.worlds[-1],) * self.pad)
            )
        e, d = cfg.env, cfg.ddpg
        self.env = envs.make_env(cfg, "learn")  # the ideal robot: noise off, the thesis's program
        self.rooms = TrainRooms(cfg)  # fixed playgrounds, or procedural rooms drawn in the program
        self.world = self.rooms.world
        f = cfg.fed
        self.num_robots = cfg.num_robots
        self.n_nets = 1 if self.method.shared_network else self.num_robots
        self.n_bufs = 1 if self.method.shared_buffer else self.num_robots
        self.writes = self.num_robots // self.n_bufs  # rows each buffer receives per step
        self.nets = ddpg.make_nets(d.hidden, d.depth, d.activation)
        self.probe = Probe(cfg, self.nets, cfg.run.eval_suite) if cfg.run.eval_every else None
        self.obs_size = self.env.obs_size
        self.T = e.episode_length
        # static client roles: the last fed.byzantine real robots are Byzantine; padding is never real
        self.real = np.arange(self.num_robots) < self.n_real
        self.byzantine = self.real & (np.arange(self.num_robots) >= self.n_real - f.byzantine)

    def env_params(self, hp: HParams, world: worlds.World | None = None) -> EnvParams:
        """The robots' EnvParams [robots] in `world` (default: the run's fixed rooms)."""
        return envs.env_params(self.world if world is None else world, hp, self.method.random_starts)

    def aggregator(self, hp: HParams):
        """The run's aggregator with its traced hyperparameters (`training.federation.aggregator`)."""
        return federation.aggregator(self, hp)

    def shared(self, agents: ddpg.AgentState) -> dict:
        """What a client sends in a federated round: its networks (and targets if configured)."""
        out = {"actor": agents.actor, "critic": agents.critic}
        if self.cfg.fed.include_targets:
            out.update(actor_targ=agents.actor_targ, critic_targ=agents.critic_targ)
        return out

    def take_shared(self, agents: ddpg.AgentState, new: dict) -> ddpg.AgentState:
        """The agents with what a federated round sent back (`shared`'s keys) put in place."""
        return agents.replace(**new)

    # ------------------------------------------------------------------ init

    def init(self, key: jax.Array, hp: HParams) -> TrainState:
        """One seed's initial state. Every agent gets its own initialisation key."""
        k_nets, k_env, k_run = jax.random.split(key, 3)
        agents = jax.vmap(lambda k: ddpg.init_agent(self.nets, k, self.obs_size))(jax.random.split(k_nets, self.n_nets))
        buffers = jax.vmap(lambda _: rb.init(self.cfg.buffer_rows, self.obs_size))(jnp.arange(self.n_bufs))
        rooms = {}
        if self.rooms.procedural:
            stream = self.rooms.stream(key)
            rooms = {"room_stream": stream, "world": self.rooms.draw(stream, 0, room_density(hp, 0))}
        params = self.env_params(hp, rooms.get("world"))
        obs, env_state = jax.vmap(self.env.reset)(jax.random.split(k_env, self.num_robots), params)
        return TrainState(
            **rooms,
            agents=agents,
            buffers=buffers,
            env_state=env_state,
            obs=obs,
            epsilon=jnp.asarray(hp["ddpg.epsilon_start"], jnp.float32),
            agg_state=self.aggregator(hp).init(self.real_rows(self.shared(agents))),
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
        from fedjax_nav.training import parallel

        self.check_mesh(mesh, len(seeds))
        shardings = parallel.state_shardings(jax.eval_shape(init, seeds, hp), mesh)
        return jax.jit(init, out_shardings=shardings)(np.asarray(seeds), hp)

    # ------------------------------------------------------------------ pieces

    def _act(self, state: TrainState, key: jax.Array) -> jax.Array:
        actor = state.agents.actor
        if self.method.shared_network:
            greedy = jax.vmap(ddpg.act, in_axes=(None, None, 0))(
                self.nets, jax.tree.map(lambda p: p[0], actor), state.obs
            )
        else:
            greedy = jax.vmap(ddpg.act, in_axes=(None, 0, 0))(self.nets, actor, state.obs)
        keys = jax.random.split(key, self.num_robots)
        return jax.vmap(ddpg.epsilon_greedy, in_axes=(0, 0, None))(keys, greedy, state.epsilon)

    def _capacity(self, hp: HParams) -> jax.Array:
        """The active buffer capacity, never beyond the allocated rows (a swept value may be)."""
        return jnp.minimum(hp["ddpg.buffer_size"], self.cfg.buffer_rows)

    def _update(self, agents: ddpg.AgentState, buffers: rb.Transition, key, count, hp: HParams):
        """One gradient step for every network, each on its own batch."""

        def one(agent, buf, k):
            batch = rb.sample(buf, k, self.cfg.ddpg.batch_size, count, self._capacity(hp))
            return ddpg.update(self.nets, agent, batch, hp["ddpg.gamma"], hp["ddpg.lr"])

        keys = jax.random.split(key, self.n_nets)
        buf_axis = 0 if self.n_bufs == self.n_nets else None
        bufs = buffers if buf_axis == 0 else jax.tree.map(lambda b: b[0], buffers)
        return jax.vmap(one, in_axes=(0, buf_axis, 0))(agents, bufs, keys)

    def federated_round(self, state: TrainState, hp: HParams) -> tuple[TrainState, dict]:
        """One federated round: the state and its stats (`training.federation.federated_round`)."""
        return federation.federated_round(self, state, hp)

    def _step(self, hp: HParams, env_params: EnvParams, state: TrainState, g):
        """One env step of every robot, with the periodic updates. g: global step (unbatched).
        Returns the new state and this step's `StepMetrics`."""
        key, k_act, k_env, k_upd = jax.random.split(state.key, 4)
        actions = self._act(state, k_act)
        env_keys = jax.random.split(k_env, self.num_robots)
        obs2, env_state, reward, term, trunc, info = jax.vmap(self.env.step)(
            env_keys, state.env_state, actions, env_params
        )
        # s' is the true observation at the pose reached, also on a terminal step (obs2 is then
        # the start of the next attempt); the (1 - D) mask cuts the bootstrap there.
        rows = rb.Transition(state.obs, actions, reward, info["final_obs"], term.astype(jnp.float32))
        rows = jax.tree.map(lambda x: x.reshape(self.n_bufs, self.writes, *x.shape[1:]), rows)
        buffers = jax.vmap(rb.add, in_axes=(0, 0, None, None))(state.buffers, rows, g * self.writes, self._capacity(hp))

        count = (g + 1) * self.writes
        ready = count >= self.cfg.ddpg.batch_size
        do_update = ready & ((g + 1) % hp["ddpg.train_every"] == 0)
        zeros = jnp.zeros(self.n_nets)
        agents, losses = jax.lax.cond(
            do_update,
            lambda a: self._update(a, buffers, k_upd, count, hp),
            lambda a: (a, {"critic_loss": zeros, "actor_loss": zeros, "q": zeros}),
            state.agents,
        )
        do_target = ready & ((g + 1) % hp["ddpg.target_every"] == 0)
        agents = jax.lax.cond(
            do_target,
            lambda a: jax.vmap(ddpg.update_targets, in_axes=(0, None))(a, hp["ddpg.rho"]),
            lambda a: a,
            agents,
        )
        state = state.replace(
            agents=agents,
            buffers=buffers,
            env_state=env_state,
            obs=obs2,
            key=key,
            epsilon=state.epsilon * hp["ddpg.epsilon_decay"],
            reward_sum=state.reward_sum + reward,
            reward_steps=state.reward_steps + 1.0,
        )
        fed_now, fs = jnp.bool_(False), NO_ROUND
        if self.method.aggregator != "none" and self.cfg.fed.period_unit == "steps":
            fed_now = (g + 1) % hp["fed.period"] == 0
            state, fs = jax.lax.cond(fed_now, lambda s: self.federated_round(s, hp), lambda s: (s, NO_ROUND), state)
        out = StepMetrics(
            reward=reward,
            goals=info["goal"].astype(jnp.int32),
            collisions=info["collision"].astype(jnp.int32),
            critic_loss=losses["critic_loss"],
            actor_loss=losses["actor_loss"],
            q=losses["q"],
            updates=do_update.astype(jnp.int32),
            fed_events=fed_now.astype(jnp.int32),
            fed_clients=fs["clients"],
            fed_skipped=fs["skipped"],
        )
        return state, out

    def episode(self, state: TrainState, hp: HParams, ep: jax.Array) -> tuple[TrainState, dict]:
        """One episode of T steps for one seed; ep (the episode index) must be unbatched."""
        state, world = self.rooms.episode_world(state, hp, ep)  # new rooms / placements when configured
        env_params = self.env_params(hp, world)
        key, k_reset = jax.random.split(state.key)
        obs, env_state = jax.vmap(self.env.reset)(jax.random.split(k_reset, self.num_robots), env_params)
        state = state.replace(obs=obs, env_state=env_state, key=key)
        steps = ep * self.T + jnp.arange(self.T)
        step = partial(self._step, hp, env_params)

        def body(carry, g):  # the step metrics are summed in the carry: see EPISODE_METRICS
            state, sums = carry
            state, m = step(state, g)
            return (state, jax.tree.map(jnp.add, sums, m)), None

        zeros = jax.tree.map(lambda x: jnp.zeros(x.shape, x.dtype), jax.eval_shape(step, state, steps[0])[1])
        (state, sums), _ = jax.lax.scan(body, (state, zeros), steps)
        fed_end, fs = jnp.int32(0), NO_ROUND
        if self.method.aggregator != "none" and self.cfg.fed.period_unit == "episodes":
            fed_now = (ep + 1) % hp["fed.period"] == 0
            state, fs = jax.lax.cond(fed_now, lambda s: self.federated_round(s, hp), lambda s: (s, NO_ROUND), state)
            fed_end = fed_now.astype(jnp.int32)
        metrics = {name: reduce(sums, self.T) for name, reduce in EPISODE_METRICS.items()}
        metrics["fed_events"] = metrics["fed_events"] + fed_end
        metrics["fed_clients"] = metrics["fed_clients"] + fs["clients"]
        metrics["fed_skipped"] = metrics["fed_skipped"] + fs["skipped"]
        metrics["epsilon"] = state.epsilon
        metrics["params_finite"] = jax.vmap(all_finite)((state.agents.actor, state.agents.critic))  # [n_nets]
        if self.probe is not None:  # run.eval_every: greedy success on the held-out probe, NaN between
            every = self.cfg.run.eval_every
            metrics["eval_success"] = jax.lax.cond(
                (ep + 1) % every == 0,
                lambda a: self.probe.success(a, hp),
                lambda a: jnp.full(self.n_nets, jnp.nan),
                state.agents.actor,
            )
        if self.pad:  # the padding clients' rows are not results
            metrics = jax.tree.map(
                lambda x: x[: self.n_real] if x.ndim and x.shape[0] == self.num_robots else x, metrics
            )
        return state, metrics

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
        from fedjax_nav.training import parallel

        if states is None or hp is None:
            raise ValueError("compiled_chunk(mesh=...) needs the states and hp templates")
        self.check_mesh(mesh, jax.tree.leaves(states.epsilon)[0].shape[0])
        st = parallel.state_shardings(states, mesh)
        rep = parallel.replicated(mesh)
        return jax.jit(
            fn, donate_argnums=0, in_shardings=(st, parallel.seed_shardings(hp, mesh), rep), out_shardings=(st, rep)
        )

    def check_mesh(self, mesh, num_seeds: int) -> None:
        """Raise `parallel.ShardingError` if this run cannot be placed on `mesh`."""
        from fedjax_nav.training import parallel

        parallel.check_placement(
            mesh, num_seeds, self.num_robots, self.method.shared_network, self.method.shared_buffer
        )

    def num_params(self) -> int:
        """Parameters of one agent (actor + critic), what one client sends per federated round."""
        st = jax.eval_shape(lambda k: ddpg.init_agent(self.nets, k, self.obs_size), jax.random.key(0))
        return int(sum(np.prod(x.shape) for x in jax.tree.leaves((st.actor, st.critic))))
