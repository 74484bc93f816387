"""A run of a learner other than DDPG end to end: `train` writes what the learner shares, resumes
from its checkpoints (zero-size leaves included: a feed-forward PPO's empty GRU state), and both
evaluations drive its greedy policy; export says which learners it supports."""

from __future__ import annotations

import numpy as np
import pytest

from fedjax_nav import rundir
from fedjax_nav.config import load_config

TINY = [
    "env.episode_length=16",
    "env.envs_per_robot=2",
    "run.episodes=2",
    "run.chunk_episodes=1",
    "run.checkpoint_every=1",
    "fed.period=1",
    "ddpg.batch_size=8",
    "ddpg.buffer_size=64",
    "ddpg.hidden=16",
    "ppo.rollout=8",
    "ppo.minibatches=2",
    "ppo.epochs=1",
    "ppo.hidden=16",
]


@pytest.fixture(scope="module", params=["ppo", "td3"])
def learner_run(request, tmp_path_factory):
    from fedjax_nav.training.run import train

    cfg = load_config("thesis/flddpg", TINY + [f"learner={request.param}"])
    out = tmp_path_factory.mktemp(request.param) / "run"
    train(cfg, out, progress=False)
    return request.param, cfg, out


def test_params_hold_what_the_learner_shares(learner_run):
    from fedjax_nav.agents import learners

    name, cfg, out = learner_run
    with np.load(out / rundir.PARAMS) as z:
        tops = {k.split("/")[0] for k in z.files}
        leaves = [z[k] for k in z.files]
    assert tops == set(learners.get(name).shared_fields)
    assert all(x.shape[:2] == (1, cfg.num_robots) and np.isfinite(x).all() for x in leaves)


def test_resume_from_the_learners_checkpoint_equals_the_uninterrupted_run(learner_run, tmp_path):
    import dataclasses

    from fedjax_nav.training.run import train

    name, cfg, out = learner_run
    if name != "ppo":  # off-policy state resumes as DDPG's does (tests/test_checkpoint.py); PPO's has empty leaves
        pytest.skip("resume of a replay-buffer learner: tests/test_checkpoint.py")
    short = dataclasses.replace(cfg, run=dataclasses.replace(cfg.run, episodes=1))
    train(short, tmp_path / "r", progress=False)
    train(cfg, tmp_path / "r", progress=False, resume=True, allow_config_change=True)
    with np.load(out / rundir.PARAMS) as a, np.load(tmp_path / "r" / rundir.PARAMS) as b:
        assert sorted(a.files) == sorted(b.files)
        for k in a.files:
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_both_evaluations_drive_the_learners_greedy_policy(learner_run):
    from fedjax_nav.evaluation import evaluate_run
    from fedjax_nav.evaluation.suite import evaluate_suite

    name, cfg, out = learner_run
    ev = evaluate_run(out, attempts=1, max_steps=16)
    assert ev.summary["episodes"] == len(ev.frame) > 0 and ev.frame["success"].isin([0, 1]).all()
    suite = evaluate_suite(out, "probe", attempts=1, max_steps=8)
    assert len(suite["episodes"]) > 0


def test_export_takes_the_deterministic_actors_and_names_the_others(learner_run, tmp_path):
    from fedjax_nav.deploy.export import EXPORTABLE, ExportError, export_run

    name, cfg, out = learner_run
    if name in EXPORTABLE:
        written = export_run(out, tmp_path / "x", "numpy", None, None)
        assert any(p.name == "policy.py" for p in written)
    else:
        with pytest.raises(ExportError, match=f"learner {name}: export supports"):
            export_run(out, tmp_path / "x", "numpy", None, None)
