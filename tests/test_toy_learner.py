"""Acceptance of the learner table (docs/learners.md, "Adding a learner"): a learner added from one
module and one row registered at test time (tests/toy_learner.py; no package file edited) is
accepted by the config, trains, resumes from a checkpoint, is evaluated and exported."""

import json

import numpy as np
import pandas as pd
import pytest
import toy_learner

from fedjax_nav import learner_table
from fedjax_nav.config import ConfigError, load_config

TINY = [
    "learner=toy",
    "method=flddpg",
    "env.worlds=[train-0,train-2]",
    "env.episode_length=8",
    "run.chunk_episodes=1",
    "run.checkpoint_every=1",
    "offpolicy.hidden=8",
    "offpolicy.depth=1",
    "offpolicy.batch_size=4",
    "offpolicy.buffer_size=32",
    "offpolicy.train_every=2",
    "fed.period=1",
]


@pytest.fixture
def toy():
    learner_table.register(toy_learner.ROW)
    yield toy_learner.ROW
    learner_table.unregister("toy")


def test_the_config_refuses_an_unregistered_learner():
    with pytest.raises(ConfigError, match="learner: 'toy' is not one of ddpg"):
        load_config(None, TINY + ["run.episodes=2"])


def test_a_toy_learner_trains_resumes_evaluates_and_exports(toy, tmp_path):
    from fedjax_nav.deploy.export import export_run
    from fedjax_nav.evaluation import evaluate_run
    from fedjax_nav.training.run import train

    out = tmp_path / "run"
    train(load_config(None, TINY + ["run.episodes=2"]), out, progress=False)
    summary = train(
        load_config(None, TINY + ["run.episodes=3"]), out, progress=False, resume=True, allow_config_change=True
    )
    m = pd.read_csv(out / "metrics.csv")
    assert sorted(m["episode"].unique()) == [0, 1, 2]  # two episodes, then one more after the resume
    assert np.isfinite(m["critic_loss"]).all() and (m["epsilon"] == 0).all()  # no epsilon: its carry is ()
    assert summary["episodes"] == 3 if "episodes" in summary else True
    res = evaluate_run(out, attempts=1, max_steps=8)
    assert len(res.frame) > 0 and res.run.cfg.learner == "toy"
    files = export_run(out, tmp_path / "export", fmt="numpy")
    meta = json.loads((tmp_path / "export" / "meta.json").read_text())
    assert meta["learner"] == "toy" and meta["network"]["kind"] == "heads" and files
