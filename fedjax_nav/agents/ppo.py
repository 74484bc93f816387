"""PPO (Schulman et al. 2017) for one agent as pure functions (vmap over agents, seeds), with an
optional GRU policy and value.

Algorithm outline (the trainer's loop; this module is everything but the rollout):
    rollout: T steps in E environments with `act` -> `Rollout` [T, E]; a recurrent policy carries
             `Hidden` between steps (reset at episode starts) and the rollout keeps its value at step 0
    update:  V(s_t), V(s'_t) with the rollout's parameters (s'_t: the true next observation, so a
             time-out bootstraps), then GAE(lambda) (`gae`, a reverse scan):
                 delta_t = r_t + gamma (1 - terminated_t) V(s'_t) - V(s_t)
                 A_t = delta_t + gamma lambda (1 - end_t) A_{t+1}      end = terminated or truncated
                 R_t = A_t + V(s_t)
             epochs x minibatches (two nested scans over a permutation of the rows, or of the
             environments for a recurrent policy, so that each minibatch keeps whole sequences):
                 rho = pi(a|s) / pi_old(a|s),  A normalised within the minibatch
                 L = -mean min(rho A, clip(rho, 1 - eps, 1 + eps) A) + c_V L_V - c_H H
                 L_V = 0.5 mean max((V - R)^2, (V_old + clip(V - V_old, -eps_V, eps_V) - R)^2)
                 one Adam step on (actor, log_std, value), the gradient clipped to a global norm

The policy is the tanh-squashed Gaussian on the action box (distributions.py; brax's PPO uses the
same) with a state-independent log-std: the rollout keeps each draw's raw (pre-tanh) action, on
which the log-density is exact. H is its one-sample entropy estimate. `hp` is the config's traced
values (config.traced.HParams, read duck-typed: `hp.ppo.lr`, `.gamma`, `.gae_lambda`, `.clip_eps`,
`.value_clip` (0 = not clipped), `.vf_coef`, `.ent_coef`, `.max_grad_norm`); they and `init`'s
init_log_std are traced; Nets fix the shapes and loops (hidden sizes, GRU, epochs, minibatches).
Federated: a round averages actor (with its observation statistics when normalised), log_std and
value (PPO's row of fedjax_nav/learner_table.py); the Adam moments stay local.

Observation normalisation (`make_nets(normalize_obs=True)`; docs/learners.md): the actor's variable
dict holds, beside "params", a collection `NORM` with the running statistics of the observations
(`normalize.moments`: count, mean, mean of squares), as flax keeps BatchNorm's statistics in
"batch_stats". Every network input is `normalize.normalize(stats, obs)`: in `act`, `greedy`,
`evaluate` and `update`. The rollout keeps raw observations; `update` normalises them with the
statistics that acted and merges the rollout into the statistics after its epochs (not per step),
so that pi_old in the ratio is the policy that acted. The statistics are part of the actor: a
round averages them with it (an average of per-row moments is their exact pool when the clients'
counts are equal, which PPO's are), params.npz keeps them, and evaluation and export read them
with the actor (`Learner.policy`). Without it the actor is {"params": ...} as before.
"""

from __future__ import annotations

from typing import NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import optax
from flax import struct

from fedjax_nav.agents import distributions as dist
from fedjax_nav.agents import normalize, shuffle
from fedjax_nav.agents.networks_extra import MeanNet, RecurrentMLP, ValueNet

NORM = "obs_norm"  # the actor's variable collection of observation statistics (normalize.moments)
_ADAM = optax.scale_by_adam()


@struct.dataclass
class Nets:
    """Module definitions and the static loop sizes."""

    actor: nn.Module = struct.field(pytree_node=False)
    value: nn.Module = struct.field(pytree_node=False)
    gru: int = struct.field(pytree_node=False)  # GRU hidden size, 0 without one
    epochs: int = struct.field(pytree_node=False)
    minibatches: int = struct.field(pytree_node=False)
    action_size: int = struct.field(pytree_node=False)
    normalize_obs: bool = struct.field(pytree_node=False, default=False)  # the actor's NORM statistics

    @property
    def recurrent(self) -> bool:
        return self.gru > 0


@struct.dataclass
class State:
    actor: dict
    log_std: jax.Array  # f32[A], state-independent
    value: dict
    opt: optax.OptState  # Adam over (actor, log_std, value)


class Hidden(NamedTuple):
    actor: jax.Array  # f32[gru] (f32[0] without a GRU)
    value: jax.Array


class Step(NamedTuple):
    action: jax.Array  # f32[A] in the box, for the env
    raw_action: jax.Array  # f32[A] pre-tanh, for the rollout
    log_prob: jax.Array  # f32[]
    value: jax.Array  # f32[] V(s) (logging; `update` recomputes it)


@struct.dataclass
class Rollout:
    """T steps of E environments (leading axes [T, E]) under one parameter set."""

    obs: jax.Array  # f32[T, E, obs] the raw observation (`update` normalises it, if the actor does)
    raw_action: jax.Array  # f32[T, E, A] Step.raw_action
    log_prob: jax.Array  # f32[T, E] Step.log_prob
    reward: jax.Array  # f32[T, E]
    next_obs: jax.Array  # f32[T, E, obs] the true next observation (an episode's last one at its end)
    terminated: jax.Array  # f32/bool[T, E] goal or collision: no bootstrap
    truncated: jax.Array  # f32/bool[T, E] time limit: bootstrap from next_obs
    reset: jax.Array  # bool[T, E] obs_t is an episode's first: a GRU starts again from zeros there
    hidden: Hidden  # [E, gru] the hidden states before step 0 (before reset[0] applies)


def make_nets(
    hidden: int = 64,
    depth: int = 2,
    activation: str = "tanh",
    recurrent: bool = False,
    gru: int = 64,
    epochs: int = 4,
    minibatches: int = 4,
    action_size: int = 2,
    normalize_obs: bool = False,
) -> Nets:
    for name, value in (("epochs", epochs), ("minibatches", minibatches), ("gru", gru if recurrent else 1)):
        if value < 1:
            raise ValueError(f"ppo.{name} must be >= 1, got {value}")
    if recurrent:
        actor = RecurrentMLP(hidden, depth, activation, gru, action_size, small_head=True)
        value = RecurrentMLP(hidden, depth, activation, gru, 1)
        return Nets(actor, value, gru, epochs, minibatches, action_size, normalize_obs)
    return Nets(
        MeanNet(hidden, depth, activation, action_size),
        ValueNet(hidden, depth, activation),
        0,
        epochs,
        minibatches,
        action_size,
        normalize_obs,
    )


def init(nets: Nets, key: jax.Array, obs_size: int, init_log_std=0.0) -> State:
    """init_log_std: the initial log-std of the raw action (traced)."""
    ka, kv = jax.random.split(key)
    obs = jnp.zeros((obs_size,))
    if nets.recurrent:
        h, seq, no = jnp.zeros((nets.gru,)), obs[None], jnp.zeros((1,), bool)
        actor, value = nets.actor.init(ka, h, seq, no), nets.value.init(kv, h, seq, no)
    else:
        actor, value = nets.actor.init(ka, obs), nets.value.init(kv, obs)
    log_std = jnp.full((nets.action_size,), init_log_std, jnp.float32)
    opt = _ADAM.init((actor, log_std, value))  # the networks' weights only: the statistics are not learned
    if nets.normalize_obs:
        actor = {**actor, NORM: normalize.moments(normalize.init(obs_size))}
    return State(actor, log_std, value, opt)


def weights(actor: dict) -> dict:
    """The actor's network variables ({"params": ...}) without its observation statistics."""
    return {k: v for k, v in actor.items() if k != NORM}


def observe(nets: Nets, actor: dict, obs: jax.Array) -> jax.Array:
    """The networks' input for raw observations f32[..., obs]: normalised with the actor's
    statistics when nets.normalize_obs, else obs itself."""
    return normalize.normalize(normalize.from_moments(actor[NORM]), obs) if nets.normalize_obs else obs


def input_affine(actor: dict) -> tuple[jax.Array, jax.Array, float] | None:
    """(mean, std, clip) with `observe`(obs) = clip((obs - mean) / std, -clip, clip) for an actor's
    variables (what an export writes: deploy/export.py), or None for an actor without statistics."""
    if NORM not in actor:
        return None
    mean, std = normalize.affine(normalize.from_moments(actor[NORM]))
    return mean, std, normalize.CLIP


def observe_rollout(nets: Nets, actor: dict, rollout: Rollout) -> Rollout:
    """The rollout with obs and next_obs as the networks see them (`observe`)."""
    if not nets.normalize_obs:
        return rollout
    return rollout.replace(obs=observe(nets, actor, rollout.obs), next_obs=observe(nets, actor, rollout.next_obs))


def merge_rollout(nets: Nets, actor: dict, rollout: Rollout) -> dict:
    """The actor with the rollout's raw observations (every [T, E] row) merged into its statistics."""
    if not nets.normalize_obs:
        return actor
    stats = normalize.update(normalize.from_moments(actor[NORM]), rollout.obs)
    return {**actor, NORM: normalize.moments(stats)}


def initial_hidden(nets: Nets) -> Hidden:
    """Zeros: the hidden state at an episode's start (f32[0] pieces without a GRU)."""
    return Hidden(jnp.zeros((nets.gru,)), jnp.zeros((nets.gru,)))


def _net_step(nets: Nets, net: nn.Module, params: dict, h: jax.Array, obs: jax.Array, reset: jax.Array):
    """One step of a net: (h', out) for one observation f32[obs]."""
    if not nets.recurrent:
        return h, net.apply(params, obs)
    h, out, _ = net.apply(params, h, obs[None], jnp.reshape(reset, (1,)))
    return h, out[0]


def act(nets: Nets, state: State, obs: jax.Array, key: jax.Array, hidden: Hidden, reset) -> tuple[Step, Hidden]:
    """Exploration: a draw from the policy at one observation. reset: obs is an episode's first
    (the GRUs start from zeros); hidden passes through untouched without a GRU."""
    x = observe(nets, state.actor, obs)
    h_a, mean = _net_step(nets, nets.actor, weights(state.actor), hidden.actor, x, reset)
    h_v, v = _net_step(nets, nets.value, state.value, hidden.value, x, reset)
    action, raw, logp = dist.sample(key, mean, state.log_std)
    return Step(action, raw, logp, jnp.reshape(v, ())), Hidden(h_a, h_v)


def value(nets: Nets, actor: dict, value: dict, obs: jax.Array, hidden: jax.Array, reset) -> tuple:
    """(V(obs) f32[], the value GRU's next hidden state): what `act` logs as Step.value, from the
    value's parameters and the actor's (its observation statistics normalise obs, when kept)."""
    h_v, v = _net_step(nets, nets.value, value, hidden, observe(nets, actor, obs), reset)
    return jnp.reshape(v, ()), h_v


def greedy(nets: Nets, state: State, obs: jax.Array, hidden: Hidden, reset) -> tuple[jax.Array, Hidden]:
    """The deterministic action (the squashed mean). Only the actor's hidden state advances
    (evaluation needs no value)."""
    return greedy_actor(nets, state.actor, obs, hidden, reset)


def greedy_actor(nets: Nets, actor: dict, obs: jax.Array, hidden: Hidden, reset) -> tuple[jax.Array, Hidden]:
    """`greedy` from the actor's parameters alone (what evaluation and export hold; its
    observation statistics too, when normalised)."""
    h_a, mean = _net_step(nets, nets.actor, weights(actor), hidden.actor, observe(nets, actor, obs), reset)
    return dist.mode(mean), hidden._replace(actor=h_a)


# ----------------------------------------------------------------------------- estimates, losses


def gae(rewards, values, next_values, terminated, episode_end, gamma, lam) -> tuple[jax.Array, jax.Array]:
    """(advantages, returns = advantages + values), all f32[T, ...] (time leading). next_values:
    V of the true next observation; terminated cuts the bootstrap, episode_end (terminated or
    truncated) the recursion; the rollout's last step bootstraps from its next_values."""
    term = jnp.asarray(terminated, jnp.float32)
    end = jnp.asarray(episode_end, jnp.float32)
    deltas = rewards + gamma * (1.0 - term) * next_values - values

    def back(acc, x):
        delta, e = x
        acc = delta + gamma * lam * (1.0 - e) * acc
        return acc, acc

    _, adv = jax.lax.scan(back, jnp.zeros_like(values[0]), (deltas, end), reverse=True)
    return adv, adv + values


def normalize_advantages(adv: jax.Array) -> jax.Array:
    return (adv - jnp.mean(adv)) / (jnp.std(adv) + 1e-8)


def clipped_surrogate(log_prob, old_log_prob, adv, clip_eps) -> tuple[jax.Array, jax.Array]:
    """(-mean min(rho A, clip(rho, 1 - eps, 1 + eps) A), fraction of rows with |rho - 1| > eps)."""
    ratio = jnp.exp(log_prob - old_log_prob)
    surr = jnp.minimum(ratio * adv, jnp.clip(ratio, 1.0 - clip_eps, 1.0 + clip_eps) * adv)
    return -jnp.mean(surr), jnp.mean((jnp.abs(ratio - 1.0) > clip_eps).astype(jnp.float32))


def value_loss(values, old_values, returns, value_clip) -> jax.Array:
    """0.5 mean max((V - R)^2, (V_old + clip(V - V_old, -eps_V, eps_V) - R)^2); eps_V = 0 (the
    config's ppo.value_clip default) or inf: not clipped, 0.5 mean (V - R)^2."""
    value_clip = jnp.where(value_clip > 0, value_clip, jnp.inf)
    clipped = old_values + jnp.clip(values - old_values, -value_clip, value_clip)
    return 0.5 * jnp.mean(jnp.maximum((values - returns) ** 2, (clipped - returns) ** 2))


# ----------------------------------------------------------------------------- sequences


def _env_forward(nets: Nets, actor: dict, value: dict, hidden: Hidden, obs, reset):
    """Policy means f32[T, A] and values f32[T] along one environment's sequence f32[T, obs]."""
    if not nets.recurrent:
        return nets.actor.apply(actor, obs), nets.value.apply(value, obs)
    _, mean, _ = nets.actor.apply(actor, hidden.actor, obs, reset)
    _, v, _ = nets.value.apply(value, hidden.value, obs, reset)
    return mean, v[:, 0]


def _env_next_values(nets: Nets, value: dict, hidden: Hidden, obs, reset, next_obs) -> jax.Array:
    """V(next_obs_t) f32[T] along one environment's sequence: a GRU sees next_obs_t after the
    history up to obs_t (the hidden state after step t, no reset)."""
    if not nets.recurrent:
        return nets.value.apply(value, next_obs)
    _, _, hs = nets.value.apply(value, hidden.value, obs, reset)
    no = jnp.zeros((1,), bool)
    return jax.vmap(lambda h, o: nets.value.apply(value, h, o[None], no)[1][0, 0])(hs, next_obs)


def evaluate(nets: Nets, state: State, rollout: Rollout) -> tuple[jax.Array, jax.Array, jax.Array]:
    """(log pi(raw_action), V(obs), V(next_obs)), each f32[T, E], under the state's parameters
    (its observation statistics included) for a rollout of raw observations."""
    return _evaluate(nets, state, observe_rollout(nets, state.actor, rollout))


def _evaluate(nets: Nets, state: State, rollout: Rollout) -> tuple[jax.Array, jax.Array, jax.Array]:
    """`evaluate` on observations already as the networks see them."""
    env_axes = (Hidden(0, 0), 1, 1)
    actor = weights(state.actor)
    mean, v = jax.vmap(lambda h, o, r: _env_forward(nets, actor, state.value, h, o, r), env_axes, 1)(
        rollout.hidden, rollout.obs, rollout.reset
    )
    nv = jax.vmap(lambda h, o, r, n: _env_next_values(nets, state.value, h, o, r, n), (*env_axes, 1), 1)(
        rollout.hidden, rollout.obs, rollout.reset, rollout.next_obs
    )
    return dist.log_prob_raw(mean, state.log_std, rollout.raw_action), v, nv


def _minibatch_loss(params, nets: Nets, mb: dict, key: jax.Array, hp):
    actor, log_std, value = params
    if nets.recurrent:  # mb: [e, T, ...] whole sequences, hidden [e, gru]
        mean, v = jax.vmap(lambda h, o, r: _env_forward(nets, actor, value, h, o, r))(
            mb["hidden"], mb["obs"], mb["reset"]
        )
        mean, v = mean.reshape(-1, mean.shape[-1]), v.reshape(-1)
        mb = {k: x.reshape(-1, *x.shape[2:]) for k, x in mb.items() if k != "hidden"}
    else:  # mb: rows
        mean, v = nets.actor.apply(actor, mb["obs"]), nets.value.apply(value, mb["obs"])
    log_std = jnp.broadcast_to(log_std, mean.shape)
    logp = dist.log_prob_raw(mean, log_std, mb["raw_action"])
    pg, clip_frac = clipped_surrogate(logp, mb["log_prob"], normalize_advantages(mb["adv"]), hp.ppo.clip_eps)
    v_loss = value_loss(v, mb["value"], mb["return"], hp.ppo.value_clip)
    ent = jnp.mean(dist.entropy(key, mean, log_std))
    log_ratio = logp - mb["log_prob"]
    total = pg + hp.ppo.vf_coef * v_loss - hp.ppo.ent_coef * ent
    aux = {
        "loss": total,
        "policy_loss": pg,
        "value_loss": v_loss,
        "entropy": ent,
        "approx_kl": jnp.mean(jnp.expm1(log_ratio) - log_ratio),  # Schulman's k3 estimator of KL(old, new)
        "clip_frac": clip_frac,
    }
    return total, aux


def update(nets: Nets, state: State, rollout: Rollout, key: jax.Array, hp) -> tuple[State, dict]:
    """epochs x minibatches Adam steps on one rollout [T, E]. The rows (T * E of them; for a
    recurrent policy the E environments, each a whole sequence) are permuted each epoch and cut
    into nets.minibatches equal parts: a ValueError naming ppo.minibatches if they do not divide.
    Losses: the means over every minibatch of loss, policy_loss, value_loss, entropy, approx_kl,
    clip_frac. With nets.normalize_obs the rollout's observations are normalised with the
    statistics that acted, and merged into them after the epochs."""
    steps, envs = rollout.reward.shape
    m = nets.minibatches
    rows = envs if nets.recurrent else steps * envs
    if rows % m:
        what = "environments per rollout (a recurrent policy's rows)" if nets.recurrent else "rollout rows (T * E)"
        raise ValueError(f"ppo.minibatches: {m} does not divide the {what}: {rows}")
    raw, rollout = rollout, observe_rollout(nets, state.actor, rollout)
    _, values, next_values = _evaluate(nets, state, rollout)
    end = jnp.maximum(jnp.asarray(rollout.terminated, jnp.float32), jnp.asarray(rollout.truncated, jnp.float32))
    adv, returns = gae(rollout.reward, values, next_values, rollout.terminated, end, hp.ppo.gamma, hp.ppo.gae_lambda)
    data = {
        "obs": rollout.obs,
        "raw_action": rollout.raw_action,
        "log_prob": rollout.log_prob,
        "adv": adv,
        "return": returns,
        "value": values,
        "reset": rollout.reset,
    }
    data = jax.lax.stop_gradient(data)
    if nets.recurrent:  # environment-major: a row is one environment's sequence
        data = {k: jnp.swapaxes(x, 0, 1) for k, x in data.items()}
        data["hidden"] = rollout.hidden
    else:
        data = {k: x.reshape(rows, *x.shape[2:]) for k, x in data.items() if k != "reset"}

    def minibatch(carry, inp):
        params, opt = carry
        mb, k = inp
        grads, aux = jax.grad(_minibatch_loss, has_aux=True)(params, nets, mb, k, hp)
        grads, _ = optax.clip_by_global_norm(hp.ppo.max_grad_norm).update(grads, optax.EmptyState())
        upd, opt = _ADAM.update(grads, opt, params)
        return (jax.tree.map(lambda p, u: p - hp.ppo.lr * u, params, upd), opt), aux

    def epoch(carry, k):
        k_perm, k_mb = jax.random.split(k)
        perm = shuffle.permutation(k_perm, rows)  # jax.random.permutation's, sorted faster
        mbs = jax.tree.map(lambda x: jnp.take(x, perm, axis=0).reshape(m, rows // m, *x.shape[1:]), data)
        return jax.lax.scan(minibatch, carry, (mbs, jax.random.split(k_mb, m)))

    carry = ((weights(state.actor), state.log_std, state.value), state.opt)
    ((actor, log_std, value), opt), info = jax.lax.scan(epoch, carry, jax.random.split(key, nets.epochs))
    actor = merge_rollout(nets, {**state.actor, **actor}, raw)
    return State(actor, log_std, value, opt), jax.tree.map(jnp.mean, info)
