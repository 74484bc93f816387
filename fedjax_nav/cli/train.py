"""`fedjax-nav train`: the run's config from the flags (a preset, `--set`, `--episodes`, or a run to
resume), the devices, the start line, the training and its summary (docs/reliability.md)."""

from __future__ import annotations

import argparse
import functools
import os
import time
from pathlib import Path

from fedjax_nav.cli.commands import UserError, _auto_seed_devices, _is_dir, _is_file, _memory_budget

# What `train` without --config would train: the defaults are this preset's values (fedjax_nav/config/__init__.py).
DEFAULT_PRESET = "thesis/flddpg"


def _train(args: argparse.Namespace) -> int:
    """`train`: a new run (`--config`, `--set`, `--episodes`) or a resumed one (`--resume`), its
    start line, the run (`training.run.train`), its curves and its summary line."""
    from fedjax_nav.training import parallel

    _start_distributed(args)  # before anything starts jax's backends
    import jax

    from fedjax_nav.training.run import train

    budget = _memory_budget(args.memory_budget)
    cfg, out, src = _train_config(args)
    # flushed: piped (`| tee log`, a parent process) the start line is seen when it is said, not at exit
    say = functools.partial(print, flush=True) if jax.process_index() == 0 else (lambda *a, **k: None)
    if _auto_seed_devices(args) and cfg.run.seeds % jax.local_device_count() == 0 and jax.local_device_count() > 1:
        args.devices, args.shard = jax.local_device_count(), "seeds"  # the fast path: whole seeds per device
    try:
        # one device and one process: no mesh, the program of a plain run
        mesh = parallel.make_mesh(args.devices, args.shard) if args.distributed or (args.devices or 1) > 1 else None
        say(_start_line(args, cfg, out, mesh))
        s = train(
            cfg,
            out,
            progress=not args.quiet,
            resume=bool(args.resume),
            mesh=mesh,
            overwrite=args.overwrite,
            allow_config_change=args.allow_config_change,
            memory_budget=budget,
            src=src,
            from_checkpoint=args.from_checkpoint,
        )
    except (FileExistsError, parallel.ShardingError) as e:
        raise UserError(str(e)) from None
    if jax.process_index() == 0:
        from fedjax_nav.analysis.plots import draw_run

        draw_run(out)
    _say_summary(say, s, out)
    return 0


def _start_distributed(args: argparse.Namespace) -> None:
    """`--distributed`: join the other processes (`parallel.initialize_distributed`), which must
    happen before anything starts jax's backends."""
    if not args.distributed:
        return
    from fedjax_nav.training import parallel

    if not (args.out or args.resume):
        raise UserError(
            "--distributed needs --out DIR (or --resume DIR): every process must use the same run directory"
        )
    try:
        parallel.initialize_distributed(args.coordinator, args.num_processes, args.process_id)
    except parallel.ShardingError as e:
        raise UserError(str(e)) from None


def _train_overrides(args: argparse.Namespace) -> list[str]:
    """`--set` and the flags that are shortcuts for one (`--seeds`, `--episodes`, `--tensorboard`)."""
    overrides = list(args.set or [])
    if args.seeds is not None:
        overrides.append(f"run.seeds={args.seeds}")
    if args.episodes is not None:
        overrides.append(f"run.episodes={args.episodes}")
    if args.tensorboard:
        overrides.append("run.tensorboard=true")
    return overrides


def _train_config(args: argparse.Namespace):
    """(config, run directory, where the config came from) of `train`: the run's saved config
    with `--resume` (`_resumed_config`); otherwise `--config` with the overrides, or the defaults
    when `--set` or `--episodes` says what to change. A bare `train` (no --config, no --set, no
    --episodes) is refused: it would train the whole thesis preset, silently (docs/reliability.md)."""
    from fedjax_nav.config import Config, load_config

    overrides = _train_overrides(args)
    src = f"{args.config}{' (with --set)' if overrides else ''}" if args.config else "<defaults> (with --set)"
    if args.from_checkpoint is not None and not args.resume:
        raise UserError("--from-checkpoint N needs --resume RUN_DIR")
    if args.resume:
        return _resumed_config(args, overrides)
    if not (args.config or args.set or args.episodes is not None):
        d = Config()
        raise UserError(
            f"train: no --config; give one (e.g. --config {DEFAULT_PRESET}; `fedjax-nav configs` lists them), or "
            f"--set / --episodes to train the defaults ({DEFAULT_PRESET}: {d.run.episodes} episodes x "
            f"{d.env.episode_length} steps, the whole thesis run)"
        )
    cfg = load_config(args.config, overrides)
    # microseconds and the PID: two runs started in the same second never share a folder
    stamp = f"{time.strftime('%Y%m%d-%H%M%S')}-{time.time() % 1 * 1e6:06.0f}-{os.getpid()}"
    return cfg, args.out or f"runs/{cfg.method}-{stamp}", src


def _resumed_config(args: argparse.Namespace, overrides: list[str]):
    """`train --resume RUN`: the config saved in RUN, or the one asked for (`--config`, `--set`,
    `--episodes`) where it differs only as `--allow-config-change` permits. The chunk of the
    saved run stays: a new `--episodes` that it does not divide is refused in one line."""
    from fedjax_nav import rundir
    from fedjax_nav.config import diff, load_config
    from fedjax_nav.training.preflight import refuse_config_change

    saved_path = Path(args.resume) / rundir.CONFIG
    if not _is_file(saved_path):
        why = (
            f"{args.resume} holds no run to resume (a run killed before it wrote its config): "
            f"start it again with --out {args.resume}"
            if _is_dir(args.resume) and not rundir.results_in(args.resume)
            else f"{args.resume} is not a run directory"
        )
        raise UserError(f"{saved_path}: missing; {why}")
    cfg = load_config(saved_path)  # the run as it was started
    if args.config or overrides:
        asked = load_config(args.config or saved_path, overrides)
        chunk = cfg.run.chunk_episodes
        if asked.run.chunk_episodes != chunk and not any(o.startswith("run.chunk_episodes=") for o in overrides):
            flag = f"--episodes {args.episodes}" if args.episodes is not None else f"run.episodes={asked.run.episodes}"
            raise UserError(
                f"{flag}: {args.resume} trains in chunks of {chunk} episodes "
                f"(run.chunk_episodes in {saved_path}); a resumed run keeps them: give a multiple of {chunk}"
            )
        changed = diff(cfg, asked)
        refuse_config_change(changed, args.allow_config_change, saved_path, "the config asked for on the command line")
        cfg = asked if changed else cfg
    return cfg, args.resume, str(saved_path)


def _start_line(args: argparse.Namespace, cfg, out, mesh) -> str:
    """`training flddpg on train-0, ...: 125 episodes x 1024 steps, 1 seed(s) -> runs/...`."""
    import jax

    verb = "resuming" if args.resume else "training"
    where = (
        ""
        if mesh is None
        else (
            f" on {mesh.size} devices ({args.shard} sharded"
            f"{f', {jax.process_count()} processes' if args.distributed else ''})"
        )
    )
    n_envs = cfg.env.envs_per_robot
    envs = f" ({n_envs} environments per robot)" if n_envs > 1 else ""
    learner = "" if cfg.learner == type(cfg)().learner else f" ({cfg.learner})"  # the default learner unnamed
    return (
        f"{verb} {cfg.method}{learner} on "
        f"{', '.join(cfg.env.worlds)}{envs}: {cfg.run.episodes} episodes x "
        f"{cfg.env.episode_length} steps, {cfg.run.seeds} seed(s){where} -> {out}"
    )


def _say_summary(say, s: dict, out) -> None:
    """The last lines of `train`: the success over the last episodes, and the files written."""
    from fedjax_nav import rundir

    say(
        f"success over the last {s['last_episodes']} episodes: {s['success_last']:.3f} "
        f"+- {s['success_last_std']:.3f} (std over {s['seeds']} seeds); mean reward per step "
        f"{s['reward_last']:.3f}; {s['wall_s']:.0f} s"
    )
    wrote = (rundir.CONFIG, rundir.METRICS, rundir.SUMMARY, rundir.PARAMS, rundir.CURVES, rundir.CHECKPOINTS + "/")
    say(f"wrote {out}/ ({', '.join(wrote)})")
