"""The host side of a training run: chunks of compiled episodes, progress, results on disk.

The run directory's files (config.yaml, metrics.csv, summary.json, params.npz, checkpoints/) are
written through `fedjax_nav.rundir`, atomically. What a run refuses before its loop starts, and
where a resumed one starts, is `fedjax_nav.training.preflight`. The learning-curve figure is drawn
by the layer above (`fedjax_nav.analysis.plots.draw_run`, called by `fedjax-nav train`).
"""

from __future__ import annotations

import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from fedjax_nav import rundir
from fedjax_nav.config import Config, never_updates
from fedjax_nav.runlock import RunLock
from fedjax_nav.training import preflight
from fedjax_nav.training.hparams import HParams, hparams_from_config
from fedjax_nav.training.metrics import (
    DivergenceError,
    Facts,
    Interrupted,
    check_finite,
    metrics_frame,
    summarize,
)
from fedjax_nav.training.tblog import TensorBoardLog
from fedjax_nav.training.trainer import Trainer


def train(
    cfg: Config,
    out: str | Path,
    progress: bool = True,
    hp: HParams | None = None,
    resume: bool = False,
    mesh=None,
    overwrite: bool = False,
    allow_config_change: bool = False,
    memory_budget: int | None = None,
    src: str = "config",
    from_checkpoint: int | None = None,
) -> dict:
    """Train `cfg.run.seeds` seeds in one program; write the run directory; return the summary.

    Checkpoints every `run.checkpoint_every` episodes and at the end; `resume=True` continues
    from the latest one, or from the newest intact one when the latest is damaged (a line on
    stderr names both), or from checkpoint `from_checkpoint` (the newer ones are removed: the run
    saves them again); a run without a complete checkpoint (stopped before its first one) starts
    again from episode 0, saying so. Every way ends bitwise equal to the uninterrupted run.
    Ctrl-C finishes the current chunk, saves and raises `Interrupted`.
    `mesh` (`fedjax_nav.training.parallel.make_mesh`): spread the clients or seeds over its devices, in
    this process or, after `parallel.initialize_distributed`, over every process (each process
    runs this same call; only process 0 writes files).

    Before allocating anything: the memory estimate against `memory_budget` (bytes; default the
    available memory; `ResourceError` naming the field), then `out` is locked (`runlock.RunLock`)
    for the whole run. A new run refuses a folder holding results unless `overwrite` (they are
    removed first); a resumed one refuses a config that differs from the one saved in the
    checkpoint, except the `RESUME_CHANGEABLE` fields with `allow_config_change` (these refusals and
    the choice of the checkpoint to resume from: `fedjax_nav.training.preflight`).
    """
    from fedjax_nav.training import parallel
    from fedjax_nav.training.resources import check_memory

    out = Path(out)
    trainer = Trainer(cfg, pad=parallel.client_padding(mesh, cfg.num_robots))  # masked clients fill the devices
    check_memory(trainer, memory_budget, src)
    writer = parallel.is_writer()
    if writer and (why := never_updates(cfg)):  # a run that only drives (a smoke run): said, not refused
        print(f"warning: {why}", file=sys.stderr, flush=True)
    args = (cfg, out, trainer, progress, hp, resume, mesh, overwrite, allow_config_change, writer, from_checkpoint)
    if not writer:
        return _train(*args)
    rundir.make_folder(out, "run directory")
    with RunLock(out):
        return _train(*args)


# ----------------------------------------------------------------------------- the run, step by step


@dataclass(frozen=True)
class _Run:
    """What every step of one run reads: its config, its folder, the trainer, the mesh (or None),
    whether this process writes files (process 0), and the run's `Checkpointer`."""

    cfg: Config
    out: Path
    trainer: Trainer
    mesh: Any
    writer: bool
    ckpt: Any
    resume: preflight.Resume | None  # None: a new run
    facts: Facts  # what the metrics tables need of the run (`Trainer.facts()`)

    def say(self, line: str) -> None:
        """A one-line notice on stderr (by the writer): what a resume did instead of the obvious."""
        if self.writer:
            print(line, file=sys.stderr, flush=True)

    def write_metrics(self, metrics: dict):
        """The metrics table of episodes 0.. (leaves [seeds, episodes, ...]); metrics.csv by the writer."""
        df = metrics_frame(metrics, self.cfg, self.facts)
        if self.writer:
            rundir.write_metrics(self.out, df)
        return df


def _train(
    cfg: Config,
    out: Path,
    trainer: Trainer,
    progress: bool,
    hp: HParams | None,
    resume: bool,
    mesh,
    overwrite: bool,
    allow_config_change: bool,
    writer: bool,
    from_checkpoint: int | None = None,
) -> dict:
    """prepare (refusals, config.yaml, checkpoints) -> init -> restore -> the loop of chunks (a
    divergence: salvage what is good) -> finish (summary.json, params.npz)."""
    run = _prepare(cfg, out, trainer, resume, overwrite, allow_config_change, mesh, writer, from_checkpoint)
    hp = hparams_from_config(cfg) if hp is None else hp
    states = trainer.init_seeds(jnp.arange(cfg.run.seeds) + cfg.run.seed, hp, mesh=mesh)
    states, metrics, start, all_df = _restore(run, states)
    if writer and resume:  # (a new run wrote it first, in _prepare)
        rundir.write_config(out, cfg)
    chunk = trainer.compiled_chunk(mesh=mesh, states=states, hp=hp)
    t0 = time.time()
    states, all_df, timings = _loop(run, chunk, states, hp, metrics, start, all_df, progress)
    return _finish(run, states, all_df, {"wall_s": time.time() - t0, **timings, "resumed_from_episode": start})


def _prepare(cfg, out, trainer, resume, overwrite, allow_config_change, mesh, writer, from_checkpoint=None) -> _Run:
    """A new run refuses a folder holding results (or clears them, `overwrite`), then writes its
    config.yaml before anything else (so that a run killed at any later moment can be resumed);
    the checkpoints are opened; a resumed run refuses a config that differs from its checkpoint's."""
    from fedjax_nav.training import parallel
    from fedjax_nav.training.checkpoint import Checkpointer

    if writer and not resume:  # (other processes: process 0 may have begun)
        preflight.check_new_folder(out, overwrite)
        rundir.write_config(out, cfg)
    ckpt = Checkpointer(out, keep=cfg.run.keep_checkpoints, process=parallel.checkpoint_process(mesh))
    plan = preflight.plan_resume(ckpt, cfg, out, allow_config_change, from_checkpoint) if resume else None
    return _Run(cfg, out, trainer, mesh, writer, ckpt, plan, trainer.facts())


def _restore(run: _Run, states):
    """(states, metrics, first episode, metrics table). A new run: `states` as they are (refusing
    a folder that holds checkpoints). A resumed one: the first checkpoint of its plan that
    restores (`preflight.Resume`; the newer, damaged ones are removed and a line names both steps), its
    metrics.csv written again from it (also when the run had already finished); or, when none is
    complete, episode 0 (metrics.csv and tensorboard/ of the stopped attempt removed, a line says so)."""
    from fedjax_nav.training import parallel

    plan = run.resume
    if plan is None:
        preflight.refuse_held_checkpoints(run.ckpt, run.out)
        return states, None, 0, None
    if not plan.steps:
        run.say(f"{run.out}: no complete checkpoint (stopped before its first one); starting again from episode 0")
        if run.writer:
            rundir.clear_results(run.out, (rundir.METRICS, rundir.TENSORBOARD))
        return states, None, 0, None
    step, restored, metrics, damaged = run.ckpt.restore_intact(
        parallel.checkpoint_template(states, run.mesh),
        plan.steps,
        check=lambda step: preflight.check_resumable(run.ckpt, run.cfg, run.out, plan.allow_config_change, step),
        damaged=plan.damaged,
        asked=plan.asked,
    )
    removed = run.ckpt.remove_after(step) if run.writer else []  # the run saves those steps again
    if damaged:
        newest = max(damaged)
        also = sorted(set(damaged) - {newest}, reverse=True)
        also_s = f" (checkpoints {', '.join(map(str, also))} too)" if also else ""
        run.say(
            f"{damaged[newest]}{also_s}; resuming from checkpoint {step} instead, the newest intact one "
            f"(removed: {', '.join(map(str, removed or sorted(damaged)))})"
        )
    elif removed:
        run.say(
            f"{run.ckpt.dir}: resuming from checkpoint {step} (--from-checkpoint); the newer ones "
            f"({', '.join(map(str, removed))}) are removed, the run saves them again"
        )
    states = parallel.from_checkpoint(restored, states, run.mesh)
    return states, metrics, int(step), run.write_metrics(metrics)


class _DeferredInterrupt:
    """While installed, the first Ctrl-C only sets `caught` (the chunk finishes, a checkpoint is
    saved, then `Interrupted`); a second one restores the previous handler and stops at once. A
    process started with Ctrl-C ignored (a script's background job, POSIX) keeps ignoring it, as
    Python itself does."""

    def __init__(self):
        self.caught = False
        self.previous = signal.getsignal(signal.SIGINT)
        if self.previous is not signal.SIG_IGN:
            signal.signal(signal.SIGINT, self._on_sigint)

    def _on_sigint(self, signum, frame):
        if self.caught:
            signal.signal(signal.SIGINT, self.previous)
            raise KeyboardInterrupt
        self.caught = True

    def restore(self) -> None:
        signal.signal(signal.SIGINT, self.previous)


def _append(metrics: dict | None, m: dict) -> dict:
    """Episodes `m` after `metrics` (leaves [seeds, episodes, ...])."""
    return m if metrics is None else {k: np.concatenate([metrics[k], m[k]], axis=1) for k in m}


def _loop(run: _Run, chunk, states, hp: HParams, metrics, start: int, all_df, progress: bool):
    """The chunks from episode `start` to `run.episodes`: each one checked (`check_finite`; a
    divergence ends the run through `_salvage`), appended to the metrics, written (metrics.csv,
    TensorBoard), shown on the progress bar and checkpointed every `run.checkpoint_every`
    episodes, at the end and after a Ctrl-C (then `Interrupted`). Returns (states, metrics table,
    timings)."""
    from tqdm.auto import tqdm

    from fedjax_nav.config import to_dict
    from fedjax_nav.training import parallel

    cfg, ckpt = run.cfg, run.ckpt
    K, every = cfg.run.chunk_episodes, cfg.run.checkpoint_every
    sigint = _DeferredInterrupt()
    t_compile, ckpt_s = None, 0.0
    bar = tqdm(
        total=cfg.run.episodes,
        initial=start,
        desc=f"{cfg.method} x{cfg.run.seeds} seeds",
        unit="ep",
        disable=not (progress and run.writer),
    )
    tb = TensorBoardLog(run.out, cfg) if cfg.run.tensorboard and run.writer else None
    if tb is not None and all_df is not None and len(all_df):  # resumed: the episodes already done
        tb.remember(all_df[all_df.episode < start])
    try:
        for first in range(start, cfg.run.episodes, K):
            tc = time.time()
            states, m = chunk(states, hp, jnp.int32(first))
            m = jax.device_get(m)
            if t_compile is None:
                t_compile = time.time() - tc
            try:
                check_finite(m, first, cfg, run.facts)
            except DivergenceError as err:
                raise _salvage(run, err, first, metrics, m) from None
            metrics = _append(metrics, m)
            all_df = run.write_metrics(metrics)
            done = first + K
            if tb is not None:  # live scalars of this chunk's episodes
                tb.episodes(all_df[all_df.episode >= first])
            last = all_df[all_df.episode == done - 1]
            bar.set_postfix(
                success=f"{last.reached_goal.mean():.2f}",
                goal_share=f"{rundir.share_of_goals(last.goals, last.collisions):.2f}",  # what the environments did
                reward=f"{last.reward.mean():.3f}",
            )
            bar.update(K)
            if (every and done % every == 0) or done == cfg.run.episodes or sigint.caught:
                tk = time.time()
                view = parallel.checkpoint_view(states, run.mesh)  # a copy: states get donated next
                if run.writer:
                    ckpt.save(done, view, metrics, config=to_dict(cfg))
                ckpt_s += time.time() - tk
            if sigint.caught and done < cfg.run.episodes:
                ckpt.wait()
                resume_with = f"fedjax-nav train --resume {run.out}"
                raise Interrupted(f"interrupted after episode {done}; checkpoint saved. Resume with: {resume_with}")
    finally:
        bar.close()
        if tb is not None:
            tb.close()
        sigint.restore()
        tk = time.time()
        ckpt.close()
        ckpt_s += time.time() - tk
    return states, all_df, {"first_chunk_s_incl_compile": t_compile, "checkpoint_s": ckpt_s}


def _salvage(run: _Run, err: DivergenceError, first: int, metrics: dict | None, m: dict) -> DivergenceError:
    """A divergence in the chunk from episode `first` (its metrics `m`): keep every good episode
    (those before the bad one, in metrics.csv) and the last good checkpoint; the error to raise
    says what is kept."""
    good = err.episode - first  # episodes of this chunk before the bad one
    if good > 0:
        metrics = _append(metrics, {k: v[:, :good] for k, v in m.items()})
    n = 0 if metrics is None else int(metrics["reward"].shape[1])
    if n:
        run.write_metrics(metrics)
    run.ckpt.wait()
    step = run.ckpt.latest()
    kept = (
        f"the last good checkpoint (episode {step}) is kept"
        if step is not None
        else "no checkpoint was saved yet (nothing to resume)"
    )
    kept += f"; metrics.csv holds episodes 0-{n - 1}" if n else "; no episode finished"
    return DivergenceError(f"{err}; {kept}", err.episode)


def _finish(run: _Run, states, all_df, timings: dict) -> dict:
    """The summary (in every process: the final gather is a collective) with `timings`; by the
    writer, summary.json and params.npz (without the padding clients)."""
    from fedjax_nav.training import parallel

    summary = summarize(all_df, run.cfg, run.facts)
    summary.update({**timings, "jax_backend": jax.default_backend()})
    mesh = run.mesh
    if mesh is not None:
        summary.update(
            {"devices": int(mesh.size), "shard": ",".join(mesh.axis_names), "processes": jax.process_count()}
        )
    final = states if mesh is None else parallel.checkpoint_view(states, mesh)  # every process joins the gather
    if not run.writer:
        return summary
    rundir.write_json(run.out / rundir.SUMMARY, summary)
    agents = jax.tree.map(lambda x: x[:, : run.trainer.n_real], final.agents) if run.trainer.pad else final.agents
    rundir.write_params(run.out, run.trainer.learner.shared(agents))  # without the padding clients
    return summary
