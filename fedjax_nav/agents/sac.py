"""SAC with a learned temperature (Haarnoja et al. 2018, "SAC: algorithms and applications") for
one agent as pure functions (vmap over agents, seeds).

Algorithm outline (the trainer's loop; rejax's sac.py and brax's sac/losses.py in the same shape):
    every step: a ~ pi(.|s), the tanh-squashed Gaussian on the box (`act`); store (s, a, r, s', done)
    every update: batch B from the buffer -> `offpolicy.one_step` / `offpolicy.nstep`
        critic:  a' ~ pi(.|s'),  y = r + discount (1 - done) (min_j Q_targ_j(s', a') - alpha log pi(a'|s'))
                 minimise sum_j mean (Q_j(s, a) - y)^2
        actor:   a~ ~ pi(.|s) reparameterised,  minimise mean (alpha log pi(a~|s) - min_j Q_j(s, a~))
        alpha:   minimise mean (alpha * stop_grad(-log pi(a~|s) - target_entropy)),  alpha = exp(log_alpha)
        targets: targ <- (1 - tau) targ + tau online   (both critics, every update)

The log-densities are in box units (tanh and affine Jacobians: distributions.py), so the default
target entropy -action_size is for the box [0, 1] x [-1, 1]. The alpha loss's gradient in log_alpha
is alpha (H - target_entropy) with H the batch's entropy estimate: above the target the
temperature falls. `hp` is the config's traced values (config.traced.HParams, read duck-typed):
`hp.offpolicy.lr` (actor and critics) and `hp.sac.alpha_lr`, `.tau`, `.target_entropy`; they and
`init`'s init_alpha are traced; Nets fix shapes.

Federated: a round averages actor, critics and log_alpha (the temperature belongs with the policy
whose entropy it tunes), critics_targ only with `fed.include_targets`: SAC's row of
fedjax_nav/learner_table.py; the Adam moments stay local.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax
from flax import struct

from fedjax_nav.agents import distributions as dist
from fedjax_nav.agents.networks import Critic
from fedjax_nav.agents.networks_extra import SquashedGaussianActor
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
    critics_targ: dict
    log_alpha: jax.Array  # f32[]
    actor_opt: optax.OptState
    critic_opt: optax.OptState
    alpha_opt: optax.OptState


def make_nets(hidden: int = 64, depth: int = 2, activation: str = "relu", action_size: int = 2) -> Nets:
    return Nets(SquashedGaussianActor(hidden, depth, activation, action_size), Critic(hidden, depth, activation))


def init(nets: Nets, key: jax.Array, obs_size: int, init_alpha=1.0, action_size: int = 2) -> State:
    """init_alpha: the initial temperature (traced)."""
    actor, critics = init_twin(nets, key, obs_size, action_size)
    log_alpha = jnp.log(jnp.asarray(init_alpha, jnp.float32))
    return State(
        actor=actor,
        critics=critics,
        critics_targ=copy(critics),
        log_alpha=log_alpha,
        actor_opt=ADAM.init(actor),
        critic_opt=ADAM.init(critics),
        alpha_opt=ADAM.init(log_alpha),
    )


def act(nets: Nets, actor_params: dict, obs: jax.Array, key: jax.Array) -> jax.Array:
    """Exploration: a draw from the policy, f32[A] in the box."""
    mean, log_std = nets.actor.apply(actor_params, obs)
    return dist.sample(key, mean, log_std)[0]


def greedy(nets: Nets, actor_params: dict, obs: jax.Array) -> jax.Array:
    """The deterministic action: the squashed mean."""
    return dist.mode(nets.actor.apply(actor_params, obs)[0])


def _sample(nets: Nets, actor_params: dict, obs: jax.Array, key: jax.Array):
    mean, log_std = nets.actor.apply(actor_params, obs)
    a, _, logp = dist.sample(key, mean, log_std)
    return a, logp


def alpha_loss(log_alpha: jax.Array, log_prob: jax.Array, target_entropy) -> jax.Array:
    """mean(alpha * stop_grad(-log_prob - target_entropy)) (brax's form); log_prob f32[B]."""
    return jnp.mean(jnp.exp(log_alpha) * jax.lax.stop_gradient(-log_prob - target_entropy))


def target(nets: Nets, state: State, batch: Batch, key: jax.Array) -> jax.Array:
    """The critics' soft target y f32[B], with the current actor and temperature (no gradient)."""
    a_next, logp_next = _sample(nets, state.actor, batch.next_obs, key)
    v_next = min_q(nets.critic, state.critics_targ, batch.next_obs, a_next) - jnp.exp(state.log_alpha) * logp_next
    return td_target(batch, v_next)


def update(nets: Nets, state: State, batch: Batch, key: jax.Array, hp) -> tuple[State, dict]:
    """Critic step, actor step (against the updated critics), temperature step (on the actor
    step's log-densities), soft target update. Losses: critic_loss, actor_loss, alpha_loss, alpha
    (before this step), entropy (the batch's estimate -mean log pi), q."""
    k_target, k_actor = jax.random.split(key)
    alpha = jnp.exp(state.log_alpha)
    y = target(nets, state, batch, k_target)

    critics, critic_opt, c_loss, q = critic_step(
        nets.critic, state.critics, state.critic_opt, batch, y, hp.offpolicy.lr
    )

    def actor_loss(p):
        a, logp = _sample(nets, p, batch.obs, k_actor)
        q_pi = min_q(nets.critic, critics, batch.obs, a)
        return jnp.mean(alpha * logp - q_pi), logp

    (a_loss, logp), a_grads = jax.value_and_grad(actor_loss, has_aux=True)(state.actor)
    actor, actor_opt = adam_step(ADAM, state.actor, a_grads, state.actor_opt, hp.offpolicy.lr)

    t_loss, t_grad = jax.value_and_grad(alpha_loss)(state.log_alpha, logp, hp.sac.target_entropy)
    log_alpha, alpha_opt = adam_step(ADAM, state.log_alpha, t_grad, state.alpha_opt, hp.sac.alpha_lr)

    state = State(
        actor=actor,
        critics=critics,
        critics_targ=soft_update(state.critics_targ, critics, hp.sac.tau),
        log_alpha=log_alpha,
        actor_opt=actor_opt,
        critic_opt=critic_opt,
        alpha_opt=alpha_opt,
    )
    losses = {
        "critic_loss": c_loss,
        "actor_loss": a_loss,
        "alpha_loss": t_loss,
        "alpha": alpha,
        "entropy": -jnp.mean(logp),
        "q": jnp.mean(q),
    }
    return state, losses
