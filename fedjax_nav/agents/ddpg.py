"""DDPG for one learner as pure functions (vmap over a leading axis for several).

    y = r + gamma (1 - D) Q_targ(s', mu_targ(s'))        critic: mean (Q(s, a) - y)^2
    actor: maximise mean Q(s, mu(s))                       targets: (1 - rho) targ + rho net

Adam without a built-in learning rate (`optax.scale_by_adam`), so that the learning rate is a
traced hyperparameter: updates are scaled by `-lr` here.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax
from flax import struct

from fedjax_nav.agents.buffer import Transition
from fedjax_nav.agents.networks import Actor, Critic

_ADAM = optax.scale_by_adam()


@struct.dataclass
class AgentState:
    actor: dict
    critic: dict
    actor_targ: dict
    critic_targ: dict
    actor_opt: optax.OptState
    critic_opt: optax.OptState


@struct.dataclass
class Nets:
    """The two module definitions (static: they fix shapes)."""

    actor: Actor = struct.field(pytree_node=False)
    critic: Critic = struct.field(pytree_node=False)


def make_nets(hidden: int, depth: int, activation: str) -> Nets:
    return Nets(Actor(hidden, depth, activation), Critic(hidden, depth, activation))


def init_agent(nets: Nets, key: jax.Array, obs_size: int, action_size: int = 2) -> AgentState:
    ka, kc = jax.random.split(key)
    obs, act = jnp.zeros((obs_size,)), jnp.zeros((action_size,))
    actor = nets.actor.init(ka, obs)
    critic = nets.critic.init(kc, obs, act)
    # Targets are copies, not aliases: XLA refuses to donate one buffer twice (jit donates the state).
    copy = lambda t: jax.tree.map(jnp.copy, t)  # noqa: E731
    return AgentState(actor, critic, copy(actor), copy(critic), _ADAM.init(actor), _ADAM.init(critic))


def act(nets: Nets, actor_params: dict, obs: jax.Array) -> jax.Array:
    return nets.actor.apply(actor_params, obs)


def epsilon_greedy(key: jax.Array, greedy: jax.Array, epsilon: jax.Array) -> jax.Array:
    """With probability epsilon a uniform action from [0, 1] x [-1, 1], else `greedy` (f32[2])."""
    k_coin, k_act = jax.random.split(key)
    rand = jax.random.uniform(k_act, (2,), minval=jnp.array([0.0, -1.0]), maxval=1.0)
    return jnp.where(jax.random.uniform(k_coin) < epsilon, rand, greedy)


def update(nets: Nets, agent: AgentState, batch: Transition, gamma, lr) -> tuple[AgentState, dict]:
    """One gradient step of the critic, then of the actor (against the updated critic). gamma:
    f32[] or a discount per row f32[B] (n-step rows bootstrap with gamma^k: offpolicy.Batch)."""
    next_a = nets.actor.apply(agent.actor_targ, batch.next_obs)
    q_next = nets.critic.apply(agent.critic_targ, batch.next_obs, next_a)
    y = jax.lax.stop_gradient(batch.reward + gamma * (1.0 - batch.done) * q_next)

    def critic_loss(p):
        q = nets.critic.apply(p, batch.obs, batch.action)
        return jnp.mean((q - y) ** 2), q

    (c_loss, q), c_grads = jax.value_and_grad(critic_loss, has_aux=True)(agent.critic)
    c_upd, critic_opt = _ADAM.update(c_grads, agent.critic_opt)
    critic = jax.tree.map(lambda p, u: p - lr * u, agent.critic, c_upd)

    def actor_loss(p):
        return -jnp.mean(nets.critic.apply(critic, batch.obs, nets.actor.apply(p, batch.obs)))

    a_loss, a_grads = jax.value_and_grad(actor_loss)(agent.actor)
    a_upd, actor_opt = _ADAM.update(a_grads, agent.actor_opt)
    actor = jax.tree.map(lambda p, u: p - lr * u, agent.actor, a_upd)
    agent = agent.replace(actor=actor, critic=critic, actor_opt=actor_opt, critic_opt=critic_opt)
    return agent, {"critic_loss": c_loss, "actor_loss": a_loss, "q": jnp.mean(q)}


def soft_update(target: dict, online: dict, rho) -> dict:
    """target <- (1 - rho) target + rho online."""
    return jax.tree.map(lambda t, p: (1.0 - rho) * t + rho * p, target, online)


def update_targets(agent: AgentState, rho) -> AgentState:
    return agent.replace(
        actor_targ=soft_update(agent.actor_targ, agent.actor, rho),
        critic_targ=soft_update(agent.critic_targ, agent.critic, rho),
    )


def update_flops(obs_size: int, hidden: int, depth: int, batch: int, action_size: int = 2) -> int:
    """FLOPs of one `update` (matmuls only): forward = 2 MAC, backward = 2x forward.

    critic step: target actor fwd + target critic fwd + critic fwd/bwd (3x);
    actor step: actor fwd/bwd (3x) + critic fwd and its backward to the input only (2x: the
    critic's weight gradient is not taken there).
    """
    from fedjax_nav.agents.networks import mlp_flops

    fa = mlp_flops(obs_size, hidden, depth, action_size)
    fc = mlp_flops(obs_size + action_size, hidden, depth, 1)
    per_row = fa + fc + 3 * fc + 3 * fa + 2 * fc
    return per_row * batch
