"""A sweep killed at any moment and run again ends bitwise equal to the uninterrupted sweep: every
point's parameters and metrics, and results.csv; batch checkpoints go once their points are written
(fedjax_nav/training/sweep/layout.py; docs/reliability.md, "Resume").

One tiny FLDDPG sweep (buffer size x tau, 2 seeds, 2 episodes of 16 steps, a 1-episode run folded
into one of them) packed two points per batch: two batches of one compiled program. The kill is an
exception raised at the moment (`Killed`, as a KeyboardInterrupt is: nothing below catches it),
in-process so that every run shares one compilation; a real kill differs only in skipping the
`finally` blocks that close the progress bar and wait for an asynchronous save (an unfinished
save is ignored on restore: tests/test_checkpoint.py kills real processes).

Before plan.json, two of these moments retrained points in another layout (the remaining points
planned afresh: fewer rows, a smaller buffer allocation) and their parameters differed in the
last bits; `test_the_moments_change_a_fresh_plan` checks that they still would. The full tier
(a cold compilation of the tiny program, then 5-9 s per moment); tests/test_sweep_layout.py checks
plan.json itself without training."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from fedjax_nav import rundir
from fedjax_nav.config import sweepfile as sf
from fedjax_nav.config import to_dict
from fedjax_nav.experiments import sweeps as sweeps_cmd
from fedjax_nav.training import sweep as sw
from fedjax_nav.training.sweep import layout
from fedjax_nav.training.sweep import run as sweep_run

ROOT = Path(__file__).resolve().parents[1]
TINY = [
    "env.episode_length=16",
    "env.worlds=[train-0,train-0,train-0,train-0,train-0]",  # the smallest shipped room
    "run.episodes=2",
    "run.chunk_episodes=1",
    "run.checkpoint_every=1",
    "offpolicy.batch_size=8",
    "offpolicy.hidden=16",
    "fed.period=1",
]


pytestmark = pytest.mark.full


class Killed(BaseException):
    """The kill: not an Exception, so that no handler of the sweep swallows it."""


def tiny_sweep(folder: Path) -> sf.Sweep:
    spec = {
        "name": "resume",
        "base": "thesis/flddpg",
        "seeds": 2,  # with 1 seed a point alone in a batch still matched (fresh plans differed at 2)
        "set": TINY,
        "grid": {"offpolicy.buffer_size": [48, 16], "fed.tau": [0.0, 1.0]},
        "points": [{"offpolicy.buffer_size": 16, "fed.tau": 1.0, "run.episodes": 1}],  # a prefix of the last
    }
    path = folder / "resume.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return sf.load_sweep(path)


_CHUNKS: dict = {}  # one jitted chunk per trainer config, shared by every run of this module


class SharedCompiled(sweep_run.Compiled):
    def __post_init__(self):
        key = (json.dumps(to_dict(self.trainer.cfg), sort_keys=True), self.num_episodes)
        if key not in _CHUNKS:
            super().__post_init__()
            _CHUNKS[key] = self.fn
        self.fn = _CHUNKS[key]


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    folder = tmp_path_factory.mktemp("resume")
    sweep = tiny_sweep(folder)
    (g,) = sw.plan(sw.fold_prefixes(sw.merge_jobs(sweep.points)), 2**40)
    per_row, once = sw.point_bytes(g.trainer)
    budget = 4 * per_row + once  # two points of 2 seeds per batch: two batches
    ref = folder / "reference"
    mp = pytest.MonkeyPatch()
    mp.setattr(sweep_run, "Compiled", SharedCompiled)
    _, stats = sweeps_cmd.run_sweep(sweep, ref, budget=budget, progress=False, echo=lambda s: None)
    assert [(g["batches"], g["batch_rows"]) for g in stats["groups"]] == [(2, 4)]
    yield {"folder": folder, "sweep": sweep, "budget": budget, "ref": ref}
    mp.undo()


def run(setup, out: Path, echo=lambda s: None):
    return sweeps_cmd.run_sweep(setup["sweep"], out, budget=setup["budget"], progress=False, echo=echo)[1]


def kill_at(monkeypatch, moment: str) -> None:
    """Raise Killed at `moment`: the n-th call of a function the sweep calls (MOMENTS)."""
    target, name, n = MOMENTS[moment]
    calls = []

    def dying(fn):
        def call(*a, **k):
            calls.append(1)
            if len(calls) == n:
                raise Killed(moment)
            return fn(*a, **k)

        return call

    real = getattr(target, name)
    if name == "Compiled":  # its chunk: the n-th chunk call dies

        class Dying(real):
            def __post_init__(self):
                super().__post_init__()
                self.fn = dying(self.fn)

        monkeypatch.setattr(target, name, Dying)
    else:
        monkeypatch.setattr(target, name, dying(real))


# moment -> (module, function, its call that dies). Batch 1: chunks 1-2, points 1-2 (48 x tau), then
# its checkpoints go (finish 1); batch 2: chunk 3, the prefix (point 3) and its checkpoint at episode
# 1, chunk 4, points 4-5 (16 x tau), finish 2; then the tables (results.csv).
MOMENTS = {
    "before any checkpoint": (sweep_run, "Compiled", 1),
    "between two batches": (sweep_run, "Compiled", 3),
    "after a batch checkpoint": (sweep_run, "Compiled", 4),
    "between two point writes": (sweep_run, "write_point", 5),
    "before a batch's checkpoints go": (layout, "finish", 2),
    "before results.csv": (sweeps_cmd, "write_tables", 1),
}


def stamps(out: Path) -> dict:
    points = rundir.points_dir(out)
    return {d.name: (d / rundir.SUMMARY).stat().st_mtime_ns for d in points.iterdir() if (d / rundir.SUMMARY).exists()}


def assert_bitwise_equal(out: Path, ref: Path, sweep: sf.Sweep) -> None:
    for p in sweep.points:
        a, b = rundir.points_dir(out) / p.id, rundir.points_dir(ref) / p.id
        za, zb = np.load(a / rundir.PARAMS), np.load(b / rundir.PARAMS)
        assert sorted(za.files) == sorted(zb.files)
        for k in za.files:
            assert za[k].dtype == zb[k].dtype and np.array_equal(za[k], zb[k]), f"{p.label}: {k}"
        assert (a / rundir.METRICS).read_bytes() == (b / rundir.METRICS).read_bytes(), p.label
    assert (out / rundir.SWEEP_RESULTS).read_bytes() == (ref / rundir.SWEEP_RESULTS).read_bytes()


@pytest.mark.parametrize("moment", list(MOMENTS))
def test_a_sweep_killed_at_any_moment_resumes_bitwise_equal(setup, tmp_path, monkeypatch, moment):
    monkeypatch.setattr(sweep_run, "Compiled", SharedCompiled)
    out = tmp_path / "killed"
    with monkeypatch.context() as m:
        kill_at(m, moment)
        with pytest.raises(Killed):
            run(setup, out)
    before = stamps(out)
    if moment != "before results.csv":
        assert rundir.batch_plan(out).exists()
    lines: list[str] = []
    stats = run(setup, out, lines.append)
    assert_bitwise_equal(out, setup["ref"], setup["sweep"])
    assert not rundir.batches_dir(out).exists(), "batch checkpoints or the plan stayed after the sweep"
    assert {k: v for k, v in stamps(out).items() if k in before} == before, "a written point was written again"
    assert not any("planned again" in s or "removed" in s for s in lines), lines
    if moment in ("before a batch's checkpoints go", "before results.csv"):
        assert stats["groups"] == [], "a finished batch was trained again"
    if moment == "after a batch checkpoint":
        last = setup["sweep"].points[3]
        assert rundir.read_json(rundir.points_dir(out) / last.id / rundir.SUMMARY)["resumed_from_episode"] == 1


def test_the_moments_change_a_fresh_plan(setup, tmp_path, monkeypatch):
    """What plan.json prevents: the unfinished points of the batch in flight, planned afresh, get
    another layout (fewer rows, a smaller buffer allocation) than the batch they started in."""
    monkeypatch.setattr(sweep_run, "Compiled", SharedCompiled)
    out = tmp_path / "killed"
    with monkeypatch.context() as m:
        kill_at(m, "between two point writes")
        with pytest.raises(Killed):
            run(setup, out)
    (recorded,) = layout.read(out)
    todo = [j for j in sw.merge_jobs(setup["sweep"].points) if not layout.is_done(rundir.points_dir(out), j)]
    (fresh,) = sw.plan(sw.fold_prefixes(todo), setup["budget"])
    assert len(todo) == 1 and recorded.raw["rows"] == 4 and fresh.batch_rows == 2
    assert fresh.trainer.cfg.offpolicy.buffer_alloc < recorded.trainer.offpolicy.buffer_alloc
