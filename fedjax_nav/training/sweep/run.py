"""Running a sweep's jobs: one jitted chunk per group, batches resumable from checkpoints in the
layout they were first planned in (`layout`), each finished point written as a run directory
(`points/<id>/`)."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from fedjax_nav import rundir
from fedjax_nav.training.hparams import HParams
from fedjax_nav.training.metrics import Facts, metrics_frame, summarize
from fedjax_nav.training.sweep import layout
from fedjax_nav.training.sweep.layout import is_done
from fedjax_nav.training.sweep.plan import Group, batch_id, batch_rows, default_memory_budget
from fedjax_nav.training.sweep.spec import Job
from fedjax_nav.training.tblog import TensorBoardLog
from fedjax_nav.training.trainer import Trainer

# ----------------------------------------------------------------------------- running


@dataclass
class Compiled:
    """One jitted chunk per group, with a count of its traces (a sweep should trace once); with a
    mesh the rows (the trainer's seed axis) are spread over its devices."""

    trainer: Trainer
    num_episodes: int
    mesh: Any = None
    traces: int = 0
    fn: Callable | None = None

    def __post_init__(self):
        if self.mesh is None:  # else built on the first batch, from its states' shapes
            self.fn = self.trainer.compiled_chunk(self.num_episodes, on_trace=self._count)

    def _count(self):
        self.traces += 1

    def init(self, seeds: np.ndarray, hp: HParams):
        states = self.trainer.init_seeds(jnp.asarray(seeds), hp, mesh=self.mesh)
        if self.fn is None:
            self.fn = self.trainer.compiled_chunk(
                self.num_episodes, mesh=self.mesh, states=states, hp=hp, on_trace=self._count
            )
        return states


def _slice(tree, lo: int, n: int):
    return jax.tree.map(lambda x: x[lo : lo + n], tree)


def write_point(points_dir: Path, job: Job, facts: Facts, params: dict, metrics: dict, extra: dict) -> dict:
    """Save one job as a run directory (what `fedjax-nav train` writes, checkpoints aside): `params`
    its seeds' shared fields (`Learner.shared`), `facts` its group's `metrics.Facts`."""
    d = points_dir / job.id
    d.mkdir(parents=True, exist_ok=True)
    cfg = job.cfg
    df = metrics_frame(metrics, cfg, facts)
    summary = summarize(df, cfg, facts)
    finite = np.asarray(metrics["params_finite"]).all(axis=(1, 2)) & np.isfinite(np.asarray(metrics["reward"])).all(
        axis=(1, 2)
    )
    summary.update(
        {"diverged_seeds": [int(cfg.run.seed + i) for i in np.nonzero(~finite)[0]], "point_id": job.id, **extra}
    )
    rundir.write_config(d, cfg)
    rundir.write_metrics(d, df)
    rundir.write_params(d, params)
    rundir.write_json(d / rundir.SUMMARY, summary)  # last: marks done
    return summary


def run_batch(
    group: Group, compiled: Compiled, jobs: list[Job], batches_dir: Path, points_dir: Path, progress: bool, desc: str
) -> float:
    """Train one batch (resuming its checkpoint if any), save its points, return its wall time. A
    point already written (a batch trained again after a kill between its writes) is not written
    again: its numbers are the ones written (`layout`). The caller removes the checkpoints
    (`layout.finish`) once every point is written."""
    from tqdm.auto import tqdm

    from fedjax_nav.training.checkpoint import Checkpointer

    trainer = group.trainer
    cfg = trainer.cfg
    facts = trainer.facts()
    seeds, hp, spans = batch_rows(jobs, group.batch_rows, group.batched)
    bdir = batches_dir / batch_id(jobs, group.batch_rows)
    states = compiled.init(seeds, hp)
    ckpt = Checkpointer(bdir, keep=2)
    E, K, every = cfg.run.episodes, cfg.run.chunk_episodes, cfg.run.checkpoint_every
    start, metrics = 0, None
    if ckpt.latest() is not None:  # orbax restores into the template's shardings
        states, metrics = ckpt.restore(states)
        start = int(ckpt.latest())
    t0 = time.time()
    tb = {job.id: TensorBoardLog(points_dir / job.id, job.cfg) for job, _, _ in spans if job.cfg.run.tensorboard}
    bar = tqdm(total=E, initial=start, desc=desc, unit="ep", leave=False, disable=not progress)
    try:
        for first in range(start, E, K):
            states, m = compiled.fn(states, hp, jnp.int32(first))
            m = jax.device_get(m)
            metrics = m if metrics is None else {k: np.concatenate([metrics[k], m[k]], axis=1) for k in m}
            for job, lo, n in spans:
                if job.id in tb:  # live scalars of the chunk's episodes (metrics.csv is written at the end)
                    df = metrics_frame({k: v[lo : lo + n] for k, v in m.items()}, job.cfg, facts)
                    tb[job.id].episodes(df.assign(episode=df["episode"] + first))
            done = first + K
            for job, lo, _ in spans:  # shorter budgets of the same run (spec.fold_prefixes)
                for pre in (p for p in job.prefixes if p.cfg.run.episodes == done and not is_done(points_dir, p)):
                    k = pre.cfg.run.seeds
                    extra = {"prefix_of": job.id, "wall_s": (time.time() - t0) * k / group.batch_rows}
                    rows = {key: v[lo : lo + k] for key, v in metrics.items()}
                    shared = trainer.learner.shared(_slice(states, lo, k).agents)
                    write_point(points_dir, pre, facts, shared, rows, extra)
            bar.update(K)
            bar.set_postfix(
                success=f"{(np.asarray(m['goals'][:, -1]) > 0).mean():.2f}",
                goal_share=f"{rundir.share_of_goals(m['goals'][:, -1], m['collisions'][:, -1]):.2f}",
            )
            if every and done % every == 0 and done < E:
                ckpt.save(done, jax.tree.map(jnp.copy, states), metrics)  # a copy: states get donated next
    finally:
        bar.close()
        ckpt.close()
        for log in tb.values():
            log.close()
    wall = time.time() - t0
    for job, lo, n in spans:
        if is_done(points_dir, job):  # written before a kill: kept as written (layout)
            continue
        extra = {
            "sweep_batch_rows": group.batch_rows,
            "sweep_batch_wall_s": wall,
            "wall_s": wall * n / group.batch_rows,
            "resumed_from_episode": start,
        }
        shared = trainer.learner.shared(_slice(states, lo, n).agents)
        write_point(points_dir, job, facts, shared, {k: v[lo : lo + n] for k, v in metrics.items()}, extra)
    return wall


def run_jobs(
    jobs: list[Job],
    out: str | Path,
    budget: int | None = None,
    progress: bool = True,
    desc: str = "sweep",
    echo: Callable[[str], None] = print,
    devices: int | None = None,
) -> dict:
    """Train every job not already saved under `out/points/`. Returns timings and trace counts.

    `devices` (default: every local device): the rows of a batch are spread over that many
    devices (`fedjax-nav sweep` on CPU forces one host device per core: both cores busy)."""
    from tqdm.auto import tqdm

    from fedjax_nav.training import parallel

    devices = jax.local_device_count() if devices is None else devices
    mesh = parallel.make_mesh(devices, "seeds", jax.local_devices()) if devices > 1 else None

    out = Path(out)
    points_dir, batches_dir = rundir.points_dir(out), rundir.batches_dir(out)
    points_dir.mkdir(parents=True, exist_ok=True)
    todo = [j for j in jobs if not is_done(points_dir, j)]
    skipped = len(jobs) - len(todo)
    budget = budget or default_memory_budget()
    groups, record = layout.plan_batches(todo, out, budget, devices, echo, desc)
    heads = [j for g in groups for j in g.jobs]
    again = sum(is_done(points_dir, j) for j in heads)  # rows of a batch re-formed after a kill (layout)
    prefixes = sum(not is_done(points_dir, p) for j in heads for p in j.prefixes)
    n_batches = sum(len(g.batches) for g in groups)
    notes = [f"and {prefixes} saved from their first episodes"] if prefixes else []
    notes += [f"beside {again} done in their batches, trained again as planned, not rewritten"] if again else []
    saved = f" ({'; '.join(notes)})" if notes else ""
    echo(
        f"{desc}: {len(jobs)} point(s), {skipped} already done; {len(heads) - again} to train{saved} in "
        f"{len(groups)} compiled group(s), {n_batches} batch(es) (memory budget {budget / 2**30:.1f} GiB, "
        f"{devices} device(s))"
    )
    stats = {
        "points": len(jobs),
        "skipped": skipped,
        "prefixes": prefixes,
        "groups": [],
        "wall_s": 0.0,
        "devices": devices,
    }
    t0 = time.time()
    outer = tqdm(total=n_batches, desc=desc, unit="batch", disable=not progress or n_batches < 2)
    try:
        for gi, g in enumerate(groups):
            compiled = Compiled(g.trainer, g.trainer.cfg.run.chunk_episodes, mesh)
            walls = []
            for bi, b in enumerate(g.batches):
                what = f"{g.trainer.cfg.method} [{gi + 1}/{len(groups)}] batch {bi + 1}/{len(g.batches)}"
                walls.append(run_batch(g, compiled, b, batches_dir, points_dir, progress, what))
                record = layout.finish(out, record, batch_id(b, g.batch_rows))
                outer.update(1)
            stats["groups"].append(
                {
                    "method": g.trainer.cfg.method,
                    "jobs": len(g.jobs),
                    "batches": len(g.batches),
                    "batch_rows": g.batch_rows,
                    "traces": compiled.traces,
                    "wall_s": sum(walls),
                }
            )
    finally:
        outer.close()
    stats["wall_s"] = time.time() - t0
    return stats
