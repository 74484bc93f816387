"""What TD3 and SAC learn from: a batch whose rows carry their own discount, and the helpers that
build it from the replay buffer's 1-step transitions (one step, or an n-step window).

    target = reward + discount * (1 - done) * V(next_obs)          (V: the learner's bootstrap)

One-step rows have discount = gamma. An n-step row sums k <= n rewards of one episode,
reward = sum_i gamma^i r_i, and bootstraps with discount = gamma^k from the observation after its
k-th step; k < n where the window meets an episode's end. The learners' target is then one line for
both, and gamma (traced) enters where rewards are summed, so the buffer keeps 1-step rows and a
sweep over gamma or n needs nothing stored differently.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from fedjax_nav.agents.buffer import Transition


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


def soft_update(target, online, tau):
    """target <- (1 - tau) target + tau online (any matching pytrees; tau traced)."""
    return jax.tree.map(lambda t, p: (1.0 - tau) * t + tau * p, target, online)


def adam_step(tx, params, grads, opt_state, lr):
    """One step of a learning-rate-free optax transformation (Adam: `optax.scale_by_adam()`),
    scaled by -lr by hand so that lr is traced (as ddpg.update does)."""
    upd, opt_state = tx.update(grads, opt_state, params)
    return jax.tree.map(lambda p, u: p - lr * u, params, upd), opt_state
