"""Robust "center" functions: the aggregate model theta_w from the clients that participate.

Every function takes `params`, a pytree whose leaves are stacked `[K, ...]` (K clients), and a
participation mask `mask: bool[K]` (which clients send this round), and returns a pytree of the
same structure WITHOUT the client axis (each leaf in its input dtype). The robust rules
(docs/robustness.md) mix it back into the clients like any other theta_w (`aggregators.mix`).

Conventions shared by every function here:

- Pure JAX: jittable and vmappable (the trainer vmaps over seeds). Every hyperparameter a user
  may sweep (`trim`, `f`, `m`, `eps`, `max_norm`, the weights and the mask itself) is used as a
  traced value: one compilation serves every value. Only `iters` (a loop length) is static.
  Pass traced hyperparameters with a fixed dtype (e.g. always `jnp.float32(x)`): a Python float
  and a `jnp.float32` are different jit signatures (weak versus strong type) and retrace.
- Rows whose mask is False are replaced by zeros before any arithmetic, so whatever a
  non-participating client holds (huge values, inf, NaN) never reaches the result.
- An all-False mask (which the caller rules out) is read as "every client participates": each
  function then returns its own unmasked center (the plain mean, the median of all K, ...), so
  the result stays finite whatever the mask.
- Norms and distances are over the whole flattened pytree (every leaf of one client together);
  sums are plain multiply-and-reduce (no `dot`), so no TF32 on GPUs and no cancellation from
  the |a|^2 + |b|^2 - 2 a.b expansion.
- Participating values are assumed finite.

References: Yin et al. 2018 (coordinate-wise median and trimmed mean), Blanchard et al. 2017
(Krum, Multi-Krum), Weiszfeld 1937 and Pillutla, Kakade & Harchaoui 2022 (smoothed Weiszfeld,
RFA), Sun et al. 2019 (norm bounding).
"""

from __future__ import annotations

import operator
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp

from fedjax_nav.federated.stacked import num_clients, rows, weighted_sum, zero_out

# Weiszfeld iterations of `geometric_median` by default. Starting from the mean, one far outlier
# (1e6 against a cluster of spread 0.1) costs about log_(n-1)(1e6 / 0.1) iterations to walk back
# to the cluster: 12 for n = 5; 32 leaves margin and is cheap (two passes over K x params each).
GEOMETRIC_MEDIAN_ITERS = 32


# ----------------------------------------------------------------------------- helpers


def effective_mask(mask, k: int) -> jax.Array:
    """mask as bool[K]; an all-False mask becomes all-True (every client participates)."""
    mask = jnp.asarray(mask).astype(bool)
    if mask.shape != (k,):
        raise ValueError(f"mask must have shape ({k},) (one entry per client); got {mask.shape}")
    return jnp.where(jnp.any(mask), mask, jnp.ones_like(mask))


def _sq_norms(params) -> jax.Array:
    """f32[K]: ||theta_k||^2 over the whole flattened pytree of each client."""
    parts = [
        jnp.sum(jnp.square(p.astype(jnp.float32)).reshape(p.shape[0], -1), axis=1) for p in jax.tree.leaves(params)
    ]
    return sum(parts[1:], parts[0])


def _sq_dists_to(params, z) -> jax.Array:
    """f32[K]: ||theta_k - z||^2 over the whole pytree (z without the client axis)."""
    return _sq_norms(jax.tree.map(lambda p, c: p.astype(jnp.float32) - c.astype(jnp.float32)[None], params, z))


def pairwise_sq_dists(params) -> jax.Array:
    """f32[K, K]: ||theta_i - theta_j||^2 over the whole flattened pytree (exactly symmetric,
    zero diagonal). Computed from the differences (XLA fuses the broadcast into the reduction)."""

    def leaf(p):
        x = p.astype(jnp.float32).reshape(p.shape[0], -1)
        return jnp.sum(jnp.square(x[:, None, :] - x[None, :, :]), axis=-1)

    parts = [leaf(p) for p in jax.tree.leaves(params)]
    return sum(parts[1:], parts[0])


def _count(mask) -> jax.Array:
    return jnp.sum(mask.astype(jnp.int32))


def _sorted_window_mean(params, mask, lo, hi):
    """Per coordinate: sort the participating values ascending (non-participants pushed to +inf,
    after them) and average the ranks lo <= rank < hi (traced ints, hi > lo, hi <= n)."""

    def leaf(p):
        acc = jnp.promote_types(p.dtype, jnp.float32)
        x = jnp.where(rows(mask, p), p.astype(acc), jnp.asarray(jnp.inf, acc))
        s = jnp.sort(x, axis=0)
        rank = rows(jnp.arange(p.shape[0]), p)
        keep = (rank >= lo) & (rank < hi)
        total = jnp.sum(jnp.where(keep, s, jnp.zeros((), acc)), axis=0)
        return (total / (hi - lo).astype(acc)).astype(p.dtype)

    return jax.tree.map(leaf, params)


# ----------------------------------------------------------------------------- centers


def masked_mean(params, mask, weights=None):
    """Weighted mean of the participating clients.

        theta_w = sum_k m_k w_k theta_k / sum_k m_k |w_k|

    with m_k the mask and w_k the weights (1 when `weights` is None). Dividing by the sum of
    |w_k| keeps the reading of the real-valued weighting (RW, Algorithm 4: signed weights
    normalised by the sum of their magnitudes) and is the usual renormalisation for nonnegative
    weights (PW's softmax, data sizes). If every participating weight is 0 the participating
    clients are averaged uniformly; an all-False mask means every client.
    Reference: McMahan et al. 2017 (FedAvg), over the clients of the round.
    """
    k = num_clients(params)
    mask = effective_mask(mask, k)
    w = jnp.ones((k,), jnp.float32) if weights is None else jnp.asarray(weights).astype(jnp.float32)
    if w.shape != (k,):
        raise ValueError(f"weights must have shape ({k},); got {w.shape}")
    w = jnp.where(mask, w, 0.0)
    total = jnp.sum(jnp.abs(w))
    uniform = mask.astype(jnp.float32) / _count(mask).astype(jnp.float32)
    w = jnp.where(total > 0, w / jnp.where(total > 0, total, 1.0), uniform)
    return weighted_sum(zero_out(params, mask), w)


def coordinate_median(params, mask):
    """Coordinate-wise median of the participating clients.

        theta_w[j] = median{ theta_k[j] : m_k }

    for an even count n the mean of the two middle values (numpy.median's convention): the
    average of the sorted ranks (n - 1) // 2 and n // 2. n is traced: non-participants are
    sorted to +inf, after every participating value. Reference: Yin, Chen, Ramchandran &
    Bartlett 2018, "Byzantine-Robust Distributed Learning: Towards Optimal Statistical Rates".
    """
    k = num_clients(params)
    mask = effective_mask(mask, k)
    n = _count(mask)
    return _sorted_window_mean(params, mask, (n - 1) // 2, n // 2 + 1)


def trim_count(n, trim) -> jax.Array:
    """int32: how many values `trimmed_mean` drops at EACH end out of n:
    t = clip(floor(trim * n + 1e-4), 0, (n - 1) // 2). The 1e-4 absorbs float32's rounding of
    trim * n (float32(0.42) * 150 is 62.99999 where 0.42 * 150 = 63); the upper clip
    keeps the median element(s) (1 value for odd n, 2 for even) whatever trim is."""
    n = jnp.asarray(n).astype(jnp.int32)
    t = jnp.floor(jnp.asarray(trim).astype(jnp.float32) * n.astype(jnp.float32) + 1e-4).astype(jnp.int32)
    return jnp.clip(t, 0, jnp.maximum((n - 1) // 2, 0))


def trimmed_mean(params, mask, trim):
    """Coordinate-wise trimmed mean of the participating clients.

        theta_w[j] = 1 / (n - 2t) sum_{r = t}^{n - t - 1} x_(r)[j],   t = floor(trim * n)

    with x_(0) <= ... <= x_(n-1) the sorted participating values of coordinate j and n their
    count. `trim` is traced, meant in [0, 0.5); t is clipped to [0, (n - 1) // 2] so that at
    least the median element(s) remain (see `trim_count`; trim = 0 is the mean, trim >= 0.5 the
    median). Reference: Yin, Chen, Ramchandran & Bartlett 2018 (Byzantine-robust distributed
    learning).
    """
    k = num_clients(params)
    mask = effective_mask(mask, k)
    n = _count(mask)
    t = trim_count(n, trim)
    return _sorted_window_mean(params, mask, t, n - t)


def krum_select(params, mask, f, m):
    """bool[K]: the clients (Multi-)Krum selects, and f32[K]: their scores.

        s_i = sum_{j in N_i} ||theta_i - theta_j||^2

    over the q = n - f - 2 participating clients j != i nearest to i (whole-pytree L2); the m
    participating clients with the lowest scores are selected (ties: the lower index). f and m
    are traced ints. Blanchard et al. require n >= 2f + 3 (the config check); here q is clipped
    to [1, n - 1] (to 0 when n = 1) and m to [1, n], so any f and m give a finite answer.
    Non-participants score +inf and are never selected. Reference: Blanchard, El Mhamdi,
    Guerraoui & Stainer 2017, "Machine Learning with Adversaries: Byzantine Tolerant Gradient
    Descent" (NeurIPS).
    """
    k = num_clients(params)
    mask = effective_mask(mask, k)
    n = _count(mask)
    f = jnp.asarray(f).astype(jnp.int32)
    m = jnp.asarray(m).astype(jnp.int32)
    q = jnp.clip(n - f - 2, jnp.minimum(1, n - 1), n - 1)
    big = jnp.finfo(jnp.float32).max
    d = jnp.minimum(pairwise_sq_dists(zero_out(params, mask)), big)
    others = mask[None, :] & mask[:, None] & ~jnp.eye(k, dtype=bool)
    d = jnp.sort(jnp.where(others, d, jnp.inf), axis=1)
    # The q nearest others of a participant are all finite (q <= n - 1).
    score = jnp.sum(jnp.where(jnp.arange(k)[None, :] < q, d, 0.0), axis=1)
    score = jnp.where(mask, jnp.minimum(score, big), jnp.inf)
    rank = jnp.argsort(jnp.argsort(score, stable=True), stable=True)
    selected = mask & (rank < jnp.clip(m, 1, n))
    return selected, score


def krum(params, mask, f, m):
    """(Multi-)Krum: the mean of the m participating clients with the lowest Krum scores.

        theta_w = 1/m sum_{i in S} theta_i,   S = the m lowest s_i,
        s_i = sum of ||theta_i - theta_j||^2 over the n - f - 2 nearest other participants j

    m = 1 is Krum (the single most central client), m = n - f Multi-Krum's usual choice. f and
    m are traced ints, clipped as in `krum_select` (finite for any f, m; the n >= 2f + 3
    condition of the paper is the caller's config check). Reference: Blanchard, El Mhamdi,
    Guerraoui & Stainer 2017 (NeurIPS), sections 4-5.
    """
    selected, _ = krum_select(params, mask, f, m)
    return masked_mean(params, selected)


def geometric_median(params, mask, iters: int = GEOMETRIC_MEDIAN_ITERS, eps=1e-8):
    """Geometric median of the participating clients by the smoothed Weiszfeld algorithm.

        theta_w = argmin_z sum_k m_k ||theta_k - z||   (whole-pytree L2 norm)
        z_0 = masked mean;  z_{t+1} = sum_k b_k theta_k / sum_k b_k,
        b_k = m_k / max(eps, ||theta_k - z_t||)

    for `iters` iterations (static, a `lax.fori_loop`); eps (traced) keeps the weight of a
    client finite when z_t reaches it. Convergence is linear: from the mean, an outlier at
    distance D from a cluster of spread s needs about log_(n-1)(D / s) iterations to lose its
    pull (see GEOMETRIC_MEDIAN_ITERS). References: Weiszfeld 1937; Pillutla, Kakade & Harchaoui
    2022, "Robust Aggregation for Federated Learning" (IEEE TSP; RFA, Algorithm 2).
    """
    try:
        iters = operator.index(iters)
    except TypeError:
        raise ValueError(f"iters must be a static int >= 0; got {iters!r}") from None
    if iters < 0:
        raise ValueError(f"iters must be a static int >= 0; got {iters!r}")
    k = num_clients(params)
    mask = effective_mask(mask, k)
    x = zero_out(params, mask)
    z0 = masked_mean(x, mask)

    def step(_, z):
        dist = jnp.sqrt(_sq_dists_to(x, z))
        b = jnp.where(mask, 1.0 / jnp.maximum(eps, dist), 0.0)
        return weighted_sum(x, b / jnp.sum(b))

    return jax.lax.fori_loop(0, iters, step, z0)


def norm_bounded_mean(params, mask, reference, max_norm, weights=None):
    """Mean of the participating clients' updates, each clipped to an L2 ball around the
    previous global model.

        delta_k = theta_k - reference
        theta_w = reference + masked_mean_k( delta_k * min(1, max_norm / ||delta_k||) )

    with ||.|| over the whole flattened pytree and `masked_mean`'s weighting (uniform unless
    `weights` is given). `reference` is the previous global model (no client axis); `max_norm`
    is traced (negative values act as 0: every update is dropped and theta_w = reference).
    Reference: Sun, Kairouz, Suresh & McMahan 2019, "Can You Really Backdoor Federated
    Learning?" (norm bounding defence).
    """
    k = num_clients(params)
    mask = effective_mask(mask, k)
    if jax.tree.structure(reference) != jax.tree.structure(params):
        raise ValueError("reference must have the structure of params (without the client axis)")
    delta = zero_out(jax.tree.map(lambda p, r: p - r[None].astype(p.dtype), params, reference), mask)
    norm = jnp.sqrt(_sq_norms(delta))
    max_norm = jnp.maximum(jnp.asarray(max_norm).astype(jnp.float32), 0.0)
    s = jnp.minimum(1.0, max_norm / jnp.maximum(norm, jnp.finfo(jnp.float32).tiny))
    clipped = jax.tree.map(lambda d: (d.astype(jnp.float32) * rows(s, d)).astype(d.dtype), delta)
    mean = masked_mean(clipped, mask, weights)
    return jax.tree.map(lambda r, d: (r + d.astype(r.dtype)).astype(r.dtype), reference, mean)


class Center(NamedTuple):
    """A robust center as data: fn(params, mask, reference, *hparams) -> theta_w, with the `fed.*`
    config names of its traced hyperparameters in fn's order (`reference` is the previous global
    model; only norm bounding reads it)."""

    fn: Callable
    hparams: tuple[str, ...]


# The one table of robust centers: `fed.aggregator` names, and the aggregators built on them
# (`fedjax_nav.federated.aggregators.RULES`), are its keys.
CENTERS: dict[str, Center] = {
    "mean": Center(lambda p, mask, ref: masked_mean(p, mask), ()),
    "median": Center(lambda p, mask, ref: coordinate_median(p, mask), ()),
    "trimmed_mean": Center(lambda p, mask, ref, trim: trimmed_mean(p, mask, trim), ("trim",)),
    "krum": Center(lambda p, mask, ref, f, m: krum(p, mask, f, m), ("krum_f", "krum_m")),
    "geometric_median": Center(lambda p, mask, ref: geometric_median(p, mask), ()),
    "norm_bounded": Center(lambda p, mask, ref, max_norm: norm_bounded_mean(p, mask, ref, max_norm), ("max_norm",)),
}
