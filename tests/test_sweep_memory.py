"""A sweep point's memory is train's estimate (`training.resources.memory_estimate`): the sweep's plan
refuses a point exactly where `train` refuses its config, the per-update activations of a large
`offpolicy.batch_size` included (a small replay buffer does not hide them), and packs rows by the same
bytes. Nothing is allocated or compiled: the estimates come from shapes."""

import importlib
import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

from fedjax_nav.config import load_config  # noqa: E402
from fedjax_nav.config.sweepfile import SweepError  # noqa: E402
from fedjax_nav.training import sweep as sw  # noqa: E402
from fedjax_nav.training.resources import ResourceError, check_memory, memory_estimate  # noqa: E402
from fedjax_nav.training.trainer import Trainer  # noqa: E402

plan_module = importlib.import_module("fedjax_nav.training.sweep.plan")  # the package's `plan` is the function
ROOT = Path(__file__).resolve().parents[1]
# FLDDPG (5 networks), a buffer no larger than one huge batch: the activations dominate the estimate
# (100 episodes of 1000 steps: a buffer receives a batch's 100,000 rows; fewer, and the run could
# never update, which the config refuses)
BIG_BATCH = [
    "offpolicy.batch_size=100000",
    "offpolicy.buffer_size=100000",
    "env.episode_length=1000",
    "run.episodes=100",
]


def config(seeds: int, extra=()):
    return load_config(ROOT / "configs/thesis/flddpg.yaml", [*BIG_BATCH, f"run.seeds={seeds}", *extra])


@pytest.mark.parametrize("seeds", [1, 3])
def test_the_sweep_refuses_a_point_exactly_where_train_refuses_its_config(seeds):
    cfg = config(seeds)
    est = memory_estimate(Trainer(cfg))
    assert est["update"] > 0.5 * est["total"], est  # the part a state-only estimate leaves out
    job = sw.Job(cfg, "big-batch")
    check_memory(Trainer(cfg), budget=est["total"])
    (g,) = sw.plan([job], budget=est["total"])
    assert g.batches == [[job]]
    with pytest.raises(ResourceError, match="offpolicy.batch_size"):
        check_memory(Trainer(cfg), budget=est["total"] - 1)
    with pytest.raises(SweepError, match="memory budget"):
        sw.plan([job], budget=est["total"] - 1)


def test_rows_are_packed_by_train_s_bytes_per_seed():
    """Three points of 2 seeds (one group: fed.tau is traced) in a budget of train's estimate of
    5 seeds: 2 points (4 rows) per batch, and the third alone."""
    jobs = [sw.Job(config(2, [f"fed.tau={t}"]), f"tau-{t}") for t in (0.0, 0.5, 1.0)]
    budget = memory_estimate(Trainer(config(5)))["total"]
    (g,) = sw.plan(jobs, budget=budget)
    assert [len(b) for b in g.batches] == [2, 1] and g.batch_rows == 4
    per_row, once = plan_module.point_bytes(g.trainer)
    assert 4 * per_row + once <= budget < 6 * per_row + once


def test_the_default_budget_is_half_the_available_memory(monkeypatch):
    monkeypatch.setattr(plan_module, "available_memory", lambda: 10 * 2**30)
    assert sw.default_memory_budget() == 5 * 2**30
