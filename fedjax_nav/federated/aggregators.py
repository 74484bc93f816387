"""Federated aggregators as optax-style pairs of pure functions over stacked pytrees.

    agg = make("soft", tau=0.5)              # or RULES[name].make(**hyperparameters)
    state = agg.init(params)                 # params: pytree with leaves [K, ...] (K clients)
    params, state = agg.update(params, rewards, state, mask)

A rule's hyperparameters are arguments of its constructor, used as traced values (build the
aggregator inside the jitted program from the run's traced config, as optax builds
`optax.adam(learning_rate)`; `fedjax_nav.training.federation.aggregator` is the one place that
maps the config onto them). `params` is what the clients send: any pytree stacked over clients
(the learner decides what it shares; the rules never look inside). `rewards` (f32[K]) are the
clients' mean rewards per step since the last round; `mask` (bool[K]) the clients that take part.
A client outside the mask neither sends nor receives: its parameters come back unchanged.

The thesis's four rules (docs/decisions.md, "Federated aggregation"); every one ends with the
soft mix of Algorithm 2 except GS, which replaces the clients by its global model:

    soft:  theta_w = mean_k theta_k;                    theta_k <- (1 - tau) theta_k + tau theta_w
    pw:    theta_w = sum_k softmax(beta r)_k theta_k;    same mix
    rw:    theta_w = sum_k sign(r_k)|r_k|^beta / sum_l |r_l|^beta theta_k;  same mix
    gs:    theta_w = (1 - beta) theta_w_prev + beta mean_k theta_k;  theta_k <- theta_w

and the robust rules (docs/robustness.md): theta_w = a robust center of the participants
(`fedjax_nav.federated.robust.CENTERS`), then the soft mix. States are NamedTuples: `EmptyState`,
GS's `GlobalState` (its global model), the robust rules' `ReferenceState` (the global model of
the last round, which norm bounding clips against and the attacks that need "the model the
clients last received" read), and `WithReferenceState` (a thesis rule plus that reference).
`RULES` is the one table: config name -> constructor, the `fed.*` hyperparameters it takes, and
whether its state keeps a reference.
"""

from __future__ import annotations

from functools import partial
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

from fedjax_nav.federated import robust
from fedjax_nav.federated.stacked import mean_over_clients, select, weighted_sum

TARGET_SUFFIX = "_targ"  # keys of a shared dict that hold target networks ("actor_targ")


class Aggregator(NamedTuple):
    """init(params) -> state; update(params, rewards, state, mask) -> (params, state)."""

    init: Callable[[Any], Any]
    update: Callable[..., tuple[Any, Any]]


class EmptyState(NamedTuple):
    """The state of a rule that keeps none (optax's EmptyState)."""


class GlobalState(NamedTuple):
    theta_w: Any  # GS's global model (no client axis)


class ReferenceState(NamedTuple):
    reference: Any  # the global model of the last round (no client axis)


class WithReferenceState(NamedTuple):
    inner: Any  # the wrapped rule's state
    reference: Any  # the participants' mean after the last round (no client axis)


# ----------------------------------------------------------------------------- building blocks


def mix(params, theta_w, tau):
    """theta_k <- (1 - tau) theta_k + tau theta_w (theta_w broadcast over clients)."""
    return jax.tree.map(lambda p, w: (1.0 - tau) * p + tau * w[None], params, theta_w)


def keep_absent(new, old, mask: jax.Array):
    """Clients outside `mask` keep their own parameters (they neither sent nor received)."""
    return select(mask, new, old)


def _all(rewards: jax.Array, mask):
    return jnp.ones(rewards.shape, bool) if mask is None else mask


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


# ----------------------------------------------------------------------------- the thesis's rules


def weighted(weights: Callable[[jax.Array, jax.Array], jax.Array], tau) -> Aggregator:
    """theta_w = sum_k w_k theta_k over the participants (weights(r, mask) -> f32[K]);
    theta_k <- (1 - tau) theta_k + tau theta_w."""

    def update(params, rewards, state, mask=None):
        mask = _all(rewards, mask)
        theta_w = weighted_sum(params, weights(rewards, mask))
        return keep_absent(mix(params, theta_w, tau), params, mask), state

    return Aggregator(init=lambda params: EmptyState(), update=update)


def soft(tau) -> Aggregator:
    """Algorithm 2: uniform FedAvg with the soft mix tau (tau = 1: hard FedAvg)."""
    return weighted(uniform_weights, tau)


def positive_weighting(tau, beta) -> Aggregator:
    """Algorithm 3 (PWDDPG)."""
    return weighted(lambda r, mask: positive_weights(r, beta, mask), tau)


def real_weighting(tau, beta) -> Aggregator:
    """Algorithm 4 (RWDDPG)."""
    return weighted(lambda r, mask: real_weights(r, beta, mask), tau)


def _nets(params):
    """The shared dict without its target networks (GS keeps one global model per network)."""
    return {k: v for k, v in params.items() if not k.endswith(TARGET_SUFFIX)}


def global_soft(beta) -> Aggregator:
    """Algorithm 5 (GSDDPG): a global model moved by beta towards the participants' mean; every
    participant takes the global model. theta_w_prev starts as the mean of the initial
    parameters (docs/decisions.md). `params` must be a dict of networks; target networks in it
    ("actor_targ") follow the new global model of their network ("actor")."""

    def init(params):
        return GlobalState(mean_over_clients(_nets(params)))

    def update(params, rewards, state, mask=None):
        mask = _all(rewards, mask)
        mean = weighted_sum(_nets(params), uniform_weights(rewards, mask))
        theta_w = jax.tree.map(lambda prev, m: (1.0 - beta) * prev + beta * m, state.theta_w, mean)
        k = rewards.shape[0]
        glob = {name: theta_w[name.removesuffix(TARGET_SUFFIX)] for name in params}
        new = jax.tree.map(lambda w: jnp.broadcast_to(w[None], (k, *w.shape)), glob)
        return keep_absent(new, params, mask), GlobalState(theta_w)

    return Aggregator(init=init, update=update)


def identity() -> Aggregator:
    """No federated step (IDDPG, SEDDPG, SNDDPG)."""

    def update(params, rewards, state, mask=None):
        return params, state

    return Aggregator(init=lambda params: EmptyState(), update=update)


# ----------------------------------------------------------------------------- robust rules


def robust_rule(kind: str, tau, **hparams) -> Aggregator:
    """theta_w = robust.CENTERS[kind] over the participants, with its hyperparameters (by their
    `fed.*` names, e.g. trim, krum_f, krum_m, max_norm); theta_k <- (1 - tau) theta_k + tau theta_w.
    The state's reference (init: the mean of the initial parameters) is the last theta_w."""
    if kind not in robust.CENTERS:
        raise ValueError(f"unknown robust center {kind!r}; allowed: {', '.join(robust.CENTERS)}")
    center = robust.CENTERS[kind]
    args = [hparams[name] for name in center.hparams]

    def update(params, rewards, state, mask=None):
        mask = _all(rewards, mask)
        theta_w = center.fn(params, mask, state.reference, *args)
        return keep_absent(mix(params, theta_w, tau), params, mask), ReferenceState(theta_w)

    return Aggregator(init=lambda params: ReferenceState(mean_over_clients(params)), update=update)


def with_reference(inner: Aggregator) -> Aggregator:
    """`inner` plus the global model of its last round in the state, for the attacks that need
    it with the thesis's rules. The reference is the participants' mean after the round: theta_w
    itself for soft FedAvg (its mix keeps the mean), the mean of what the participants hold for
    PW/RW/GS."""

    def init(params):
        return WithReferenceState(inner.init(params), mean_over_clients(params))

    def update(params, rewards, state, mask=None):
        mask = _all(rewards, mask)
        new, inner_state = inner.update(params, rewards, state.inner, mask)
        return new, WithReferenceState(inner_state, robust.masked_mean(new, mask))

    return Aggregator(init=init, update=update)


# ----------------------------------------------------------------------------- the table


class Rule(NamedTuple):
    make: Callable[..., Aggregator]  # keyword arguments: the names in `hparams`
    hparams: tuple[str, ...]  # the fed.* config fields it takes (traced values)
    keeps_reference: bool = False  # its state has `.reference` (the last global model)


RULES: dict[str, Rule] = {
    "none": Rule(identity, ()),
    "soft": Rule(soft, ("tau",)),
    "pw": Rule(positive_weighting, ("tau", "beta")),
    "rw": Rule(real_weighting, ("tau", "beta")),
    "gs": Rule(global_soft, ("beta",)),
    **{name: Rule(partial(robust_rule, name), ("tau", *c.hparams), True) for name, c in robust.CENTERS.items()},
}
ROBUST = tuple(robust.CENTERS)  # the names `fed.aggregator` may give instead of the method's rule


def rule(name: str) -> Rule:
    try:
        return RULES[name]
    except KeyError:
        raise ValueError(f"unknown aggregator {name!r}; allowed: {', '.join(RULES)}") from None


def make(name: str, **hparams) -> Aggregator:
    """The rule `name` with its hyperparameters (exactly `RULES[name].hparams`, by name)."""
    r = rule(name)
    if set(hparams) != set(r.hparams):
        raise TypeError(f"aggregator {name!r} takes {r.hparams}; got {tuple(sorted(hparams))}")
    return r.make(**hparams)


def reference(state):
    """The global model of the last round that a rule's state keeps (`Rule.keeps_reference`, or
    a `with_reference` wrapper)."""
    return state.reference
