"""Federated aggregators against numpy (float64) references on random stacked pytrees, and the
communication accounting of Table 3 (docs/decisions.md, Federated aggregation and Communication)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fedjax_nav import methods
from fedjax_nav.federated import aggregators as agg
from fedjax_nav.federated import communication

K = 4


def random_params(seed: int, k: int = K):
    """A nested pytree of stacked client parameters, leaves [K, ...]."""
    rng = np.random.default_rng(seed)
    f = lambda *s: jnp.asarray(rng.normal(size=(k, *s)), jnp.float32)  # noqa: E731
    return {
        "actor": {"Dense_0": {"kernel": f(3, 2), "bias": f(2)}, "v_head": {"bias": f(1)}},
        "critic": {"Dense_0": {"kernel": f(5, 4)}, "scale": f()},
    }


def np_leaves(tree):
    return [np.asarray(x, np.float64) for x in jax.tree.leaves(tree)]


def np_mix(params, weights, tau):
    """Reference: theta_w = sum_k w_k theta_k; theta_k <- (1 - tau) theta_k + tau theta_w."""
    out = []
    for p in np_leaves(params):
        w = np.tensordot(np.asarray(weights, np.float64), p, axes=1)
        out.append((1 - tau) * p + tau * w[None])
    return out


def assert_leaves_close(tree, ref, rtol=1e-5, atol=1e-6):
    got = jax.tree.leaves(tree)
    assert len(got) == len(ref)
    for g, r in zip(got, ref):
        assert g.shape == r.shape
        np.testing.assert_allclose(np.asarray(g), r, rtol=rtol, atol=atol)


R = jnp.array([0.5, -1.0, 2.0, 0.25], jnp.float32)


def aggregate(kind, params, r, tau, beta, state=None, mask=None):
    """One `update` of the named aggregator with the hyperparameters it takes (state: its own
    init when None)."""
    given = {"tau": tau, "beta": beta}
    a = agg.make(kind, **{h: given[h] for h in agg.RULES[kind].hparams})
    state = a.init(params) if state is None else state
    return a.update(params, r, state, mask)


# ----------------------------------------------------------------------------- soft FedAvg


@pytest.mark.parametrize("tau", [0.0, 0.3, 0.5, 1.0])
def test_soft_fedavg_against_numpy(tau):
    p = random_params(0)
    out, _ = aggregate("soft", p, R, jnp.float32(tau), jnp.float32(0.5))
    assert_leaves_close(out, np_mix(p, np.full(K, 1 / K), tau))
    assert jax.tree.structure(out) == jax.tree.structure(p)


def test_soft_fedavg_tau0_is_unchanged_and_tau1_is_the_mean():
    p = random_params(1)
    same, _ = aggregate("soft", p, R, jnp.float32(0.0), None)
    for a, b in zip(jax.tree.leaves(same), jax.tree.leaves(p)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))  # IDDPG, bitwise
    hard, _ = aggregate("soft", p, R, jnp.float32(1.0), None)
    for a, b in zip(jax.tree.leaves(hard), np_leaves(p)):
        a = np.asarray(a)
        for k in range(K):
            np.testing.assert_array_equal(a[k], a[0])  # every client holds the same model
        np.testing.assert_allclose(a[0], b.mean(0), rtol=1e-5, atol=1e-6)


def test_soft_fedavg_ignores_rewards():
    p = random_params(2)
    a, _ = aggregate("soft", p, R, jnp.float32(0.5), jnp.float32(0.5))
    b, _ = aggregate("soft", p, -10 * R, jnp.float32(0.5), jnp.float32(2.0))
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


# ----------------------------------------------------------------------------- PW / RW


@pytest.mark.parametrize("beta", [0.25, 0.5, 1.5])
@pytest.mark.parametrize("tau", [0.0, 0.5, 1.0])
def test_positive_weighting_is_a_softmax_of_rewards(beta, tau):
    p = random_params(3)
    r = np.asarray(R, np.float64)
    w = np.exp(beta * r) / np.exp(beta * r).sum()
    np.testing.assert_allclose(np.asarray(agg.positive_weights(R, jnp.float32(beta))), w, rtol=1e-6)
    out, _ = aggregate("pw", p, R, jnp.float32(tau), jnp.float32(beta))
    assert_leaves_close(out, np_mix(p, w, tau))


def test_positive_weighting_with_equal_rewards_is_fedavg():
    p = random_params(4)
    r = jnp.full(K, -3.0)
    a, _ = aggregate("pw", p, r, jnp.float32(0.5), jnp.float32(1.0))
    assert_leaves_close(a, np_mix(p, np.full(K, 1 / K), 0.5))


@pytest.mark.parametrize("beta", [0.5, 1.0, 1.5])
@pytest.mark.parametrize("tau", [0.5, 1.0])
def test_real_weighting_signed_normalised_with_negative_rewards(beta, tau):
    p = random_params(5)
    r = np.asarray(R, np.float64)  # two of four rewards are negative
    w = np.sign(r) * np.abs(r) ** beta / (np.abs(r) ** beta).sum()
    assert (w < 0).any()  # negative rewards push the aggregate away from those clients
    np.testing.assert_allclose(np.asarray(agg.real_weights(R, jnp.float32(beta))), w, rtol=1e-5)
    out, _ = aggregate("rw", p, R, jnp.float32(tau), jnp.float32(beta))
    assert_leaves_close(out, np_mix(p, w, tau), rtol=1e-5, atol=1e-5)


def test_real_weighting_all_negative_rewards():
    p = random_params(6)
    r = jnp.array([-1.0, -2.0, -0.5, -4.0])
    w = -(np.abs(np.asarray(r, np.float64)) ** 0.5) / (np.abs(np.asarray(r, np.float64)) ** 0.5).sum()
    out, _ = aggregate("rw", p, r, jnp.float32(1.0), jnp.float32(0.5))
    assert_leaves_close(out, np_mix(p, w, 1.0), rtol=1e-5, atol=1e-5)  # theta_w = -(convex mean)


def test_real_weighting_all_zero_rewards_falls_back_to_the_mean():
    p = random_params(7)
    r = jnp.zeros(K)
    w = np.asarray(agg.real_weights(r, jnp.float32(0.5)))
    assert np.all(np.isfinite(w))
    np.testing.assert_allclose(w, np.full(K, 1 / K))
    out, _ = aggregate("rw", p, r, jnp.float32(0.5), jnp.float32(0.5))
    assert_leaves_close(out, np_mix(p, np.full(K, 1 / K), 0.5))
    # and under jit with a zero somewhere (sign(0) = 0 weight, no nan from 0 ** beta)
    r1 = jnp.array([0.0, 1.0, 0.0, 3.0])
    out = jax.jit(agg.real_weights)(r1, jnp.float32(0.5))
    ref = np.array([0, 1, 0, np.sqrt(3)]) / (1 + np.sqrt(3))
    np.testing.assert_allclose(np.asarray(out), ref, rtol=1e-6)


# ----------------------------------------------------------------------------- global soft


def test_init_global_is_the_mean_of_the_initial_params():
    p = random_params(8)
    g = agg.global_soft(jnp.float32(0.5)).init(p).theta_w
    assert jax.tree.structure(g) == jax.tree.structure(p)
    for a, b in zip(jax.tree.leaves(g), np_leaves(p)):
        np.testing.assert_allclose(np.asarray(a), b.mean(0), rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("beta", [0.0, 0.5, 1.0])
def test_global_soft_first_and_second_step_against_numpy(beta):
    p0 = random_params(9)  # the initial params
    p1 = random_params(10)  # after some local training
    p2 = random_params(11)
    prev = agg.global_soft(jnp.float32(0.5)).init(p0)  # Decision: theta_w_prev starts as the mean of the initial params
    out1, tw1 = aggregate("gs", p1, R, jnp.float32(0.5), jnp.float32(beta), prev)
    ref1 = [(1 - beta) * a.mean(0) + beta * b.mean(0) for a, b in zip(np_leaves(p0), np_leaves(p1))]
    assert_leaves_close(tw1, ref1)
    assert_leaves_close(out1, [np.broadcast_to(r[None], (K, *r.shape)) for r in ref1])  # theta_k <- theta_w
    out2, tw2 = aggregate("gs", p2, R, jnp.float32(0.5), jnp.float32(beta), tw1)
    ref2 = [(1 - beta) * r1 + beta * c.mean(0) for r1, c in zip(ref1, np_leaves(p2))]
    assert_leaves_close(tw2, ref2)
    assert_leaves_close(out2, [np.broadcast_to(r[None], (K, *r.shape)) for r in ref2])


def test_global_soft_ignores_tau_and_rewards():
    p, prev = random_params(12), agg.global_soft(jnp.float32(0.5)).init(random_params(13))
    a, ta = aggregate("gs", p, R, jnp.float32(0.0), jnp.float32(0.5), prev)
    b, tb = aggregate("gs", p, -R, jnp.float32(1.0), jnp.float32(0.5), prev)
    for x, y in zip(jax.tree.leaves((a, ta)), jax.tree.leaves((b, tb))):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


# ----------------------------------------------------------------------------- dispatch


def test_aggregate_none_and_unknown():
    p = random_params(14)
    out, st = aggregate("none", p, R, jnp.float32(1.0), jnp.float32(1.0))
    assert out is p and st == agg.EmptyState()
    with pytest.raises(ValueError, match="unknown aggregator 'nonsense'"):
        agg.make("nonsense")
    with pytest.raises(TypeError, match="takes"):  # a rule's hyperparameters are exactly its own
        agg.make("soft", tau=0.5, beta=1.0)


@pytest.mark.parametrize("kind", ["soft", "pw", "rw", "gs"])
def test_absent_clients_keep_their_params_and_do_not_count(kind):
    """A client outside the participation mask neither sends nor receives."""
    p = random_params(16)
    mask = jnp.array([True, False, True, True])
    rule = agg.RULES[kind]
    state = rule.make(**{h: 0.5 for h in rule.hparams}).init(random_params(17))  # GS: a global model from elsewhere
    out, _ = aggregate(kind, p, R, jnp.float32(0.5), jnp.float32(0.5), state, mask)
    for g, x in zip(jax.tree.leaves(out), jax.tree.leaves(p)):
        np.testing.assert_array_equal(np.asarray(g)[1], np.asarray(x)[1])
    # the absent client's parameters do not enter the aggregate: moving them changes nothing
    moved = jax.tree.map(lambda x: x.at[1].add(1e3), p)
    out2, _ = aggregate(kind, moved, R, jnp.float32(0.5), jnp.float32(0.5), state, mask)
    for a, b in zip(jax.tree.leaves(out), jax.tree.leaves(out2)):
        np.testing.assert_allclose(np.asarray(a)[[0, 2, 3]], np.asarray(b)[[0, 2, 3]], rtol=1e-6, atol=1e-6)


def test_aggregators_jit_with_traced_hyperparameters():
    p = random_params(15)
    traces = []

    @jax.jit
    def f(params, r, tau, beta):
        traces.append(1)
        return aggregate("rw", params, r, tau, beta)[0]

    for tau, beta in [(0.2, 0.5), (0.7, 1.5)]:
        r = np.asarray(R, np.float64)
        w = np.sign(r) * np.abs(r) ** beta / (np.abs(r) ** beta).sum()
        assert_leaves_close(f(p, R, jnp.float32(tau), jnp.float32(beta)), np_mix(p, w, tau), rtol=1e-5, atol=1e-5)
    assert len(traces) == 1


def test_methods_table_is_the_one_source_of_names():
    """The config's method choices and the aggregators the methods name come from the tables
    (what each method does is tested on the trainer it builds: tests/test_trainer.py)."""
    from fedjax_nav.config import METHODS

    assert METHODS == tuple(methods.METHODS)
    for m in methods.METHODS.values():
        assert m.aggregator in agg.RULES, m.name
        assert m.sends_rewards == (m.aggregator in ("pw", "rw")), m.name  # Table 3: PW/RW send r_k
    assert methods.get("FLDDPG") is methods.METHODS["flddpg"]
    with pytest.raises(ValueError, match="unknown method"):
        methods.get("ppo")


# ----------------------------------------------------------------------------- Table 3

THESIS = dict(episodes=125, steps=1024, train_every=5, batch=512)


@pytest.mark.parametrize(
    "name, n_data, n_nn, n_comm",
    [
        ("iddpg", 0, 0, 0),
        ("seddpg", 1024 + 205 * 512, 0, 13_248_000),
        ("snddpg", 1024, 205, 153_625),
        ("flddpg", 0, 0.5, 62.5),
        ("gsddpg", 0, 0.5, 62.5),
        ("flsddpg", 0, 0.5, 62.5),
        ("pwddpg", 0, 1.0, 125),
        ("rwddpg", 0, 1.0, 125),
    ],
)
def test_table3_exactly(name, n_data, n_nn, n_comm):
    c = communication(methods.get(name), period_unit="episodes", period=2, **THESIS)
    assert c["n_data_per_episode"] == n_data
    assert c["n_nn_per_episode"] == n_nn
    assert c["n_comm"] == n_comm  # exact (the thesis prints 63 and 126, rounded up)


def test_communication_with_a_step_period():
    """T_update = 64 steps: T / T_update = 16 rounds per episode (twice that for PW/RW)."""
    fl = communication(methods.get("flddpg"), period_unit="steps", period=64, **THESIS)
    assert fl["n_nn_per_episode"] == 16 and fl["n_comm"] == 16 * 125
    pw = communication(methods.get("pwddpg"), period_unit="steps", period=64, **THESIS)
    assert pw["n_nn_per_episode"] == 32 and pw["n_comm"] == 32 * 125
    # the period does not change the methods without a federated step
    se = communication(methods.get("seddpg"), period_unit="steps", period=64, **THESIS)
    assert se["n_comm"] == 13_248_000


def test_soft_fedavg_and_the_robust_mean_are_one_weighted_sum():
    """The method's soft rule and `fed.aggregator=mean` compute theta_w with the same sum, so
    they agree to the bit (with 40 clients a dot product and a multiply-and-reduce differed in
    the last bit on this CPU, and may differ more on a GPU in TF32)."""
    p = random_params(21, k=40)
    r = jnp.zeros(40)
    tau = jnp.float32(0.5)
    soft = jax.jit(lambda p: agg.make("soft", tau=tau).update(p, r, agg.EmptyState())[0])(p)
    mean_rule = agg.make("mean", tau=tau)
    mean = jax.jit(lambda p: mean_rule.update(p, r, mean_rule.init(p))[0])(p)
    for a, b in zip(jax.tree.leaves(soft), jax.tree.leaves(mean)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
