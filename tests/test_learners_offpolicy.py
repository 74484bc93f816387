"""The off-policy learners (TD3, SAC) and their pieces against hand-computed and float64 references:
the squashed Gaussian (change of variables, mass 1 on the box, samples inside it), the running
normaliser, the n-step rows, TD3's smoothed twin target on networks whose outputs are known, SAC's
temperature loss and its sign; then each learner on a probe problem with a known answer and a
trace count over its traced hyperparameters.

Probe (DDPG's, tests/test_ddpg.py): one state (obs = ones), reward -(a0 - 0.3)^2 - (a1 + 0.5)^2 for
actions in the box [0, 1] x [-1, 1], every transition terminal: Q(s, a) = r(a), best action
(0.3, -0.5).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fedjax_nav.agents import buffer as rb
from fedjax_nav.agents import distributions as dist
from fedjax_nav.agents import normalize, offpolicy, sac, td3
from fedjax_nav.config.traced import HParams

LOW, HIGH = np.array([0.0, -1.0]), np.array([1.0, 1.0])
BEST = np.array([0.3, -0.5], np.float32)
OBS, ROWS, BATCH = 3, 512, 128

# ----------------------------------------------------------------------------- squashed Gaussian


def np_log_prob(mean, log_std, action):
    """float64 change of variables: a = loc + scale tanh(u), p_A(a) = p_U(u) / |da/du|."""
    mean, log_std, action = (np.asarray(x, np.float64) for x in (mean, log_std, action))
    loc, scale = (HIGH + LOW) / 2, (HIGH - LOW) / 2
    y = (action - loc) / scale
    u = np.arctanh(y)
    std = np.exp(log_std)
    log_pu = -0.5 * ((u - mean) / std) ** 2 - np.log(std) - 0.5 * np.log(2 * np.pi)
    log_dadu = np.log(scale * (1.0 - y**2))
    return np.sum(log_pu - log_dadu, axis=-1)


def test_log_prob_is_the_change_of_variables_in_float64():
    rng = np.random.default_rng(0)
    mean = rng.normal(0, 0.8, (500, 2)).astype(np.float32)
    log_std = rng.uniform(-1.5, 0.5, (500, 2)).astype(np.float32)
    u = (mean + np.exp(log_std) * rng.normal(size=(500, 2))).astype(np.float32)
    u = np.clip(u, -3.0, 3.0)  # where float64 arctanh(tanh(u)) still recovers u exactly enough
    action = np.asarray(jax.jit(dist.squash)(u))
    ref = np_log_prob(mean, log_std, np.tanh(u.astype(np.float64)) * (HIGH - LOW) / 2 + (HIGH + LOW) / 2)
    np.testing.assert_allclose(np.asarray(jax.jit(dist.log_prob_raw)(mean, log_std, u)), ref, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(np.asarray(jax.jit(dist.log_prob)(mean, log_std, action)), ref, rtol=2e-3, atol=2e-3)


def test_density_has_mass_one_on_the_box_and_its_entropy_estimate_is_unbiased():
    mean, log_std = jnp.array([0.4, -0.3]), jnp.array([-0.5, -0.2])
    n = 800
    edges0, edges1 = np.linspace(LOW[0], HIGH[0], n + 1), np.linspace(LOW[1], HIGH[1], n + 1)
    mid0, mid1 = (edges0[1:] + edges0[:-1]) / 2, (edges1[1:] + edges1[:-1]) / 2
    grid = np.stack(np.meshgrid(mid0, mid1, indexing="ij"), -1).reshape(-1, 2)
    cell = (edges0[1] - edges0[0]) * (edges1[1] - edges1[0])
    logp = np.asarray(jax.jit(dist.log_prob)(mean, log_std, jnp.asarray(grid, jnp.float32)), np.float64)
    p = np.exp(logp)
    # Without the affine Jacobian (scale 0.5 x 1) the mass would be 2, without tanh's far off.
    assert abs(np.sum(p) * cell - 1.0) < 2e-3
    np.testing.assert_allclose(logp, np_log_prob(mean, log_std, grid), rtol=1e-3, atol=1e-3)
    h_ref = -np.sum(p * logp) * cell
    keys = jax.random.split(jax.random.key(0), 20000)
    h_est = jax.jit(jax.vmap(dist.entropy, in_axes=(0, None, None)))(keys, mean, log_std)
    assert abs(float(jnp.mean(h_est)) - h_ref) < 0.02, (float(jnp.mean(h_est)), h_ref)


def test_samples_stay_in_the_box_and_mode_is_the_squashed_mean():
    keys = jax.random.split(jax.random.key(1), 4000)
    draw = jax.jit(jax.vmap(dist.sample, in_axes=(0, None, None)))
    # a saturating distribution: tanh(u) rounds to +-1 in float32, log-densities stay finite
    mean, log_std = jnp.array([3.0, -4.0]), jnp.array([1.5, 1.5])
    a, u, logp = draw(keys, mean, log_std)
    a = np.asarray(a)
    assert np.all(a >= LOW) and np.all(a <= HIGH)
    assert np.all(np.isfinite(np.asarray(logp)))
    assert np.any(a[:, 0] == 1.0) and np.any(a[:, 1] == -1.0)  # saturation was reached
    np.testing.assert_allclose(np.asarray(logp), np.asarray(dist.log_prob_raw(mean, log_std, u)), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(dist.mode(jnp.array([0.0, 0.0]))), [0.5, 0.0])
    np.testing.assert_allclose(np.asarray(dist.mode(mean)), [0.5 + 0.5 * np.tanh(3.0), np.tanh(-4.0)], rtol=1e-6)
    # a draw's mean and spread follow (mean, std) before the squash
    _, u, _ = draw(keys, jnp.array([0.2, -0.1]), jnp.array([-1.0, -2.0]))
    np.testing.assert_allclose(np.asarray(u).mean(0), [0.2, -0.1], atol=0.02)
    np.testing.assert_allclose(np.asarray(u).std(0), np.exp([-1.0, -2.0]), rtol=0.05)


# ----------------------------------------------------------------------------- normaliser


def test_running_stats_match_numpy_over_batches_masks_and_clients():
    rng = np.random.default_rng(3)
    upd, norm, var = jax.jit(normalize.update), jax.jit(normalize.normalize), jax.jit(normalize.variance)
    clients, seen = [], []
    for _ in range(3):
        stats, rows = normalize.init(5), []
        for size in (1, 40, 40):
            x = rng.normal(loc=[0, 10, -3, 100, 0.5], scale=[1, 0.1, 5, 20, 0], size=(size, 5)).astype(np.float32)
            mask = rng.uniform(size=size) < 0.7 if size > 1 else np.ones(1, bool)
            stats = upd(stats, jnp.asarray(x), jnp.asarray(mask))
            rows.append(x[mask].astype(np.float64))
        data = np.concatenate(rows)
        assert float(stats.count) == len(data)
        np.testing.assert_allclose(np.asarray(stats.mean), data.mean(0), rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(np.asarray(var(stats)), data.var(0), rtol=1e-4, atol=1e-6)
        z = np.asarray(norm(stats, jnp.asarray(data, jnp.float32)))
        z_ref = np.clip((data - data.mean(0)) / np.sqrt(data.var(0) + 1e-8), -10, 10)
        np.testing.assert_allclose(z, z_ref, rtol=1e-3, atol=1e-3)
        clients.append(stats)
        seen.append(data)
    stacked = jax.tree.map(lambda *x: jnp.stack(x), *clients)
    pool = jax.jit(normalize.pool)
    pooled = pool(stacked)
    everything = np.concatenate(seen)
    np.testing.assert_allclose(float(pooled.count), len(everything))
    np.testing.assert_allclose(np.asarray(pooled.mean), everything.mean(0), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(var(pooled)), everything.var(0), rtol=1e-4, atol=1e-6)
    some = pool(stacked, jnp.array([True, False, True]))
    both = np.concatenate([seen[0], seen[2]])
    np.testing.assert_allclose(np.asarray(some.mean), both.mean(0), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(var(some)), both.var(0), rtol=1e-4, atol=1e-6)


def test_fresh_statistics_normalise_as_the_identity():
    x = jnp.array([[0.3, -2.0, 5.0]])
    np.testing.assert_array_equal(np.asarray(normalize.normalize(normalize.init(3), x)), np.asarray(x))


# ----------------------------------------------------------------------------- n-step rows


def _window(rewards, done):
    n = len(rewards)
    ids = jnp.arange(n, dtype=jnp.float32)
    return rb.Transition(
        obs=jnp.stack([ids] * OBS, -1),
        action=jnp.stack([ids, -ids], -1),
        reward=jnp.asarray(rewards, jnp.float32),
        next_obs=jnp.stack([ids + 0.5] * OBS, -1),
        done=jnp.asarray(done, jnp.float32),
    )


@pytest.mark.parametrize(
    "done, end, reward, discount, last",
    [
        ([0, 0, 0], [0, 0, 0], 1 + 0.5 * 2 + 0.25 * 4, 0.125, 2),  # the whole window, bootstraps
        ([0, 1, 0], [0, 1, 0], 1 + 0.5 * 2, 0.25, 1),  # terminated at 1: done, no bootstrap
        ([0, 0, 0], [1, 0, 1], 1.0, 0.5, 0),  # time-out at 0: bootstraps from next_obs[0]
    ],
)
def test_nstep_rows_by_hand(done, end, reward, discount, last):
    row = jax.jit(offpolicy.nstep)(_window([1.0, 2.0, 4.0], done), jnp.asarray(end), jnp.float32(0.5))
    assert float(row.reward) == pytest.approx(reward)
    assert float(row.discount) == pytest.approx(discount)
    assert float(row.done) == done[last]
    np.testing.assert_array_equal(np.asarray(row.next_obs), [last + 0.5] * OBS)
    np.testing.assert_array_equal(np.asarray(row.obs), [0.0] * OBS)
    one = offpolicy.one_step(_window([1.0, 2.0, 4.0], done), 0.5)
    np.testing.assert_array_equal(np.asarray(one.discount), [0.5] * 3)


# ----------------------------------------------------------------------------- TD3 target


HID, DEPTH = 8, 2


def affine_critic(c, b):
    """Critic params with Q(s, a) = c . a + b on the box (relu kept in its linear part)."""
    p = {}
    k0 = np.zeros((OBS + 2, HID), np.float32)
    k0[OBS, 0] = k0[OBS + 1, 1] = 1.0
    b0 = np.zeros(HID, np.float32)
    b0[:2] = 10.0
    p["Dense_0"] = {"kernel": k0, "bias": b0}
    for i in range(1, DEPTH):
        p[f"Dense_{i}"] = {"kernel": np.eye(HID, dtype=np.float32), "bias": np.zeros(HID, np.float32)}
    kl = np.zeros((HID, 1), np.float32)
    kl[:2, 0] = c
    p[f"Dense_{DEPTH}"] = {"kernel": kl, "bias": np.array([b - 10.0 * (c[0] + c[1])], np.float32)}
    return {"params": p}


def constant_actor(v, w):
    """Actor params whose output is (v, w) for every observation."""
    p = {
        f"Dense_{i}": {"kernel": np.zeros((OBS if i == 0 else HID, HID), np.float32), "bias": np.zeros(HID, np.float32)}
        for i in range(DEPTH)
    }
    p["v_head"] = {"kernel": np.zeros((HID, 1), np.float32), "bias": np.array([np.log(v / (1 - v))], np.float32)}
    p["omega_head"] = {"kernel": np.zeros((HID, 1), np.float32), "bias": np.array([np.arctanh(w)], np.float32)}
    return {"params": p}


@pytest.fixture(scope="module")
def td3_known():
    """A TD3 state whose target networks are known: mu_targ = (0.9, -0.5), Q_targ_1 = a0 + 2 a1 +
    0.5, Q_targ_2 = -a0 + a1 + 2 (the online networks are random, and must not be used); and the
    jitted `td3.target`."""
    nets = td3.make_nets(HID, DEPTH, "relu")
    state = jax.jit(lambda k: td3.init(nets, k, OBS))(jax.random.key(0))
    twins = jax.tree.map(
        lambda a, b: jnp.stack([a, b]), affine_critic((1.0, 2.0), 0.5), affine_critic((-1.0, 1.0), 2.0)
    )
    state = state.replace(actor_targ=jax.tree.map(jnp.asarray, constant_actor(0.9, -0.5)), critics_targ=twins)
    return nets, state, jax.jit(td3.target)


def _batch(n, reward, discount, done):
    ones = jnp.ones((n, OBS))
    full = lambda x: jnp.full((n,), x, jnp.float32)
    return offpolicy.Batch(ones, jnp.zeros((n, 2)), full(reward), ones, full(done), full(discount))


def test_td3_target_is_the_min_of_the_twins_at_the_target_action(td3_known):
    nets, state, target = td3_known
    hp = HParams().replace_flat({"td3.policy_noise": 0.0, "td3.noise_clip": 0.5})
    # Q1 = 0.9 - 1 + 0.5 = 0.4, Q2 = -0.9 - 0.5 + 2 = 0.6: min 0.4
    y = target(nets, state, _batch(256, 1.0, 0.5, 0.0), jax.random.key(1), hp)
    np.testing.assert_allclose(np.asarray(y), 1.0 + 0.5 * 0.4, rtol=1e-5)
    y = target(nets, state, _batch(256, 1.0, 0.5, 1.0), jax.random.key(1), hp)
    np.testing.assert_allclose(np.asarray(y), 1.0, rtol=1e-6)  # terminal: no bootstrap


def test_td3_target_smoothing_noise_is_clipped_then_the_action_to_the_box(td3_known):
    nets, state, target = td3_known
    # huge noise clipped to +-0.3 half-widths: a' = clip(0.9 +- 0.15, 0, 1) x (-0.5 +- 0.3)
    hp = HParams().replace_flat({"td3.policy_noise": 1e4, "td3.noise_clip": 0.3})
    y = np.asarray(target(nets, state, _batch(256, 0.0, 1.0, 0.0), jax.random.key(2), hp))
    # (a0, a1) -> min(Q1, Q2): (1, -0.2) -> min(1.1, 0.8); (1, -0.8) -> min(-0.1, 0.2);
    # (0.75, -0.2) -> min(0.85, 1.05); (0.75, -0.8) -> min(-0.35, 0.45). Without the clip to the
    # box, a0 = 1.05 would give 0.75 and -0.15 instead of the first two.
    expected = np.array([0.8, -0.1, 0.85, -0.35])
    nearest = np.abs(y[:, None] - expected[None]).min(1)
    assert nearest.max() < 1e-5, y[nearest >= 1e-5][:5]
    assert set(np.abs(y[:, None] - expected[None]).argmin(1)) == {0, 1, 2, 3}
    a = td3.target_action(jnp.array([0.9, -0.5]), jnp.array([1e4, -1e4]), 1.0, 0.3)
    np.testing.assert_allclose(np.asarray(a), [1.0, -0.8], rtol=1e-6)


def test_td3_actor_and_targets_move_only_on_actor_steps(td3_known):
    nets, _, _ = td3_known
    state = jax.jit(lambda k: td3.init(nets, k, OBS))(jax.random.key(4))
    state = state.replace(critics_targ=jax.tree.map(lambda x: x + 0.1, state.critics_targ))  # targets != nets
    batch = _batch(16, 1.0, 0.9, 0.0).replace(action=jnp.full((16, 2), 0.3))
    update = jax.jit(td3.update)
    hp = HParams().replace_flat({"td3.tau": 0.25})
    leaves = lambda t: [np.asarray(x, np.float64) for x in jax.tree.leaves(t)]
    held, _ = update(nets, state, batch, jax.random.key(5), hp, jnp.bool_(False))
    for name in ("actor", "actor_targ", "critics_targ", "actor_opt"):
        for x, y in zip(leaves(getattr(held, name)), leaves(getattr(state, name))):
            np.testing.assert_array_equal(x, y)
    assert any(not np.array_equal(x, y) for x, y in zip(leaves(held.critics), leaves(state.critics)))
    moved, info = update(nets, state, batch, jax.random.key(5), hp, jnp.bool_(True))
    assert float(info["actor_step"]) == 1.0
    assert any(not np.array_equal(x, y) for x, y in zip(leaves(moved.actor), leaves(state.actor)))
    # the critic step is the same either way; the targets mix towards the new networks by tau
    for x, y in zip(leaves(moved.critics), leaves(held.critics)):
        np.testing.assert_array_equal(x, y)
    for name, net in (("actor_targ", "actor"), ("critics_targ", "critics")):
        for t, t0, p in zip(leaves(getattr(moved, name)), leaves(getattr(state, name)), leaves(getattr(moved, net))):
            np.testing.assert_allclose(t, 0.75 * t0 + 0.25 * p, rtol=1e-6, atol=1e-7)


# ----------------------------------------------------------------------------- SAC temperature


def test_sac_temperature_loss_and_its_gradient_by_hand():
    log_alpha = jnp.log(jnp.float32(0.5))
    logp = jnp.array([-1.0, -3.0])  # entropy estimate 2
    # -logp - target = [1 + 1, 3 + 1] = [2, 4] for target -1: loss = 0.5 * 3
    loss, grad = jax.value_and_grad(sac.alpha_loss)(log_alpha, logp, -1.0)
    assert float(loss) == pytest.approx(1.5)
    assert float(grad) == pytest.approx(1.5)  # d alpha / d log_alpha = alpha: descent lowers alpha
    # entropy 2 below a target of 5: the gradient is negative, the temperature rises
    loss, grad = jax.value_and_grad(sac.alpha_loss)(log_alpha, logp, 5.0)
    assert float(loss) == pytest.approx(0.5 * (2.0 - 5.0))
    assert float(grad) < 0.0
    # the policy's log-density gets no gradient from the temperature's loss
    assert float(jax.grad(sac.alpha_loss, argnums=1)(log_alpha, logp, -1.0).sum()) == 0.0


# ----------------------------------------------------------------------------- probes


def bandit_buffer(key):
    a = jax.random.uniform(key, (ROWS, 2), minval=jnp.asarray(LOW), maxval=jnp.asarray(HIGH))
    r = -((a[:, 0] - BEST[0]) ** 2) - (a[:, 1] - BEST[1]) ** 2
    obs = jnp.ones((ROWS, OBS))
    rows = rb.Transition(obs, a, r, obs, jnp.ones((ROWS,), jnp.float32))
    return rb.add(rb.init(ROWS, OBS), rows, jnp.int32(0), jnp.int32(ROWS))


def sample(buf, key, gamma):
    return offpolicy.one_step(rb.sample(buf, key, BATCH, jnp.int32(ROWS), jnp.int32(ROWS)), gamma)


@pytest.fixture(scope="module")
def td3_train():
    """jit(train)(key, buf, gamma, hp): 1500 TD3 updates on the probe buffer, the actor every
    second one (the policy delay) after 300 critic-only ones (a warm-up: an actor that follows a
    critic still near its random start runs into the corner of the box, where its sigmoid and tanh
    saturate)."""
    nets = td3.make_nets(64, 2, "tanh")
    traces = []

    @jax.jit
    def train(key, buf, gamma, hp):
        traces.append(1)
        k_init, k_steps = jax.random.split(key)
        state0 = td3.init(nets, k_init, OBS)

        def body(state, x):
            i, k = x
            k_b, k_u = jax.random.split(k)
            actor_step = (i % 2 == 0) & (i >= 300)
            state, info = td3.update(nets, state, sample(buf, k_b, gamma), k_u, hp, actor_step)
            return state, info["critic_loss"]

        steps = jnp.arange(1500)
        state, losses = jax.lax.scan(body, state0, (steps, jax.random.split(k_steps, steps.shape[0])))
        return state0, state, losses

    return nets, train, traces


def test_td3_bandit_probe_finds_the_best_action(td3_train):
    nets, train, _ = td3_train
    buf = bandit_buffer(jax.random.key(1))
    s0, s, losses = train(
        jax.random.key(0), buf, jnp.float32(0.9), HParams().replace_flat({"offpolicy.lr": 3e-3, "td3.tau": 0.05})
    )
    assert np.all(np.isfinite(np.asarray(losses)))
    mu0, mu = (np.asarray(td3.greedy(nets, x.actor, jnp.ones(OBS))) for x in (s0, s))
    assert np.abs(mu0 - BEST).max() > 0.1
    np.testing.assert_allclose(mu, BEST, atol=0.04)
    a = np.asarray(td3.act(nets, s.actor, jnp.ones(OBS), jax.random.key(3), 5.0))  # exploration: in the box
    assert np.all(a >= LOW) and np.all(a <= HIGH)


def test_td3_update_compiles_once_for_every_traced_hyperparameter(td3_train):
    _, train, traces = td3_train
    buf = bandit_buffer(jax.random.key(1))
    hp = HParams().replace_flat({"offpolicy.lr": 3e-4, "td3.tau": 0.01, "td3.policy_noise": 0.1, "td3.noise_clip": 0.2})
    train(jax.random.key(0), buf, jnp.float32(0.5), hp)
    train(jax.random.key(0), buf, jnp.float32(0.99), HParams())
    assert len(traces) == 1


# The optimal soft policy of the probe is pi(a) ~ exp(r(a) / alpha): a Gaussian of variance alpha / 2
# per dimension around the best action; its entropy per dimension, 0.5 log(2 pi e alpha / 2), is the
# target's half (-2) at alpha* = exp(-4) / (pi e).
SAC_TARGET_ENTROPY = -4.0
SAC_ALPHA = float(np.exp(SAC_TARGET_ENTROPY) / (np.pi * np.e))
SAC_HP = HParams().replace_flat(
    {"offpolicy.lr": 3e-3, "sac.alpha_lr": 3e-2, "sac.tau": 0.05, "sac.target_entropy": SAC_TARGET_ENTROPY}
)


@pytest.fixture(scope="module")
def sac_train():
    """jit(train)(key, buf, gamma, init_alpha, hp): 2000 SAC updates on the probe buffer; returns
    the first and last states, the entropy estimates and the temperatures (before each update)."""
    nets = sac.make_nets(64, 2, "tanh")
    traces = []

    @jax.jit
    def train(key, buf, gamma, init_alpha, hp):
        traces.append(1)
        k_init, k_steps = jax.random.split(key)
        state0 = sac.init(nets, k_init, OBS, init_alpha)

        def body(state, k):
            k_b, k_u = jax.random.split(k)
            state, info = sac.update(nets, state, sample(buf, k_b, gamma), k_u, hp)
            return state, (info["entropy"], info["alpha"])

        state, (ent, alpha) = jax.lax.scan(body, state0, jax.random.split(k_steps, 2000))
        return state0, state, ent, alpha

    return nets, train, traces


def test_sac_bandit_probe_finds_the_best_action_and_the_temperature_of_the_target_entropy(sac_train):
    nets, train, _ = sac_train
    buf = bandit_buffer(jax.random.key(1))
    s0, s, ent, alpha = train(jax.random.key(0), buf, jnp.float32(0.9), jnp.float32(0.1), SAC_HP)
    mu0, mu = (np.asarray(sac.greedy(nets, x.actor, jnp.ones(OBS))) for x in (s0, s))
    assert np.abs(mu0 - BEST).max() > 0.1
    np.testing.assert_allclose(mu, BEST, atol=0.04)
    ent, alpha = np.asarray(ent), np.asarray(alpha)
    assert abs(ent[-200:].mean() - SAC_TARGET_ENTROPY) < 0.25, ent[-200:].mean()
    assert abs(alpha[-1] / SAC_ALPHA - 1.0) < 0.25, (alpha[-1], SAC_ALPHA)  # from 0.1 to ~0.0021
    draws = jax.vmap(lambda k: sac.act(nets, s.actor, jnp.ones(OBS), k))(jax.random.split(jax.random.key(5), 500))
    assert np.all(np.asarray(draws) >= LOW) and np.all(np.asarray(draws) <= HIGH)


def test_sac_temperature_moves_towards_the_target_and_compiles_once(sac_train):
    _, train, traces = sac_train
    buf = bandit_buffer(jax.random.key(1))
    # every traced value differs between the calls (gamma, init_alpha and each HParams field)
    _, _, _, up = train(
        jax.random.key(0),
        buf,
        jnp.float32(0.5),
        jnp.float32(0.3),
        HParams().replace_flat(
            {"offpolicy.lr": 1e-4, "sac.alpha_lr": 3e-4, "sac.tau": 0.1, "sac.target_entropy": 10.0}
        ),
    )
    _, _, _, down = train(
        jax.random.key(0),
        buf,
        jnp.float32(0.99),
        jnp.float32(2.0),
        HParams().replace_flat({"sac.target_entropy": -20.0, "offpolicy.lr": 3e-4}),
    )
    assert float(up[1]) > float(up[0]) == pytest.approx(0.3)  # entropy below the target: alpha rises
    assert float(down[1]) < float(down[0]) == pytest.approx(2.0)
    assert len(traces) == 1
