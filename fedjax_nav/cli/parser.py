"""The `fedjax-nav` parser: the program's flags, one subparser per command (`COMMANDS`, in the
order `--help` lists them), each bound to its command in `fedjax_nav.cli.commands`; the flags'
value types and the one-line errors are `fedjax_nav.cli.argtypes`'. argparse only: building
it imports nothing heavy, so that `--help` is instant. Running a command is `fedjax_nav.cli.main`.
"""

from __future__ import annotations

import argparse

from fedjax_nav import __version__
from fedjax_nav.cli.argtypes import (
    MAX_RENDER_STEPS,
    SEED_RANGE,
    OneLineParser,
    bounded_int,
    positive_int,
    robots_per_room,
)
from fedjax_nav.cli.commands import (
    _bench,
    _configs,
    _evaluate,
    _render,
    _reproduce,
    _sweep,
    _worlds,
)
from fedjax_nav.cli.train import _train
from fedjax_nav.robots import ROBOT_MODELS

DESCRIPTION = "`fedjax-nav`: the command line. Each command parses its flags and dispatches to a module."


def _tensorboard_flag(p: argparse.ArgumentParser) -> None:
    """--tensorboard, of the commands that train (train, sweep)."""
    p.add_argument(
        "--tensorboard",
        action="store_true",
        help="also write per-episode scalars (x-axis: agent-steps) and the hyperparameters for TensorBoard "
        "(RUN/tensorboard/; = --set run.tensorboard=true)",
    )


def _batch_flags(p: argparse.ArgumentParser) -> None:
    """The flags of the commands that train batches of runs (sweep, reproduce)."""
    p.add_argument(
        "--memory-budget",
        default=None,
        metavar="SIZE",
        help="memory for one batch of runs, e.g. 4G (default: half of the available memory)",
    )
    p.add_argument(
        "--devices",
        type=positive_int,
        default=None,
        metavar="N",
        help="spread each batch of runs over N devices (default: all; on CPU one per core)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    _tensorboard_flag(p)


def _device_flags(p: argparse.ArgumentParser) -> None:
    """The flags of `train` that spread one run over devices and processes."""
    p.add_argument(
        "--devices",
        type=positive_int,
        default=None,
        metavar="N",
        help="spread the run over N devices (on CPU: N forced host devices); default one, or every "
        "device of every process with --distributed",
    )
    p.add_argument(
        "--shard",
        choices=["clients", "seeds"],
        default="clients",
        help="the axis spread over the devices (default clients: robots; SEDDPG/SNDDPG: seeds)",
    )
    p.add_argument(
        "--distributed",
        action="store_true",
        help="one of several processes (jax.distributed); start one per host with the same flags",
    )
    p.add_argument(
        "--coordinator",
        default=None,
        metavar="HOST:PORT",
        help="process 0's address (default $JAX_COORDINATOR_ADDRESS)",
    )
    p.add_argument("--num-processes", type=positive_int, default=None, help="default $JAX_NUM_PROCESSES")
    p.add_argument("--process-id", type=int, default=None, help="default $JAX_PROCESS_ID")


def add_train(sub) -> None:
    """`train`: one config, all robots and seeds in one program; resume, devices, processes."""
    p = sub.add_parser("train", help="train a method (all robots and seeds in one program)")
    p.add_argument(
        "--config",
        required=False,
        default=None,
        help="a shipped config name or a YAML file, e.g. thesis/flddpg (`fedjax-nav configs` lists them); "
        "without it, --set or --episodes train the defaults (= thesis/flddpg)",
    )
    p.add_argument(
        "--seeds",
        type=int,
        default=None,
        help="number of seeds, trained together (vmap); a multiple of the cores spreads "
        "them over one device per core unless --devices is given",
    )
    p.add_argument(
        "--episodes",
        type=int,
        default=None,
        help="shortcut for --set run.episodes=N; any N: run.chunk_episodes and run.checkpoint_every follow it "
        "unless set (docs/reliability.md)",
    )
    p.add_argument(
        "--out",
        default=None,
        help="run directory (default runs/<method>-<time>-<microseconds>-<pid>); one "
        "holding results is refused unless --overwrite",
    )
    p.add_argument(
        "--set", action="append", metavar="KEY=VALUE", help="override a config field, e.g. offpolicy.gamma=0.99"
    )
    p.add_argument("--resume", metavar="RUN_DIR", default=None, help="continue a run from its latest checkpoint")
    p.add_argument(
        "--from-checkpoint",
        type=int,
        default=None,
        metavar="N",
        help="with --resume: continue from checkpoint N (episodes done) instead of the latest intact one; "
        "the newer checkpoints are removed (the run saves them again, bitwise the same)",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="--out may hold an earlier run's results: remove them first (default: refuse)",
    )
    p.add_argument(
        "--allow-config-change",
        action="store_true",
        help="with --resume: allow changing run.episodes, run.checkpoint_every, run.keep_checkpoints, run.tensorboard "
        "and the learners' divergence bounds: run.max_abs_q, run.max_critic_loss, ppo.max_approx_kl, "
        "ppo.max_abs_entropy (docs/reliability.md)",
    )
    p.add_argument(
        "--memory-budget",
        default=None,
        metavar="SIZE",
        help="refuse a run whose estimated memory exceeds SIZE, e.g. 8G (default: the available memory)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    _tensorboard_flag(p)
    _device_flags(p)
    p.set_defaults(func=_train)


def add_evaluate(sub) -> None:
    """`evaluate`: trained agents in an evaluation world or a held-out suite; several runs compared."""
    p = sub.add_parser("evaluate", help="evaluate trained agents: success, time, efficiency, trajectories")
    p.add_argument("run_dirs", nargs="+", metavar="RUN_DIR", help="training run directories (several: a comparison)")
    p.add_argument("--world", default="eval", help="evaluation world: shipped name or world file (default eval)")
    p.add_argument(
        "--attempts", type=positive_int, default=4, help="attempts per agent and goal (x num_robots for SNDDPG)"
    )
    p.add_argument("--range-noise", type=float, default=0.01, help="std of the lidar noise in m (default 0.01)")
    p.add_argument("--action-noise", type=float, default=0.01, help="std of the action noise, action units (0.01)")
    p.add_argument("--seed", type=bounded_int(*SEED_RANGE), default=0, help="PRNG seed of the evaluation noise")
    p.add_argument(
        "--max-steps", type=positive_int, default=None, help="time-out T (default: the run's episode_length)"
    )
    p.add_argument(
        "--out",
        default=None,
        help="one run: folder for its evaluation files (default RUN/eval/<world>/); several runs: "
        "folder for the comparison (default PARENT/eval/<world>/, PARENT: the first run's parent)",
    )
    p.add_argument(
        "--no-figures", action="store_true", help="skip the PNGs (with --suite: the worst rooms' worst_rooms.png)"
    )
    p.add_argument(
        "--robot",
        default=None,
        metavar="MODEL",
        help=f"evaluate under this robot model ({', '.join(m for m in ROBOT_MODELS if m != 'custom')}; default: "
        "the run's own); kept in RUN/eval/<world or suite>-robot-<MODEL>/ (docs/robot.md)",
    )
    p.add_argument(
        "--suite",
        default=None,
        metavar="NAME|DIR",
        help="evaluate on a held-out suite of generated rooms instead of --world (e.g. heldout: 50 rooms "
        "per family x 4 goals), or on every world file of a folder or a quoted glob ('maps/*.yaml'; each "
        "file a family, named by its stem); results per family with 95%% bootstrap CIs and the tail (worst "
        "10%% of rooms, collision and time-out rates, path-length ratio) in RUN/eval/<NAME or folder name>/",
    )
    p.add_argument(
        "--robots-per-room",
        default=None,
        metavar="K[,K...]",
        type=robots_per_room,
        help="every agent drives K copies of itself together in each room of --suite (placed apart), or in "
        "--world from its start i to its goal i (--attempts times; e.g. --world eval-crossing "
        "--robots-per-room 4), for each K (e.g. 1,2,4,8): success, obstacle and robot-robot collisions, "
        "time-outs, deadlocks per K and family in RUN/eval/<suite or world>-shared/ (docs/shared_rooms.md)",
    )
    p.add_argument(
        "--memory-budget",
        default=None,
        metavar="SIZE",
        help="refuse an evaluation whose estimated memory exceeds SIZE, e.g. 4G (default: the available memory)",
    )
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="evaluate under a changed traced value (or env.plan_cells), as `train --set`, e.g. --set "
        "env.plan_keep_right=0.45 (docs/shared_rooms.md); one run, into --out (its own eval/ keeps its own values)",
    )
    p.set_defaults(func=_evaluate)


def add_render(sub) -> None:
    """`render`: PNGs of playgrounds with a short random-policy trajectory."""
    p = sub.add_parser("render", help="draw playgrounds with a short random-policy trajectory")
    p.add_argument("worlds", nargs="*", help="world names or files (default: every shipped world)")
    p.add_argument("--out", default="runs/render", help="output folder for the PNGs")
    p.add_argument(
        "--steps",
        type=bounded_int(1, MAX_RENDER_STEPS),
        default=300,
        help=f"random-policy steps to draw (at most {MAX_RENDER_STEPS:,})",
    )
    p.add_argument("--seed", type=bounded_int(*SEED_RANGE), default=0)
    p.set_defaults(func=_render)


def add_sweep(sub) -> None:
    """`sweep`: one sweep file's grid x seeds, resumable."""
    p = sub.add_parser("sweep", help="train a grid of settings x seeds, one compilation per static group")
    p.add_argument("file", help="sweep file (e.g. configs/sweeps/tau.yaml)")
    p.add_argument("--seeds", type=int, default=None, help="seeds per grid point (default: the file's)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a field of every point")
    p.add_argument("--out", default=None, help="output folder (default runs/sweeps/<name>); run again to resume")
    p.add_argument(
        "--only",
        action="append",
        metavar="KEY=VALUE",
        help="train only the points with this value (repeat: values of one key are alternatives, different "
        "keys must all hold, e.g. --only method=iddpg --only method=snddpg); the tables cover the whole sweep",
    )
    _batch_flags(p)
    p.set_defaults(func=_sweep)


def add_reproduce(sub) -> None:
    """`reproduce`: every experiment of thesis chapter 4 into one report folder."""
    p = sub.add_parser("reproduce", help="every experiment of thesis chapter 4 -> figures, tables, report.md")
    p.add_argument(
        "--scale",
        choices=["ci", "thesis"],
        default="ci",
        help="ci: 10 episodes x 64 steps, 2 seeds (minutes); thesis: the thesis's scale (many hours)",
    )
    p.add_argument("--out", default=None, help="report folder (default runs/reproduce-<scale>); run again to resume")
    p.add_argument("--only", default=None, metavar="A,B", help="comma-separated experiments (default: all)")
    p.add_argument("--seeds", type=int, default=None, help="seeds per setting (default: the scale's / each file's)")
    _batch_flags(p)
    p.set_defaults(func=_reproduce)


def add_bench(sub) -> None:
    """`bench`: env, train, sweep and shared-room throughput."""
    p = sub.add_parser("bench", help="measure throughput (env, train, sweep, shared rooms, all)")
    p.add_argument("what", nargs="?", default="env", choices=["env", "train", "sweep", "shared", "all"])
    p.add_argument("--quick", action="store_true", help="small sizes, for a smoke test")
    p.add_argument("--record", default=None, help="append the results to this markdown file")
    p.set_defaults(func=_bench)


def add_export(sub) -> None:
    """`export`: one trained actor as a numpy or ONNX folder (its flags live beside the exporter)."""
    from fedjax_nav.deploy import export as _export  # argparse only at import: --help stays instant

    _export.add_parser(sub)


def add_worlds(sub) -> None:
    """`worlds generate`: one procedural room written as a world file; `worlds import`: a ROS map."""
    p = sub.add_parser(
        "worlds", help="write world files: procedural rooms (docs/generator.md), ROS maps (docs/worlds.md)"
    )
    wsub = p.add_subparsers(dest="worlds_command", required=True)
    g = wsub.add_parser(
        "generate",
        help="draw one procedural room and write it as a world file",
        description="Draw one procedural room (see docs/generator.md) and write it as a world file.",
    )
    g.add_argument(
        "--family",
        required=True,
        help="cylinders, boxes, walls, mixture, a dense one: forest, warehouse, maze, cave, or an indoor one: "
        "office, corridors (docs/generator.md)",
    )
    g.add_argument(
        "--seed",
        required=True,
        help="room seed, an integer in [0, 2**32); seeds >= 2**31 belong to the held-out test suites",
    )
    g.add_argument("--out", required=True, help="output file (.json, or .yaml / .yml)")
    g.add_argument(
        "--set",
        action="append",
        metavar="FIELD=VALUE",
        help="override a RoomSpec field, e.g. cylinders_max=4 (repeatable)",
    )
    g.set_defaults(func=_worlds)
    _add_worlds_import(wsub)


def _add_worlds_import(wsub) -> None:
    """`worlds import`: a ROS map_server map written as a world file (docs/worlds.md)."""
    i = wsub.add_parser(
        "import",
        help="turn a ROS map_server map (YAML + PGM/PNG) into a world file",
        description="Turn a ROS map_server map (its YAML and image) into a world file: occupied and unknown "
        "cells become boxes, starts and goals are drawn in the free space (docs/worlds.md, "
        "'Maps you already have'). `worlds.load` and every --world take the map's YAML directly too.",
    )
    i.add_argument("map", help="the map's YAML file (keys image, resolution, origin, negate, *_thresh)")
    i.add_argument("--out", required=True, help="output world file (.json, or .yaml / .yml)")
    i.add_argument(
        "--starts", type=positive_int, default=None, metavar="N", help="draw N starts (default: the map's own, else 1)"
    )
    i.add_argument(
        "--goals", type=positive_int, default=None, metavar="N", help="draw N goals (default: the map's own, else 1)"
    )
    i.add_argument(
        "--seed", default=None, help="seed of the draw, an integer in [0, 2**32) (default: the map's, else 0)"
    )
    i.add_argument(
        "--cell",
        type=float,
        default=None,
        metavar="M",
        help="coarser cells of M m (a whole multiple of the map's resolution; occupied where any pixel is)",
    )
    i.set_defaults(func=_worlds)


def add_configs(sub) -> None:
    """`configs`: list the shipped configs and sweep files."""
    p = sub.add_parser("configs", help="list the shipped configs and experiment (sweep) files")
    p.set_defaults(func=_configs)


# The commands in the order `--help` lists them.
COMMANDS = (
    add_train,
    add_evaluate,
    add_render,
    add_sweep,
    add_reproduce,
    add_bench,
    add_export,
    add_worlds,
    add_configs,
)


def build_parser() -> argparse.ArgumentParser:
    """The `fedjax-nav` parser: the program's flags, then one subparser per command (`COMMANDS`)."""
    parser = OneLineParser(
        prog="fedjax-nav",
        description=DESCRIPTION,
        epilog="exit codes: 0 done, 2 input error (one line naming the file and field), "
        "3 divergence, 4 failed write (e.g. a full disk), 130 interrupted "
        "(docs/reliability.md)",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    for add in COMMANDS:
        add(sub)
    return parser
