"""`fedjax-nav`: the command line. Each command parses its flags and dispatches to a module.

Heavy imports (jax, brax, matplotlib) happen inside the commands so that `--help` is instant.
Input errors (bad config, world file, checkpoint) end with one line and exit code 2.
"""
from __future__ import annotations

import argparse
import os
import sys


class UserError(Exception):
    """An input error the user can fix; printed as one line, exit code 2."""


def _train(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from fedjax_nav import parallel

    if args.distributed:  # before anything starts jax's backends
        if not (args.out or args.resume):
            raise UserError("--distributed needs --out DIR (or --resume DIR): every process must use the same "
                            "run directory")
        try:
            parallel.initialize_distributed(args.coordinator, args.num_processes, args.process_id)
        except parallel.ShardingError as e:
            raise UserError(str(e)) from None

    import jax

    from fedjax_nav.config import diff, load_config
    from fedjax_nav.training.run import train

    overrides = list(args.set or [])
    if args.seeds is not None:
        overrides.append(f"run.seeds={args.seeds}")
    if args.episodes is not None:
        overrides.append(f"run.episodes={args.episodes}")
    if args.resume:
        saved_path = Path(args.resume) / "config.yaml"
        if not saved_path.exists():
            raise UserError(f"{saved_path}: missing; {args.resume} is not a run directory")
        cfg = load_config(saved_path)
        if args.config or overrides:
            asked = load_config(args.config or saved_path, overrides)
            changed = diff(cfg, asked)
            if changed:
                raise UserError(f"{saved_path}: --resume with a changed config; differing fields: {', '.join(changed)}")
        out = args.resume
    else:
        cfg = load_config(args.config, overrides)
        out = args.out or f"runs/{cfg.method}-{time.strftime('%Y%m%d-%H%M%S')}"
    verb = "resuming" if args.resume else "training"
    say = print if jax.process_index() == 0 else (lambda *a, **k: None)
    if _auto_seed_devices(args) and cfg.run.seeds % jax.local_device_count() == 0 and jax.local_device_count() > 1:
        args.devices, args.shard = jax.local_device_count(), "seeds"  # the fast path: whole seeds per device
    try:
        # one device and one process: no mesh, the program of a plain run
        mesh = parallel.make_mesh(args.devices, args.shard) if args.distributed or (args.devices or 1) > 1 else None
        where = "" if mesh is None else (f" on {mesh.size} devices ({args.shard} sharded"
                                         f"{f', {jax.process_count()} processes' if args.distributed else ''})")
        say(f"{verb} {cfg.method} on {', '.join(cfg.env.worlds)}: {cfg.run.episodes} episodes x "
            f"{cfg.env.episode_length} steps, {cfg.run.seeds} seed(s){where} -> {out}")
        s = train(cfg, out, progress=not args.quiet, resume=bool(args.resume), mesh=mesh)
    except (FileExistsError, parallel.ShardingError) as e:
        raise UserError(str(e)) from None
    say(f"success over the last {s['last_episodes']} episodes: {s['success_last']:.3f} "
        f"+- {s['success_last_std']:.3f} (std over {s['seeds']} seeds); mean reward per step "
        f"{s['reward_last']:.3f}; {s['wall_s']:.0f} s")
    say(f"wrote {out}/ (config.yaml, metrics.csv, summary.json, params.npz, learning_curves.png, checkpoints/)")
    return 0


def _auto_seed_devices(args: argparse.Namespace) -> bool:
    """`train --seeds N` (N > 1, a multiple of the cores, no --devices, not resuming, one process)
    spreads its seeds over one device per core by default: one XLA CPU device keeps only ~1-1.5
    of the cores busy. Seeds stay whole on a device, so each seed's numbers match a one-device
    run to float32 round-off (docs/scaling.md); `--devices 1` gives the one-device program."""
    cores = os.cpu_count() or 1
    return (args.devices is None and not args.distributed and not args.resume and args.seeds is not None
            and args.seeds > 1 and cores > 1 and args.seeds % cores == 0)


def _evaluate(args: argparse.Namespace) -> int:
    from fedjax_nav.evaluation import EvalError
    from fedjax_nav.evaluation.protocol import evaluate_runs

    try:
        evaluate_runs(args.run_dirs, world=args.world, attempts=args.attempts, range_noise=args.range_noise,
                      action_noise=args.action_noise, seed=args.seed, max_steps=args.max_steps, out=args.out,
                      figures=not args.no_figures)
    except EvalError as e:
        raise UserError(str(e)) from None
    return 0


def _render(args: argparse.Namespace) -> int:
    from fedjax_nav.env.render import render_worlds

    paths = render_worlds(args.worlds or None, out_dir=args.out, steps=args.steps, seed=args.seed)
    for p in paths:
        print(f"wrote {p}")
    return 0


def _bench(args: argparse.Namespace) -> int:
    from fedjax_nav.bench import main as bench_main

    return bench_main(args)


def _sweep(args: argparse.Namespace) -> int:
    from pathlib import Path

    from fedjax_nav.sweep import SweepError, load_sweep, parse_bytes, run_sweep

    try:
        sweep = load_sweep(args.file, overrides=list(args.set or []), seeds=args.seeds)
        budget = parse_bytes(args.memory_budget) if args.memory_budget else None
    except SweepError as e:
        raise UserError(str(e)) from None
    out = Path(args.out or f"runs/sweeps/{sweep.name}")
    summ, stats = run_sweep(sweep, out, budget=budget, progress=not args.quiet, devices=args.devices)
    if len(summ):
        cols = ["label", "seeds", "success_last", "success_last_std", "reward_last", "reward_last_std"]
        print(summ[cols].to_string(index=False, float_format=lambda x: f"{x:.3f}"))
    traces = ", ".join(f"{g['method']}: {g['traces']}" for g in stats["groups"]) or "none (all points were done)"
    print(f"{stats['wall_s']:.0f} s; compilations per group: {traces}")
    print(f"wrote {out}/ (summary.csv, results.csv, learning_curves.png, points/<id>/ run directories)")
    return 0


def _reproduce(args: argparse.Namespace) -> int:
    from fedjax_nav.reproduce import reproduce
    from fedjax_nav.sweep import SweepError, parse_bytes

    only = [x.strip() for x in args.only.split(",") if x.strip()] if args.only else None
    try:
        budget = parse_bytes(args.memory_budget) if args.memory_budget else None
        reproduce(args.scale, args.out, only=only, seeds=args.seeds, budget=budget, progress=not args.quiet,
                  devices=args.devices)
    except SweepError as e:
        raise UserError(str(e)) from None
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="fedjax-nav", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("train", help="train a method (all robots and seeds in one program)")
    p.add_argument("--config", required=False, default=None, help="YAML config (e.g. configs/thesis/flddpg.yaml)")
    p.add_argument("--seeds", type=int, default=None, help="number of seeds, trained together (vmap); a multiple of the cores spreads "
                   "them over one device per core unless --devices is given")
    p.add_argument("--episodes", type=int, default=None, help="shortcut for --set run.episodes=N")
    p.add_argument("--out", default=None, help="run directory (default runs/<method>-<time>)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a config field, e.g. ddpg.gamma=0.99")
    p.add_argument("--resume", metavar="RUN_DIR", default=None, help="continue a run from its latest checkpoint")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--devices", type=int, default=None, metavar="N",
                   help="spread the run over N devices (on CPU: N forced host devices); default one, or every "
                        "device of every process with --distributed")
    p.add_argument("--shard", choices=["clients", "seeds"], default="clients",
                   help="the axis spread over the devices (default clients: robots; SEDDPG/SNDDPG: seeds)")
    p.add_argument("--distributed", action="store_true",
                   help="one of several processes (jax.distributed); start one per host with the same flags")
    p.add_argument("--coordinator", default=None, metavar="HOST:PORT",
                   help="process 0's address (default $JAX_COORDINATOR_ADDRESS)")
    p.add_argument("--num-processes", type=int, default=None, help="default $JAX_NUM_PROCESSES")
    p.add_argument("--process-id", type=int, default=None, help="default $JAX_PROCESS_ID")
    p.set_defaults(func=_train)

    p = sub.add_parser("evaluate", help="evaluate trained agents: success, time, efficiency, trajectories")
    p.add_argument("run_dirs", nargs="+", metavar="RUN_DIR", help="training run directories (several: a comparison)")
    p.add_argument("--world", default="eval", help="evaluation world: shipped name or world file (default eval)")
    p.add_argument("--attempts", type=int, default=4, help="attempts per agent and goal (x num_robots for SNDDPG)")
    p.add_argument("--range-noise", type=float, default=0.01, help="std of the lidar noise in m (default 0.01)")
    p.add_argument("--action-noise", type=float, default=0.01, help="std of the action noise, action units (0.01)")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed of the evaluation noise")
    p.add_argument("--max-steps", type=int, default=None, help="time-out T (default: the run's episode_length)")
    p.add_argument("--out", default=None, help="folder for the comparison of several runs (default: next to the first)")
    p.add_argument("--no-figures", action="store_true", help="skip the PNGs")
    p.set_defaults(func=_evaluate)

    p = sub.add_parser("render", help="draw playgrounds with a short random-policy trajectory")
    p.add_argument("worlds", nargs="*", help="world names or files (default: every shipped world)")
    p.add_argument("--out", default="runs/render", help="output folder for the PNGs")
    p.add_argument("--steps", type=int, default=300, help="random-policy steps to draw")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=_render)

    p = sub.add_parser("sweep", help="train a grid of settings x seeds, one compilation per static group")
    p.add_argument("file", help="sweep file (e.g. configs/sweeps/tau.yaml)")
    p.add_argument("--seeds", type=int, default=None, help="seeds per grid point (default: the file's)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a field of every point")
    p.add_argument("--out", default=None, help="output folder (default runs/sweeps/<name>); run again to resume")
    p.add_argument("--memory-budget", default=None, metavar="SIZE",
                   help="memory for one batch of runs, e.g. 4G (default: half of the available memory)")
    p.add_argument("--devices", type=int, default=None, metavar="N",
                   help="spread each batch of runs over N devices (default: all; on CPU one per core)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_sweep)

    p = sub.add_parser("reproduce", help="every experiment of thesis chapter 4 -> figures, tables, report.md")
    p.add_argument("--scale", choices=["ci", "thesis"], default="ci",
                   help="ci: 10 episodes x 64 steps, 2 seeds (minutes); thesis: the thesis's scale (many hours)")
    p.add_argument("--out", default=None, help="report folder (default runs/reproduce-<scale>); run again to resume")
    p.add_argument("--only", default=None, metavar="A,B", help="comma-separated experiments (default: all)")
    p.add_argument("--seeds", type=int, default=None, help="seeds per setting (default: the scale's / each file's)")
    p.add_argument("--memory-budget", default=None, metavar="SIZE", help="memory for one batch of runs, e.g. 4G")
    p.add_argument("--devices", type=int, default=None, metavar="N",
                   help="spread each batch of runs over N devices (default: all; on CPU one per core)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=_reproduce)

    p = sub.add_parser("bench", help="measure throughput (env, train, sweep, all)")
    p.add_argument("what", nargs="?", default="env", choices=["env", "train", "sweep", "all"])
    p.add_argument("--quick", action="store_true", help="small sizes, for a smoke test")
    p.add_argument("--record", default=None, help="append the results to this markdown file")
    p.set_defaults(func=_bench)
    return parser


def _host_devices(args: argparse.Namespace) -> int:
    """How many CPU devices to force for this command (GPUs ignore the flag). One XLA CPU device
    keeps only ~1-1.5 of the cores busy on these programs, so the fast paths spread work over one
    device per core: bench measures both; sweep/reproduce spread a batch's rows; train spreads
    `--seeds N` (a multiple of the cores), or the N of `--devices N` (its share per process with
    --distributed)."""
    cores = os.cpu_count() or 1
    if args.command == "bench":
        return cores
    if args.command in ("sweep", "reproduce"):
        return args.devices or cores
    if args.command == "train":
        if (args.devices or 1) > 1:
            env_n = os.environ.get("JAX_NUM_PROCESSES", "1")
            nproc = (args.num_processes or (int(env_n) if env_n.isdigit() else 1)) if args.distributed else 1
            return max(1, args.devices // nproc)
        if _auto_seed_devices(args):
            return cores
    return 1


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    n = _host_devices(args)
    if n > 1 and "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", "") \
            and "jax" not in sys.modules:  # only before jax starts (in-process callers keep theirs)
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") +
                                   f" --xla_force_host_platform_device_count={n}").strip()
    from fedjax_nav.checkpoint import CheckpointError
    from fedjax_nav.config import ConfigError
    from fedjax_nav.training.run import DivergenceError, Interrupted
    from fedjax_nav.worlds import WorldError

    try:
        return int(args.func(args) or 0)
    except (UserError, WorldError, ConfigError, CheckpointError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except DivergenceError as e:
        print(f"error: divergence: {e}; the last good checkpoint is kept (see the run's checkpoints/)", file=sys.stderr)
        return 3
    except Interrupted as e:
        print(str(e), file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
