"""Robust federation (docs/robustness.md): the center functions of `federated.robust` against independent
float64 numpy references (plain loops, np.median, np.sort) on random stacked pytrees and random
participation masks, their traced hyperparameters (one compilation for every value), vmap over
seeds, robustness to an outlier, and the Byzantine attacks of `federated.attacks`."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fedjax_nav.federated import aggregators, attacks, robust

KS = (1, 3, 5, 6, 8)
OUTLIER = 1e30  # what non-participating rows hold (with some inf and NaN too): must be ignored
GM_ITERS = 20

# One jitted function per center, every hyperparameter and the mask traced: one compilation per
# pytree shape (K) for the whole file.
J_MEAN = jax.jit(robust.masked_mean)
J_MEDIAN = jax.jit(robust.coordinate_median)
J_TRIM = jax.jit(robust.trimmed_mean)
J_KRUM = jax.jit(robust.krum)
J_GM = jax.jit(robust.geometric_median, static_argnames="iters")
J_NB = jax.jit(robust.norm_bounded_mean)


# ----------------------------------------------------------------------------- data


def random_params(rng, k, loc=0.0, spread=1.0):
    """Three leaves of different shapes, stacked [K, ...], float32."""
    f = lambda *s: jnp.asarray(loc + spread * rng.normal(size=(k, *s)), jnp.float32)  # noqa: E731
    return {"dense": {"kernel": f(3, 2), "bias": f(2)}, "head": f(4)}


def random_reference(rng):
    f = lambda *s: jnp.asarray(rng.normal(size=s), jnp.float32)  # noqa: E731
    return {"dense": {"kernel": f(3, 2), "bias": f(2)}, "head": f(4)}


def poison_absent(params, mask):
    """Rows outside the mask hold huge values, inf or NaN."""
    bad = np.array([OUTLIER, -OUTLIER, np.inf, np.nan], np.float32)
    absent = np.flatnonzero(~np.asarray(mask))

    def leaf(p):
        p = np.array(p)
        for i, row in enumerate(absent):
            p[row] = bad[i % len(bad)]
        return jnp.asarray(p)

    return jax.tree.map(leaf, params)


def masks_for(k, rng):
    """All clients, a single participant, a single non-participant and random masks (>= 1 True)."""
    out = [np.ones(k, bool)]
    one = np.zeros(k, bool)
    one[rng.integers(k)] = True
    out.append(one)
    if k > 1:
        out.append(~one)
    for _ in range(3):
        m = rng.random(k) < 0.6
        m[rng.integers(k)] = True
        out.append(m)
    return out


def leaves64(tree):
    return [np.asarray(x, np.float64) for x in jax.tree.leaves(tree)]


def flat64(params):
    """[K, D] float64: each client's whole pytree flattened (the references' vectors)."""
    return np.concatenate([x.reshape(x.shape[0], -1) for x in leaves64(params)], axis=1)


def unflat(vec, params):
    """A flat float64 vector back into a list of leaves shaped like params without K."""
    out, i = [], 0
    for x in jax.tree.leaves(params):
        size = int(np.prod(x.shape[1:]))
        out.append(vec[i : i + size].reshape(x.shape[1:]))
        i += size
    return out


def assert_close(tree, ref, rtol=1e-5, atol=1e-6):
    got = jax.tree.leaves(tree)
    assert len(got) == len(ref)
    for g, r in zip(got, ref):
        assert g.shape == r.shape
        assert np.all(np.isfinite(np.asarray(g)))
        np.testing.assert_allclose(np.asarray(g, np.float64), r, rtol=rtol, atol=atol)


# ----------------------------------------------------------------------------- numpy references


def ref_masked_mean(params, mask, weights=None):
    idx = np.flatnonzero(mask)
    w = np.ones(len(mask)) if weights is None else np.asarray(weights, np.float64)
    w = w[idx]
    total = np.sum(np.abs(w))
    w = w / total if total > 0 else np.full(len(idx), 1.0 / len(idx))
    out = []
    for x in leaves64(params):
        acc = np.zeros(x.shape[1:])
        for wk, k in zip(w, idx):
            acc += wk * x[k]
        out.append(acc)
    return out


def ref_median(params, mask):
    idx = np.flatnonzero(mask)
    return [np.median(x[idx], axis=0) for x in leaves64(params)]


def ref_trim_count(n, trim):
    return min(max(math.floor(trim * n + 1e-9), 0), (n - 1) // 2)


def ref_trimmed(params, mask, trim):
    idx = np.flatnonzero(mask)
    n = len(idx)
    t = ref_trim_count(n, trim)
    return [np.sort(x[idx], axis=0)[t : n - t].mean(axis=0) for x in leaves64(params)]


def ref_krum(params, mask, f, m):
    x = flat64(params)
    idx = list(np.flatnonzero(mask))
    n = len(idx)
    q = min(max(n - f - 2, min(1, n - 1)), n - 1)
    scores = []
    for i in idx:
        d = sorted(float(np.sum((x[i] - x[j]) ** 2)) for j in idx if j != i)
        scores.append(sum(d[:q]))
    order = np.argsort(np.asarray(scores), kind="stable")
    chosen = [idx[o] for o in order[: min(max(m, 1), n)]]
    return unflat(np.mean(x[chosen], axis=0), params)


def ref_geometric_median(params, mask, iters, eps=1e-8):
    x = flat64(params)[np.flatnonzero(mask)]
    z = x.mean(axis=0)
    for _ in range(iters):
        b = 1.0 / np.maximum(eps, np.sqrt(((x - z) ** 2).sum(axis=1)))
        z = (b[:, None] * x).sum(axis=0) / b.sum()
    return unflat(z, params)


def ref_norm_bounded(params, mask, reference, max_norm):
    x = flat64(params)
    r = np.concatenate([v.ravel() for v in leaves64(reference)])
    idx = np.flatnonzero(mask)
    acc = np.zeros_like(r)
    for k in idx:
        d = x[k] - r
        norm = np.linalg.norm(d)
        acc += d * (min(1.0, max_norm / norm) if norm > 0 else 1.0)
    return unflat(r + acc / len(idx), params)


def sum_dist(params, z_leaves, mask):
    """sum_k ||theta_k - z|| over the participants (the geometric median's objective)."""
    x = flat64(params)[np.flatnonzero(mask)]
    z = np.concatenate([v.ravel() for v in z_leaves])
    return float(np.sqrt(((x - z) ** 2).sum(axis=1)).sum())


# ----------------------------------------------------------------------------- against numpy


@pytest.mark.parametrize("k", KS)
def test_masked_mean_against_numpy(k):
    rng = np.random.default_rng(10 + k)
    for mask in masks_for(k, rng):
        p = poison_absent(random_params(rng, k), mask)
        assert_close(J_MEAN(p, jnp.asarray(mask), None), ref_masked_mean(p, mask))
        w = rng.random(k).astype(np.float32) + 0.1
        assert_close(J_MEAN(p, jnp.asarray(mask), jnp.asarray(w)), ref_masked_mean(p, mask, w))
        # Signed weights (RW's): normalised by the sum of magnitudes over the participants.
        w = rng.normal(size=k).astype(np.float32)
        assert_close(J_MEAN(p, jnp.asarray(mask), jnp.asarray(w)), ref_masked_mean(p, mask, w))


@pytest.mark.parametrize("k", KS)
def test_coordinate_median_against_numpy(k):
    rng = np.random.default_rng(20 + k)
    for mask in masks_for(k, rng):
        p = poison_absent(random_params(rng, k), mask)
        assert_close(J_MEDIAN(p, jnp.asarray(mask)), ref_median(p, mask))


@pytest.mark.parametrize("k", KS)
def test_trimmed_mean_against_numpy(k):
    rng = np.random.default_rng(30 + k)
    for mask in masks_for(k, rng):
        p = poison_absent(random_params(rng, k), mask)
        for trim in (0.0, 0.1, 0.2, 0.25, 0.34, 0.49, 0.7):
            assert_close(J_TRIM(p, jnp.asarray(mask), jnp.float32(trim)), ref_trimmed(p, mask, trim))


def test_trimmed_mean_ends_and_trim_count():
    rng = np.random.default_rng(3)
    p, mask = random_params(rng, 6), np.array([1, 1, 0, 1, 1, 1], bool)
    # trim 0 is the mean, trim >= 0.5 keeps only the median elements.
    assert_close(J_TRIM(p, jnp.asarray(mask), jnp.float32(0.0)), ref_masked_mean(p, mask))
    assert_close(J_TRIM(p, jnp.asarray(mask), jnp.float32(0.9)), ref_median(p, mask))
    # float32(0.42) * 150 rounds to 62.99999: still 63 per end, as 0.42 * 150 = 63 exactly.
    counts = [
        int(robust.trim_count(n, jnp.float32(t)))
        for n, t in [
            (150, 0.42),
            (200, 0.265),
            (20, 0.35),
            (10, 0.3),
            (5, 0.2),
            (5, 0.19),
            (4, 0.49),
            (1, 0.4),
            (0, 0.2),
            (7, -0.1),
        ]
    ]
    assert counts == [63, 53, 7, 3, 1, 0, 1, 0, 0, 0]


@pytest.mark.parametrize("k", KS)
def test_krum_against_numpy(k):
    rng = np.random.default_rng(40 + k)
    for mask in masks_for(k, rng):
        p = poison_absent(random_params(rng, k), mask)
        n = int(mask.sum())
        for f, m in {(0, 1), (1, 1), (1, 2), (2, 3), (1, n), (5, 1), (0, 99)}:
            got = J_KRUM(p, jnp.asarray(mask), jnp.int32(f), jnp.int32(m))
            assert_close(got, ref_krum(p, mask, f, m))


def test_krum_select_marks_the_lowest_scores():
    rng = np.random.default_rng(4)
    p = random_params(rng, 6)
    p = jax.tree.map(lambda x: x.at[2].multiply(50.0), p)  # client 2 far from the others
    mask = np.array([1, 1, 1, 1, 1, 0], bool)
    selected, score = jax.jit(robust.krum_select)(p, jnp.asarray(mask), jnp.int32(1), jnp.int32(3))
    selected, score = np.asarray(selected), np.asarray(score)
    assert selected.sum() == 3 and not selected[2] and not selected[5]
    assert np.isinf(score[5]) and np.all(np.isfinite(score[:5]))
    assert score[selected].max() <= score[mask & ~selected].min()


@pytest.mark.parametrize("k", KS)
def test_geometric_median_against_numpy(k):
    rng = np.random.default_rng(50 + k)
    for mask in masks_for(k, rng):
        p = poison_absent(random_params(rng, k), mask)
        assert_close(
            J_GM(p, jnp.asarray(mask), iters=GM_ITERS, eps=jnp.float32(1e-8)),
            ref_geometric_median(p, mask, GM_ITERS),
            rtol=2e-5,
            atol=2e-6,
        )


def test_geometric_median_minimises_the_sum_of_distances():
    rng = np.random.default_rng(5)
    p, mask = random_params(rng, 8), np.array([1, 1, 1, 0, 1, 1, 1, 1], bool)
    got = leaves64(J_GM(p, jnp.asarray(mask), iters=200))
    best = ref_geometric_median(p, mask, 5000)
    assert sum_dist(p, got, mask) <= sum_dist(p, best, mask) * (1 + 1e-6)
    # ... and it beats the mean and the median on that objective.
    assert sum_dist(p, got, mask) < sum_dist(p, ref_masked_mean(p, mask), mask)
    assert sum_dist(p, got, mask) < sum_dist(p, ref_median(p, mask), mask)


@pytest.mark.parametrize("k", KS)
def test_norm_bounded_mean_against_numpy(k):
    rng = np.random.default_rng(60 + k)
    ref = random_reference(rng)
    for mask in masks_for(k, rng):
        p = poison_absent(random_params(rng, k), mask)
        for max_norm in (0.0, 0.5, 3.0, 1e6):
            got = J_NB(p, jnp.asarray(mask), ref, jnp.float32(max_norm), None)
            assert_close(got, ref_norm_bounded(p, mask, ref, max_norm))
    # Updates shorter than 1 (clients near the reference): clipped below and above their norms.
    near = jax.tree.map(lambda r, x: r[None] + 0.05 * x, ref, random_params(rng, k))
    for max_norm in (0.01, 0.1, 0.3):
        got = J_NB(near, jnp.ones(k, bool), ref, jnp.float32(max_norm), None)
        assert_close(got, ref_norm_bounded(near, np.ones(k, bool), ref, max_norm))
    # A huge bound is the plain masked mean; a zero bound is the reference.
    p, mask = random_params(rng, k), np.ones(k, bool)
    assert_close(
        J_NB(p, jnp.asarray(mask), ref, jnp.float32(1e9), None), ref_masked_mean(p, mask), rtol=1e-5, atol=1e-5
    )
    assert_close(J_NB(p, jnp.asarray(mask), ref, jnp.float32(0.0), None), leaves64(ref))


@pytest.mark.parametrize("k", (1, 5))
def test_all_false_mask_is_every_client(k):
    """The caller guarantees a participant; an all-False mask still gives finite numbers: every
    function's unmasked center."""
    rng = np.random.default_rng(70 + k)
    p, ref = random_params(rng, k), random_reference(rng)
    none, every = jnp.zeros(k, bool), np.ones(k, bool)
    assert_close(J_MEAN(p, none, None), ref_masked_mean(p, every))
    assert_close(J_MEAN(p, none, jnp.zeros(k, jnp.float32)), ref_masked_mean(p, every))  # zero weights: uniform
    assert_close(J_MEDIAN(p, none), ref_median(p, every))
    assert_close(J_TRIM(p, none, jnp.float32(0.2)), ref_trimmed(p, every, 0.2))
    assert_close(J_KRUM(p, none, jnp.int32(1), jnp.int32(1)), ref_krum(p, every, 1, 1))
    assert_close(
        J_GM(p, none, iters=GM_ITERS, eps=jnp.float32(1e-8)),
        ref_geometric_median(p, every, GM_ITERS),
        rtol=2e-5,
        atol=2e-6,
    )
    assert_close(J_NB(p, none, ref, jnp.float32(0.5), None), ref_norm_bounded(p, every, ref, 0.5))


# ----------------------------------------------------------------------------- traced, vmapped


def all_centers(params, mask, weights, trim, f, m, eps, reference, max_norm):
    return {
        "mean": robust.masked_mean(params, mask, weights),
        "median": robust.coordinate_median(params, mask),
        "trimmed": robust.trimmed_mean(params, mask, trim),
        "krum": robust.krum(params, mask, f, m),
        "gm": robust.geometric_median(params, mask, GM_ITERS, eps),
        "nb": robust.norm_bounded_mean(params, mask, reference, max_norm),
    }


def references(params, mask, weights, trim, f, m, reference, max_norm):
    return {
        "mean": ref_masked_mean(params, mask, weights),
        "median": ref_median(params, mask),
        "trimmed": ref_trimmed(params, mask, trim),
        "krum": ref_krum(params, mask, f, m),
        "gm": ref_geometric_median(params, mask, GM_ITERS),
        "nb": ref_norm_bounded(params, mask, reference, max_norm),
    }


def assert_all_close(got, want):
    for name in want:
        assert_close(got[name], want[name], rtol=2e-5, atol=2e-6)


SETTINGS = [  # mask, trim, f, m, max_norm
    ([1, 1, 1, 1, 1, 1], 0.2, 1, 1, 0.5),
    ([1, 0, 1, 1, 0, 1], 0.3, 0, 2, 2.0),
    ([0, 0, 0, 1, 0, 0], 0.0, 2, 1, 0.1),
    ([1, 1, 0, 1, 1, 1], 0.45, 1, 3, 100.0),
]


def test_hyperparameters_and_mask_are_traced():
    """One compilation serves every trim, f, m, eps, max_norm, weights and mask, and every
    attack scale and Byzantine mask."""
    traces = []

    def counted(*args):
        traces.append(1)
        return all_centers(*args)

    fn = jax.jit(counted)
    rng = np.random.default_rng(8)
    p, ref = random_params(rng, 6), random_reference(rng)
    for mask, trim, f, m, max_norm in SETTINGS:
        mask = np.asarray(mask, bool)
        w = rng.random(6).astype(np.float32)
        got = fn(
            p,
            jnp.asarray(mask),
            jnp.asarray(w),
            jnp.float32(trim),
            jnp.int32(f),
            jnp.int32(m),
            jnp.float32(1e-8),
            ref,
            jnp.float32(max_norm),
        )
        assert_all_close(got, references(p, mask, w, trim, f, m, ref, max_norm))
    assert len(traces) == 1

    attack_traces = []

    def attacked(kind, sent, byz, key, scale, reference):
        attack_traces.append(kind)
        return attacks.apply_attack(kind, sent, byz, key, scale, reference)

    att = jax.jit(attacked, static_argnums=0)
    for scale, byz in [(-10.0, [1, 0, 0, 0, 0, 0]), (3.0, [0, 1, 1, 0, 0, 1]), (0.5, [0] * 6)]:
        att("scale", p, jnp.asarray(byz, bool), jax.random.key(0), jnp.float32(scale), ref)
        att("noise", p, jnp.asarray(byz, bool), jax.random.key(1), jnp.float32(scale), ref)
    assert attack_traces == ["scale", "noise"]


def test_vmap_over_seeds():
    """The trainer vmaps over seeds: params [S, K, ...], masks [S, K], hyperparameters [S]."""
    rng = np.random.default_rng(9)
    seeds = [random_params(rng, 6) for _ in SETTINGS]
    refs = [random_reference(rng) for _ in SETTINGS]
    weights = rng.random((len(SETTINGS), 6)).astype(np.float32)
    stack = lambda trees: jax.tree.map(lambda *xs: jnp.stack(xs), *trees)  # noqa: E731
    masks = np.asarray([s[0] for s in SETTINGS], bool)
    col = lambda i, dtype: jnp.asarray([s[i] for s in SETTINGS], dtype)  # noqa: E731
    fn = jax.jit(jax.vmap(all_centers))
    got = fn(
        stack(seeds),
        jnp.asarray(masks),
        jnp.asarray(weights),
        col(1, jnp.float32),
        col(2, jnp.int32),
        col(3, jnp.int32),
        jnp.full(len(SETTINGS), 1e-8, jnp.float32),
        stack(refs),
        col(4, jnp.float32),
    )
    for s, (mask, trim, f, m, max_norm) in enumerate(SETTINGS):
        row = jax.tree.map(lambda x, s=s: x[s], got)
        assert_all_close(row, references(seeds[s], np.asarray(mask, bool), weights[s], trim, f, m, refs[s], max_norm))

    # Attacks under vmap: one key per seed, Byzantine rows differ across seeds.
    byz = jnp.asarray(np.eye(len(SETTINGS), 6, dtype=bool))
    keys = jax.random.split(jax.random.key(3), len(SETTINGS))
    noisy = jax.jit(jax.vmap(lambda s, b, k: attacks.apply_attack("noise", s, b, k, jnp.float32(1.0))))(
        stack(seeds), byz, keys
    )
    one_seed = jax.jit(lambda s, b, k: attacks.apply_attack("noise", s, b, k, jnp.float32(1.0)))
    for s in range(len(SETTINGS)):
        single = one_seed(seeds[s], byz[s], keys[s])
        for a, b in zip(jax.tree.leaves(jax.tree.map(lambda x, s=s: x[s], noisy)), jax.tree.leaves(single)):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6, atol=1e-7)


# ----------------------------------------------------------------------------- robustness


def test_one_outlier_of_five_moves_only_the_mean():
    """4 honest clients within 0.01 of each other, client 0 replaced by 1e6 everywhere: the
    robust centers stay within 0.05 of the honest mean, the plain mean moves by 2e5."""
    rng = np.random.default_rng(11)
    p = random_params(rng, 5, loc=1.0, spread=0.01)
    honest = [x[1:].mean(axis=0) for x in leaves64(p)]
    p = jax.tree.map(lambda x: x.at[0].set(1e6), p)
    mask = jnp.ones(5, bool)
    ref = jax.tree.unflatten(jax.tree.structure(p), [jnp.asarray(h, jnp.float32) for h in honest])

    def error(tree):
        return max(float(np.max(np.abs(g - h))) for g, h in zip(leaves64(tree), honest))

    errors = {
        "mean": error(J_MEAN(p, mask, None)),
        "median": error(J_MEDIAN(p, mask)),
        "trimmed_mean(0.2)": error(J_TRIM(p, mask, jnp.float32(0.2))),
        "krum(f=1)": error(J_KRUM(p, mask, jnp.int32(1), jnp.int32(1))),
        "multi_krum(f=1, m=3)": error(J_KRUM(p, mask, jnp.int32(1), jnp.int32(3))),
        "geometric_median": error(J_GM(p, mask)),  # the default iterations
        "norm_bounded(0.1)": error(J_NB(p, mask, ref, jnp.float32(0.1), None)),
    }
    print(errors)
    assert errors["mean"] > 1.9e5
    for name, e in errors.items():
        if name != "mean":
            assert e < 0.05, (name, e)


# ----------------------------------------------------------------------------- attacks


def test_attacks_replace_only_byzantine_rows():
    rng = np.random.default_rng(12)
    k = 5
    sent, ref = random_params(rng, k), random_reference(rng)
    byz = np.array([1, 0, 1, 0, 0], bool)
    x, r = leaves64(sent), leaves64(ref)
    key = jax.random.key(5)
    fn = jax.jit(attacks.apply_attack, static_argnums=0)
    formulas = {
        "scale": lambda s: [rr + s * (xx - rr) for xx, rr in zip(x, r)],
        "sign_flip": lambda s: [rr - (xx - rr) for xx, rr in zip(x, r)],
        "zeros": lambda s: [np.zeros_like(xx) for xx in x],
        "stale": lambda s: [np.broadcast_to(rr, xx.shape) for xx, rr in zip(x, r)],
        "none": lambda s: x,
    }
    assert set(attacks.ATTACKS) == set(formulas) | {"noise"}
    for kind, formula in formulas.items():
        for scale in (-10.0, 2.5):
            out = leaves64(fn(kind, sent, jnp.asarray(byz), key, jnp.float32(scale), ref))
            for got, want, honest in zip(out, formula(scale), x):
                np.testing.assert_allclose(got[byz], want[byz], rtol=1e-5, atol=1e-5)
                np.testing.assert_array_equal(got[~byz], honest[~byz])  # bit for bit
    # The default scales: "scale" is -10.
    out = leaves64(attacks.apply_attack("scale", sent, jnp.asarray(byz), key, None, ref))
    for got, want in zip(out, formulas["scale"](-10.0)):
        np.testing.assert_allclose(got[byz], want[byz], rtol=1e-5, atol=1e-5)


def test_noise_attack_is_gaussian_with_std_scale():
    k = 4
    sent = {"big": jnp.ones((k, 4000), jnp.float32), "small": jnp.ones((k, 3), jnp.float32)}
    byz = jnp.asarray([0, 1, 1, 0], bool)
    key = jax.random.key(6)
    noise = jax.jit(attacks.apply_attack, static_argnums=0)
    one = noise("noise", sent, byz, key, jnp.float32(1.0))
    three = noise("noise", sent, byz, key, jnp.float32(3.0))
    assert float(attacks.DEFAULT_SCALES["noise"]) == 1.0
    default = attacks.apply_attack("noise", sent, byz, key)
    leaves = zip(jax.tree.leaves(one), jax.tree.leaves(three), jax.tree.leaves(default), jax.tree.leaves(sent))
    for a, b, d, s in leaves:
        a, b, d, s = map(np.asarray, (a, b, d, s))
        np.testing.assert_array_equal(a[[0, 3]], s[[0, 3]])  # honest rows untouched
        np.testing.assert_allclose(b[[1, 2]], 3.0 * a[[1, 2]], rtol=1e-6)  # N(0, scale^2) = scale N(0, 1)
        np.testing.assert_array_equal(d, a)
        assert not np.allclose(a[1], a[2])  # independent draws per Byzantine client
    big = np.asarray(three["big"])[[1, 2]]
    assert abs(big.mean()) < 0.1 and abs(big.std() - 3.0) < 0.1
    other = noise("noise", sent, byz, jax.random.key(7), jnp.float32(1.0))
    assert not np.allclose(np.asarray(other["big"])[1], np.asarray(one["big"])[1])


def test_inflate_reward():
    r = jnp.asarray([0.5, -0.2, 0.1, -1.5], jnp.float32)
    byz = jnp.asarray([0, 1, 0, 1], bool)
    got = np.asarray(jax.jit(attacks.inflate_reward)(r, byz, jnp.float32(10.0)))
    np.testing.assert_allclose(got, [0.5, 0.2 * 10 + 10, 0.1, 1.5 * 10 + 10], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(attacks.inflate_reward(r, byz)), got, rtol=1e-6)  # default 10


def test_errors_name_the_problem():
    rng = np.random.default_rng(13)
    p = random_params(rng, 3)
    with pytest.raises(ValueError, match="mask must have shape"):
        robust.masked_mean(p, jnp.ones(4, bool))
    with pytest.raises(ValueError, match="iters"):
        robust.geometric_median(p, jnp.ones(3, bool), iters=2.5)
    with pytest.raises(ValueError, match="unknown robust center 'average'"):
        aggregators.robust_rule("average", tau=1.0)
    with pytest.raises(ValueError, match="reference must have the structure"):
        robust.norm_bounded_mean(p, jnp.ones(3, bool), None, 1.0)
    with pytest.raises(ValueError, match="unknown attack"):
        attacks.apply_attack("flip", p, jnp.zeros(3, bool), jax.random.key(0), 1.0, None)
    with pytest.raises(ValueError, match="needs reference"):
        attacks.apply_attack("stale", p, jnp.zeros(3, bool), jax.random.key(0), 1.0, None)
    with pytest.raises(ValueError, match="byzantine must have shape"):
        attacks.apply_attack("zeros", p, jnp.zeros(2, bool))


def test_center_dispatch():
    rng = np.random.default_rng(14)
    p, ref, mask = random_params(rng, 5), random_reference(rng), np.array([1, 1, 0, 1, 1], bool)
    cases = {
        "mean": ref_masked_mean(p, mask),
        "median": ref_median(p, mask),
        "trimmed_mean": ref_trimmed(p, mask, 0.3),
        "krum": ref_krum(p, mask, 1, 2),
        "geometric_median": ref_geometric_median(p, mask, robust.GEOMETRIC_MEDIAN_ITERS),
        "norm_bounded": ref_norm_bounded(p, mask, ref, 0.7),
    }
    assert set(cases) == set(robust.CENTERS)
    hp = {"trim": jnp.float32(0.3), "krum_f": jnp.int32(1), "krum_m": jnp.int32(2), "max_norm": jnp.float32(0.7)}
    for kind, want in cases.items():
        c = robust.CENTERS[kind]
        got = jax.jit(c.fn)(p, jnp.asarray(mask), ref, *[hp[h] for h in c.hparams])
        assert_close(got, want, rtol=2e-5, atol=2e-6)
