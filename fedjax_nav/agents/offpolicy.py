"""What TD3 and SAC learn from: a batch whose rows carry their own discount, and the helpers that
build it from the replay buffer's 1-step transitions (one step, or an n-step window); then what the
two share beside it: the modules (an actor and twin critics), their initialisation, the bootstrapped
target, the twin critics' Adam step and the soft target update.

    target = reward + discount * (1 - done) * V(next_obs)          (V: the learner's bootstrap)

One-step rows have discount = gamma. An n-step row sums k <= n rewards of one episode,
reward = sum_i gamma^i r_i, and bootstraps with discount = gamma^k from the observation after its
k-th step; k < n where the window meets an episode's end. The learners' target is then one line for
both, and gamma (traced) enters where rewards are summed, so the buffer keeps 1-step rows and a
sweep over gamma or n needs nothing stored differently.
"""

from __future__ import annotations

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct

from fedjax_nav.agents.buffer import Transition
from fedjax_nav.agents.networks import Critic
from fedjax_nav.agents.networks_extra import twin_apply, twin_init

# Adam without its learning rate: `adam_step` applies a traced one (a sweep over it compiles once).
ADAM = optax.scale_by_adam()


@struct.dataclass
class Batch:
    obs: jax.Array  # f32[..., obs]
    action: jax.Array  # f32[..., A] in box units
    reward: jax.Array  # f32[...]  (n-step: the discounted sum)
    next_obs: jax.Array  # f32[..., obs] the observation bootstrapped from (a time-out's true last one)
    done: jax.Array  # f32[...]  1: terminated (goal, collision): no bootstrap
    discount: jax.Array  # f32[...]  gamma^k


def one_step(tr: Transition, gamma) -> Batch:
    """1-step rows (any leading shape): discount = gamma. `tr.done` is 1 on termination only, so a
    time-out row bootstraps from its `next_obs` (the true last observation)."""
    return Batch(tr.obs, tr.action, tr.reward, tr.next_obs, tr.done, jnp.full_like(tr.reward, gamma))


def nstep(window: Transition, end: jax.Array, gamma) -> Batch:
    """One n-step row from n consecutive 1-step transitions of ONE environment (fields f32[n, ...]).

    end: f32/bool[n], 1 where transition i ends its episode (terminated or truncated), or where the
    window must stop (the newest row of the buffer: it then bootstraps there, like a time-out).
    The row starts at transition 0 and runs to the first end (inclusive) or to n: k steps,
    reward = sum_{i<k} gamma^i r_i, next_obs = next_obs[k-1], done = done[k-1], discount = gamma^k.
    vmap it over a batch of windows."""
    n = window.reward.shape[0]
    end = jnp.asarray(end, jnp.float32)
    # alive[i]: transitions 0..i-1 did not end the episode, so transition i belongs to the row
    alive = jnp.concatenate([jnp.ones((1,), jnp.float32), jnp.cumprod(1.0 - end[:-1])])
    powers = gamma ** jnp.arange(n, dtype=jnp.float32)
    k = jnp.sum(alive).astype(jnp.int32)
    last = k - 1
    return Batch(
        obs=window.obs[0],
        action=window.action[0],
        reward=jnp.sum(alive * powers * window.reward),
        next_obs=window.next_obs[last],
        done=window.done[last],
        discount=gamma ** k.astype(jnp.float32),
    )


@struct.dataclass
class TwinNets:
    """TD3's and SAC's modules (static): the actor and ONE of the twin critics, whose parameters
    are stacked on a leading axis of 2 (`networks_extra.twin_init`)."""

    actor: nn.Module = struct.field(pytree_node=False)
    critic: Critic = struct.field(pytree_node=False)  # one of the twins


def init_twin(nets, key: jax.Array, obs_size: int, action_size: int = 2) -> tuple[dict, dict]:
    """(actor parameters, the twin critics' parameters [2, ...]) from one key (split in two)."""
    ka, kc = jax.random.split(key)
    obs, act = jnp.zeros((obs_size,)), jnp.zeros((action_size,))
    return nets.actor.init(ka, obs), twin_init(nets.critic, kc, obs, act)


def copy(tree):
    """A copy of a pytree of arrays: a target starts as its online network's copy, not the same
    buffers (jit may donate the state)."""
    return jax.tree.map(jnp.copy, tree)


def min_q(critic: Critic, critics: dict, obs: jax.Array, action: jax.Array) -> jax.Array:
    """min_j Q_j(obs, action) over the twins, f32[B]."""
    return jnp.min(twin_apply(critic, critics, obs, action), axis=0)


def td_target(batch: Batch, v_next: jax.Array) -> jax.Array:
    """y = reward + discount (1 - done) v_next, f32[B], with no gradient through it; v_next is the
    learner's bootstrap (TD3: the twins' min; SAC: minus alpha log pi too)."""
    return jax.lax.stop_gradient(batch.reward + batch.discount * (1.0 - batch.done) * v_next)


def critic_step(critic: Critic, critics: dict, opt_state, batch: Batch, y: jax.Array, lr):
    """One Adam step of both critics on sum_j mean (Q_j(s, a) - y)^2. Returns (critics, opt_state,
    the loss f32[], Q f32[2, B] before the step)."""

    def loss(p):
        q = twin_apply(critic, p, batch.obs, batch.action)  # [2, B]
        return jnp.sum(jnp.mean((q - y) ** 2, axis=-1)), q

    (c_loss, q), grads = jax.value_and_grad(loss, has_aux=True)(critics)
    critics, opt_state = adam_step(ADAM, critics, grads, opt_state, lr)
    return critics, opt_state, c_loss, q


def soft_update(target, online, tau):
    """target <- (1 - tau) target + tau online (any matching pytrees; tau traced)."""
    return jax.tree.map(lambda t, p: (1.0 - tau) * t + tau * p, target, online)


def adam_step(tx, params, grads, opt_state, lr):
    """One step of a learning-rate-free optax transformation (Adam: `optax.scale_by_adam()`),
    scaled by -lr by hand so that lr is traced (as ddpg.update does)."""
    upd, opt_state = tx.update(grads, opt_state, params)
    return jax.tree.map(lambda p, u: p - lr * u, params, upd), opt_state
