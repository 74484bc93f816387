"""One episode of one seed's training program: the step (act, step every environment, store,
the learner's updates, a federated round when due) and the scan over an episode's steps. Pure
functions of the run's `Trainer` (its frozen description: sizes, learner, env, rooms, round) and
the `TrainState`; `Trainer.episode` calls `episode` (docs/architecture.md). `tr` is always the
run's `training.trainer.Trainer` (not imported here: the trainer imports this module).

The step counter `g` and the episode index `ep` enter unbatched over seeds, so the learner's and
the federation's periodic gates are real `lax.cond`s (training/trainer.py says why).
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp

from fedjax_nav.agents.distributions import ACTION_HIGH, ACTION_LOW
from fedjax_nav.agents.learners import Record
from fedjax_nav.env.nav import EnvParams
from fedjax_nav.training import step_metrics
from fedjax_nav.training.hparams import HParams
from fedjax_nav.training.state import TrainState
from fedjax_nav.training.step_metrics import EPISODE_METRICS, NO_ROUND, StepMetrics, all_finite, loss_metrics


def explore(tr, state: TrainState, key: jax.Array, hp: HParams):
    """(actions f32[environments, 2], the learner's extras, its new memory) for one step."""

    def one(agent, obs, k, memory, first):
        return tr.learner.explore(tr.nets, agent, obs, k, hp, state.explore, memory, first)

    keys = tr.robot_rows(key, tr.envs_per_robot)
    return tr.by_net(one, state.agents, state.obs, keys, state.memory, state.first)


def update(tr, agents, buffers, key, g, hp: HParams):
    """One update event of every network, each on its own storage (or all on the shared one)."""

    def one(agent, buf, k):
        return tr.learner.update(tr.nets, agent, buf, k, g, tr.writes, hp)

    keys = tr.robot_rows(key, not tr.method.shared_network)
    buf_axis = 0 if tr.n_bufs == tr.n_nets else None
    bufs = buffers if buf_axis == 0 else jax.tree.map(lambda b: b[0], buffers)
    return jax.vmap(one, in_axes=(0, buf_axis, 0))(agents, bufs, keys)


def step(tr, hp: HParams, env_params: EnvParams, state: TrainState, g) -> tuple[TrainState, StepMetrics]:
    """One env step of every environment, with the periodic updates. g: global step (unbatched).
    Returns the new state and this step's `StepMetrics`."""
    L = tr.learner
    key, k_act, k_env, k_upd = jax.random.split(state.key, 4)
    actions, extra, memory = explore(tr, state, k_act, hp)
    if not L.on_policy:  # the warm-up (offpolicy.random_steps): its own key, the other streams unchanged
        k = jax.random.fold_in(k_act, 1)
        draw = lambda n: jax.random.uniform(k, (n, *actions.shape[1:]), minval=ACTION_LOW, maxval=ACTION_HIGH)
        warm = tr.robot_rows(k, tr.envs_per_robot, draw)
        actions = jnp.where(g < hp.offpolicy.random_steps, warm, actions)
    env_keys = tr.robot_rows(k_env, tr.envs_per_robot)
    obs2, env_state, reward, term, trunc, info = tr.env_step(env_keys, state.env_state, actions, env_params)
    # s' is the true observation at the pose reached, also on a terminal step (obs2 is then
    # the start of the next attempt): `terminated` cuts the bootstrap there, `truncated` does not.
    rec = Record(state.obs, actions, reward, info["final_obs"], term, trunc, state.first, extra, state.memory)
    rec = jax.tree.map(lambda x: x.reshape(tr.n_bufs, tr.writes, *x.shape[1:]), rec)
    buffers = jax.vmap(lambda b, r: L.store(tr.nets, b, r, g, tr.writes, hp))(state.buffers, rec)

    do_update = L.due(tr.nets, g, tr.writes, hp)
    zeros = jnp.zeros(tr.n_nets)
    agents, losses = jax.lax.cond(
        do_update,
        lambda a: update(tr, a, buffers, k_upd, g, hp),
        lambda a: (a, {m: zeros for m in L.metrics}),
        state.agents,
    )
    if L.targets is not None:  # a target update of its own period (DDPG's T_target)
        agents = jax.lax.cond(
            L.targets_due(tr.nets, g, tr.writes, hp),
            lambda a: jax.vmap(lambda x: L.targets(tr.nets, x, hp))(a),
            lambda a: a,
            agents,
        )
    mean_reward = tr.per_robot(reward, jnp.mean)
    state = state.replace(
        agents=agents,
        buffers=buffers,
        env_state=env_state,
        obs=obs2,
        key=key,
        explore=tr.learner.explore_next(state.explore, hp),
        reward_sum=state.reward_sum + mean_reward,
        reward_steps=state.reward_steps + 1.0,
        memory=memory,
        first=None if state.first is None else term,  # after a goal or collision obs2 is a start
    )
    outcome = {}
    if tr.rooms.learnability:  # per environment, for its room's score: an attempt ends in a goal,
        # a collision (terminated) or the episode's time-out (truncated, the last step only)
        outcome = {"env_goals": info["goal"].astype(jnp.int32), "env_attempts": (term | trunc).astype(jnp.int32)}
    if tr.rooms.shared:  # robot i's collisions with the robots of its rooms (also in `collisions`)
        outcome["robot_collisions"] = tr.per_robot(info["robot_collision"].astype(jnp.int32))
    fed_now, fs = jnp.bool_(False), NO_ROUND
    if tr.rounds and tr.cfg.fed.period_unit == "steps":
        fed_now = (g + 1) % hp.fed.period == 0
        state, fs = jax.lax.cond(fed_now, lambda s: tr.federated_round(s, hp), lambda s: (s, NO_ROUND), state)
    out = StepMetrics(
        reward=mean_reward,
        goals=tr.per_robot(info["goal"].astype(jnp.int32)),
        collisions=tr.per_robot(info["collision"].astype(jnp.int32)),
        losses=losses,
        updates=do_update.astype(jnp.int32),
        fed_events=fed_now.astype(jnp.int32),
        fed_clients=fs["clients"],
        fed_skipped=fs["skipped"],
        **outcome,
    )
    return state, out


def episode(tr, state: TrainState, hp: HParams, ep: jax.Array) -> tuple[TrainState, dict]:
    """One episode of T steps for one seed; ep (the episode index) must be unbatched."""
    state, world = tr.rooms.episode_world(state, hp, ep)  # new rooms / placements when configured
    env_params = tr.env_params(hp, world)
    key, k_reset = jax.random.split(state.key)
    obs, env_state = jax.vmap(tr.env.reset)(tr.robot_rows(k_reset, tr.envs_per_robot), env_params)
    first = None if state.first is None else jnp.ones_like(state.first)
    state = state.replace(obs=obs, env_state=env_state, key=key, first=first)
    steps = ep * tr.T + jnp.arange(tr.T)
    one_step = partial(step, tr, hp, env_params)

    def body(carry, g):  # the step metrics are summed in the carry: see EPISODE_METRICS
        state, sums = carry
        state, m = one_step(state, g)
        return (state, jax.tree.map(jnp.add, sums, m)), None

    zeros = jax.tree.map(lambda x: jnp.zeros(x.shape, x.dtype), jax.eval_shape(one_step, state, steps[0])[1])
    (state, sums), _ = jax.lax.scan(body, (state, zeros), steps)
    if tr.rooms.learnability:  # the episode's goal share scores each environment's room
        state = state.replace(bank=tr.rooms.score(state.bank, hp, sums.env_goals, sums.env_attempts))
    fed_end, fs = jnp.int32(0), NO_ROUND
    if tr.rounds and tr.cfg.fed.period_unit == "episodes":
        fed_now = (ep + 1) % hp.fed.period == 0
        state, fs = jax.lax.cond(fed_now, lambda s: tr.federated_round(s, hp), lambda s: (s, NO_ROUND), state)
        fed_end = fed_now.astype(jnp.int32)
    metrics = {name: reduce(sums, tr.T) for name, reduce in EPISODE_METRICS.items()}
    metrics |= loss_metrics(sums, tr.learner.metrics) | step_metrics.optional_metrics(sums)
    metrics["fed_events"] = metrics["fed_events"] + fed_end
    metrics["fed_clients"] = metrics["fed_clients"] + fs["clients"]
    metrics["fed_skipped"] = metrics["fed_skipped"] + fs["skipped"]
    metrics["epsilon"] = tr.learner.explore_metric(state.explore)
    metrics["params_finite"] = jax.vmap(all_finite)(tr.learner.shared(state.agents))  # [n_nets]
    if tr.rooms.learnability:  # room_p, fresh_rooms: [robots], means over each robot's environments
        metrics |= {k: tr.per_robot(v, jnp.mean) for k, v in tr.rooms.bank_metrics(state.bank).items()}
    if tr.probe is not None:  # run.eval_every: greedy success on the held-out probe, NaN between
        every = tr.cfg.run.eval_every
        metrics["eval_success"] = jax.lax.cond(
            (ep + 1) % every == 0,
            lambda a: tr.probe.success(a, hp),
            lambda a: jnp.full(tr.n_nets, jnp.nan),
            tr.policy(state.agents),
        )
    if tr.pad:  # the padding clients' rows are not results
        metrics = jax.tree.map(lambda x: x[: tr.n_real] if x.ndim and x.shape[0] == tr.num_robots else x, metrics)
    return state, metrics
