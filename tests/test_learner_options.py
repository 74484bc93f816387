"""Two learner options of docs/learners.md: PPO's observation normalisation (`ppo.normalize_obs`)
and n-step returns of the off-policy learners (`offpolicy.n_step`, for ddpg, td3 and sac).

- The normaliser's statistics after each rollout are numpy's mean and variance over every
  rollout seen; the rollout is evaluated with the statistics that acted (the stored log-densities
  come back); in a federated run (soft FedAvg, tau 1) every client ends with the exact pool of
  all clients' rows.
- n-step rows: with n = 1 the windows are today's 1-step rows and every learner's update is
  today's, bit for bit; with n = 4 the targets equal a float64 numpy loop over a hand-made
  sequence of 3 environments written into a ring that wraps (a terminal, time-outs and the newest
  rows inside the windows).
- A tiny training run with each option is finite; the config refuses the options where they do
  not apply.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fedjax_nav.agents import buffer as rb
from fedjax_nav.agents import ddpg, learners, normalize, offpolicy, ppo, sac, td3
from fedjax_nav.config import ConfigError, apply_overrides, from_dict, read_yaml, values
from fedjax_nav.config.traced import HParams
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.trainer import Trainer

THESIS = Path(__file__).resolve().parents[1] / "configs" / "thesis"
OBS = 5

# ----------------------------------------------------------------------------- PPO's normaliser


def _rollout_obs(rng, T, E):
    """Observations with different scales per feature, as the robot's: a range near its maximum
    (3.4 +- 0.05 m), a goal distance (5 +- 2 m), a bearing (0 +- 1.5 rad), an action (0.5 +- 0.3),
    an offset feature (-8 +- 0.5)."""
    loc, scale = np.array([3.4, 5.0, 0.0, 0.5, -8.0]), np.array([0.05, 2.0, 1.5, 0.3, 0.5])
    return (loc + scale * rng.normal(size=(T, E, OBS))).astype(np.float32)


@partial(jax.jit, static_argnums=0)
def _act_rollout(nets, state, obs, key) -> ppo.Rollout:
    """A rollout [T, E] acted by `state` on the given observations (feed-forward PPO)."""
    T, E = obs.shape[:2]
    keys = jax.random.split(key, T * E).reshape(T, E)
    hidden = ppo.initial_hidden(nets)
    steps, _ = jax.vmap(jax.vmap(lambda o, k: ppo.act(nets, state, o, k, hidden, False)))(jnp.asarray(obs), keys)
    z = jnp.zeros((T, E))
    return ppo.Rollout(
        obs=jnp.asarray(obs),
        raw_action=steps.raw_action,
        log_prob=steps.log_prob,
        reward=jnp.asarray(obs[..., 0]),
        next_obs=jnp.asarray(obs[..., ::-1]),
        terminated=z,
        truncated=z,
        reset=jnp.zeros((T, E), bool),
        hidden=ppo.Hidden(jnp.zeros((E, 0)), jnp.zeros((E, 0))),
    )


def test_ppo_normaliser_holds_numpys_statistics_of_the_rollouts_seen():
    nets = ppo.make_nets(hidden=8, depth=1, epochs=1, minibatches=2, normalize_obs=True)
    state = ppo.init(nets, jax.random.key(0), OBS)
    assert set(state.actor) == {"params", ppo.NORM}
    assert set(ppo.init(ppo.make_nets(hidden=8, depth=1), jax.random.key(0), OBS).actor) == {"params"}  # default
    update, evaluate = (
        jax.jit(lambda s, r, k: ppo.update(nets, s, r, k, HParams())),
        jax.jit(lambda s, r: ppo.evaluate(nets, s, r)),
    )
    rng, seen = np.random.default_rng(1), []
    x0 = _rollout_obs(rng, 1, 1)[0, 0]
    np.testing.assert_array_equal(np.asarray(ppo.observe(nets, state.actor, x0)), x0)  # nothing seen: raw
    for i in range(3):
        obs = _rollout_obs(rng, 4, 3)
        ro = _act_rollout(nets, state, obs, jax.random.key(10 + i))
        logp, _, _ = evaluate(state, ro)  # the rollout under the statistics that acted
        np.testing.assert_allclose(np.asarray(logp), np.asarray(ro.log_prob), rtol=1e-5, atol=1e-5)
        state, info = update(state, ro, jax.random.key(20 + i))
        assert np.isfinite(float(info["loss"]))
        seen.append(obs.reshape(-1, OBS).astype(np.float64))
        rows = np.concatenate(seen)
        stats = normalize.from_moments(state.actor[ppo.NORM])
        assert float(stats.count) == len(rows)
        np.testing.assert_allclose(np.asarray(stats.mean), rows.mean(0), rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(np.asarray(normalize.variance(stats)), rows.var(0), rtol=1e-3, atol=1e-7)
        want = np.clip((x0 - rows.mean(0)) / np.sqrt(rows.var(0) + 1e-8), -10, 10)
        np.testing.assert_allclose(np.asarray(ppo.observe(nets, state.actor, x0)), want, rtol=1e-3, atol=1e-3)
    # the greedy policy reads the statistics from the actor alone (what evaluation and export hold)
    a, _ = ppo.greedy_actor(nets, state.actor, jnp.asarray(x0), ppo.initial_hidden(nets), False)
    plain = nets.replace(normalize_obs=False)
    raw = ppo.greedy_actor(plain, ppo.weights(state.actor), jnp.asarray(x0), ppo.initial_hidden(nets), False)
    assert not np.allclose(np.asarray(a), np.asarray(raw[0]))


def test_averaged_moments_are_the_pool_of_the_clients_rows():
    rng = np.random.default_rng(2)
    rows = [_rollout_obs(rng, 8, 2).reshape(-1, OBS) + k for k in range(3)]  # 3 clients, shifted means
    per = [normalize.moments(normalize.update(normalize.init(OBS), jnp.asarray(x))) for x in rows]
    mean = jax.tree.map(lambda *xs: sum(xs) / len(xs), *per)  # a hard FedAvg round
    stats, pooled = normalize.from_moments(mean), np.concatenate(rows).astype(np.float64)
    np.testing.assert_allclose(np.asarray(stats.mean), pooled.mean(0), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(normalize.variance(stats)), pooled.var(0), rtol=1e-3, atol=1e-6)
    # a mean of the RunningStats themselves misses the spread between the clients' means
    naive = jax.tree.map(lambda *xs: sum(xs) / len(xs), *[normalize.from_moments(m) for m in per])
    assert not np.allclose(np.asarray(normalize.variance(naive)), pooled.var(0), rtol=0.05)


# ----------------------------------------------------------------------------- tiny runs

TINY = [
    "env.episode_length=4",
    "env.worlds=[train-0, train-2]",
    "env.envs_per_robot=2",
    "run.chunk_episodes=1",
    "run.checkpoint_every=0",
    "fed.period=1",
    "offpolicy.batch_size=4",
    "offpolicy.buffer_size=64",
    "offpolicy.hidden=8",
    "offpolicy.depth=1",
    "offpolicy.train_every=2",
    "ppo.hidden=8",
    "ppo.depth=1",
    "ppo.rollout=4",
    "ppo.minibatches=2",
    "ppo.epochs=1",
]


def make_cfg(learner: str, extra=(), method: str = "flddpg"):
    data = apply_overrides(read_yaml(THESIS / f"{method}.yaml"), TINY + list(extra))
    return from_dict({**data, "learner": learner})


def run_chunk(cfg):
    """One compiled chunk of every episode, seed 0: (trainer, states, metrics as numpy)."""
    tr, hp = Trainer(cfg), hparams_from_config(cfg)
    states, m = tr.compiled_chunk()(tr.init_seeds(jnp.arange(1), hp), hp, jnp.int32(0))
    return tr, states, jax.tree.map(np.asarray, m)


def _finite(m):
    for k, v in m.items():
        if k != "eval_success":
            assert np.all(np.isfinite(v)), k
    assert np.all(m["params_finite"])


@pytest.fixture(scope="module")
def ppo_run():
    """Normalised PPO, 2 robots x 2 environments, one 4-step episode = one rollout, then a hard
    FedAvg round: the rollout left in the buffers is every row the statistics saw."""
    return run_chunk(make_cfg("ppo", ["ppo.normalize_obs=true", "fed.tau=1.0", "run.episodes=1"]))


def test_a_normalised_federated_ppo_run_is_finite_and_pools_its_statistics(ppo_run):
    tr, st, m = ppo_run
    _finite(m)
    assert tr.nets.ppo.normalize_obs and np.any(m["policy_loss"] != 0)
    rows = np.asarray(st.buffers.obs[0], np.float64).reshape(-1, tr.obs_size)  # both robots' rollouts
    norm = jax.tree.map(lambda x: x[0], st.agents.actor[ppo.NORM])  # [clients, ...]
    for k in range(tr.n_nets):
        stats = normalize.from_moments(jax.tree.map(lambda x, k=k: x[k], norm))
        assert float(stats.count) == len(rows) / tr.n_nets  # a client's count: its own rows
        np.testing.assert_allclose(np.asarray(stats.mean), rows.mean(0), rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(np.asarray(normalize.variance(stats)), rows.var(0), rtol=2e-3, atol=1e-5)
    # what evaluation and export read: the policy carries the statistics, the shared fields too
    assert ppo.NORM in tr.policy(st.agents) and ppo.NORM in tr.shared(st.agents)["actor"]


@pytest.fixture(scope="module")
def nstep_run():
    """DDPG with 3-step targets and SEDDPG's one buffer of every robot's environments (4 rows a
    step), 2 episodes: windows of one environment step 4 rows at a time (the learners share the
    replay code: TD3's and SAC's n-step updates are tested below)."""
    return run_chunk(make_cfg("ddpg", ["offpolicy.n_step=3", "run.episodes=2", "run.chunk_episodes=2"], "seddpg"))


def test_an_n_step_run_is_finite_and_keeps_where_episodes_were_cut(nstep_run):
    tr, st, m = nstep_run
    _finite(m)
    assert tr.nets.n_step == 3 and np.any(m["critic_loss"] != 0)
    trunc = np.asarray(st.buffers.truncated[0])  # [buffers, rows]: steps 3 and 7 are episodes' last
    rows = tr.writes
    assert trunc.shape[0] == 1 and rows == 4
    want = np.zeros(trunc.shape[1])
    for g in (3, 7):
        want[g * rows : (g + 1) * rows] = 1
    np.testing.assert_array_equal(trunc, np.broadcast_to(want, trunc.shape))


@pytest.mark.parametrize("learner", ["td3", "ddpg"])
def test_the_warm_up_acts_uniformly_for_its_steps_and_then_hands_over(learner):
    """offpolicy.random_steps over 2 episodes of 4 steps: at 0 the run is bitwise the one without the
    field (the draws have their own key); at 2 the rows of steps 0-1 are uniform draws over the box,
    the same draws as a warm-up of all 8 steps makes, and from step 2 on the exploration acts."""
    base = ["run.episodes=2", "run.chunk_episodes=2", "offpolicy.buffer_size=64", "offpolicy.train_every=1000"]
    runs = [
        run_chunk(make_cfg(learner, [*base, *x]))
        for x in ([], ["offpolicy.random_steps=0"], ["offpolicy.random_steps=2"])
    ]
    runs.append(run_chunk(make_cfg(learner, [*base, "offpolicy.random_steps=8"])))
    tr = runs[0][0]
    plain, zero, two, all_ = (np.asarray(r[1].buffers.action[0]).reshape(tr.n_bufs, -1, tr.writes, 2) for r in runs)
    np.testing.assert_array_equal(zero, plain)
    np.testing.assert_array_equal(two[:, :2], all_[:, :2])  # the same uniform draws
    assert not np.allclose(two[:, 2:4], all_[:, 2:4])  # step 2 on: the exploration, not the draws
    assert not np.allclose(two[:, :2], plain[:, :2])
    warm = all_[:, :8].reshape(-1, 2)  # the 8 steps written (the buffer's other rows are empty)
    assert np.all((warm >= [0.0, -1.0]) & (warm <= [1.0, 1.0])) and len(np.unique(warm)) == warm.size
    # uniform over the box: 8 steps x 2 envs x 2 robots = 32 draws, loose bounds on the moments
    assert abs(warm[:, 0].mean() - 0.5) < 0.15 and abs(warm[:, 1].mean()) < 0.3 and warm[:, 1].std() > 0.4


# ----------------------------------------------------------------------------- n-step rows

ENVS, STEPS, CAP, N, GAMMA = 3, 13, 29, 4, 0.9  # 39 rows written into 29: the ring wraps, 29 % 3 != 0
EPISODE = 6  # time-outs at steps 5 and 11; step 12 is the newest; terminals below


def _sequence():
    """One hand-made history: [STEPS, ENVS] rewards, flags, observations (obs[0] = environment,
    obs[1] = step) and next observations unlike the next row's obs (a reset follows an end)."""
    rng = np.random.default_rng(3)
    reward = rng.normal(size=(STEPS, ENVS))
    term = np.zeros((STEPS, ENVS), bool)
    term[8, 0] = term[9, 1] = term[3, 2] = True  # goal or collision inside an episode
    trunc = np.zeros((STEPS, ENVS), bool)
    trunc[EPISODE - 1 :: EPISODE] = True
    obs = rng.normal(size=(STEPS, ENVS, OBS))
    obs[..., 0], obs[..., 1] = np.arange(ENVS)[None], np.arange(STEPS)[:, None]
    next_obs = rng.normal(size=(STEPS, ENVS, OBS))
    return reward, term, trunc, obs, next_obs


def np_nstep(seq, env, t, n, gamma):
    """float64: (sum_i gamma^i r_i, gamma^k, done, next obs, why) for the window from step t of
    `env`, cut at a terminal (no bootstrap), a time-out or the newest step (bootstrap there)."""
    reward, term, trunc, _, next_obs = seq
    total = 0.0
    for i in range(n):
        s = t + i
        total += gamma**i * reward[s, env]
        why = "terminal" if term[s, env] else "timeout" if trunc[s, env] else "newest" if s == STEPS - 1 else None
        if why or i == n - 1:
            return total, gamma ** (i + 1), float(term[s, env]), next_obs[s, env], why or "full"


def _filled(nets, seq):
    """The learner's storage after the sequence, written by its own `store` (rows = ENVS)."""
    reward, term, trunc, obs, next_obs = seq
    hp = HParams() | {"offpolicy.buffer_size": jnp.int32(CAP)}
    buf = learners.TD3.storage(nets, OBS, ENVS)
    store = jax.jit(lambda b, r, g: learners.TD3.store(nets, b, r, g, ENVS, hp))
    f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    for g in range(STEPS):
        rec = learners.Record(
            f32(obs[g]), f32(np.stack([obs[g, :, 2]] * 2, -1)), f32(reward[g]), f32(next_obs[g]),
            jnp.asarray(term[g]), jnp.asarray(trunc[g]), None, (), None,
        )  # fmt: skip
        buf = store(buf, rec, jnp.int32(g))
    return buf


OFF_POLICY = ["offpolicy.batch_size=4", "offpolicy.train_every=1", f"offpolicy.buffer_size={CAP}"]


def _nets(n_step: int, batch: int = 256):
    return learners.TD3.make_nets(values(make_cfg("td3", OFF_POLICY))).replace(n_step=n_step, batch_size=batch)


@pytest.fixture(scope="module")
def filled():
    """{n_step: the storage after the sequence}, n_step 1 (today's rows) and N."""
    return {n: _filled(_nets(n), _sequence()) for n in (1, N)}


def _sample(nets, buf, key):
    fn = jax.jit(lambda b, k: learners.sample_batch(nets, b, k, STEPS * ENVS, CAP, ENVS, GAMMA))
    return fn(buf, key)


def test_n_step_targets_equal_a_float64_numpy_loop(filled):
    seq, nets, buf = _sequence(), _nets(N), filled[N]
    assert isinstance(buf, rb.EpisodeRows)
    w = np.random.default_rng(4).normal(size=OBS)  # a known bootstrap V(s) = w . s
    why_seen = set()
    for i in range(4):
        b = _sample(nets, buf, jax.random.key(i))
        y = np.asarray(offpolicy.td_target(b, jnp.asarray(b.next_obs) @ jnp.asarray(w, jnp.float32)))
        obs = np.asarray(b.obs)
        for j in range(len(y)):
            env, t = int(obs[j, 0]), int(obs[j, 1])
            assert t * ENVS + env >= STEPS * ENVS - CAP  # drawn from the rows still in the ring
            ret, disc, done, nxt, why = np_nstep(seq, env, t, N, GAMMA)
            why_seen.add(why)
            np.testing.assert_allclose(float(b.reward[j]), ret, rtol=1e-5, atol=1e-5)
            np.testing.assert_allclose(float(b.discount[j]), disc, rtol=1e-6)
            assert float(b.done[j]) == done
            np.testing.assert_allclose(np.asarray(b.next_obs[j]), nxt, rtol=1e-6, atol=1e-6)
            np.testing.assert_allclose(y[j], ret + disc * (1 - done) * float(nxt @ w), rtol=1e-5, atol=1e-4)
    assert why_seen == {"full", "terminal", "timeout", "newest"}


def test_n_step_one_windows_are_todays_rows(filled):
    plain, windows = filled[1], filled[N]
    assert isinstance(plain, rb.Transition)  # n_step 1: the buffer is today's
    key, count, cap = jax.random.key(7), jnp.int32(STEPS * ENVS), jnp.int32(CAP)
    today = offpolicy.one_step(rb.sample(plain, key, 256, count, cap), GAMMA)

    @jax.jit
    def one_step_windows(buf, k):  # the n-step machinery with windows of one step
        w, end = rb.sample_windows(buf, k, 256, count, cap, 1, ENVS)
        return jax.vmap(lambda x, e: offpolicy.nstep(x, e, GAMMA))(w, end)

    for got in (_sample(_nets(1), plain, key), one_step_windows(windows, key)):
        for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(today)):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def _today(name, nets, state, buf, key, g, hp):
    """Each learner's update event (one gradient step after step g) as it was written before
    n-step rows: DDPG samples with the event's key and discounts by the scalar gamma; TD3 and SAC
    split it and learn from `one_step` rows."""
    count = (g + 1) * ENVS
    if name == "ddpg":
        return ddpg.update(nets, state, rb.sample(buf, key, 4, count, CAP), hp.offpolicy.gamma, hp.offpolicy.lr)
    k_batch, k_step = jax.random.split(key)
    batch = offpolicy.one_step(rb.sample(buf, k_batch, 4, count, CAP), hp.offpolicy.gamma)
    if name == "td3":
        index = (g + 1) // hp.offpolicy.train_every - 1  # the gradient step's index in the run
        return td3.update(nets, state, batch, k_step, hp, index % hp.td3.policy_delay == 0)
    return sac.update(nets, state, batch, k_step, hp)


@pytest.mark.parametrize("name", ["ddpg", "td3", "sac"])
def test_n_step_one_updates_are_todays_and_n_step_updates_are_finite(name, filled):
    cfg = make_cfg(name, OFF_POLICY)
    learner, hp = learners.get(name), hparams_from_config(cfg)
    nets = learner.make_nets(values(cfg))
    state = learner.init(nets, jax.random.key(1), OBS, hp)
    g, nets_n = jnp.int32(STEPS - 1), nets.replace(n_step=N)

    @jax.jit  # one program: the learner's update with n = 1 and n = N, and today's
    def updates(state, buf, buf_n, key):
        new, old = learner.update(nets, state, buf, key, g, ENVS, hp), _today(name, nets, state, buf, key, g, hp)
        return new, old, learner.update(nets_n, state, buf_n, key, g, ENVS, hp)

    (new, losses), (old, old_losses), (_, losses_n) = updates(state, filled[1], filled[N], jax.random.key(5))
    for a, b in zip(jax.tree.leaves((new, losses)), jax.tree.leaves((old, {m: old_losses[m] for m in losses}))):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert all(np.isfinite(float(v)) for v in losses_n.values())
    assert float(losses_n["critic_loss"]) != float(losses["critic_loss"])  # other targets on the same rows


# ----------------------------------------------------------------------------- config


@pytest.mark.parametrize(
    "learner,extra,match",
    [
        ("ppo", ["offpolicy.n_step=3"], r"offpolicy.n_step \(3\) needs an off-policy learner: ddpg, td3, sac"),
        ("td3", ["ppo.normalize_obs=true"], "ppo.normalize_obs needs learner: ppo"),
        ("sac", ["offpolicy.n_step=40"], r"offpolicy.n_step \(40\) x rows written per step into one buffer \(2\)"),
        ("sac", ["offpolicy.n_step=0"], "offpolicy.n_step"),
        ("ppo", ["offpolicy.random_steps=10"], r"offpolicy.random_steps \(10\) needs an off-policy learner"),
    ],
)
def test_config_refuses_the_options_where_they_do_not_apply(learner, extra, match):
    with pytest.raises(ConfigError, match=match) as e:
        make_cfg(learner, extra)
    assert "\n" not in str(e.value)
