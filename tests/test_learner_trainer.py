"""The trainer hosts every learner (DDPG, TD3, SAC, PPO) with several environments per robot.

Tiny runs (2 robots, 4-step episodes, 8-unit networks), one compiled chunk per case shared through
a module-scoped cache: each learner trains with envs_per_robot 1 and 3 (finite metrics, its own
loss names, its storage filled); soft FedAvg averages exactly the learner's SHARED fields (against
numpy); two values of every traced hyperparameter of a learner compile once and the program reads
each; PPO's rollout keeps a time-out apart from a termination and bootstraps there; the config
refuses what a learner cannot do.
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fedjax_nav import config
from fedjax_nav.agents import learners, ppo
from fedjax_nav.config import ConfigError, apply_overrides, from_dict, load_config, read_yaml, traced_fields
from fedjax_nav.learner_table import LEARNERS
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.trainer import Trainer

THESIS = Path(__file__).resolve().parents[1] / "configs" / "thesis"
T, ROLLOUT = 4, 8  # a PPO rollout spans two episodes: the first one's time-out is mid-rollout
TINY = [
    f"env.episode_length={T}",
    "env.worlds=[train-0, train-2]",
    "run.episodes=2",
    "run.chunk_episodes=2",
    "run.checkpoint_every=0",
    "fed.period=1",
    "offpolicy.batch_size=4",
    "offpolicy.buffer_size=64",
    "offpolicy.hidden=8",
    "offpolicy.depth=1",
    "offpolicy.train_every=2",
    "ppo.hidden=8",
    "ppo.depth=1",
    f"ppo.rollout={ROLLOUT}",
    "ppo.minibatches=2",
    "ppo.epochs=2",
    "ppo.gru_hidden=4",
]


def make_cfg(learner: str, method: str = "flddpg", extra=()) -> config.Config:
    """A preset with the tiny overrides and `learner`, validated once, as a whole."""
    data = apply_overrides(read_yaml(THESIS / f"{method}.yaml"), TINY + list(extra))
    return from_dict({**data, "learner": learner})


class Run:
    """One compiled chunk of a tiny run and what it returned (seeds = 1)."""

    def __init__(self, cfg):
        self.traces = 0
        self.cfg, self.tr, self.hp = cfg, Trainer(cfg), hparams_from_config(cfg)
        self.fn = self.tr.compiled_chunk(on_trace=self._count)
        self.states, self.metrics = self(self.hp)

    def _count(self):
        self.traces += 1

    def __call__(self, hp):
        states, m = self.fn(self.tr.init_seeds(jnp.arange(1), hp), hp, jnp.int32(0))
        return states, jax.tree.map(np.asarray, m)


@pytest.fixture(scope="module")
def runs():
    cache = {}

    def get(learner: str, n: int, recurrent: bool = False) -> Run:
        key = (learner, n, recurrent)
        if key not in cache:
            # N = 3 runs federate (soft FedAvg) and take 2 gradient steps per update event;
            # N = 1 runs are independent learners (a smaller program)
            extra = [f"env.envs_per_robot={n}"]
            extra += ["offpolicy.gradient_steps=2"] if n > 1 else []
            extra += ["ppo.recurrent=gru", "ppo.minibatches=3"] if recurrent else []
            cache[key] = Run(make_cfg(learner, "flddpg" if n > 1 else "iddpg", extra))
        return cache[key]

    return get


def test_config_names_the_learners_of_the_table():
    assert tuple(config.LEARNERS) == tuple(LEARNERS) and "ddpg" in config.LEARNERS
    assert Trainer(load_config(THESIS / "flddpg.yaml", TINY)).learner == learners.get("ddpg")  # the default
    for name, row in LEARNERS.items():  # the row's facts reach the implementation
        x = learners.get(name)
        assert (x.name, x.on_policy, x.shared_fields, x.target_fields) == (name, row.on_policy, row.shared, row.targets)


def test_nothing_branches_on_a_learner_name():
    """The learner table is the one place a learner's name means something (docs/learners.md)."""
    import re
    from pathlib import Path

    pkg = Path(config.__file__).resolve().parents[1]
    names = "|".join(LEARNERS)
    pattern = re.compile(rf"""(==|!=|\bin)\s*\(?\s*["']({names})["']|learner\s*(==|!=)\s*["']""")
    hits = [
        f"{p.relative_to(pkg)}:{i}"
        for p in sorted(pkg.rglob("*.py"))
        # the learner table itself
        if p.name != "learner_table.py"
        for i, line in enumerate(p.read_text().splitlines(), 1)
        if pattern.search(line)
    ]
    assert not hits, hits


# N = 3 for every learner; N = 1 for PPO only: one environment of an off-policy learner is the
# thesis's DDPG program (tests/test_trainer.py), and TD3 and SAC store and sample through DDPG's
# replay code (agents/learners.py builds the three from one helper)
CASES = [(name, 3) for name in LEARNERS] + [("ppo", 1)]


@pytest.mark.parametrize("learner,n", CASES, ids=[f"{a}-{b}" for a, b in CASES])
def test_each_learner_trains_a_tiny_run(runs, learner, n):
    r = runs(learner, n)
    tr, m, st = r.tr, r.metrics, r.states
    assert tr.num_envs == 2 * n and st.obs.shape == (1, 2 * n, tr.obs_size)
    assert set(tr.learner.metrics) <= set(m) and "reward" in m and "params_finite" in m
    for k, v in m.items():
        if k != "eval_success":
            assert np.all(np.isfinite(v)), k
    assert np.all(m["params_finite"])
    assert m["reward"].shape == (1, 2, 2) and m["goals"].shape == (1, 2, 2)  # [seeds, episodes, robots]
    loss = tr.learner.metrics[0]  # critic_loss or policy_loss
    assert m[loss].shape == (1, 2, tr.n_nets) and np.any(m[loss] != 0)
    if tr.learner.on_policy:  # a rollout [nets, T_roll, environments of the robot]
        assert st.buffers.reward.shape == (1, 2, ROLLOUT, n) and np.all(np.asarray(st.buffers.obs).any(-1))
    else:  # every environment's rows are in its robot's buffer: T * 2 episodes * n rows
        filled = np.abs(np.asarray(st.buffers.obs[0])).sum(-1) > 0  # [buffers, rows]
        assert filled.sum(1).tolist() == [2 * T * n] * 2
    # the procedural program is not involved: each environment of a robot is in the robot's room
    if n > 1:
        np.testing.assert_array_equal(np.asarray(tr.world.segments[0]), np.asarray(tr.world.segments[n - 1]))


def test_recurrent_ppo_trains_with_its_gru_states_carried(runs):
    r = runs("ppo", 3, recurrent=True)
    tr, st = r.tr, r.states
    assert tr.nets.ppo.recurrent and st.memory.actor.shape == (1, 6, 4) and st.first.shape == (1, 6)
    assert np.all(np.isfinite(r.metrics["policy_loss"])) and np.all(r.metrics["params_finite"])
    assert np.abs(np.asarray(st.memory.actor)).sum() > 0  # the carry moved
    # the rollout kept the states before its first step, and the greedy policy (what the probe
    # drives) starts from the learner's memory at an episode's first observation
    assert st.buffers.hidden.actor.shape == (1, 2, 3, 4)
    policy = jax.tree.map(lambda x: x[0, 0], tr.policy(st.agents))
    action, memory = tr.learner.greedy(tr.nets, policy, st.obs[0, 0], tr.learner.memory(tr.nets), jnp.bool_(True))
    assert action.shape == (2,) and 0 <= float(action[0]) <= 1 and memory.actor.shape == (4,)


@pytest.mark.parametrize("learner", list(LEARNERS))
def test_soft_fedavg_averages_exactly_the_shared_fields(runs, learner):
    r = runs(learner, 3)
    tr = r.tr
    state = jax.tree.map(lambda x: x[0], tr.init_seeds(jnp.arange(1), r.hp))  # two differently initialised clients
    hp = r.hp | {"fed.tau": jnp.float32(0.5)}
    new, stats = jax.jit(tr.federated_round)(state, hp)
    shared = set(tr.learner.shared_fields)
    assert shared == set(tr.shared(state.agents)) and int(stats["clients"]) == 2
    differ = False  # there was something to average
    for field in type(state.agents).__dataclass_fields__:
        old_leaves = jax.tree.leaves(getattr(state.agents, field))
        new_leaves = jax.tree.leaves(getattr(new.agents, field))
        for a, b in zip(old_leaves, new_leaves):
            a, b = np.asarray(a, np.float64), np.asarray(b)
            if field in shared:
                np.testing.assert_allclose(b, 0.5 * a + 0.5 * a.mean(0, keepdims=True), rtol=1e-5, atol=1e-6)
                differ |= not np.allclose(a[0], a[1])
            else:  # targets (without fed.include_targets), optimiser moments: each client's own
                np.testing.assert_array_equal(b, a, err_msg=field)
    assert differ


def _changed(hp, names):
    """hp with every name in `names` moved to another valid value."""
    flat = hp.to_flat()
    out = {}
    for k in names:
        v = np.asarray(flat[k])
        new = v + 1 if v.dtype.kind == "i" else 0.5 * v + 0.01
        out[k] = jnp.asarray(-0.5 if k == "ppo.init_log_std" else new, v.dtype)
    return hp.replace_flat(out)


def _own_traced(learner: str):
    shared = ("offpolicy.lr", "offpolicy.gamma") if learner in ("td3", "sac") else ()
    return [k for k in traced_fields() if k.startswith(f"{learner}.")] + list(shared)


@pytest.mark.parametrize("learner", list(LEARNERS))
def test_two_values_of_every_traced_hyperparameter_compile_once(runs, learner):
    r = runs(learner, 3)
    names = _own_traced(learner)
    assert len(names) >= 3
    _, m2 = r(_changed(r.hp, names))
    assert r.traces == 1
    assert any(not np.allclose(r.metrics[k], m2[k]) for k in r.tr.learner.metrics)


@pytest.mark.parametrize("learner", list(LEARNERS))
def test_the_program_reads_every_traced_hyperparameter_of_the_learner(runs, learner):
    tr, hp = runs(learner, 3).tr, runs(learner, 3).hp

    def init_and_train(h):
        states = jax.vmap(lambda k: tr.init(k, h))(jax.random.split(jax.random.key(0), 1))
        return tr.chunk(states, h, jnp.int32(0), 1)

    closed = jax.make_jaxpr(init_and_train)(hp)
    used = {v for eqn in closed.jaxpr.eqns for v in eqn.invars if hasattr(v, "aval") and not hasattr(v, "val")}
    unused = {n for n, v in zip(hp.to_flat(), closed.jaxpr.invars) if v not in used}
    assert not unused & set(_own_traced(learner)), sorted(unused & set(_own_traced(learner)))


def test_ppo_rollout_keeps_a_timeout_apart_and_bootstraps_there(runs):
    """Episodes of T = 4 steps, a rollout of 8: step 3 is the first episode's last (truncated, not
    terminated unless the robot also hit something there), step 4 the second one's first. The
    return at step 3 bootstraps from V(the true last observation), not from step 4's start."""
    r = runs("ppo", 3)
    tr = r.tr
    ro = jax.tree.map(lambda x: np.asarray(x[0]), r.states.buffers)  # [nets, T_roll, envs]
    trunc, term, reset = ro.truncated, ro.terminated, ro.reset
    assert np.all(trunc[:, [T - 1, 2 * T - 1]] == 1) and trunc.sum() == 2 * trunc.shape[0] * trunc.shape[2]
    assert np.all(reset[:, 0]) and np.all(reset[:, T])
    assert not np.allclose(ro.next_obs[:, T - 1], ro.obs[:, T])  # s' at the time-out is where the robot stood
    agents = jax.tree.map(lambda x: x[0], r.states.agents)
    g = float(r.hp.ppo.gamma)
    for k in range(tr.n_nets):
        state = jax.tree.map(lambda x, k=k: x[k], agents)
        rollout = jax.tree.map(lambda x, k=k: jnp.asarray(x[k]), ro)
        _, values, next_values = ppo.evaluate(tr.nets.ppo, state, rollout)
        end = np.maximum(ro.terminated[k], ro.truncated[k])
        _, returns = ppo.gae(rollout.reward, values, next_values, rollout.terminated, end, g, 0.95)
        timeout = term[k, T - 1] == 0  # the environments that timed out without a goal or collision
        assert timeout.any()
        boot = ro.reward[k, T - 1] + g * np.asarray(next_values)[T - 1]
        np.testing.assert_allclose(np.asarray(returns)[T - 1][timeout], boot[timeout], rtol=1e-5, atol=1e-5)
        assert np.all(np.abs(np.asarray(next_values)[T - 1][timeout]) > 1e-4)  # a termination would drop it


@pytest.mark.parametrize(
    "extra,learner,method,match",
    [
        ([], "a2c", "flddpg", "learner: 'a2c' is not one of ddpg, td3, sac, ppo"),
        (["ppo.minibatches=3"], "ppo", "flddpg", r"ppo.minibatches \(3\) must divide ppo.rollout x env.envs_per_robot"),
        (["ppo.recurrent=gru", "ppo.minibatches=2", "env.envs_per_robot=3"], "ppo", "flddpg", "env.envs_per_robot"),
        (["ppo.recurrent=gru"], "td3", "flddpg", r"ppo.recurrent \('gru'\) needs learner: ppo"),
        ([], "ppo", "seddpg", "method seddpg shares one replay buffer between the robots' own networks"),
    ],
)
def test_config_refuses_what_a_learner_cannot_do(extra, learner, method, match):
    with pytest.raises(ConfigError, match=match) as e:
        make_cfg(learner, method, extra)
    assert "\n" not in str(e.value)


def test_a_central_ppo_learner_is_one_network_over_every_robots_environments():
    # snddpg with PPO: one policy acts in all 2 robots x 2 environments and learns from one
    # rollout of all of them (the central learner of docs/generalization.md)
    r = Run(make_cfg("ppo", "snddpg", ["env.envs_per_robot=2"]))
    tr, st, m = r.tr, r.states, r.metrics
    assert tr.n_nets == 1 and tr.n_bufs == 1 and tr.num_envs == 4
    assert st.buffers.reward.shape == (1, 1, ROLLOUT, 4) and np.all(np.asarray(st.buffers.obs).any(-1))
    assert m["policy_loss"].shape == (1, 2, 1) and np.all(m["policy_loss"][:, 1] != 0)  # the rollout ends in episode 2
    assert np.all(m["params_finite"]) and m["goals"].shape == (1, 2, 2)  # still counted per robot
