"""PPO against independent references: GAE against a float64 numpy sum over the episode (time-outs
bootstrap, terminations do not), the clipped objective and the value loss on hand-computed cases,
the minibatch check; then PPO on probe problems with known answers, one compiled program for the
feed-forward ones (each probe is data) and one for the recurrent one:

- bandit: one-step episodes (terminated), context c in {0, 1} in the observation, reward
  -|a - best(c)|^2: the greedy action approaches best(c);
- time-out: reward 1 every step, never terminated, truncated every 3 steps, the observation does
  not show the time: V = 1 / (1 - gamma) (treating time-outs as terminations would give ~1.42);
- memory (GRU): a cue +-1 shown at an episode's first step only, reward at the second
  -(a0 - 0.5)^2 - (a1 - 0.6 cue)^2: only a policy that remembers the cue reaches (0.5, 0.6 cue).
  Rollouts of 5 steps cut 2-step episodes, so the hidden state carried between rollouts is used.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fedjax_nav.agents import ppo
from fedjax_nav.config.traced import HParams

# ----------------------------------------------------------------------------- GAE


def np_gae(r, v, nv, term, trunc, gamma, lam):
    """float64, per environment: A_t = sum_l (gamma lambda)^l delta_{t+l} over the rest of the
    episode within the rollout; delta_t = r_t + gamma (1 - term_t) V(s'_t) - V(s_t)."""
    r, v, nv, term, trunc = (np.asarray(x, np.float64) for x in (r, v, nv, term, trunc))
    delta = r + gamma * (1.0 - term) * nv - v
    adv = np.zeros_like(r)
    for t in range(len(r)):
        for lag in range(len(r) - t):
            adv[t] += (gamma * lam) ** lag * delta[t + lag]
            if term[t + lag] or trunc[t + lag]:
                break
    return adv


def test_gae_matches_the_numpy_sum_with_terminations_and_time_outs():
    rng = np.random.default_rng(0)
    steps, envs = 12, 5
    r, v, nv = (rng.normal(size=(steps, envs)).astype(np.float32) for _ in range(3))
    term = rng.uniform(size=(steps, envs)) < 0.15
    trunc = (rng.uniform(size=(steps, envs)) < 0.15) & ~term
    gamma, lam = 0.9, 0.8
    adv, ret = jax.jit(ppo.gae)(r, v, nv, term, term | trunc, jnp.float32(gamma), jnp.float32(lam))
    ref = np.stack([np_gae(r[:, e], v[:, e], nv[:, e], term[:, e], trunc[:, e], gamma, lam) for e in range(envs)], 1)
    np.testing.assert_allclose(np.asarray(adv), ref, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(ret), ref + v, rtol=1e-5, atol=1e-5)
    assert term.any() and trunc.any()


def test_gae_time_out_bootstraps_and_termination_does_not_by_hand():
    # steps: 0 plain, 1 truncated, 2 terminated, 3 the rollout's last (bootstraps from nv[3])
    r = jnp.array([1.0, 2.0, 3.0, 4.0])
    v = jnp.array([0.5, 0.5, 0.5, 0.5])
    nv = jnp.array([10.0, 20.0, 30.0, 40.0])
    term = jnp.array([0.0, 0.0, 1.0, 0.0])
    end = jnp.array([0.0, 1.0, 1.0, 0.0])
    adv, _ = ppo.gae(r, v, nv, term, end, 0.5, 1.0)
    a3 = 4.0 + 0.5 * 40.0 - 0.5  # 23.5
    a2 = 3.0 - 0.5  # terminated: no V(s'), and the recursion stops: 2.5
    a1 = 2.0 + 0.5 * 20.0 - 0.5  # truncated: V(s') of the true last observation: 11.5
    a0 = (1.0 + 0.5 * 10.0 - 0.5) + 0.5 * a1  # 5.5 + 5.75
    np.testing.assert_allclose(np.asarray(adv), [a0, a1, a2, a3], rtol=1e-6)


# ----------------------------------------------------------------------------- losses


def test_clipped_surrogate_by_hand_and_no_gradient_where_clipped():
    old = jnp.zeros(3)
    logp = jnp.log(jnp.array([1.5, 0.5, 1.1]))
    adv = jnp.array([1.0, -1.0, 2.0])
    # min(1.5, 1.2) = 1.2; min(-0.5, -0.8) = -0.8; min(2.2, 2.2) = 2.2
    loss, frac = ppo.clipped_surrogate(logp, old, adv, 0.2)
    assert float(loss) == pytest.approx(-(1.2 - 0.8 + 2.2) / 3, rel=1e-6)
    assert float(frac) == pytest.approx(2 / 3)
    g = np.asarray(jax.grad(lambda lp: ppo.clipped_surrogate(lp, old, adv, 0.2)[0])(logp))
    np.testing.assert_allclose(g, [0.0, 0.0, -1.1 * 2.0 / 3], rtol=1e-5, atol=1e-7)


def test_value_loss_by_hand_clipped_and_not():
    v, v_old, ret = jnp.array([1.0, 3.0]), jnp.array([2.0, 2.0]), jnp.array([0.0, 0.0])
    # unclipped (V - R)^2 = [1, 9]; V clipped to V_old +- 0.5 = [1.5, 2.5] -> [2.25, 6.25]; max [2.25, 9]
    assert float(ppo.value_loss(v, v_old, ret, 0.5)) == pytest.approx(0.5 * (2.25 + 9.0) / 2)
    assert float(ppo.value_loss(v, v_old, ret, jnp.inf)) == pytest.approx(0.5 * (1.0 + 9.0) / 2)
    # 0 is "off", as the config's ppo.value_clip default says (the one convention): inf's number
    assert float(ppo.value_loss(v, v_old, ret, 0.0)) == float(ppo.value_loss(v, v_old, ret, jnp.inf))
    adv = ppo.normalize_advantages(jnp.array([1.0, 2.0, 6.0]))
    assert abs(float(adv.mean())) < 1e-6 and float(adv.std()) == pytest.approx(1.0, rel=1e-6)


@pytest.mark.parametrize("recurrent, envs", [(False, 5), (True, 6)])
def test_minibatches_that_do_not_divide_the_batch_are_an_error_naming_the_field(recurrent, envs):
    # feed-forward: 3 steps x 5 envs = 15 rows, 4 minibatches; recurrent: 6 environments, 4 minibatches
    nets = ppo.make_nets(8, 1, recurrent=recurrent, gru=4, epochs=1, minibatches=4)
    z = lambda *s: jnp.zeros((3, envs, *s))
    hidden = jax.tree.map(lambda h: jnp.zeros((envs, *h.shape)), ppo.initial_hidden(nets))
    ro = ppo.Rollout(z(3), z(2), z(), z(), z(3), z(), z(), z().astype(bool), hidden)
    upd = lambda k, r: ppo.update(nets, ppo.init(nets, k, 3), r, k, HParams())
    with pytest.raises(ValueError, match="ppo.minibatches"):
        jax.eval_shape(upd, jax.random.key(0), ro)
    # a count that divides is accepted: 3 for the 15 rows, 6 for the 6 environments
    ok = ppo.make_nets(8, 1, recurrent=recurrent, gru=4, epochs=1, minibatches=envs if recurrent else 3)
    jax.eval_shape(lambda k, r: ppo.update(ok, ppo.init(ok, k, 3), r, k, HParams()), jax.random.key(0), ro)


@pytest.mark.parametrize(
    "kw, field",
    [
        ({"epochs": 0}, "ppo.epochs"),
        ({"minibatches": 0}, "ppo.minibatches"),
        ({"recurrent": True, "gru": 0}, "ppo.gru"),
    ],
)
def test_static_sizes_below_one_are_errors_naming_the_field(kw, field):
    with pytest.raises(ValueError, match=field):
        ppo.make_nets(**kw)


# ----------------------------------------------------------------------------- probes


def bandit_best(c):
    return jnp.where(c[..., None] > 0.5, jnp.array([0.7, 0.4]), jnp.array([0.3, -0.5]))


def probe_env(p):
    """The feed-forward probes as one env whose behaviour is data p: episode length L, terminal (1:
    episodes end terminated, 0: truncated), bandit and constant reward weights. State (t, c)."""

    def obs(c):
        return jnp.array([c, 1.0 - c, 1.0])

    def reset(key):
        c = jax.random.bernoulli(key).astype(jnp.float32)
        return (jnp.int32(0), c), obs(c)

    def step(key, s, a):
        t, c = s
        r = p["bandit"] * -jnp.sum((a - bandit_best(c)) ** 2) + p["const"]
        last = t + 1 >= p["L"]
        return (t + 1, c), obs(c), r, last & (p["terminal"] > 0), last & (p["terminal"] == 0)

    return reset, step


def memory_env(p):
    """State (phase, cue): phase 0 shows the cue, phase 1 is rewarded and terminated."""
    del p

    def reset(key):
        cue = jnp.where(jax.random.bernoulli(key), 1.0, -1.0)
        return (jnp.int32(0), cue), jnp.array([cue, 1.0, 0.0])

    def step(key, s, a):
        phase, cue = s
        blank = jnp.array([0.0, 0.0, 1.0])
        r = jnp.where(phase == 1, -((a[0] - 0.5) ** 2) - (a[1] - 0.6 * cue) ** 2, 0.0)
        return (phase + 1, cue), blank, r, phase == 1, jnp.bool_(False)

    return reset, step


def make_train(nets, make_env, steps, envs, updates):
    """jit(train)(key, p, hp) -> (state, losses per update, |log pi recomputed - log pi stored|
    per update): `updates` iterations of (rollout of `steps` x `envs`, ppo.update). Counts traces."""
    traces = []
    where = lambda m, a, b: jax.tree.map(
        lambda x, y: jnp.where(jnp.reshape(m, m.shape + (1,) * (x.ndim - 1)), x, y), a, b
    )

    @jax.jit
    def train(key, p, hp):
        traces.append(1)
        reset, step = make_env(p)
        k_init, k_env, k_run = jax.random.split(key, 3)
        state = ppo.init(nets, k_init, 3)
        es, obs = jax.vmap(reset)(jax.random.split(k_env, envs))
        hidden = jax.tree.map(lambda h: jnp.zeros((envs, *h.shape)), ppo.initial_hidden(nets))
        carry = (es, obs, jnp.ones((envs,), bool), hidden)

        def env_step(state, carry, k):
            es, obs, first, hidden = carry
            k_act, k_step, k_reset = jax.random.split(k, 3)
            act = jax.vmap(lambda o, kk, h, f: ppo.act(nets, state, o, kk, h, f))
            out, hidden = act(obs, jax.random.split(k_act, envs), hidden, first)
            es2, next_obs, r, term, trunc = jax.vmap(step)(jax.random.split(k_step, envs), es, out.action)
            end = term | trunc
            es_new, obs_new = jax.vmap(reset)(jax.random.split(k_reset, envs))
            row = (obs, out.raw_action, out.log_prob, r, next_obs, term, trunc, first)
            return (where(end, es_new, es2), where(end, obs_new, next_obs), end, hidden), row

        def iteration(c, k):
            state, carry = c
            k_roll, k_upd = jax.random.split(k)
            h0 = carry[3]
            carry, rows = jax.lax.scan(lambda cc, kk: env_step(state, cc, kk), carry, jax.random.split(k_roll, steps))
            rollout = ppo.Rollout(*rows, hidden=h0)
            err = jnp.max(jnp.abs(ppo.evaluate(nets, state, rollout)[0] - rollout.log_prob))
            state, losses = ppo.update(nets, state, rollout, k_upd, hp)
            return (state, carry), (losses, err)

        (state, _), (losses, err) = jax.lax.scan(iteration, (state, carry), jax.random.split(k_run, updates))
        return state, losses, err

    return train, traces


BANDIT = {"L": 1, "terminal": 1, "bandit": 1.0, "const": 0.0}
TIMEOUT = {"L": 3, "terminal": 0, "bandit": 0.0, "const": 1.0}
FF_HP = HParams().replace_flat({"ppo.lr": 3e-3, "ppo.gamma": 0.5, "ppo.gae_lambda": 0.95})


@pytest.fixture(scope="module")
def ff():
    nets = ppo.make_nets(32, 2, "tanh", epochs=4, minibatches=4)
    train, traces = make_train(nets, probe_env, steps=8, envs=16, updates=150)
    return nets, train, traces


def _p(d):
    return {k: jnp.asarray(v) for k, v in d.items()}


def test_ppo_bandit_probe_finds_the_best_action_per_context(ff):
    nets, train, _ = ff
    state, losses, err = train(jax.random.key(0), _p(BANDIT), FF_HP)
    assert float(jnp.max(err)) < 1e-5  # the stored log-densities are the update's pi_old
    hidden = ppo.initial_hidden(nets)
    for c in (0.0, 1.0):
        a, _ = ppo.greedy(nets, state, jnp.array([c, 1.0 - c, 1.0]), hidden, jnp.bool_(True))
        np.testing.assert_allclose(np.asarray(a), np.asarray(bandit_best(jnp.float32(c))), atol=0.03)
    assert np.all(np.isfinite(np.asarray(losses["loss"])))


def test_ppo_time_out_probe_bootstraps_the_value(ff):
    nets, train, _ = ff
    state, _, _ = train(jax.random.key(1), _p(TIMEOUT), FF_HP)
    for c in (0.0, 1.0):
        v = float(nets.value.apply(state.value, jnp.array([c, 1.0 - c, 1.0])))
        assert abs(v - 1.0 / (1.0 - 0.5)) < 0.1, v


def test_ppo_update_compiles_once_for_every_traced_hyperparameter(ff):
    nets, train, traces = ff
    n = len(traces)
    hp = HParams().replace_flat(
        {
            "ppo.lr": 1e-4,
            "ppo.gamma": 0.9,
            "ppo.gae_lambda": 0.5,
            "ppo.clip_eps": 0.1,
            "ppo.value_clip": 0.2,
            "ppo.vf_coef": 1.0,
            "ppo.ent_coef": 0.01,
            "ppo.max_grad_norm": 1.0,
        }
    )
    train(jax.random.key(2), _p(BANDIT), hp)
    train(jax.random.key(2), _p(TIMEOUT), HParams())
    assert len(traces) == max(n, 1)
    # init's traced initial log-std
    init_traces = []
    init = jax.jit(lambda k, s: (init_traces.append(1), ppo.init(nets, k, 3, s))[1])
    for s in (0.0, -1.5):
        np.testing.assert_array_equal(np.asarray(init(jax.random.key(0), jnp.float32(s)).log_std), [s, s])
    assert len(init_traces) == 1


@pytest.fixture(scope="module")
def rnn():
    nets = ppo.make_nets(32, 1, "tanh", recurrent=True, gru=16, epochs=4, minibatches=4)
    train, _ = make_train(nets, memory_env, steps=5, envs=16, updates=200)
    return nets, train


def test_gru_reset_starts_from_zeros(rnn):
    nets, _ = rnn
    state = jax.jit(lambda k: ppo.init(nets, k, 3))(jax.random.key(0))
    step = jax.jit(lambda h, r: ppo.act(nets, state, jnp.array([1.0, 1.0, 0.0]), jax.random.key(1), h, r))
    noise = jax.tree.map(lambda h: jnp.full_like(h, 0.7), ppo.initial_hidden(nets))
    fresh, h_fresh = step(ppo.initial_hidden(nets), jnp.bool_(False))
    reset, h_reset = step(noise, jnp.bool_(True))
    carried, _ = step(noise, jnp.bool_(False))
    np.testing.assert_array_equal(np.asarray(reset.action), np.asarray(fresh.action))
    np.testing.assert_array_equal(np.asarray(h_reset.actor), np.asarray(h_fresh.actor))
    assert not np.allclose(np.asarray(carried.action), np.asarray(fresh.action))


def test_recurrent_ppo_memory_probe_remembers_the_cue(rnn):
    nets, train = rnn
    state, losses, err = train(jax.random.key(0), {}, HParams().replace_flat({"ppo.lr": 3e-3, "ppo.gamma": 0.9}))
    # the update's sequences (from the rollout's start hidden state, resets) reproduce acting
    assert float(jnp.max(err)) < 1e-4
    for cue in (-1.0, 1.0):
        h = ppo.initial_hidden(nets)
        _, h = ppo.greedy(nets, state, jnp.array([cue, 1.0, 0.0]), h, jnp.bool_(True))
        a, _ = ppo.greedy(nets, state, jnp.array([0.0, 0.0, 1.0]), h, jnp.bool_(False))
        np.testing.assert_allclose(np.asarray(a), [0.5, 0.6 * cue], atol=0.05)  # memoryless best: a1 = 0


@pytest.mark.parametrize("shape", [(64, 64), (64, 2), (28, 64)])
def test_the_orthogonal_init_is_jaxs_without_a_lapack_call(shape):
    """The GRU's recurrent kernels and the policy head start orthogonal as flax's defaults do (the same
    draw: the same matrix up to rounding), but the vmapped init lowers to no LAPACK QR, which hung
    under load when several threads called scipy's OpenBLAS at once (docs/learners.md)."""
    from fedjax_nav.agents.networks_extra import orthogonal

    key = jax.random.key(3)
    np.testing.assert_allclose(orthogonal(0.5)(key, shape), jax.nn.initializers.orthogonal(0.5)(key, shape), atol=1e-6)
    q = np.asarray(orthogonal()(key, shape), np.float64)
    small = q if shape[0] >= shape[1] else q.T
    np.testing.assert_allclose(small.T @ small, np.eye(min(shape)), atol=1e-5)
    keys = jax.random.split(key, 4)
    hlo = jax.jit(jax.vmap(lambda k: orthogonal()(k, shape))).lower(keys).as_text().lower()
    assert "lapack" not in hlo and "geqrf" not in hlo
