"""Federated aggregators as optax-style pairs of pure functions over stacked pytrees.

    agg = make("soft")                       # or AGGREGATORS[name](**options)
    state = agg.init(params)                 # params: pytree with leaves [K, ...] (K clients)
    params, state = agg.update(params, rewards, state, hp, mask)

`params` is what the clients send (their actor and critic, plus the targets when
`fed.include_targets`); `rewards` (f32[K]) the clients' mean rewards per step since the last
federated step; `hp` the run's HParams (a dict of traced scalars keyed by config name:
`hp["fed.tau"]`, `hp["fed.beta"]`); `mask` (bool[K]) the clients that take part in this round
(every client today; the robust-federation issue adds partial participation). A client outside
the mask neither sends nor receives: its parameters come back unchanged.

The thesis's four rules (docs/decisions.md, "Federated aggregation"); every one ends with the
soft mix of Algorithm 2 except GS, which replaces the clients by its global model:

    soft:  theta_w = mean_k theta_k;                    theta_k <- (1 - tau) theta_k + tau theta_w
    pw:    theta_w = sum_k softmax(beta r)_k theta_k;    same mix
    rw:    theta_w = sum_k sign(r_k)|r_k|^beta / sum_l |r_l|^beta theta_k;  same mix
    gs:    theta_w = (1 - beta) theta_w_prev + beta mean_k theta_k;  theta_k <- theta_w

GS's global model theta_w_prev is ordinary aggregator state (`init` sets it to the mean of the
initial parameters). The rules are data: `AGGREGATORS` maps a config name to a constructor.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

TARGET_SUFFIX = "_targ"  # keys of the shared pytree that hold target networks ("actor_targ")


class Aggregator(NamedTuple):
    """init(params) -> state; update(params, rewards, state, hp, mask) -> (params, state)."""

    init: Callable[[Any], Any]
    update: Callable[..., tuple[Any, Any]]


# ----------------------------------------------------------------------------- building blocks


def weighted_mean(params, weights: jax.Array):
    """sum_k w_k theta_k over the leading axis (weights f32[K])."""
    return jax.tree.map(lambda p: jnp.tensordot(weights.astype(p.dtype), p, axes=1), params)


def mix(params, theta_w, tau):
    """theta_k <- (1 - tau) theta_k + tau theta_w (theta_w broadcast over clients)."""
    return jax.tree.map(lambda p, w: (1.0 - tau) * p + tau * w[None], params, theta_w)


def keep_absent(new, old, mask: jax.Array):
    """Clients outside `mask` keep their own parameters (they neither sent nor received)."""
    return jax.tree.map(lambda n, o: jnp.where(mask.reshape((-1,) + (1,) * (n.ndim - 1)), n, o), new, old)


def uniform_weights(r: jax.Array, mask: jax.Array | None = None) -> jax.Array:
    """1 / n over the n participating clients (every client when mask is None)."""
    m = jnp.ones(r.shape, jnp.float32) if mask is None else mask.astype(jnp.float32)
    return m / jnp.maximum(jnp.sum(m), 1.0)


def positive_weights(r: jax.Array, beta, mask: jax.Array | None = None) -> jax.Array:
    """Algorithm 3: softmax(beta r) over the participating clients."""
    logits = beta * r if mask is None else jnp.where(mask, beta * r, -jnp.inf)
    return jax.nn.softmax(logits)


def real_weights(r: jax.Array, beta, mask: jax.Array | None = None) -> jax.Array:
    """Algorithm 4: sign(r_k) |r_k|^beta / sum_l |r_l|^beta (uniform if every r_k is 0)."""
    mag = jnp.abs(r) ** beta
    if mask is not None:
        mag = jnp.where(mask, mag, 0.0)
    total = jnp.sum(mag)
    return jnp.where(total > 0, jnp.sign(r) * mag / jnp.where(total > 0, total, 1.0), uniform_weights(r, mask))


def _all(rewards: jax.Array, mask):
    return jnp.ones(rewards.shape, bool) if mask is None else mask


# ----------------------------------------------------------------------------- the rules

WeightFn = Callable[[jax.Array, jax.Array, jax.Array], jax.Array]  # (r, beta, mask) -> f32[K]


def weighted(weights: WeightFn) -> Aggregator:
    """theta_w = sum_k w_k theta_k over the participants; theta_k <- (1 - tau) theta_k + tau theta_w."""

    def update(params, rewards, state, hp, mask=None):
        mask = _all(rewards, mask)
        theta_w = weighted_mean(params, weights(rewards, hp["fed.beta"], mask))
        return keep_absent(mix(params, theta_w, hp["fed.tau"]), params, mask), state

    return Aggregator(init=lambda params: {}, update=update)


def soft() -> Aggregator:
    """Algorithm 2: uniform FedAvg with the soft mix tau (tau = 1: hard FedAvg)."""
    return weighted(lambda r, beta, mask: uniform_weights(r, mask))


def positive_weighting() -> Aggregator:
    """Algorithm 3 (PWDDPG)."""
    return weighted(positive_weights)


def real_weighting() -> Aggregator:
    """Algorithm 4 (RWDDPG)."""
    return weighted(real_weights)


def init_global(params):
    """theta_w_prev starts as the mean of the initial parameters (docs/decisions.md)."""
    return jax.tree.map(lambda p: jnp.mean(p, axis=0), params)


def global_soft() -> Aggregator:
    """Algorithm 5 (GSDDPG): a global model moved by beta towards the participants' mean; every
    participant takes the global model. Target networks in the shared pytree ("actor_targ") follow
    the new global model of their network ("actor"), not a global model of their own."""

    def nets(params):
        return {k: v for k, v in params.items() if not k.endswith(TARGET_SUFFIX)}

    def init(params):
        return init_global(nets(params))

    def update(params, rewards, theta_w_prev, hp, mask=None):
        mask = _all(rewards, mask)
        beta = hp["fed.beta"]
        mean = weighted_mean(nets(params), uniform_weights(rewards, mask))
        theta_w = jax.tree.map(lambda prev, m: (1.0 - beta) * prev + beta * m, theta_w_prev, mean)
        k = rewards.shape[0]
        glob = {name: theta_w[name.removesuffix(TARGET_SUFFIX)] for name in params}
        new = jax.tree.map(lambda w: jnp.broadcast_to(w[None], (k, *w.shape)), glob)
        return keep_absent(new, params, mask), theta_w

    return Aggregator(init=init, update=update)


def identity() -> Aggregator:
    """No federated step (IDDPG, SEDDPG, SNDDPG)."""
    return Aggregator(init=lambda params: {}, update=lambda params, rewards, state, hp, mask=None: (params, state))


# ----------------------------------------------------------------------------- robust rules (issue 14)
# Each: theta_w = a robust center (fedjax_nav.federated.robust) of the participants, then the
# soft mix with tau, absent clients unchanged. The state holds the global model theta_w of the
# last round ("reference", no client axis; init: the mean of the initial parameters): the
# norm-bounded rule clips updates relative to it, and the attacks that need "the model the
# clients last received" read it (`reference`).


def robust_rule(kind: str) -> Aggregator:
    """theta_w = robust.center(kind) over the participants (hyperparameters from hp:
    fed.trim, fed.krum_f, fed.krum_m, fed.max_norm); theta_k <- (1 - tau) theta_k + tau theta_w."""
    from fedjax_nav.federated import robust

    if kind not in robust.CENTERS:
        raise ValueError(f"unknown robust center {kind!r}; allowed: {', '.join(robust.CENTERS)}")

    def init(params):
        return {"reference": init_global(params)}

    def update(params, rewards, state, hp, mask=None):
        mask = _all(rewards, mask)
        theta_w = robust.center(
            kind,
            params,
            mask,
            trim=hp["fed.trim"],
            f=hp["fed.krum_f"],
            m=hp["fed.krum_m"],
            reference=state["reference"],
            max_norm=hp["fed.max_norm"],
        )
        return keep_absent(mix(params, theta_w, hp["fed.tau"]), params, mask), {"reference": theta_w}

    return Aggregator(init=init, update=update)


def with_reference(inner: Aggregator) -> Aggregator:
    """`inner` plus the global model of its last round in the state ({"inner", "reference"}),
    for the attacks that need it with the thesis's rules. The reference is the participants'
    mean after the round: theta_w itself for soft FedAvg (its mix keeps the mean), the mean
    of what the participants hold for PW/RW/GS."""
    from fedjax_nav.federated import robust

    def init(params):
        return {"inner": inner.init(params), "reference": init_global(params)}

    def update(params, rewards, state, hp, mask=None):
        mask = _all(rewards, mask)
        new, inner_state = inner.update(params, rewards, state["inner"], hp, mask)
        return new, {"inner": inner_state, "reference": robust.masked_mean(new, mask)}

    return Aggregator(init=init, update=update)


def reference(agg_state):
    """The global model an aggregator's state keeps (`robust_rule`, `with_reference`), or None."""
    return agg_state.get("reference") if isinstance(agg_state, dict) else None


ROBUST = ("mean", "median", "trimmed_mean", "krum", "geometric_median", "norm_bounded")

# Config name -> constructor. `fedjax_nav.methods.METHODS` names one of the first five per
# method; `fed.aggregator` may name a robust rule instead.
AGGREGATORS: dict[str, Callable[[], Aggregator]] = {
    "none": identity,
    "soft": soft,
    "pw": positive_weighting,
    "rw": real_weighting,
    "gs": global_soft,
    **{name: (lambda name=name: robust_rule(name)) for name in ROBUST},
}


def make(name: str) -> Aggregator:
    try:
        return AGGREGATORS[name]()
    except KeyError:
        raise ValueError(f"unknown aggregator {name!r}; allowed: {', '.join(AGGREGATORS)}") from None
