"""Learners as data: everything the trainer needs of DDPG, TD3, SAC and PPO, one table entry each
(as `federated.aggregators.RULES` is for the servers' rules). The trainer calls these functions and
never looks at a learner's name (docs/learners.md, "The trainer's side").

    learner = get(cfg.learner)                         # its row in fedjax_nav.learner_table, resolved
    nets = learner.make_nets(config.values(cfg))     # static: modules, batch and loop sizes
    state = learner.init(nets, key, obs_size, hp)      # one agent
    carry = learner.explore_init(hp)                   # the exploration carry (DDPG: epsilon), per seed
    action, extra, memory = learner.explore(nets, state, obs, key, hp, carry, memory, first)
    carry = learner.explore_next(carry, hp)            # after every step
    storage = learner.storage(nets, obs_size, rows)    # one buffer: replay rows, or a rollout
    storage = learner.store(nets, storage, record, g, rows, hp)
    state, losses = learner.update(nets, state, storage, key, g, rows, hp)    # where learner.due(...)
    v, memory = learner.value(nets, params, obs, memory, first)   # the evaluation's learned value

Every function is for ONE agent, ONE buffer or ONE environment, unbatched (the trainer adds agents,
environments and seeds with vmap). `hp` is the trainer's HParams (config.traced: the traced config
values, `hp.td3.tau`; each learner reads its own section and the shared off-policy ones of `hp.offpolicy`); `g` is the
global step, an unbatched i32 (the gates stay real conds); `rows` (static) is how many rows one
buffer receives per step. `record` is a `Record` with a leading [rows] axis.

Off-policy learners (DDPG, TD3, SAC) store 1-step rows in the replay buffer (`buffer.Transition`,
`done` = terminated only, `next_obs` = the true last observation: a time-out bootstraps) and learn
`gradient_steps` batches per update event. With `offpolicy.n_step` = n > 1 the buffer also keeps the
truncation flags (`buffer.EpisodeRows`) and a batch is n-step rows (`offpolicy.nstep` over
`buffer.sample_windows`): n rewards of one environment summed, cut at an episode's end or at the
newest row, bootstrapped with gamma^k (`offpolicy.Batch.discount`). PPO (learner_ppo.py) keeps a
rollout of `ppo.rollout` steps and learns from it when it is full.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
from flax import struct

from fedjax_nav import learner_table
from fedjax_nav.agents import buffer as rb
from fedjax_nav.agents import ddpg, sac, td3
from fedjax_nav.agents import learner_ppo as lp
from fedjax_nav.agents.networks import ACTIVATIONS_OUTSIDE, ACTIVATIONS_PER_LAYER, Critic
from fedjax_nav.agents.networks_extra import SquashedGaussianActor
from fedjax_nav.agents.offpolicy import Batch, min_q, nstep, one_step


class Record(NamedTuple):
    """What one env step hands to a learner's storage (leading axis: the buffer's rows)."""

    obs: jax.Array  # f32[obs] what the policy saw
    action: jax.Array  # f32[A] the box action taken
    reward: jax.Array  # f32[]
    next_obs: jax.Array  # f32[obs] the true observation reached (an episode's last one at its end)
    terminated: jax.Array  # bool[] goal or collision: no bootstrap
    truncated: jax.Array  # bool[] the episode's last step: bootstrap from next_obs
    first: Any  # bool[] obs starts an episode (learners with a memory), else None
    extra: Any  # what `explore` returned beside the action (PPO: raw action, log-density)
    memory: Any  # the learner's carry before this step (PPO: the GRU states), else None


class Learner(NamedTuple):
    """A learner as data plus pure functions (the module docstring gives the call shapes). The
    facts of the learner's row (fedjax_nav.learner_table: name, on_policy, shared, targets, bounds) are
    filled in by `get`; an implementation leaves them at their defaults."""

    metrics: tuple[str, ...]  # the losses `update` reports: the trainer's per-network metrics
    make_nets: Callable  # (values: dict of config values by dotted name) -> nets (static)
    init: Callable  # (nets, key, obs_size, hp) -> state
    memory: Callable  # (nets) -> one environment's carry at an episode start, or None (no memory)
    explore: Callable  # (nets, state, obs, key, hp, carry, memory, first) -> (action, extra, memory)
    policy: Callable  # (state) -> the greedy policy's parameters (probe, evaluation, export)
    greedy: Callable  # (nets, policy, obs, memory, first) -> (action, memory)
    storage: Callable  # (nets, obs_size, rows) -> one empty buffer
    store: Callable  # (nets, storage, record, g, rows, hp) -> storage
    due: Callable  # (nets, g, rows, hp) -> bool[]: an update event after step g
    update: Callable  # (nets, state, storage, key, g, rows, hp) -> (state, {metric: f32[]})
    # (nets, obs_size, rows) -> peak bytes of one `update` of one agent beyond its state and storage:
    # the batches it gathers and its networks' activations and gradients (training.resources)
    update_bytes: Callable
    targets_due: Callable | None = None  # (nets, g, rows, hp) -> bool[]: a separate target update (DDPG)
    targets: Callable | None = None  # (nets, state, hp) -> state
    # (nets, params, obs, memory, first) -> (V f32[], memory): the learned value of one observation,
    # params {network: its parameters} of the row's `value_networks` (params.npz; evaluation.values);
    # None: no value for the evaluation to call
    value: Callable | None = None
    # exploration that is not the agent's: a carry of one seed, stepped once per environment step
    explore_init: Callable = lambda hp: ()  # (hp) -> the carry at step 0
    explore_next: Callable = lambda carry, hp: carry  # (carry, hp) -> the carry after a step
    explore_metric: Callable = lambda carry: jnp.float32(0.0)  # (carry) -> metrics.csv's epsilon column
    name: str = ""  # the row's
    on_policy: bool = False  # the row's: learns from its own policy's rollout, no buffer to share
    shared_fields: tuple[str, ...] = ()  # the row's `shared`: what a federated round averages
    target_fields: tuple[str, ...] = ()  # the row's `targets`: averaged too with fed.include_targets
    bounds: tuple[learner_table.Bound, ...] = ()  # the row's divergence bounds on `metrics` (training.metrics)

    def shared(self, state, include_targets: bool = False) -> dict:
        """What a client sends in a federated round: its SHARED fields (and TARGETS if asked)."""
        names = self.shared_fields + (self.target_fields if include_targets else ())
        return {n: getattr(state, n) for n in names}

    def take_shared(self, state, new: dict):
        """`state` with what a round sent back (`shared`'s keys) put in place."""
        return state.replace(**new)


# ----------------------------------------------------------------------------- off-policy


@struct.dataclass
class OffPolicyNets:
    """The modules (duck-typed as ddpg.Nets, td3.Nets, sac.Nets: `actor` and `critic`) and the
    replay loop's static sizes."""

    actor: nn.Module = struct.field(pytree_node=False)
    critic: nn.Module = struct.field(pytree_node=False)
    batch_size: int = struct.field(pytree_node=False)
    gradient_steps: int = struct.field(pytree_node=False)  # per update event, each on its own batch
    buffer_rows: int = struct.field(pytree_node=False)  # allocated rows (the capacity is traced up to it)
    n_step: int = struct.field(pytree_node=False, default=1)  # steps per target (offpolicy.n_step)


def _off_policy_nets(actor_cls):
    def make(v: dict) -> OffPolicyNets:
        h, d, a = v["offpolicy.hidden"], v["offpolicy.depth"], v["offpolicy.activation"]
        rows = v["offpolicy.buffer_alloc"] or v["offpolicy.buffer_size"]
        batch, steps, n = v["offpolicy.batch_size"], v["offpolicy.gradient_steps"], v["offpolicy.n_step"]
        return OffPolicyNets(actor_cls(h, d, a), Critic(h, d, a), batch, steps, rows, n)

    return make


def capacity(nets: OffPolicyNets, hp) -> jax.Array:
    """The active buffer capacity, never beyond the allocated rows (a swept value may be)."""
    return jnp.minimum(hp.offpolicy.buffer_size, nets.buffer_rows)


def _replay(nets, obs_size: int, rows: int) -> rb.Transition | rb.EpisodeRows:
    """1-step rows, or with n_step > 1 the rows and their truncation flags."""
    if nets.n_step == 1:
        return rb.init(nets.buffer_rows, obs_size)
    return rb.init_episode_rows(nets.buffer_rows, obs_size)


def _store_replay(nets, buf, rec: Record, g, rows: int, hp):
    """Step g's rows at g * rows ... (g + 1) * rows - 1 (mod the capacity), in the record's order:
    environment j's rows of consecutive steps lie `rows` positions apart."""
    t = rb.Transition(rec.obs, rec.action, rec.reward, rec.next_obs, rec.terminated.astype(jnp.float32))
    if nets.n_step == 1:
        return rb.add(buf, t, g * rows, capacity(nets, hp))
    return rb.add_episode_rows(buf, t, rec.truncated.astype(jnp.float32), g * rows, capacity(nets, hp))


def sample_batch(nets, buf, key, count, cap, rows: int, gamma) -> Batch:
    """A batch of nets.batch_size rows drawn uniformly from the `count` rows written (`cap` the
    active capacity): 1-step rows (`one_step`), or with n_step > 1 n-step rows starting at the
    same draws (`buffer.sample_windows`, `offpolicy.nstep`; rows: rows written per step)."""
    if nets.n_step == 1:
        return one_step(rb.sample(buf, key, nets.batch_size, count, cap), gamma)
    windows, end = rb.sample_windows(buf, key, nets.batch_size, count, cap, nets.n_step, rows)
    return jax.vmap(lambda w, e: nstep(w, e, gamma))(windows, end)


def _ready(nets, g, rows: int):
    return (g + 1) * rows >= nets.batch_size


def _due_replay(nets, g, rows: int, hp):
    """Every offpolicy.train_every steps once the buffer holds a batch."""
    return _ready(nets, g, rows) & ((g + 1) % hp.offpolicy.train_every == 0)


def _replay_update(grad_step: Callable, metrics: tuple[str, ...]) -> Callable:
    """An update event: `gradient_steps` calls of grad_step(nets, state, sample, key, hp, i), where
    sample(key) draws a fresh `offpolicy.Batch` (`sample_batch`) and i is the gradient step's index
    in the run (unbatched); the losses averaged over them."""

    def update(nets, state, buf, key, g, rows: int, hp):
        count, cap, n = (g + 1) * rows, capacity(nets, hp), nets.gradient_steps

        def sample(k):
            return sample_batch(nets, buf, k, count, cap, rows, hp.offpolicy.gamma)

        def one(state, k, i):
            state, losses = grad_step(nets, state, sample, k, hp, i)
            return state, {m: losses[m] for m in metrics}

        index = ((g + 1) // hp.offpolicy.train_every - 1) * n  # update events before this one x gradient steps
        if n == 1:
            return one(state, key, index)
        steps = (jax.random.split(key, n), index + jnp.arange(n, dtype=jnp.int32))
        state, losses = jax.lax.scan(lambda s, x: one(s, *x), state, steps)
        return state, jax.tree.map(jnp.mean, losses)

    return update


def _ddpg_step(nets, state, sample, key, hp, i):
    b = sample(key)
    batch = rb.Transition(b.obs, b.action, b.reward, b.next_obs, b.done)
    return ddpg.update(nets, state, batch, b.discount, hp.offpolicy.lr)  # discount: gamma per row, gamma^k n-step


def _split_batch(sample, key):
    """(a fresh batch, the key left for the update)."""
    k_batch, k_step = jax.random.split(key)
    return sample(k_batch), k_step


def _td3_step(nets, state, sample, key, hp, i):
    batch, k_noise = _split_batch(sample, key)
    actor_step = i % hp.td3.policy_delay == 0  # the policy delay, from the unbatched step counter
    return td3.update(nets, state, batch, k_noise, hp, actor_step)


def _sac_step(nets, state, sample, key, hp, i):
    batch, k_step = _split_batch(sample, key)
    return sac.update(nets, state, batch, k_step, hp)


def _no_memory(nets):
    return None


def _actor(state):
    return state.actor


def _stateless(greedy: Callable) -> Callable:
    def act(nets, policy, obs, memory, first):
        return greedy(nets, policy, obs), memory

    return act


def _critic_q(nets, params, obs, action):
    """DDPG's one critic: Q(obs, action)."""
    return nets.critic.apply(params["critic"], obs, action)


def _twin_q(nets, params, obs, action):
    """TD3's and SAC's twin critics: their min, as their targets take it."""
    return min_q(nets.critic, params["critics"], obs, action)


def _q_value(greedy: Callable, q: Callable) -> Callable:
    """V(s) = Q(s, mu(s)) at the greedy action `greedy(nets, actor, obs)`, `q(nets, params, obs,
    action)` the learner's critic (`_critic_q`, `_twin_q`); no memory."""

    def value(nets, params, obs, memory, first):
        return q(nets, params, obs, greedy(nets, params["actor"], obs)), memory

    return value


OFF_POLICY_METRICS = ("critic_loss", "actor_loss", "q")


def _ddpg_explore(nets, state, obs, key, hp, epsilon, memory, first):
    """Epsilon-greedy: `epsilon` is DDPG's exploration carry (ddpg.epsilon_start, times
    ddpg.epsilon_decay after every step)."""
    return ddpg.epsilon_greedy(key, ddpg.act(nets, state.actor, obs), epsilon), (), memory


def _td3_explore(nets, state, obs, key, hp, carry, memory, first):
    return td3.act(nets, state.actor, obs, key, hp.td3.expl_noise), (), memory


def activation_bytes(obs_size: int, hidden: int, depth: int, batch: int, action_size: int = 2) -> int:
    """Peak bytes of one network's replay update beyond its state: the sampled batch (obs,
    next_obs, action, reward, done; and its gathered copy) and the actor's and critic's activations
    and gradients, (5 depth + 3) x hidden f32 per row (measured: `ACTIVATIONS_PER_LAYER`)."""
    row = 2 * (2 * obs_size + action_size + 2)
    per_row = (ACTIVATIONS_PER_LAYER * depth + ACTIVATIONS_OUTSIDE) * hidden + row
    return 4 * per_row * int(batch)


def _replay_bytes(critics: int):
    """One update event of a learner with `critics` critics: `gradient_steps` batches in turn, so one
    batch at a time; a second critic adds half of DDPG's actor-and-critic activations (SAC's and
    TD3's twins: measured 1.2x XLA CPU's temporaries, tests/test_memory_estimate.py)."""

    def size(nets: OffPolicyNets, obs_size: int, rows: int) -> int:
        one = activation_bytes(obs_size, nets.critic.hidden, nets.critic.depth, nets.batch_size)
        return one + (critics - 1) * one // 2

    return size


def _sac_explore(nets, state, obs, key, hp, carry, memory, first):
    return sac.act(nets, state.actor, obs, key), (), memory


def _ddpg_targets_due(nets, g, rows: int, hp):
    return _ready(nets, g, rows) & ((g + 1) % hp.ddpg.target_every == 0)


def _replay_learner(actor_cls, grad_step: Callable, greedy: Callable, **fields) -> Learner:
    """An off-policy learner: `actor_cls` and the critic at the offpolicy.* network sizes, replay rows
    (`_replay`, `_store_replay`, `_due_replay`), `gradient_steps` calls of `grad_step` per update
    event, a stateless `greedy(nets, policy, obs)`, no memory, the value Q(s, greedy(s)). `fields`:
    the Learner's others (init, explore; metrics if not OFF_POLICY_METRICS; DDPG's targets; `q` if
    not `_twin_q`)."""
    metrics = fields.pop("metrics", OFF_POLICY_METRICS)
    critics = fields.pop("critics", 1)  # twin critics (TD3, SAC): `_replay_bytes`
    q = fields.pop("q", _twin_q)
    return Learner(
        metrics=metrics,
        make_nets=_off_policy_nets(actor_cls),
        memory=_no_memory,
        policy=_actor,
        greedy=_stateless(greedy),
        value=_q_value(greedy, q),
        storage=_replay,
        store=_store_replay,
        due=_due_replay,
        update=_replay_update(grad_step, metrics),
        update_bytes=_replay_bytes(critics),
        **fields,
    )


DDPG = _replay_learner(
    ddpg.Actor,
    _ddpg_step,
    ddpg.act,
    init=lambda nets, key, obs_size, hp: ddpg.init_agent(nets, key, obs_size),
    explore=_ddpg_explore,
    q=_critic_q,
    targets_due=_ddpg_targets_due,
    targets=lambda nets, state, hp: ddpg.update_targets(state, hp.ddpg.rho),
    explore_init=lambda hp: jnp.asarray(hp.ddpg.epsilon_start, jnp.float32),
    explore_next=lambda epsilon, hp: epsilon * hp.ddpg.epsilon_decay,
    explore_metric=lambda epsilon: epsilon,
)
TD3 = _replay_learner(
    ddpg.Actor,
    _td3_step,
    td3.greedy,
    init=lambda nets, key, obs_size, hp: td3.init(nets, key, obs_size),
    explore=_td3_explore,
    critics=2,
)
SAC_METRICS = (*OFF_POLICY_METRICS, "alpha", "entropy")
SAC = _replay_learner(
    SquashedGaussianActor,
    _sac_step,
    sac.greedy,
    init=lambda nets, key, obs_size, hp: sac.init(nets, key, obs_size, hp.sac.init_alpha),
    explore=_sac_explore,
    metrics=SAC_METRICS,
    critics=2,
)

PPO = Learner(
    metrics=lp.METRICS,
    make_nets=lp.make_nets,
    init=lp.init,
    memory=lp.memory,
    explore=lp.explore,
    policy=_actor,
    greedy=lp.greedy,
    value=lp.value,
    storage=lp.storage,
    store=lp.store,
    due=lp.due,
    update=lp.update,
    update_bytes=lp.update_bytes,
)


def get(name: str) -> Learner:
    """The learner of a row of fedjax_nav.learner_table (a ValueError naming the allowed ones),
    with the row's facts filled in."""
    row = learner_table.get(name)
    return row.learner()._replace(
        name=row.name,
        on_policy=row.on_policy,
        shared_fields=row.shared,
        target_fields=row.targets,
        bounds=row.bounds,
    )
