"""The tanh-squashed diagonal Gaussian on an action box (SAC's and PPO's policy), as pure functions.

    u ~ N(mean, diag(exp(log_std))^2)         the raw (pre-squash) action, f32[..., A]
    a = loc + scale * tanh(u)                 loc = (high + low) / 2, scale = (high - low) / 2
    log p(a) = log N(u; mean, std) - sum_i [log(1 - tanh(u_i)^2) + log scale_i]

This is distrax's `Transformed(MultivariateNormalDiag, Chain([ScalarAffine(loc, scale), Tanh()]))`
written out in a few lines, the way brax (`NormalTanhDistribution`) and rejax
(`SquashedGaussianPolicy`) use it: the log-density of a sample is taken at its raw action `u`,
never through `arctanh(a)`, which is infinite where tanh saturates in float32 (tanh(10) == 1).
distrax itself would add tensorflow-probability to the dependencies for these few lines.

The box defaults to the robot's: [0, 1] x [-1, 1] = (v / v_max, omega / omega_max). Everything is
elementwise over leading axes; mean, log_std and u are f32[..., A], log-densities f32[...].
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

ACTION_LOW = np.array([0.0, -1.0], np.float32)
ACTION_HIGH = np.array([1.0, 1.0], np.float32)
_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)


def affine(low=ACTION_LOW, high=ACTION_HIGH) -> tuple[jax.Array, jax.Array]:
    """(loc, scale) of the map [-1, 1]^A -> [low, high]."""
    low, high = jnp.asarray(low, jnp.float32), jnp.asarray(high, jnp.float32)
    return (high + low) / 2.0, (high - low) / 2.0


def tanh_log_det(u: jax.Array) -> jax.Array:
    """log |d tanh(u) / du| = log(1 - tanh(u)^2), elementwise, in the form that stays finite for
    large |u| (distrax's and brax's Tanh bijector): 2 (log 2 - u - softplus(-2 u))."""
    return 2.0 * (math.log(2.0) - u - jax.nn.softplus(-2.0 * u))


def squash(u: jax.Array, low=ACTION_LOW, high=ACTION_HIGH) -> jax.Array:
    """Raw action -> box action."""
    loc, scale = affine(low, high)
    return loc + scale * jnp.tanh(u)


def gaussian_log_prob(mean: jax.Array, log_std: jax.Array, u: jax.Array) -> jax.Array:
    """log N(u; mean, diag(exp(log_std))^2), summed over the last axis."""
    z = (u - mean) * jnp.exp(-log_std)
    return jnp.sum(-0.5 * z**2 - log_std - _HALF_LOG_2PI, axis=-1)


def log_prob_raw(mean: jax.Array, log_std: jax.Array, u: jax.Array, low=ACTION_LOW, high=ACTION_HIGH) -> jax.Array:
    """log-density, in box units, of the box action squash(u): the Gaussian's at u minus the
    log-Jacobians of tanh and of the affine map."""
    _, scale = affine(low, high)
    return gaussian_log_prob(mean, log_std, u) - jnp.sum(tanh_log_det(u) + jnp.log(scale), axis=-1)


def log_prob(
    mean: jax.Array, log_std: jax.Array, action: jax.Array, low=ACTION_LOW, high=ACTION_HIGH, eps: float = 1e-6
) -> jax.Array:
    """log-density of a box action (one not drawn here: prefer `log_prob_raw` on a sample's raw
    action). The action is pulled eps inside the box before arctanh, as rejax does."""
    loc, scale = affine(low, high)
    y = jnp.clip((action - loc) / scale, -1.0 + eps, 1.0 - eps)
    return log_prob_raw(mean, log_std, jnp.arctanh(y), low, high)


def sample(
    key: jax.Array, mean: jax.Array, log_std: jax.Array, low=ACTION_LOW, high=ACTION_HIGH
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """A reparameterised draw: (box action, raw action u, log-density). Gradients flow to mean and
    log_std through u = mean + std * noise."""
    u = mean + jnp.exp(log_std) * jax.random.normal(key, jnp.shape(mean))
    return squash(u, low, high), u, log_prob_raw(mean, log_std, u, low, high)


def entropy(key: jax.Array, mean: jax.Array, log_std: jax.Array, low=ACTION_LOW, high=ACTION_HIGH) -> jax.Array:
    """One-sample estimate of the squashed distribution's entropy (it has no closed form), as
    brax's `ParametricDistribution.entropy`: the Gaussian's entropy plus the log-Jacobian of the
    squash at a fresh reparameterised draw. Its mean over a batch is -E[log p(a)]."""
    _, scale = affine(low, high)
    u = mean + jnp.exp(log_std) * jax.random.normal(key, jnp.shape(mean))
    gauss = jnp.sum(0.5 + _HALF_LOG_2PI + log_std, axis=-1)
    return gauss + jnp.sum(tanh_log_det(u) + jnp.log(scale), axis=-1)


def mode(mean: jax.Array, low=ACTION_LOW, high=ACTION_HIGH) -> jax.Array:
    """The deterministic (evaluation) action: the squashed mean."""
    return squash(mean, low, high)
