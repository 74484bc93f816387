"""The `fedjax-nav` commands: each takes the parsed flags, imports what it needs (so that
`--help` stays instant) and returns an exit code; `UserError` is an input error (exit 2)."""

from __future__ import annotations

import argparse
import functools
import os
import time
from pathlib import Path

# A noise std (m, or action units) beyond the world bound (`worlds.MAX_COORD`, 1e4) is no lidar or
# actuator; 1e300 became inf in float32 and the evaluation ran on infinite noise.
MAX_NOISE_STD = 1e4

# What `train` without --config would train: the defaults are this preset's values (fedjax_nav/config/__init__.py).
DEFAULT_PRESET = "thesis/flddpg"


class UserError(Exception):
    """An input error the user can fix; printed as one line, exit code 2."""


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
    cfg = load_config(saved_path)
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


def _is_file(path) -> bool:
    try:
        return Path(path).is_file()
    except (OSError, ValueError):  # e.g. a NUL byte or an over-long name
        return False


def _is_dir(path) -> bool:
    try:
        return Path(path).is_dir()
    except (OSError, ValueError):
        return False


def _auto_seed_devices(args: argparse.Namespace) -> bool:
    """`train --seeds N` (N > 1, a multiple of the cores, no --devices, not resuming, one process)
    spreads its seeds over one device per core by default: one XLA CPU device keeps only ~1-1.5
    of the cores busy. Seeds stay whole on a device, so each seed's numbers match a one-device
    run to float32 round-off (docs/scaling.md); `--devices 1` gives the one-device program."""
    cores = os.cpu_count() or 1
    return (
        args.devices is None
        and not args.distributed
        and not args.resume
        and args.seeds is not None
        and args.seeds > 1
        and cores > 1
        and args.seeds % cores == 0
    )


def _evaluate(args: argparse.Namespace) -> int:
    """`evaluate`, holding the lock of every run it evaluates (`_evaluation_lock`) throughout."""
    import contextlib

    budget = _memory_budget(args.memory_budget)  # a bad size is refused before any run is locked
    for flag, std in (("--range-noise", args.range_noise), ("--action-noise", args.action_noise)):
        if not 0 <= std <= MAX_NOISE_STD:  # NaN fails too
            raise UserError(f"{flag}: the noise std must be finite and in [0, {MAX_NOISE_STD:g}], got {std}")
    with contextlib.ExitStack() as locks:
        for run in _evaluated_dirs(args):
            locks.enter_context(_evaluation_lock(run, writes_into=args.out is None or len(args.run_dirs) > 1))
        return _evaluate_locked(args, budget)


def _memory_budget(text: str | None) -> int | None:
    """`--memory-budget SIZE` in bytes (None: the memory available now); a bad size is a UserError."""
    if text is None:
        return None
    from fedjax_nav.config.sweepfile import SweepError
    from fedjax_nav.training.sweep import parse_bytes

    try:
        return parse_bytes(text)
    except (SweepError, ValueError, OverflowError) as e:
        raise UserError(f"--memory-budget: {e}") from None


def _evaluated_dirs(args: argparse.Namespace) -> list[Path]:
    """The run directories (holding a config.yaml) of `evaluate`, each once; any other path is
    named by the loader, and no lock is created in it."""
    from fedjax_nav import rundir

    seen: dict[str, Path] = {}
    for d in args.run_dirs:
        if _is_file(Path(d) / rundir.CONFIG):
            seen.setdefault(os.path.realpath(d), Path(d))
    return list(seen.values())


def _evaluation_lock(run: Path, writes_into: bool):
    """The run's lock (`runlock.RunLock`) for the whole evaluation: its params.npz is read and its
    eval/ written while no `train` (e.g. `--overwrite`) can change the folder; a run in use is
    refused (exit 2). A run folder the user cannot write to is read without a lock when the
    evaluation is written elsewhere (`--out`)."""
    import contextlib

    from fedjax_nav.rundir import WriteError
    from fedjax_nav.runlock import RunLock

    try:
        return RunLock(run, "run directory")
    except WriteError:
        if writes_into:
            raise
        return contextlib.nullcontext()


def _evaluate_locked(args: argparse.Namespace, budget: int | None = None) -> int:
    from fedjax_nav.evaluation import EvalError, evaluate_runs

    common = dict(
        attempts=args.attempts,
        range_noise=args.range_noise,
        action_noise=args.action_noise,
        seed=args.seed,
        max_steps=args.max_steps,
        out=args.out,
        memory_budget=budget,
    )
    try:
        if getattr(args, "suite", None):  # held-out generated rooms, per family with CIs (docs/generalization.md)
            from fedjax_nav.evaluation.suite import evaluate_suite_runs

            evaluate_suite_runs(
                args.run_dirs, args.suite, then=None if args.no_figures else _worst(args.suite), **common
            )
            return 0
        robot = None
        if getattr(args, "robot", None):  # evaluate under another robot model (docs/robot.md)
            from fedjax_nav.robots import ROBOT_MODELS, RobotConfig

            if args.robot not in ROBOT_MODELS:
                raise UserError(f"--robot: unknown model {args.robot!r} (models: {', '.join(ROBOT_MODELS)})")
            robot = RobotConfig(model=args.robot)
        evaluate_runs(args.run_dirs, world=args.world, figures=not args.no_figures, robot=robot, **common)
    except EvalError as e:
        raise UserError(str(e)) from None
    return 0


def _worst(suite: str):
    """After each run's suite evaluation: its worst rooms' episodes drawn beside it (worst_rooms.png)."""
    from fedjax_nav.evaluation.worst_rooms import worst_rooms

    return lambda run_dir, folder: print(f"wrote {worst_rooms(run_dir, suite, folder=folder)}")


def _render(args: argparse.Namespace) -> int:
    from fedjax_nav.env.render import render_worlds

    paths = render_worlds(args.worlds or None, out_dir=args.out, steps=args.steps, seed=args.seed)
    for p in paths:
        print(f"wrote {p}")
    return 0


def _bench(args: argparse.Namespace) -> int:
    from fedjax_nav.experiments.bench_run import main as bench_main

    return bench_main(args)


def _sweep(args: argparse.Namespace) -> int:
    from pathlib import Path

    from fedjax_nav import rundir
    from fedjax_nav.config.sweepfile import SweepError, load_sweep, select
    from fedjax_nav.experiments.sweeps import run_sweep

    try:
        tb = ["run.tensorboard=true"] if args.tensorboard else []
        sweep = load_sweep(args.file, overrides=list(args.set or []) + tb, seeds=args.seeds)
        points = select(sweep, args.only or ())
    except SweepError as e:
        raise UserError(str(e)) from None
    budget = _memory_budget(args.memory_budget)
    out = Path(args.out or f"runs/sweeps/{sweep.name}")
    with _lock(out, "sweep folder"):
        summ, stats = run_sweep(sweep, out, budget=budget, progress=not args.quiet, devices=args.devices, points=points)
    if len(summ):
        cols = ["label", "seeds", "success_last", "success_last_std", "reward_last", "reward_last_std"]
        print(summ[cols].to_string(index=False, float_format=lambda x: f"{x:.3f}"))
    traces = ", ".join(f"{g['method']}: {g['traces']}" for g in stats["groups"]) or "none (all points were done)"
    print(f"{stats['wall_s']:.0f} s; compilations per group: {traces}")
    tables = ", ".join((rundir.SWEEP_SUMMARY, rundir.SWEEP_RESULTS, rundir.CURVES))
    print(f"wrote {stats['tables']}/ ({tables}), {rundir.points_dir(out)}/<id>/ (run directories)")
    return 0


def _reproduce(args: argparse.Namespace) -> int:
    from fedjax_nav.config.sweepfile import SweepError
    from fedjax_nav.experiments.reproduce import reproduce

    only = [x.strip() for x in args.only.split(",") if x.strip()] if args.only is not None else None
    if only == []:  # `--only ''` named no experiment: it must not mean all of them (many hours)
        raise UserError(f"--only {args.only!r}: names no experiment; give comma-separated names, e.g. --only tau,gamma")
    budget = _memory_budget(args.memory_budget)
    try:
        out = Path(args.out or f"runs/reproduce-{args.scale}")
        with _lock(out, "report folder"):
            reproduce(
                args.scale,
                out,
                only=only,
                seeds=args.seeds,
                budget=budget,
                progress=not args.quiet,
                devices=args.devices,
            )
    except SweepError as e:
        raise UserError(str(e)) from None
    return 0


def _lock(out: Path, what: str):
    """Create `out` and hold its lock (`runlock.RunLock`): one writing process per folder."""
    from fedjax_nav.rundir import make_folder
    from fedjax_nav.runlock import RunLock

    make_folder(out, what)
    return RunLock(out, what)


def _worlds(args: argparse.Namespace) -> int:
    from fedjax_nav.worlds.suites import run_cli

    return run_cli(args)


def _configs(args: argparse.Namespace) -> int:
    from fedjax_nav.configs import CONFIG_DIR, names

    print(f"configs (fedjax-nav train --config NAME), in {CONFIG_DIR}:")
    print("  " + "  ".join(names("config")))
    print("experiments (fedjax-nav sweep NAME; reproduce --only NAME):")
    print("  " + "  ".join(names("sweep")))
    return 0
