"""DDPG on probe problems whose Q is known analytically (rejax / bsuite style), the target
update and epsilon-greedy against numpy, and the ring buffer.

Probe problems (one state, obs = ones):
- bandit: reward = -(a0 - 0.3)^2 - (a1 + 0.5)^2 for actions in the actor's units
  [0, 1] x [-1, 1], done = 1 always, so Q(s, a) = r(a) and the best action is (0.3, -0.5);
- discounted: reward 1, done 0, gamma 0.5, targets copied every step (rho = 1): Q = 1 / (1 -
  gamma) = 2 for every (s, a).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fedjax_nav.agents import buffer as rb
from fedjax_nav.agents import ddpg

OBS = 3
ROWS = 512
BATCH = 128
STEPS = 3000
BEST = np.array([0.3, -0.5], np.float32)
LOW, HIGH = jnp.array([0.0, -1.0]), jnp.array([1.0, 1.0])


def bandit_reward(a):
    return -((a[..., 0] - BEST[0]) ** 2) - (a[..., 1] - BEST[1]) ** 2


def probe_buffer(key, reward, done):
    """ROWS transitions from the one state with uniform actions from the action box."""
    a = jax.random.uniform(key, (ROWS, 2), minval=LOW, maxval=HIGH)
    obs = jnp.ones((ROWS, OBS))
    rows = rb.Transition(obs, a, reward(a), obs, jnp.full((ROWS,), done, jnp.float32))
    return rb.add(rb.init(ROWS, OBS), rows, jnp.int32(0), jnp.int32(ROWS))


@pytest.fixture(scope="module")
def nets():
    # tanh fits the quadratic smoothly: its argmax is then within ~0.02 of the true one (relu
    # nets of this size fit Q as well on average but put the argmax of the fit up to 0.15 off).
    return ddpg.make_nets(64, 2, "tanh")


@pytest.fixture(scope="module")
def train_probe(nets):
    """jit(train)(key, buf, gamma, lr, rho) -> (initial agent, trained agent, critic losses):
    STEPS calls of `ddpg.update`, each followed by `ddpg.update_targets` (compiled once for both
    probes: gamma, lr and rho are traced)."""

    @jax.jit
    def train(key, buf, gamma, lr, rho):
        k_init, k_steps = jax.random.split(key)
        agent0 = ddpg.init_agent(nets, k_init, OBS)

        def body(agent, k):
            batch = rb.sample(buf, k, BATCH, jnp.int32(ROWS), jnp.int32(ROWS))
            agent, info = ddpg.update(nets, agent, batch, gamma, lr)
            return ddpg.update_targets(agent, rho), info["critic_loss"]

        agent, losses = jax.lax.scan(body, agent0, jax.random.split(k_steps, STEPS))
        return agent0, agent, losses

    return train


def test_bandit_probe_critic_fits_reward_and_actor_finds_the_best_action(nets, train_probe):
    buf = probe_buffer(jax.random.key(1), bandit_reward, 1.0)
    agent0, agent, losses = train_probe(jax.random.key(0), buf, jnp.float32(0.9), jnp.float32(1e-3), jnp.float32(1.0))
    assert np.all(np.isfinite(np.asarray(losses)))

    # Fresh actions (not the buffer's): Q(s, a) = r(a) since every transition is terminal
    # (gamma = 0.9 must not leak in).
    a = jax.random.uniform(jax.random.key(2), (256, 2), minval=LOW, maxval=HIGH)
    obs = jnp.ones((256, OBS))
    err = np.abs(np.asarray(nets.critic.apply(agent.critic, obs, a)) - np.asarray(bandit_reward(a)))
    assert err.mean() < 0.015, err.mean()
    assert err.max() < 0.06, err.max()

    mu0 = np.asarray(nets.actor.apply(agent0.actor, jnp.ones(OBS)))
    mu = np.asarray(nets.actor.apply(agent.actor, jnp.ones(OBS)))
    assert np.abs(mu0 - BEST).max() > 0.1  # the untrained actor is not there by luck
    np.testing.assert_allclose(mu, BEST, atol=0.05)
    assert float(bandit_reward(mu)) > -0.005  # near-optimal in reward, the quantity maximised


def test_discounted_probe_q_is_one_over_one_minus_gamma(nets, train_probe):
    buf = probe_buffer(jax.random.key(3), lambda a: jnp.ones(a.shape[0]), 0.0)
    _, agent, _ = train_probe(jax.random.key(0), buf, jnp.float32(0.5), jnp.float32(1e-3), jnp.float32(1.0))
    a = jax.random.uniform(jax.random.key(4), (256, 2), minval=LOW, maxval=HIGH)
    q = np.asarray(nets.critic.apply(agent.critic, jnp.ones((256, OBS)), a))
    np.testing.assert_allclose(q, 2.0, atol=0.1)
    # The targets were copied at the last step (rho = 1): they equal the online networks.
    for t, p in zip(
        jax.tree.leaves((agent.actor_targ, agent.critic_targ)), jax.tree.leaves((agent.actor, agent.critic))
    ):
        np.testing.assert_array_equal(np.asarray(t), np.asarray(p))


# ----------------------------------------------------------------------------- targets


@pytest.mark.parametrize("rho", [0.0, 0.5, 1.0])
def test_update_targets_against_numpy(nets, rho):
    k1, k2 = jax.random.split(jax.random.key(7))
    a, b = ddpg.init_agent(nets, k1, OBS), ddpg.init_agent(nets, k2, OBS)
    agent = a.replace(actor_targ=b.actor, critic_targ=b.critic)  # targets differ from the nets
    out = ddpg.update_targets(agent, jnp.float32(rho))
    for name, net in (("actor_targ", "actor"), ("critic_targ", "critic")):
        for t_new, t_old, p in zip(
            jax.tree.leaves(getattr(out, name)),
            jax.tree.leaves(getattr(agent, name)),
            jax.tree.leaves(getattr(agent, net)),
        ):
            ref = (1.0 - rho) * np.asarray(t_old, np.float64) + rho * np.asarray(p, np.float64)
            np.testing.assert_allclose(np.asarray(t_new), ref, rtol=1e-6, atol=1e-7)
    # The online networks and optimiser states are untouched.
    for x, y in zip(
        jax.tree.leaves((out.actor, out.critic, out.actor_opt, out.critic_opt)),
        jax.tree.leaves((agent.actor, agent.critic, agent.actor_opt, agent.critic_opt)),
    ):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    if rho == 0.0:
        for x, y in zip(jax.tree.leaves(out.actor_targ), jax.tree.leaves(agent.actor_targ)):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    if rho == 1.0:
        for x, y in zip(jax.tree.leaves(out.critic_targ), jax.tree.leaves(agent.critic)):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_init_agent_targets_are_copies_and_keys_matter(nets):
    a = ddpg.init_agent(nets, jax.random.key(0), OBS)
    b = ddpg.init_agent(nets, jax.random.key(1), OBS)
    for x, y in zip(jax.tree.leaves(a.actor), jax.tree.leaves(a.actor_targ)):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    assert any(not np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a.actor), jax.tree.leaves(b.actor)))
    # actor and critic get their own keys: first-layer kernels differ in the shared rows
    ka = np.asarray(a.actor["params"]["Dense_0"]["kernel"])
    kc = np.asarray(a.critic["params"]["Dense_0"]["kernel"])[:OBS]
    assert not np.array_equal(ka, kc)


# ----------------------------------------------------------------------------- exploration


@pytest.fixture(scope="module")
def eps_greedy_many():
    return jax.jit(jax.vmap(ddpg.epsilon_greedy, in_axes=(0, None, None)))


def test_epsilon_zero_is_greedy_exactly(eps_greedy_many):
    greedy = jnp.array([0.123, -0.456])
    out = np.asarray(eps_greedy_many(jax.random.split(jax.random.key(0), 1000), greedy, jnp.float32(0.0)))
    np.testing.assert_array_equal(out, np.broadcast_to(np.asarray(greedy), out.shape))


def test_epsilon_one_is_uniform_in_the_box(eps_greedy_many):
    greedy = jnp.array([5.0, 5.0])  # outside the box: any greedy leak shows
    out = np.asarray(eps_greedy_many(jax.random.split(jax.random.key(1), 4000), greedy, jnp.float32(1.0)))
    assert out[:, 0].min() >= 0.0 and out[:, 0].max() <= 1.0
    assert out[:, 1].min() >= -1.0 and out[:, 1].max() <= 1.0
    # the whole box is covered (uniform: mean at the centre, spread to the edges)
    np.testing.assert_allclose(out.mean(0), [0.5, 0.0], atol=0.03)
    assert out[:, 0].min() < 0.02 and out[:, 0].max() > 0.98
    assert out[:, 1].min() < -0.96 and out[:, 1].max() > 0.96


def test_epsilon_is_the_exploration_probability(eps_greedy_many):
    greedy = jnp.array([5.0, 5.0])
    out = np.asarray(eps_greedy_many(jax.random.split(jax.random.key(2), 10000), greedy, jnp.float32(0.3)))
    explored = ~np.all(out == 5.0, axis=1)
    assert abs(explored.mean() - 0.3) < 0.02


# ----------------------------------------------------------------------------- ring buffer


def _rows(ids):
    """Transitions whose every field encodes the row id (so positions can be read back)."""
    ids = jnp.asarray(ids, jnp.float32)
    return rb.Transition(
        obs=jnp.stack([ids] * OBS, -1),
        action=jnp.stack([ids, -ids], -1),
        reward=ids,
        next_obs=jnp.stack([ids + 0.5] * OBS, -1),
        done=ids % 2,
    )


def test_ring_buffer_wraps_at_the_traced_capacity():
    alloc, cap = 8, 5
    traces = []

    @jax.jit
    def add(buf, rows, count, capacity):
        traces.append(1)
        return rb.add(buf, rows, count, capacity)

    buf = rb.init(alloc, OBS)
    for count, pair in enumerate(([1, 2], [3, 4], [5, 6], [7, 8])):  # 8 rows into capacity 5
        buf = add(buf, _rows(pair), jnp.int32(2 * count), jnp.int32(cap))
    # row i written at (i - 1) % 5: 6, 7, 8 overwrote 1, 2, 3; rows >= capacity never touched
    np.testing.assert_array_equal(np.asarray(buf.reward), [6, 7, 8, 4, 5, 0, 0, 0])
    np.testing.assert_array_equal(np.asarray(buf.obs[:, 0]), [6, 7, 8, 4, 5, 0, 0, 0])
    np.testing.assert_array_equal(np.asarray(buf.action[:, 1]), [-6, -7, -8, -4, -5, 0, 0, 0])
    np.testing.assert_array_equal(np.asarray(buf.next_obs[:5, 2]), [6.5, 7.5, 8.5, 4.5, 5.5])
    np.testing.assert_array_equal(np.asarray(buf.done), [0, 1, 0, 0, 1, 0, 0, 0])
    # a different capacity reuses the compiled add (capacity and count are traced, not static)
    buf2 = rb.init(alloc, OBS)
    for count in range(0, 10, 2):
        buf2 = add(buf2, _rows([count + 1, count + 2]), jnp.int32(count), jnp.int32(alloc))
    np.testing.assert_array_equal(np.asarray(buf2.reward), [9, 10, 3, 4, 5, 6, 7, 8])
    assert len(traces) == 1


def test_ring_buffer_samples_only_filled_rows():
    alloc, cap = 8, 5
    sample = jax.jit(rb.sample, static_argnums=2)
    buf = rb.add(rb.init(alloc, OBS), _rows([1, 2, 3]), jnp.int32(0), jnp.int32(cap))
    out = sample(buf, jax.random.key(0), 2000, jnp.int32(3), jnp.int32(cap))
    np.testing.assert_array_equal(np.unique(np.asarray(out.reward)), [1, 2, 3])  # all filled rows, no empty one
    # rows stay whole: every field of a sampled row comes from the same transition
    np.testing.assert_array_equal(np.asarray(out.obs[:, 0]), np.asarray(out.reward))
    np.testing.assert_array_equal(np.asarray(out.next_obs[:, 1]), np.asarray(out.reward) + 0.5)
    # once wrapped, sampling covers the capacity and never the rows beyond it
    buf = rb.add(buf, _rows([4, 5, 6, 7]), jnp.int32(3), jnp.int32(cap))
    out = sample(buf, jax.random.key(1), 2000, jnp.int32(7), jnp.int32(cap))
    np.testing.assert_array_equal(np.unique(np.asarray(out.reward)), [3, 4, 5, 6, 7])
