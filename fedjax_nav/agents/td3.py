"""TD3 (Fujimoto et al. 2018) for one agent as pure functions (vmap over agents, seeds).

Algorithm outline (the trainer's loop; rejax's td3.py in the same shape):
    every step: a = clip(mu(s) + N(0, (sigma_expl * half)^2), box)   (`act`); store (s, a, r, s', done)
    every update k: batch B from the buffer -> `offpolicy.one_step` / `offpolicy.nstep`
        critic: a' = clip(mu_targ(s') + clip(sigma N(0, 1), -c, c) * half, box)   (target smoothing)
                y  = r + discount (1 - done) min_j Q_targ_j(s', a')            (twin critics)
                minimise sum_j mean (Q_j(s, a) - y)^2
        if k % policy_delay == 0 (the trainer's `actor_step` flag):
                actor: maximise mean Q_1(s, mu(s))
                targets: targ <- (1 - tau) targ + tau online   (actor and both critics)

half = the action box's half-widths (0.5, 1): noise is in units of the box, as the TD3 paper's is
in units of max_action. The actor is networks.Actor, DDPG's, so `greedy` and export are DDPG's.
Adam as `optax.scale_by_adam()` with the learning rate applied by hand. `hp` is the config's traced
values (config.traced.HParams, read duck-typed: this layer does not import config): `hp.offpolicy.lr`
(actor and critic) and `hp.td3.tau`, `.policy_noise`, `.noise_clip`; a sweep over them compiles
once. The Nets fix shapes.

Federated: what a round averages (actor, critics; the `_targ` copies only with `fed.include_targets`)
is TD3's row of fedjax_nav/learner_table.py; the Adam moments stay local.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax
from flax import struct

from fedjax_nav.agents import distributions as dist
from fedjax_nav.agents.networks import Actor, Critic
from fedjax_nav.agents.offpolicy import (
    ADAM,
    Batch,
    adam_step,
    copy,
    critic_step,
    init_twin,
    min_q,
    soft_update,
    td_target,
)
from fedjax_nav.agents.offpolicy import TwinNets as Nets


@struct.dataclass
class State:
    actor: dict
    critics: dict  # the twins' parameters stacked on a leading axis of 2
    actor_targ: dict
    critics_targ: dict
    actor_opt: optax.OptState
    critic_opt: optax.OptState


def make_nets(hidden: int = 64, depth: int = 3, activation: str = "relu") -> Nets:
    """DDPG's actor (networks.Actor) and one of the twin critics."""
    return Nets(Actor(hidden, depth, activation), Critic(hidden, depth, activation))


def init(nets: Nets, key: jax.Array, obs_size: int, action_size: int = 2) -> State:
    actor, critics = init_twin(nets, key, obs_size, action_size)
    return State(actor, critics, copy(actor), copy(critics), ADAM.init(actor), ADAM.init(critics))


def greedy(nets: Nets, actor_params: dict, obs: jax.Array) -> jax.Array:
    """The deterministic action mu(s) (evaluation, export): f32[A] in box units."""
    return nets.actor.apply(actor_params, obs)


def act(nets: Nets, actor_params: dict, obs: jax.Array, key: jax.Array, expl_noise=0.1) -> jax.Array:
    """Exploration: mu(s) plus Gaussian noise of std expl_noise box half-widths (traced; the TD3
    paper's 0.1), clipped to the box."""
    low, high = dist.ACTION_LOW, dist.ACTION_HIGH
    _, half = dist.affine(low, high)
    mu = greedy(nets, actor_params, obs)
    return jnp.clip(mu + expl_noise * half * jax.random.normal(key, mu.shape), low, high)


def target_action(mu_next: jax.Array, noise: jax.Array, policy_noise, noise_clip) -> jax.Array:
    """Target policy smoothing: clip(mu' + clip(policy_noise * noise, -c, c) * half, box); noise
    is standard normal, f32[..., A]."""
    _, half = dist.affine()
    eps = jnp.clip(policy_noise * noise, -noise_clip, noise_clip)
    return jnp.clip(mu_next + eps * half, dist.ACTION_LOW, dist.ACTION_HIGH)


def target(nets: Nets, state: State, batch: Batch, key: jax.Array, hp) -> jax.Array:
    """The critics' regression target y = r + discount (1 - done) min_j Q_targ_j(s', a'), f32[B]
    (no gradient flows through it)."""
    mu_next = nets.actor.apply(state.actor_targ, batch.next_obs)
    a_next = target_action(mu_next, jax.random.normal(key, mu_next.shape), hp.td3.policy_noise, hp.td3.noise_clip)
    return td_target(batch, min_q(nets.critic, state.critics_targ, batch.next_obs, a_next))


def update_critic(nets: Nets, state: State, batch: Batch, key: jax.Array, hp) -> tuple[State, dict]:
    """One Adam step of both critics towards the smoothed twin target."""
    y = target(nets, state, batch, key, hp)
    critics, opt, c_loss, q = critic_step(nets.critic, state.critics, state.critic_opt, batch, y, hp.offpolicy.lr)
    return state.replace(critics=critics, critic_opt=opt), {"critic_loss": c_loss, "q": jnp.mean(q)}


def update_actor(nets: Nets, state: State, batch: Batch, hp) -> tuple[State, dict]:
    """One Adam step of the actor on -mean Q_1(s, mu(s)), then the soft target update."""

    def loss(p):
        a = nets.actor.apply(p, batch.obs)
        q1 = nets.critic.apply(jax.tree.map(lambda x: x[0], state.critics), batch.obs, a)
        return -jnp.mean(q1)

    a_loss, grads = jax.value_and_grad(loss)(state.actor)
    actor, opt = adam_step(ADAM, state.actor, grads, state.actor_opt, hp.offpolicy.lr)
    state = update_targets(state.replace(actor=actor, actor_opt=opt), hp.td3.tau)
    return state, {"actor_loss": a_loss}


def update_targets(state: State, tau) -> State:
    return state.replace(
        actor_targ=soft_update(state.actor_targ, state.actor, tau),
        critics_targ=soft_update(state.critics_targ, state.critics, tau),
    )


def update(nets: Nets, state: State, batch: Batch, key: jax.Array, hp, actor_step) -> tuple[State, dict]:
    """The critic step, then (where the bool `actor_step` is set: the trainer's policy delay) the
    actor step and the target update. A `lax.cond`: keep `actor_step` unbatched under vmap (from
    an unbatched counter) so that it stays a branch. Losses: critic_loss, q, actor_loss (0 where
    skipped), actor_step."""
    state, info = update_critic(nets, state, batch, key, hp)

    def skip(s):
        return s, {"actor_loss": jnp.float32(0.0)}

    state, a_info = jax.lax.cond(actor_step, lambda s: update_actor(nets, s, batch, hp), skip, state)
    return state, {**info, **a_info, "actor_step": jnp.asarray(actor_step, jnp.float32)}
