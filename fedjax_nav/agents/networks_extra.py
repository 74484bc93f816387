"""Networks of the learners beside DDPG (flax linen); networks.py's Actor and Critic are unchanged.

- `MeanNet`: obs -> depth x Dense(hidden) + activation -> Dense(A): PPO's Gaussian mean (its
  log-std is a separate state-independent parameter, as PureJaxRL's and rejax's).
- `SquashedGaussianActor`: the same trunk -> (mean, log_std), log_std squashed into
  [LOG_STD_MIN, LOG_STD_MAX] by a tanh (CleanRL's SAC: a gradient everywhere, unlike a clip).
- `ValueNet`: the trunk -> Dense(1).
- Twin critics: two `networks.Critic` parameter sets stacked on a leading axis, initialised and
  applied with `jax.vmap` (rejax's `vmap_critic`): each is a DDPG critic.
- `ScannedGRU` / `RecurrentMLP`: obs[T] -> Dense(hidden) + activation -> GRU (flax `GRUCell`
  scanned over time; the hidden state reset to zeros before each step whose `reset` is set, as
  PureJaxRL's `ScannedRNN`) -> (depth - 1) x Dense(hidden) + activation -> Dense(out).

Unbatched: one observation f32[obs], or one environment's sequence f32[T, obs] for the recurrent
nets; vmap adds the rest.
"""

from __future__ import annotations

import functools

import flax.linen as nn
import jax
import jax.numpy as jnp

from fedjax_nav.agents.networks import ACTIVATIONS, Critic

LOG_STD_MIN, LOG_STD_MAX = -5.0, 2.0


def _gram_schmidt(z: jax.Array) -> jax.Array:
    """f32[m, n] (m >= n, full rank) -> Q f32[m, n] with orthonormal columns and z = Q R, R upper
    triangular with a positive diagonal: the Q of a QR decomposition with the sign of diag(R) fixed,
    i.e. what `jax.random.orthogonal` returns. Classical Gram-Schmidt applied twice per column
    ("twice is enough": orthogonal to rounding for the Gaussian matrices drawn here)."""
    n = z.shape[1]

    def column(j, q):
        v = jax.lax.dynamic_index_in_dim(z, j, axis=1, keepdims=False)
        earlier = jnp.arange(n) < j
        for _ in range(2):
            v = v - q @ jnp.where(earlier, q.T @ v, 0.0)
        return q.at[:, j].set(v / jnp.sqrt(jnp.sum(v * v)))

    return jax.lax.fori_loop(0, n, column, jnp.zeros_like(z))


def orthogonal(scale: float = 1.0):
    """`jax.nn.initializers.orthogonal(scale)` (a 2-D kernel; the same normal draw, so the same
    matrix up to rounding) without a LAPACK QR. Written here because XLA CPU's batched QR calls the
    multithreaded OpenBLAS of scipy from several threads at once, and on a loaded 2-core machine a
    vmapped init (robots x seeds) ran for minutes or hung there (measured: `vmap` of 4 orthogonal
    64 x 192 inits did not finish in 30 s; with `OPENBLAS_NUM_THREADS=1`, 1 s); this one is matmuls only."""

    def init(key, shape, dtype=jnp.float32):
        rows, cols = shape
        z = jax.random.normal(key, (max(rows, cols), min(rows, cols)), dtype)
        q = _gram_schmidt(z)
        return scale * (q.T if rows < cols else q)

    return init


# The policy's last layer starts small (PureJaxRL's orthogonal(0.01)): the initial mean is ~0 for
# every observation, i.e. the centre of the action box after the squash.
_SMALL = orthogonal(0.01)


def _trunk(x: jax.Array, hidden: int, depth: int, activation: str) -> jax.Array:
    act = ACTIVATIONS[activation]
    for _ in range(depth):
        x = act(nn.Dense(hidden)(x))
    return x


class MeanNet(nn.Module):
    hidden: int = 64
    depth: int = 2
    activation: str = "tanh"
    action_size: int = 2

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        x = _trunk(obs, self.hidden, self.depth, self.activation)
        return nn.Dense(self.action_size, kernel_init=_SMALL, name="mean")(x)


class SquashedGaussianActor(nn.Module):
    hidden: int = 64
    depth: int = 2
    activation: str = "relu"
    action_size: int = 2

    @nn.compact
    def __call__(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        x = _trunk(obs, self.hidden, self.depth, self.activation)
        mean = nn.Dense(self.action_size, kernel_init=_SMALL, name="mean")(x)
        raw = nn.Dense(self.action_size, name="log_std")(x)
        log_std = LOG_STD_MIN + 0.5 * (LOG_STD_MAX - LOG_STD_MIN) * (jnp.tanh(raw) + 1.0)
        return mean, log_std


class ValueNet(nn.Module):
    hidden: int = 64
    depth: int = 2
    activation: str = "tanh"

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        return nn.Dense(1)(_trunk(obs, self.hidden, self.depth, self.activation))[..., 0]


def twin_init(critic: Critic, key: jax.Array, obs: jax.Array, action: jax.Array, n: int = 2) -> dict:
    """n critic parameter sets stacked on a leading axis, each from its own key."""
    return jax.vmap(critic.init, in_axes=(0, None, None))(jax.random.split(key, n), obs, action)


def twin_apply(critic: Critic, params: dict, obs: jax.Array, action: jax.Array) -> jax.Array:
    """Q of every critic: f32[n, ...] for obs f32[..., obs] and action f32[..., A]."""
    return jax.vmap(critic.apply, in_axes=(0, None, None))(params, obs, action)


class ScannedGRU(nn.Module):
    """carry h f32[features], inputs (x f32[T, d], reset bool[T]) -> (h_T, hs f32[T, features]);
    hs[t] is the hidden state after step t (the GRU's output)."""

    features: int

    @functools.partial(nn.scan, variable_broadcast="params", in_axes=0, out_axes=0, split_rngs={"params": False})
    @nn.compact
    def __call__(self, h: jax.Array, inputs: tuple[jax.Array, jax.Array]):
        x, reset = inputs
        h = jnp.where(reset, jnp.zeros_like(h), h)
        h, y = nn.GRUCell(self.features, recurrent_kernel_init=orthogonal())(h, x)  # flax's default, LAPACK-free
        return h, y


class RecurrentMLP(nn.Module):
    """(h f32[gru], obs f32[T, obs], reset bool[T]) -> (h_T, out f32[T, out], hs f32[T, gru])."""

    hidden: int = 64
    depth: int = 2
    activation: str = "tanh"
    gru: int = 64
    out: int = 1
    small_head: bool = False  # the policy mean's small last layer

    @nn.compact
    def __call__(self, h: jax.Array, obs: jax.Array, reset: jax.Array):
        act = ACTIVATIONS[self.activation]
        x = act(nn.Dense(self.hidden, name="embed")(obs))
        h, hs = ScannedGRU(self.gru, name="gru")(h, (x, reset))
        y = _trunk(hs, self.hidden, self.depth - 1, self.activation)
        kernel_init = _SMALL if self.small_head else nn.initializers.lecun_normal()
        return h, nn.Dense(self.out, kernel_init=kernel_init, name="head")(y), hs
