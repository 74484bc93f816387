"""plan.json, without training (fedjax_nav/training/sweep/layout.py): the layout a sweep plans is
recorded before anything trains and re-formed from it as recorded, finished points masked; a
batch whose points are all written leaves it with its checkpoints; a damaged plan is one line; a
layout that can no longer run is planned again with a line. The kills themselves, trained and
compared bitwise: tests/test_sweep_resume.py (full tier)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
import yaml

from fedjax_nav import rundir
from fedjax_nav.config import sweepfile as sf
from fedjax_nav.training import sweep as sw
from fedjax_nav.training.sweep import layout

TINY = [
    "env.episode_length=16",
    "env.worlds=[train-0,train-0,train-0,train-0,train-0]",
    "run.episodes=2",
    "run.chunk_episodes=1",
    "offpolicy.batch_size=8",
    "offpolicy.hidden=16",
    "fed.period=1",
]


@pytest.fixture(scope="module")
def jobs(tmp_path_factory):
    """Four points (buffer size x tau, 2 seeds) and a 1-episode run folded into the last."""
    folder = tmp_path_factory.mktemp("layout")
    spec = {
        "name": "layout",
        "base": "thesis/flddpg",
        "seeds": 2,
        "set": TINY,
        "grid": {"offpolicy.buffer_size": [48, 16], "fed.tau": [0.0, 1.0]},
        "points": [{"offpolicy.buffer_size": 16, "fed.tau": 1.0, "run.episodes": 1}],
    }
    (folder / "s.yaml").write_text(yaml.safe_dump(spec))
    jobs = sw.merge_jobs(sf.load_sweep(folder / "s.yaml").points)
    (g,) = sw.plan(sw.fold_prefixes(jobs), 2**40)
    per_row, once = sw.point_bytes(g.trainer)
    # two points per batch; "rows": a budget of that many rows
    return {"jobs": jobs, "budget": 4 * per_row + once, "one_point": 2 * per_row + once, "rows": (per_row, once)}


def plan(jobs, out: Path, budget: int, devices: int = 1, lines: list | None = None):
    return layout.plan_batches(jobs, out, budget, devices, (lines if lines is not None else []).append, "sweep t")


def done(out: Path, job: sw.Job) -> None:
    """Mark a point written (what `layout.is_done` reads)."""
    d = rundir.points_dir(out) / job.id
    d.mkdir(parents=True, exist_ok=True)
    rundir.write_json(d / rundir.SUMMARY, {"seeds": job.cfg.run.seeds, "episodes_done": job.cfg.run.episodes})


def layout_of(groups) -> list:
    return [(g.trainer.cfg, g.batch_rows, g.batched, g.batches) for g in groups]


def test_the_plan_is_recorded_and_re_formed_as_recorded(jobs, tmp_path):
    todo, budget = jobs["jobs"], jobs["budget"]
    groups, record = plan(todo, tmp_path, budget)
    want = sw.plan(sw.fold_prefixes(todo), budget)
    assert layout_of(groups) == layout_of(want) and [len(g.batches) for g in groups] == [2]
    (r,) = layout.read(tmp_path)
    assert r.raw == record[0] and r.trainer == want[0].trainer.cfg
    assert [jobs for _, jobs in r.batches] == want[0].batches
    assert [bid for bid, _ in r.batches] == [sw.batch_id(b, 4) for b in want[0].batches]
    # the first batch written, and one point of the second: the second keeps its rows, allocation and
    # batched fields (a fresh plan of its last point: two rows, a buffer of 16)
    first, second = want[0].batches
    for j in (*first, second[0], *second[1].prefixes):
        done(tmp_path, j)
    lines: list[str] = []
    left = [j for j in todo if not layout.is_done(rundir.points_dir(tmp_path), j)]
    (g,) = plan(left, tmp_path, budget, lines=lines)[0]
    assert layout_of([g]) == [(want[0].trainer.cfg, 4, want[0].batched, [second])] and lines == []
    (fresh,) = sw.plan(sw.fold_prefixes(left), budget)
    assert (fresh.batch_rows, fresh.trainer.cfg.offpolicy.buffer_alloc, fresh.batched) == (2, 16, frozenset())
    assert [bid for bid, _ in layout.read(tmp_path)[0].batches] == [sw.batch_id(second, 4)], "batch 1 stayed"


def test_a_finished_batch_leaves_the_plan_with_its_checkpoints(jobs, tmp_path):
    groups, record = plan(jobs["jobs"], tmp_path, jobs["budget"])
    first, second = groups[0].batches
    ckpt = [rundir.batches_dir(tmp_path) / sw.batch_id(b, 4) / rundir.CHECKPOINTS for b in (first, second)]
    for c in ckpt:
        c.mkdir(parents=True)
    record = layout.finish(tmp_path, record, sw.batch_id(first, 4))
    assert not ckpt[0].parent.exists() and ckpt[1].exists()
    assert [bid for bid, _ in layout.read(tmp_path)[0].batches] == [sw.batch_id(second, 4)]
    # killed after the second batch's points were written but before `finish`: the next start drops it
    for j in layout.points_of(second):
        done(tmp_path, j)
    assert plan([], tmp_path, jobs["budget"]) == ([], [])
    assert not rundir.batches_dir(tmp_path).exists()


def test_a_damaged_plan_is_one_line_naming_it(jobs, tmp_path):
    plan(jobs["jobs"], tmp_path, jobs["budget"])
    f = rundir.batch_plan(tmp_path)
    text = f.read_text()
    for bad in (text[:-20], text.replace('"format": 1', '"format": 7'), text.replace('"rows"', '"rowz"')):
        f.write_text(bad)
        with pytest.raises(sf.SweepError) as e:
            plan(jobs["jobs"], tmp_path, jobs["budget"])
        assert "\n" not in str(e.value) and str(e.value).startswith(f"{f}: cannot be read as the sweep's batch plan")


def test_a_layout_that_cannot_run_as_recorded_is_planned_again_with_a_line(jobs, tmp_path):
    plan(jobs["jobs"], tmp_path, jobs["budget"])
    lines: list[str] = []
    groups, record = plan(jobs["jobs"], tmp_path, jobs["budget"], devices=2, lines=lines)
    assert groups[0].batch_rows % 2 == 0 and "2 unfinished batch(es)" in lines[0] and "planned again" in lines[0]
    assert len(record) == 2  # the old layout stays recorded until its points are written
    lines.clear()
    plan(jobs["jobs"], tmp_path, jobs["one_point"], lines=lines)  # a budget it no longer fits
    assert "planned again" in lines[0]


def test_checkpoint_folders_no_plan_names_are_removed_with_a_line(jobs, tmp_path):
    stray = rundir.batches_dir(tmp_path) / "0123456789ab" / rundir.CHECKPOINTS
    stray.mkdir(parents=True)
    lines: list[str] = []
    plan(jobs["jobs"], tmp_path, jobs["budget"], lines=lines)
    assert not stray.parent.exists() and lines == [
        f"sweep t: removed 1 checkpoint folder(s) of batches no plan names ({rundir.batches_dir(tmp_path)})"
    ]


def test_a_layout_padded_to_the_devices_is_re_formed_as_recorded(jobs, tmp_path):
    """Rows padded to the device count may exceed the budget's rows (as `plan` packs, before padding):
    the recorded layout still runs as recorded (on this 2-core machine `sweep` spreads rows over 2)."""
    one_seed = [sw.Job(replace(j.cfg, run=replace(j.cfg.run, seeds=1)), j.id) for j in jobs["jobs"]]
    per_row, once = jobs["rows"]
    groups, _ = plan(one_seed, tmp_path, 3 * per_row + once, devices=2)
    assert [(g.batch_rows, [len(b) for b in g.batches]) for g in groups] == [(4, [3, 1])]
    lines: list[str] = []
    again, _ = plan(one_seed, tmp_path, 3 * per_row + once, devices=2, lines=lines)
    assert layout_of(again) == layout_of(groups) and lines == []
