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

`TrainState` is one seed's state; `HParams` holds the traced hyperparameters (each leaf a
scalar, or [S] when swept over seeds/grid points).
"""
from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from fedjax_nav import worlds
from fedjax_nav.agents import buffer as rb
from fedjax_nav.agents import ddpg
from fedjax_nav.config import Config
from fedjax_nav.env import NavEnv, make_params
from fedjax_nav.env.nav import EnvParams, EnvState
from fedjax_nav.federated import aggregators as agg
from fedjax_nav.training import methods


@struct.dataclass
class HParams:
    gamma: jax.Array
    rho: jax.Array
    lr: jax.Array
    train_every: jax.Array
    target_every: jax.Array
    epsilon_start: jax.Array
    epsilon_decay: jax.Array
    tau: jax.Array
    beta: jax.Array
    fed_period: jax.Array
    buffer_size: jax.Array


def hparams_from_config(cfg: Config) -> HParams:
    d, f = cfg.ddpg, cfg.fed
    fl, it = jnp.float32, jnp.int32
    return HParams(
        gamma=fl(d.gamma), rho=fl(d.rho), lr=fl(d.lr), train_every=it(d.train_every),
        target_every=it(d.target_every), epsilon_start=fl(d.epsilon_start),
        epsilon_decay=fl(d.epsilon_decay), tau=fl(f.tau), beta=fl(f.beta), fed_period=it(f.period),
        buffer_size=it(d.buffer_size),
    )


@struct.dataclass
class TrainState:
    """One seed. Leading axes: agents [n_nets], buffers [n_bufs], env_state/obs [robots]."""

    agents: ddpg.AgentState
    buffers: rb.Transition
    env_state: EnvState
    obs: jax.Array  # f32[robots, obs]
    epsilon: jax.Array  # f32[]
    theta_w: dict  # GS: global (actor, critic) params without the client axis; else {}
    reward_sum: jax.Array  # f32[robots] since the last federated step
    reward_steps: jax.Array  # f32[]
    key: jax.Array


class Trainer:
    """Static structure of a run (shapes, method flags, networks, worlds) built from a Config."""

    def __init__(self, cfg: Config):
        self.cfg = cfg
        self.method = methods.get(cfg.method)
        e, d = cfg.env, cfg.ddpg
        self.env = NavEnv(e.num_beams, e.max_range, e.episode_length, mode="learn", collision_test=e.collision_test)
        self.world = worlds.load_many(e.worlds)
        self.env_params: EnvParams = make_params(
            self.world, random_starts=self.method.random_starts, dt=e.dt, v_max=e.v_max, omega_max=e.omega_max,
            goal_radius=e.goal_radius, collision_distance=e.collision_distance, reward_goal=e.reward_goal,
            reward_collision=e.reward_collision, progress_scale=e.progress_scale,
        )
        self.num_robots = cfg.num_robots
        self.n_nets = 1 if self.method.shared_network else self.num_robots
        self.n_bufs = 1 if self.method.shared_buffer else self.num_robots
        self.writes = self.num_robots // self.n_bufs  # rows each buffer receives per step
        self.nets = ddpg.make_nets(d.hidden, d.depth, d.activation)
        self.obs_size = self.env.obs_size
        self.T = e.episode_length

    # ------------------------------------------------------------------ init

    def init(self, key: jax.Array, hp: HParams) -> TrainState:
        """One seed's initial state. Every agent gets its own initialisation key."""
        k_nets, k_env, k_run = jax.random.split(key, 3)
        agents = jax.vmap(lambda k: ddpg.init_agent(self.nets, k, self.obs_size))(jax.random.split(k_nets, self.n_nets))
        buffers = jax.vmap(lambda _: rb.init(self.cfg.buffer_rows, self.obs_size))(jnp.arange(self.n_bufs))
        obs, env_state = jax.vmap(self.env.reset)(jax.random.split(k_env, self.num_robots), self.env_params)
        theta_w = agg.init_global({"actor": agents.actor, "critic": agents.critic}) if self.method.aggregator == "gs" else {}
        return TrainState(
            agents=agents, buffers=buffers, env_state=env_state, obs=obs,
            epsilon=jnp.asarray(hp.epsilon_start, jnp.float32), theta_w=theta_w,
            reward_sum=jnp.zeros(self.num_robots), reward_steps=jnp.float32(0), key=k_run,
        )

    def init_seeds(self, seeds: jax.Array, hp: HParams, mesh=None) -> TrainState:
        """Stacked states for integer seeds i32[S] (hp leaves scalar or [S]); with a `mesh`
        (`fedjax_nav.parallel`), created already sharded over it."""
        init = jax.vmap(lambda s, h: self.init(jax.random.key(s), h), in_axes=(0, hp_axes(hp)))
        if mesh is None:
            return jax.jit(init)(seeds, hp)  # jit: op-by-op init of the buffers took ~20 s under load
        from fedjax_nav import parallel

        self.check_mesh(mesh, len(seeds))
        shardings = parallel.state_shardings(jax.eval_shape(init, seeds, hp), mesh)
        return jax.jit(init, out_shardings=shardings)(np.asarray(seeds), hp)

    # ------------------------------------------------------------------ pieces

    def _act(self, state: TrainState, key: jax.Array) -> jax.Array:
        actor = state.agents.actor
        if self.method.shared_network:
            greedy = jax.vmap(ddpg.act, in_axes=(None, None, 0))(self.nets, jax.tree.map(lambda p: p[0], actor), state.obs)
        else:
            greedy = jax.vmap(ddpg.act, in_axes=(None, 0, 0))(self.nets, actor, state.obs)
        keys = jax.random.split(key, self.num_robots)
        return jax.vmap(ddpg.epsilon_greedy, in_axes=(0, 0, None))(keys, greedy, state.epsilon)

    def _capacity(self, hp: HParams) -> jax.Array:
        """The active buffer capacity, never beyond the allocated rows (a swept value may be)."""
        return jnp.minimum(hp.buffer_size, self.cfg.buffer_rows)

    def _update(self, agents: ddpg.AgentState, buffers: rb.Transition, key, count, hp: HParams):
        """One gradient step for every network, each on its own batch."""

        def one(agent, buf, k):
            batch = rb.sample(buf, k, self.cfg.ddpg.batch_size, count, self._capacity(hp))
            return ddpg.update(self.nets, agent, batch, hp.gamma, hp.lr)

        keys = jax.random.split(key, self.n_nets)
        buf_axis = 0 if self.n_bufs == self.n_nets else None
        bufs = buffers if buf_axis == 0 else jax.tree.map(lambda b: b[0], buffers)
        return jax.vmap(one, in_axes=(0, buf_axis, 0))(agents, bufs, keys)

    def federated_step(self, state: TrainState, hp: HParams) -> TrainState:
        kind = self.method.aggregator
        r = state.reward_sum / jnp.maximum(state.reward_steps, 1.0)
        a = state.agents
        groups = [("actor", "critic")] + ([("actor_targ", "critic_targ")] if self.cfg.fed.include_targets else [])
        theta_w = state.theta_w
        for names in groups:
            params = {"actor": getattr(a, names[0]), "critic": getattr(a, names[1])}
            if kind == "gs" and names[0] == "actor_targ":
                # targets follow the same global model as the nets (theta_w was updated just above)
                new = jax.tree.map(lambda w, p: jnp.broadcast_to(w[None], p.shape), theta_w, params)
            else:
                new, tw = agg.aggregate(kind, params, r, hp.tau, hp.beta, theta_w)
                theta_w = tw if names[0] == "actor" else theta_w
            a = a.replace(**{names[0]: new["actor"], names[1]: new["critic"]})
        return state.replace(agents=a, theta_w=theta_w, reward_sum=jnp.zeros_like(state.reward_sum),
                             reward_steps=jnp.float32(0))

    def _step(self, hp: HParams, carry, g):
        """One env step of every robot, with the periodic updates. g: global step (unbatched)."""
        state, acc = carry
        key, k_act, k_env, k_upd = jax.random.split(state.key, 4)
        actions = self._act(state, k_act)
        env_keys = jax.random.split(k_env, self.num_robots)
        obs2, env_state, reward, term, trunc, info = jax.vmap(self.env.step)(env_keys, state.env_state, actions, self.env_params)
        rows = rb.Transition(state.obs, actions, reward, obs2, term.astype(jnp.float32))
        rows = jax.tree.map(lambda x: x.reshape(self.n_bufs, self.writes, *x.shape[1:]), rows)
        buffers = jax.vmap(rb.add, in_axes=(0, 0, None, None))(state.buffers, rows, g * self.writes, self._capacity(hp))

        count = (g + 1) * self.writes
        ready = count >= self.cfg.ddpg.batch_size
        do_update = ready & ((g + 1) % hp.train_every == 0)
        zeros = jnp.zeros(self.n_nets)
        agents, losses = jax.lax.cond(
            do_update,
            lambda a: self._update(a, buffers, k_upd, count, hp),
            lambda a: (a, {"critic_loss": zeros, "actor_loss": zeros, "q": zeros}),
            state.agents,
        )
        do_target = ready & ((g + 1) % hp.target_every == 0)
        agents = jax.lax.cond(do_target, lambda a: jax.vmap(ddpg.update_targets, in_axes=(0, None))(a, hp.rho),
                              lambda a: a, agents)
        state = state.replace(agents=agents, buffers=buffers, env_state=env_state, obs=obs2, key=key,
                              epsilon=state.epsilon * hp.epsilon_decay,
                              reward_sum=state.reward_sum + reward, reward_steps=state.reward_steps + 1.0)
        fed_now = jnp.bool_(False)
        if self.method.aggregator != "none" and self.cfg.fed.period_unit == "steps":
            fed_now = (g + 1) % hp.fed_period == 0
            state = jax.lax.cond(fed_now, lambda s: self.federated_step(s, hp), lambda s: s, state)
        acc = {
            "reward": acc["reward"] + reward,
            "goals": acc["goals"] + info["goal"].astype(jnp.int32),
            "collisions": acc["collisions"] + info["collision"].astype(jnp.int32),
            "critic_loss": acc["critic_loss"] + losses["critic_loss"],
            "actor_loss": acc["actor_loss"] + losses["actor_loss"],
            "q": acc["q"] + losses["q"],
            "updates": acc["updates"] + do_update.astype(jnp.int32),
            "fed_events": acc["fed_events"] + fed_now.astype(jnp.int32),
        }
        return (state, acc), None

    def episode(self, state: TrainState, hp: HParams, ep: jax.Array) -> tuple[TrainState, dict]:
        """One episode of T steps for one seed; ep (the episode index) must be unbatched."""
        key, k_reset = jax.random.split(state.key)
        obs, env_state = jax.vmap(self.env.reset)(jax.random.split(k_reset, self.num_robots), self.env_params)
        state = state.replace(obs=obs, env_state=env_state, key=key)
        n, k = self.num_robots, self.n_nets
        acc = {"reward": jnp.zeros(n), "goals": jnp.zeros(n, jnp.int32), "collisions": jnp.zeros(n, jnp.int32),
               "critic_loss": jnp.zeros(k), "actor_loss": jnp.zeros(k), "q": jnp.zeros(k),
               "updates": jnp.int32(0), "fed_events": jnp.int32(0)}
        steps = ep * self.T + jnp.arange(self.T)
        (state, acc), _ = jax.lax.scan(partial(self._step, hp), (state, acc), steps)
        if self.method.aggregator != "none" and self.cfg.fed.period_unit == "episodes":
            fed_now = (ep + 1) % hp.fed_period == 0
            state = jax.lax.cond(fed_now, lambda s: self.federated_step(s, hp), lambda s: s, state)
            acc["fed_events"] = acc["fed_events"] + fed_now.astype(jnp.int32)
        nupd = jnp.maximum(acc.pop("updates"), 1)
        metrics = {
            "reward": acc["reward"] / self.T,  # mean reward per step, per robot
            "goals": acc["goals"],
            "collisions": acc["collisions"],
            "critic_loss": acc["critic_loss"] / nupd,  # per network
            "actor_loss": acc["actor_loss"] / nupd,
            "q": acc["q"] / nupd,
            "fed_events": acc["fed_events"],
            "epsilon": state.epsilon,
            "params_finite": jax.vmap(_all_finite)((state.agents.actor, state.agents.critic)),  # [n_nets]
        }
        return state, metrics

    def chunk(self, states: TrainState, hp: HParams, first_episode: jax.Array, num_episodes: int):
        """`num_episodes` episodes for every seed. Metrics leaves: [seeds, num_episodes, ...]."""

        def one_seed(state, h):
            eps = first_episode + jnp.arange(num_episodes)
            return jax.lax.scan(lambda s, e: self.episode(s, h, e), state, eps)

        return jax.vmap(one_seed, in_axes=(0, hp_axes(hp)))(states, hp)

    def compiled_chunk(self, num_episodes: int | None = None, mesh=None, states=None, hp: HParams | None = None,
                       on_trace=None):
        """jit(chunk) with the states donated (the replay buffers are updated in place).

        With a `mesh` (see `fedjax_nav.parallel`), `states` and `hp` (templates: arrays or
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
        from fedjax_nav import parallel

        if states is None or hp is None:
            raise ValueError("compiled_chunk(mesh=...) needs the states and hp templates")
        self.check_mesh(mesh, jax.tree.leaves(states.epsilon)[0].shape[0])
        st = parallel.state_shardings(states, mesh)
        rep = parallel.replicated(mesh)
        return jax.jit(fn, donate_argnums=0, in_shardings=(st, parallel.seed_shardings(hp, mesh), rep),
                       out_shardings=(st, rep))

    def check_mesh(self, mesh, num_seeds: int) -> None:
        """Raise `parallel.ShardingError` if this run cannot be placed on `mesh`."""
        from fedjax_nav import parallel

        parallel.check_placement(mesh, num_seeds, self.num_robots, self.method.shared_network,
                                 self.method.shared_buffer)

    def num_params(self) -> int:
        """Parameters of one agent (actor + critic), what one client sends per federated round."""
        st = jax.eval_shape(lambda k: ddpg.init_agent(self.nets, k, self.obs_size), jax.random.key(0))
        return int(sum(np.prod(x.shape) for x in jax.tree.leaves((st.actor, st.critic))))


def _all_finite(tree) -> jax.Array:
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in jax.tree.leaves(tree)]))


def hp_axes(hp: HParams):
    """vmap in_axes for HParams: 0 for leaves with a batch axis, None for scalars."""
    return jax.tree.map(lambda x: 0 if jnp.ndim(x) else None, hp)
