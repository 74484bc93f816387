"""The `fedjax-nav` commands: each takes the parsed flags, imports what it needs (so that
`--help` stays instant) and returns an exit code; `UserError` is an input error (exit 2)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

# A noise std (m, or action units) beyond the world bound (`worlds.MAX_COORD`, 1e4) is no lidar or
# actuator; 1e300 became inf in float32 and the evaluation ran on infinite noise.
MAX_NOISE_STD = 1e4


class UserError(Exception):
    """An input error the user can fix; printed as one line, exit code 2."""


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
    """The run's lock for the whole evaluation: its params.npz is read (and, without `--out`, its
    eval/ written) while no `train` (e.g. `--overwrite`) can change the folder; a run in use is
    refused (exit 2). An evaluation written elsewhere (`--out`) only reads the run: it holds a
    reader's lock (`runlock.ReadLock`), so that several evaluations of one run (other settings,
    other suites) run side by side; one written into the run holds the writer's (`runlock.RunLock`).
    A run folder the user cannot write to is read without a lock when the evaluation is written
    elsewhere."""
    import contextlib

    from fedjax_nav.rundir import WriteError
    from fedjax_nav.runlock import ReadLock, RunLock

    try:
        return RunLock(run, "run directory") if writes_into else ReadLock(run, "run directory")
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
        run_dirs = _runs_under(args)
        robot = None
        if getattr(args, "robot", None):  # evaluate under another robot model (docs/robot.md)
            from fedjax_nav.robots import ROBOT_MODELS, RobotConfig

            if args.robot not in ROBOT_MODELS:
                raise UserError(f"--robot: unknown model {args.robot!r} (models: {', '.join(ROBOT_MODELS)})")
            robot = RobotConfig(model=args.robot)
        if getattr(args, "robots_per_room", None):  # K robots per room (docs/shared_rooms.md)
            if robot is not None:
                raise UserError("--robot: not with --robots-per-room (shared rooms run the run's own robot model)")
            from fedjax_nav.evaluation.shared_rooms import evaluate_shared_runs

            if args.out is not None and len(run_dirs) > 1:
                raise UserError("--out: with --robots-per-room it names one run's folder; evaluate the runs one by one")
            kw = {k: common[k] for k in ("range_noise", "action_noise", "seed", "max_steps", "attempts", "out")}
            if not getattr(args, "suite", None):  # a world's own starts and goals, robot i: start i -> goal i
                kw["world"] = args.world
            evaluate_shared_runs(run_dirs, args.suite, args.robots_per_room, figures=not args.no_figures, **kw)
            return 0
        if getattr(args, "suite", None):  # held-out generated rooms, per family with CIs (docs/generalization.md)
            from fedjax_nav.evaluation.suite import evaluate_suite_runs

            then = None if args.no_figures else _worst(args.suite)
            evaluate_suite_runs(run_dirs, args.suite, then=then, robot=robot, **common)
            return 0
        evaluate_runs(run_dirs, world=args.world, figures=not args.no_figures, robot=robot, **common)
    except EvalError as e:
        raise UserError(str(e)) from None
    return 0


def _runs_under(args: argparse.Namespace) -> list:
    """The runs `evaluate` drives: the folders as given, or with --set the one run's agents under
    the changed values (`evaluation.overrides.run_with`), written only into --out: a run's own
    eval/ folders hold what its own config gives."""
    if not getattr(args, "set", None):
        return args.run_dirs
    if len(args.run_dirs) != 1 or args.out is None:
        raise UserError("--set: evaluates one run into --out (a run's own eval/ keeps its own values)")
    from fedjax_nav.evaluation.overrides import run_with

    return [run_with(args.run_dirs[0], args.set)]


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
