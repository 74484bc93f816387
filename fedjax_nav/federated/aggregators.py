"""Federated aggregators: pure functions over stacked pytrees with a leading client axis.

Each takes `params` (a pytree whose leaves are [K, ...]), the clients' mean rewards per step
since the last federated update `r` (f32[K]) and the hyperparameters, and returns the new
stacked params. The global soft update also carries `theta_w_prev` (a pytree without the
client axis). Conventions are SCENARIO.md section 4 (Algorithm 2's mix everywhere):

    soft:  theta_w = mean_k theta_k;                    theta_k <- (1 - tau) theta_k + tau theta_w
    pw:    theta_w = sum_k softmax(beta r)_k theta_k;    same mix
    rw:    theta_w = sum_k sign(r_k)|r_k|^beta / sum_l |r_l|^beta theta_k;  same mix
    gs:    theta_w = (1 - beta) theta_w_prev + beta mean_k theta_k;  theta_k <- theta_w
"""
from __future__ import annotations

import jax
import jax.numpy as jnp

AGGREGATORS = ("none", "soft", "pw", "rw", "gs")


def weighted_mean(params, weights: jax.Array):
    """sum_k w_k theta_k over the leading axis (weights f32[K])."""
    return jax.tree.map(lambda p: jnp.tensordot(weights.astype(p.dtype), p, axes=1), params)


def mix(params, theta_w, tau):
    """theta_k <- (1 - tau) theta_k + tau theta_w (theta_w broadcast over clients)."""
    return jax.tree.map(lambda p, w: (1.0 - tau) * p + tau * w[None], params, theta_w)


def uniform_weights(r: jax.Array, beta=None) -> jax.Array:
    return jnp.full(r.shape, 1.0 / r.shape[0], jnp.float32)


def positive_weights(r: jax.Array, beta) -> jax.Array:
    """Algorithm 3: softmax(beta r)."""
    return jax.nn.softmax(beta * r)


def real_weights(r: jax.Array, beta) -> jax.Array:
    """Algorithm 4: sign(r_k) |r_k|^beta / sum_l |r_l|^beta (uniform if every r_k is 0)."""
    mag = jnp.abs(r) ** beta
    total = jnp.sum(mag)
    return jnp.where(total > 0, jnp.sign(r) * mag / jnp.where(total > 0, total, 1.0), uniform_weights(r))


def soft_fedavg(params, r, tau, beta=None):
    return mix(params, weighted_mean(params, uniform_weights(r)), tau)


def positive_weighting(params, r, tau, beta):
    return mix(params, weighted_mean(params, positive_weights(r, beta)), tau)


def real_weighting(params, r, tau, beta):
    return mix(params, weighted_mean(params, real_weights(r, beta)), tau)


def global_soft(params, theta_w_prev, beta):
    """Algorithm 5. Returns (new stacked params, new theta_w_prev)."""
    mean = weighted_mean(params, uniform_weights(jnp.zeros(jax.tree.leaves(params)[0].shape[0])))
    theta_w = jax.tree.map(lambda prev, m: (1.0 - beta) * prev + beta * m, theta_w_prev, mean)
    k = jax.tree.leaves(params)[0].shape[0]
    return jax.tree.map(lambda w: jnp.broadcast_to(w[None], (k, *w.shape)), theta_w), theta_w


def init_global(params):
    """theta_w_prev starts as the mean of the initial parameters (Decision, SCENARIO.md)."""
    return jax.tree.map(lambda p: jnp.mean(p, axis=0), params)


def aggregate(kind: str, params, r, tau, beta, theta_w_prev=None):
    """Dispatch on the (static) aggregator name. Returns (params, theta_w_prev)."""
    if kind == "none":
        return params, theta_w_prev
    if kind == "soft":
        return soft_fedavg(params, r, tau), theta_w_prev
    if kind == "pw":
        return positive_weighting(params, r, tau, beta), theta_w_prev
    if kind == "rw":
        return real_weighting(params, r, tau, beta), theta_w_prev
    if kind == "gs":
        return global_soft(params, theta_w_prev, beta)
    raise ValueError(f"unknown aggregator {kind!r}; allowed: {', '.join(AGGREGATORS)}")
