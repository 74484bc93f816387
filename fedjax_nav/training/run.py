"""The host side of a training run: chunks of compiled episodes, progress, results on disk.

The run directory's files (config.yaml, metrics.csv, summary.json, params.npz, checkpoints/) are
written through `fedjax_nav.rundir`, atomically. The learning-curve figure is drawn by the
layer above (`fedjax_nav.analysis.plots.draw_run`, called by `fedjax-nav train`).
"""

from __future__ import annotations

import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from fedjax_nav import rundir
from fedjax_nav.config import Config
from fedjax_nav.training.hparams import HParams, hparams_from_config
from fedjax_nav.training.metrics import (  # noqa: F401  (re-exported: the run API)
    DivergenceError,
    Interrupted,
    check_finite,
    fed_bytes_per_client,
    fed_bytes_per_round,
    metrics_frame,
    summarize,
)
from fedjax_nav.training.tblog import TensorBoardLog
from fedjax_nav.training.trainer import Trainer

RESUME_CHANGEABLE = (
    "run.episodes",
    "run.checkpoint_every",
    "run.keep_checkpoints",
    "run.max_abs_q",
    "run.max_critic_loss",
    "run.tensorboard",
)


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
) -> dict:
    """Train `cfg.run.seeds` seeds in one program; write the run directory; return the summary.

    Checkpoints every `run.checkpoint_every` episodes and at the end; `resume=True` continues
    from the latest one. Ctrl-C finishes the current chunk, saves and raises `Interrupted`.
    `mesh` (`fedjax_nav.training.parallel.make_mesh`): spread the clients or seeds over its devices, in
    this process or, after `parallel.initialize_distributed`, over every process (each process
    runs this same call; only process 0 writes files).

    Before allocating anything: the memory estimate against `memory_budget` (bytes; default the
    available memory; `ResourceError` naming the field), then `out` is locked (`rundir.RunLock`)
    for the whole run. A new run refuses a folder holding results unless `overwrite` (they are
    removed first); a resumed one refuses a config that differs from the one saved in the
    checkpoint, except `RESUME_CHANGEABLE` fields with `allow_config_change`.
    """
    from fedjax_nav.training import parallel
    from fedjax_nav.training.resources import check_memory

    out = Path(out)
    trainer = Trainer(cfg, pad=parallel.client_padding(mesh, cfg.num_robots))  # masked clients fill the devices
    check_memory(trainer, memory_budget, src)
    writer = parallel.is_writer()
    if not writer:
        return _train(cfg, out, trainer, progress, hp, resume, mesh, overwrite, allow_config_change, writer)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise rundir.RunDirError(f"{out}: exists and is not a directory") from None
    except OSError as e:
        raise rundir.WriteError(f"{out}: cannot create the run directory ({e.strerror or e})") from None
    with rundir.RunLock(out):
        return _train(cfg, out, trainer, progress, hp, resume, mesh, overwrite, allow_config_change, writer)


def _check_resumable(ckpt, cfg: Config, out: Path, allow_config_change: bool) -> None:
    """The config to resume with against the one fingerprinted in the latest checkpoint."""
    from fedjax_nav.config import ConfigError, diff, from_dict
    from fedjax_nav.training.checkpoint import CheckpointError, fingerprint

    step = ckpt.latest()
    saved = ckpt.saved_config(step)  # CheckpointError when there is no checkpoint
    if saved is not None:
        src = f"{ckpt.dir / str(step)}"
        try:
            changed = diff(from_dict(saved, src), cfg)
        except ConfigError:  # saved by another version of the code: compare what it holds
            now = to_dict_flat(cfg)
            changed = [k for k, v in to_dict_flat(saved).items() if k in now and now[k] != v]
        refused = [k for k in changed if not (allow_config_change and k in RESUME_CHANGEABLE)]
        if refused:
            hint = (
                f"--allow-config-change permits only {', '.join(RESUME_CHANGEABLE)}"
                if allow_config_change
                else f"restore the file, start a new run, or pass --allow-config-change (only for "
                f"{', '.join(RESUME_CHANGEABLE)})"
            )
            sha = fingerprint(saved)[:12]
            raise CheckpointError(
                f"{out / rundir.CONFIG}: differs from the config saved in {src} (sha1 {sha}) in "
                f"{', '.join(refused)}; resuming would mix two runs: {hint}"
            )
    if cfg.run.episodes < step:
        raise ConfigError(
            f"{out / rundir.CONFIG}: run.episodes ({cfg.run.episodes}) is below the {step} episodes already done"
        )


def to_dict_flat(cfg) -> dict:
    """{"ddpg.gamma": 0.9, ...} of a Config or of its to_dict mapping."""
    from fedjax_nav.config import to_dict

    d = cfg if isinstance(cfg, dict) else to_dict(cfg)
    return {
        f"{s}.{k}" if isinstance(v, dict) else s: v
        for s, sec in d.items()
        for k, v in (sec.items() if isinstance(sec, dict) else [(s, sec)])
    }


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
) -> dict:
    import signal

    from tqdm.auto import tqdm

    from fedjax_nav.config import to_dict
    from fedjax_nav.training import parallel
    from fedjax_nav.training.checkpoint import Checkpointer

    write = rundir.atomic_write if writer else (lambda path, fn: None)
    if writer and not resume and rundir.results_in(out):  # (other processes: process 0 may have begun)
        if not overwrite:
            raise FileExistsError(
                f"{out}: already holds results ({', '.join(rundir.results_in(out))}); resume it with --resume "
                f"{out}, pick another --out, or pass --overwrite to replace them"
            )
        rundir.clear_results(out)
    ckpt = Checkpointer(out, keep=cfg.run.keep_checkpoints, process=parallel.checkpoint_process(mesh))
    if resume:
        _check_resumable(ckpt, cfg, out, allow_config_change)
    hp = hparams_from_config(cfg) if hp is None else hp
    seeds = jnp.arange(cfg.run.seeds) + cfg.run.seed
    states = trainer.init_seeds(seeds, hp, mesh=mesh)
    K, metrics, start = cfg.run.chunk_episodes, None, 0
    if resume:
        restored, metrics = ckpt.restore(parallel.checkpoint_template(states, mesh))
        states = parallel.from_checkpoint(restored, states, mesh)
        start = int(ckpt.latest())
        all_df = metrics_frame(metrics, cfg, trainer)  # also when the run had already finished
        write(out / rundir.METRICS, lambda p: all_df.to_csv(p, index=False))
    elif ckpt.latest() is not None:
        raise FileExistsError(f"{out}: already holds checkpoints; resume it with --resume {out} or pick another --out")
    if writer:
        rundir.write_config(out, cfg)
    chunk = trainer.compiled_chunk(mesh=mesh, states=states, hp=hp)

    interrupted = []
    old_handler = signal.getsignal(signal.SIGINT)

    def on_sigint(signum, frame):
        if interrupted:  # second Ctrl-C: stop now
            signal.signal(signal.SIGINT, old_handler)
            raise KeyboardInterrupt
        interrupted.append(True)

    signal.signal(signal.SIGINT, on_sigint)
    t0, t_compile, ckpt_s = time.time(), None, 0.0
    bar = tqdm(
        total=cfg.run.episodes,
        initial=start,
        desc=f"{cfg.method} x{cfg.run.seeds} seeds",
        unit="ep",
        disable=not (progress and writer),
    )
    tb = TensorBoardLog(out) if cfg.run.tensorboard and writer else None
    try:
        for first in range(start, cfg.run.episodes, K):
            tc = time.time()
            states, m = chunk(states, hp, jnp.int32(first))
            m = jax.device_get(m)
            if t_compile is None:
                t_compile = time.time() - tc
            try:
                check_finite(m, first, cfg, trainer)
            except DivergenceError as err:  # keep every good episode, say what is kept
                good = err.episode - first  # episodes of this chunk before the bad one
                if good > 0:
                    m = {k: v[:, :good] for k, v in m.items()}
                    metrics = m if metrics is None else {k: np.concatenate([metrics[k], m[k]], axis=1) for k in m}
                n = 0 if metrics is None else int(metrics["reward"].shape[1])
                if n:
                    good_df = metrics_frame(metrics, cfg, trainer)
                    write(out / rundir.METRICS, lambda p, d=good_df: d.to_csv(p, index=False))
                ckpt.wait()
                step = ckpt.latest()
                kept = (
                    f"the last good checkpoint (episode {step}) is kept"
                    if step is not None
                    else "no checkpoint was saved yet (nothing to resume)"
                )
                kept += f"; metrics.csv holds episodes 0-{n - 1}" if n else "; no episode finished"
                raise DivergenceError(f"{err}; {kept}", err.episode) from None
            metrics = m if metrics is None else {k: np.concatenate([metrics[k], m[k]], axis=1) for k in m}
            all_df = metrics_frame(metrics, cfg, trainer)
            write(out / rundir.METRICS, lambda p, d=all_df: d.to_csv(p, index=False))
            done = first + K
            if tb is not None:  # live scalars of this chunk's episodes
                tb.episodes(all_df[all_df.episode >= first])
            last = all_df[all_df.episode == done - 1]
            bar.set_postfix(success=f"{last.reached_goal.mean():.2f}", reward=f"{last.reward.mean():.3f}")
            bar.update(K)
            every = cfg.run.checkpoint_every
            if (every and done % every == 0) or done == cfg.run.episodes or interrupted:
                tk = time.time()
                view = parallel.checkpoint_view(states, mesh)  # a copy: states get donated next
                if writer:
                    ckpt.save(done, view, metrics, config=to_dict(cfg))
                ckpt_s += time.time() - tk
            if interrupted and done < cfg.run.episodes:
                ckpt.wait()
                raise Interrupted(
                    f"interrupted after episode {done}; checkpoint saved. Resume with: fedjax-nav train --resume {out}"
                )
    finally:
        bar.close()
        if tb is not None:
            tb.close()
        signal.signal(signal.SIGINT, old_handler)
        tk = time.time()
        ckpt.close()
        ckpt_s += time.time() - tk
    wall = time.time() - t0
    summary = summarize(all_df, cfg, trainer)
    summary.update(
        {
            "wall_s": wall,
            "first_chunk_s_incl_compile": t_compile,
            "checkpoint_s": ckpt_s,
            "resumed_from_episode": start,
            "jax_backend": jax.default_backend(),
        }
    )
    if mesh is not None:
        summary.update(
            {"devices": int(mesh.size), "shard": ",".join(mesh.axis_names), "processes": jax.process_count()}
        )
    final = states if mesh is None else parallel.checkpoint_view(states, mesh)  # every process joins the gather
    if not writer:
        return summary
    rundir.write_json(out / rundir.SUMMARY, summary)
    rundir.write_params(
        out, jax.tree.map(lambda x: x[:, : trainer.n_real], final.agents) if trainer.pad else final.agents
    )  # without the padding clients
    return summary
