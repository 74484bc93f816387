"""Runs that can never learn are said before training (docs/reliability.md, "Runs that cannot
learn"): a learner whose update period (its row's `update_every`: ppo.rollout, offpolicy.train_every)
is longer than the run, and an off-policy learner whose batch is more than its replay buffer has
received at the run's last update event. One warning line naming the field (`config.never_updates`,
printed by `training.run.train`); one step more (or a value one smaller) and there is none. The
warning is held to the learners' own `due` functions: it is given exactly when `due` is false at
every step of the run. Nothing is trained.
"""

import dataclasses
import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax.numpy as jnp  # noqa: E402
import pytest  # noqa: E402
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from fedjax_nav import learner_table, methods  # noqa: E402
from fedjax_nav.config import from_dict, load_config, never_updates, values  # noqa: E402

NEVER = "no update will happen"
BASE = ["fed.period=1", "run.chunk_episodes=1", "run.checkpoint_every=0", "ppo.minibatches=1"]


def refusal(overrides) -> str | None:
    """The warning of the default config with `overrides` (`never_updates`), or None."""
    return never_updates(load_config(None, BASE + list(overrides)))


# (what, the overrides it refuses, the field its line names, the same run one step longer or with
# the field one smaller, which loads)
CASES = [
    (
        "ppo's rollout beyond the run",
        ["learner=ppo", "run.episodes=2", "env.episode_length=16", "ppo.rollout=33"],
        "ppo.rollout (33 steps)",
        [["env.episode_length=17"], ["ppo.rollout=32"]],
    ),
    (
        "a GRU ppo's rollout beyond the run",
        ["learner=ppo", "ppo.recurrent=gru", "run.episodes=1", "env.episode_length=8", "ppo.rollout=9"],
        "ppo.rollout (9 steps)",
        [["env.episode_length=9"], ["ppo.rollout=8"]],
    ),
    (
        "train_every beyond the run",
        [
            "learner=td3",
            "run.episodes=1",
            "env.episode_length=16",
            "offpolicy.batch_size=8",
            "offpolicy.train_every=17",
        ],
        "offpolicy.train_every (17 steps)",
        [["env.episode_length=17"], ["offpolicy.train_every=16"]],
    ),
    (
        # updates after steps 5, 10 (14 steps): a buffer holds 10 rows at the last one
        "a batch one buffer never holds at an update",
        ["method=iddpg", "run.episodes=1", "env.episode_length=14", "offpolicy.batch_size=11"],
        "offpolicy.batch_size (11)",
        [["env.episode_length=15"], ["offpolicy.batch_size=10"]],
    ),
    (
        # 2 environments per robot write 2 rows per step into the robot's buffer: 20 at step 10
        "a batch beyond the rows of a robot's environments",
        ["learner=sac", "method=flddpg", "env.envs_per_robot=2", "run.episodes=1", "env.episode_length=14"]
        + ["offpolicy.batch_size=21"],
        "offpolicy.batch_size (21)",
        [["env.episode_length=15"], ["offpolicy.batch_size=20"]],
    ),
    (
        # one shared buffer: every robot's rows, 5 robots x 2 environments = 10 per step, 100 at step 10
        "a batch beyond a shared buffer's rows",
        ["method=snddpg", "env.envs_per_robot=2", "run.episodes=1", "env.episode_length=14"]
        + ["offpolicy.batch_size=101", "offpolicy.buffer_size=200"],
        "offpolicy.batch_size (101)",
        [["env.episode_length=15"], ["offpolicy.batch_size=100"]],
    ),
]


@pytest.mark.parametrize("what, refused, names, accepted", CASES, ids=[c[0] for c in CASES])
def test_a_run_that_can_never_update_is_said_naming_the_field(what, refused, names, accepted):
    msg = refusal(refused)
    assert msg is not None and "\n" not in msg and NEVER in msg and names in msg, msg
    for more in accepted:  # one step more, or the field one smaller: an update happens, no warning
        assert refusal(refused + more) is None, (more, refusal(refused + more))


def test_train_prints_the_warning_before_training(monkeypatch, capsys, tmp_path):
    """`training.run.train` says it on stderr, then trains (here: stopped where training begins)."""
    from fedjax_nav.training import run

    data = {"env": {"episode_length": 16}, "run": {"episodes": 2, "chunk_episodes": 1, "checkpoint_every": 0}}
    data |= {"fed": {"period": 1}, "learner": "ppo", "ppo": {"rollout": 64, "minibatches": 1}}
    cfg = from_dict(data, "tiny.yaml")
    monkeypatch.setattr(run, "_train", lambda *args: {"trained": True})
    assert run.train(cfg, tmp_path / "run", progress=False) == {"trained": True}
    err = capsys.readouterr().err
    assert err.startswith("warning: ppo.rollout (64 steps) is longer than the whole run"), err


def test_every_shipped_config_and_the_default_updates():
    from fedjax_nav.configs import names

    for name in names("config"):
        assert never_updates(load_config(name)) is None, name
    assert never_updates(load_config(None)) is None


# ----------------------------------------------------------------------------- the learners' own `due`

METHODS = ("iddpg", "flddpg", "seddpg", "snddpg")


def update_events(cfg) -> int:
    """How many update events the learner's own `due` (agents/learners.py) gives over the run's
    steps, with the trainer's rows per buffer (training/trainer.py: environments / buffers)."""
    from fedjax_nav.agents import learners
    from fedjax_nav.training.hparams import hparams_from_config

    learner = learners.get(cfg.learner)
    method = methods.get(cfg.method)
    robots = cfg.num_robots
    writes = robots * cfg.env.envs_per_robot // (1 if method.shared_buffer else robots)
    g = jnp.arange(cfg.run.episodes * cfg.env.episode_length, dtype=jnp.int32)
    due = learner.due(learner.make_nets(values(cfg)), g, writes, hparams_from_config(cfg))
    return int(jnp.sum(jnp.broadcast_to(due, g.shape)))


REFERENCE = load_config(None, BASE + ["env.worlds=[train-0,train-2]"])


@settings(max_examples=60, deadline=None, database=None, suppress_health_check=list(HealthCheck))
@given(
    learner=st.sampled_from(sorted(learner_table.LEARNERS)),
    method=st.sampled_from(METHODS),
    episodes=st.integers(1, 3),
    length=st.integers(1, 24),
    every=st.integers(1, 40),
    batch=st.integers(1, 120),
    envs=st.integers(1, 3),
)
def test_the_warning_is_exactly_a_run_without_an_update_event(learner, method, episodes, length, every, batch, envs):
    row = learner_table.get(learner)
    if row.on_policy and methods.get(method).shared_buffer and not methods.get(method).shared_network:
        return  # refused for its own reason (an on-policy learner cannot share a buffer)
    r = REFERENCE
    cfg = dataclasses.replace(
        r,
        learner=learner,
        method=method,
        env=dataclasses.replace(r.env, episode_length=length, envs_per_robot=envs),
        run=dataclasses.replace(r.run, episodes=episodes),
        ppo=dataclasses.replace(r.ppo, rollout=every),
        offpolicy=dataclasses.replace(r.offpolicy, train_every=every, batch_size=batch, buffer_size=max(batch, 8)),
    )
    said = never_updates(cfg)
    assert said is None or NEVER in said, said
    assert (said is not None) == (update_events(cfg) == 0), (said, update_events(cfg))
