"""A running mean / variance of observations (one agent), as pure functions.

Batches are merged with the parallel form of Welford's update (Chan, Golub and LeVeque 1979),
which is what brax's `acme/running_statistics.py` computes in another arrangement:

    n = n_a + n_b      mean = mean_a + d n_b / n      M2 = M2_a + M2_b + d^2 n_a n_b / n
    (d = mean_b - mean_a; M2 = sum of squared deviations from the mean; var = M2 / n)

`pool` merges several clients' statistics the same way: it equals the statistics of all their
rows together, which a mean of their means and variances would not (docs/learners.md says when
normaliser statistics are pooled in a federated run).

The count is a float32: past 2^24 rows it rounds, the weights n_b / n stay accurate to float32,
where an int32 count would overflow at 2^31 rows and turn negative.

`moments` / `from_moments` are the same statistics as a dict of per-row moments (count, mean,
mean of squares): the form a learner keeps when a federated round averages it. With equal counts,
the plain mean of several clients' moments is the moments of all their rows together (`pool`),
and a weighted mean is the statistics of a weighted pool of their rows; a mean of RunningStats
(M2 averaged) would miss the spread between the clients' means.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

CLIP = 10.0  # |normalised value| bound (gymnasium's and SB3's default)
EPS = 1e-8  # added to the variance


@struct.dataclass
class RunningStats:
    count: jax.Array  # f32[]   rows seen
    mean: jax.Array  # f32[size]
    m2: jax.Array  # f32[size] sum of squared deviations from the mean


def init(size: int) -> RunningStats:
    """No rows seen: `normalize` is then the identity (mean 0, variance 1)."""
    return RunningStats(jnp.float32(0.0), jnp.zeros((size,), jnp.float32), jnp.zeros((size,), jnp.float32))


def _merge(count_a, mean_a, m2_a, count_b, mean_b, m2_b):
    n = count_a + count_b
    w = jnp.where(n > 0, count_b / jnp.maximum(n, 1e-30), 0.0)
    d = mean_b - mean_a
    return n, mean_a + d * w, m2_a + m2_b + d**2 * count_a * w


def update(stats: RunningStats, batch: jax.Array, mask: jax.Array | None = None) -> RunningStats:
    """Merge a batch f32[..., size] (every leading axis is rows) into the statistics. mask: 0/1
    per row (the leading axes' shape): rows with 0 are left out (padded robots, invalid steps)."""
    x = jnp.reshape(batch, (-1, stats.mean.shape[-1])).astype(jnp.float32)
    w = jnp.ones(x.shape[:1], jnp.float32) if mask is None else jnp.reshape(mask, (-1,)).astype(jnp.float32)
    n_b = jnp.sum(w)
    mean_b = jnp.sum(w[:, None] * x, axis=0) / jnp.maximum(n_b, 1.0)
    m2_b = jnp.sum(w[:, None] * (x - mean_b) ** 2, axis=0)
    return RunningStats(*_merge(stats.count, stats.mean, stats.m2, n_b, mean_b, m2_b))


def variance(stats: RunningStats) -> jax.Array:
    """The population variance M2 / n; 1 before two rows are seen (no spread is known yet)."""
    return jnp.where(stats.count > 1.0, stats.m2 / jnp.maximum(stats.count, 1.0), 1.0)


def normalize(stats: RunningStats, x: jax.Array, clip=CLIP, eps=EPS) -> jax.Array:
    """(x - mean) / sqrt(var + eps), clipped to [-clip, clip] (gymnasium's and SB3's defaults: a
    lidar beam that is almost always at its maximum range has a variance near 0, and its rare
    other readings would otherwise be huge). x: f32[..., size]; clip and eps may be traced."""
    mean, std = affine(stats, eps)
    return jnp.clip((x - mean) / std, -clip, clip)


def affine(stats: RunningStats, eps=EPS) -> tuple[jax.Array, jax.Array]:
    """(mean, sqrt(var + eps)), each f32[size]: `normalize` before its clip is (x - mean) / std
    (what an exported policy applies, deploy/export.py)."""
    return stats.mean, jnp.sqrt(variance(stats) + eps)


def pool(stats: RunningStats, mask: jax.Array | None = None) -> RunningStats:
    """The statistics of every client's rows together, from statistics stacked over a leading
    client axis (mask: bool/0-1[clients], who takes part). Returns one unstacked RunningStats."""
    w = jnp.ones(stats.count.shape, jnp.float32) if mask is None else jnp.asarray(mask, jnp.float32)
    counts = w * stats.count
    n = jnp.sum(counts)
    mean = jnp.sum(counts[:, None] * stats.mean, axis=0) / jnp.maximum(n, 1e-30)
    m2 = jnp.sum(w[:, None] * stats.m2, axis=0) + jnp.sum(counts[:, None] * (stats.mean - mean) ** 2, axis=0)
    return RunningStats(n, jnp.where(n > 0, mean, 0.0), m2)


def moments(stats: RunningStats) -> dict:
    """{"count": f32[], "mean": f32[size], "mean_sq": f32[size]}: the per-row moments, linear under
    a weighted mean over clients (module docstring). A dict, so that it can sit in a flax variable
    dict and be written, read and averaged like a network's parameters."""
    var = jnp.where(stats.count > 0, stats.m2 / jnp.maximum(stats.count, 1e-30), 0.0)
    return {"count": stats.count, "mean": stats.mean, "mean_sq": var + stats.mean**2}


def from_moments(m: dict) -> RunningStats:
    """The RunningStats of `moments`' dict. A count below 0 or a variance below 0, which only an
    average with negative weights (or an attack) can make, are read as 0."""
    count = jnp.maximum(m["count"], 0.0)
    var = jnp.maximum(m["mean_sq"] - m["mean"] ** 2, 0.0)
    return RunningStats(count, m["mean"], count * var)
