"""`fedjax-nav`: the command line. Each command parses its flags and dispatches to a module.

This module runs one command line (`main`) and maps its errors to exit codes; the parser is
`fedjax_nav.cli.parser`, the commands `fedjax_nav.cli.commands`. Heavy imports (jax, brax,
matplotlib) happen inside the commands so that `--help` is instant.
Errors end with one line on stderr and an exit code (docs/reliability.md): 2 input errors (bad
config, world file, checkpoint, `--set` value; a run directory in use or holding results; not
enough memory), 3 divergence (NaN/Inf or a divergence bound), 4 a failed write (e.g. a full disk),
130 Ctrl-C (a checkpoint was saved).
"""

from __future__ import annotations

import argparse
import os
import sys

from fedjax_nav.cli.commands import UserError, _auto_seed_devices
from fedjax_nav.cli.parser import build_parser


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


# The most CPU devices one process forces (`--devices N` on CPU: N XLA host devices): N >= 2^31
# made XLA abort with its 94-line flag listing, and a few thousand take minutes to start. On GPUs
# and TPUs a process holds at most a few devices; `--devices` beyond them is refused by the mesh.
MAX_HOST_DEVICES = 256


INTERRUPTED = (
    "interrupted: stopped at once; what was written before is kept "
    "(a run: its last complete checkpoint, `fedjax-nav train --resume RUN` continues)"
)


def main(argv: list[str] | None = None) -> int:
    """`fedjax-nav ...`: the command's exit code (docs/reliability.md). A Ctrl-C the command does
    not handle itself (during start-up or compilation, or a second one while a run saves after
    the first) ends in one line and 130: the process then leaves at once (`os._exit`), because
    an interpreter shutting down under XLA's running threads crashed (a segmentation fault in 3
    of 5 trials) after printing pages of traceback."""
    try:
        return _main(argv)
    except KeyboardInterrupt:
        print(f"error: {INTERRUPTED}", file=sys.stderr)
        sys.stdout.flush()
        sys.stderr.flush()
        if argv is None:  # the console script: leave now; in-process callers get the code back
            os._exit(130)
        return 130


def _main(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    n = _host_devices(args)
    if n > MAX_HOST_DEVICES:  # before XLA reads it
        print(
            f"error: --devices {args.devices}: at most {MAX_HOST_DEVICES} devices per process "
            f"(on CPU each is a forced XLA host device; {os.cpu_count() or 1} cores here)",
            file=sys.stderr,
        )
        return 2
    if (
        n > 1
        and "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", "")
        and "jax" not in sys.modules
    ):  # only before jax starts (in-process callers keep theirs)
        os.environ["XLA_FLAGS"] = (
            os.environ.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={n}"
        ).strip()
    from fedjax_nav.config import ConfigError
    from fedjax_nav.messages import one_line
    from fedjax_nav.rundir import BAD_PATH, RunDirError, WriteError
    from fedjax_nav.training.checkpoint import CheckpointError
    from fedjax_nav.training.run import DivergenceError, Interrupted
    from fedjax_nav.worlds import WorldError

    try:
        return int(args.func(args) or 0)
    except (UserError, WorldError, ConfigError, CheckpointError, RunDirError) as e:
        print(f"error: {one_line(e)}", file=sys.stderr)  # one line, whatever the input held
        return 2
    except DivergenceError as e:  # the message says what was kept
        print(f"error: divergence: {e}", file=sys.stderr)
        return 3
    except BrokenPipeError:  # `fedjax-nav configs | head`: the reader left; nothing to report
        sys.stderr.close()
        return 0
    except WriteError as e:  # a full disk, permissions: the message says what is kept
        print(f"error: {e}", file=sys.stderr)
        return 4
    except OSError as e:  # any other failed write; a path that cannot be written to as asked is bad input
        if e.errno in BAD_PATH:
            why = (e.strerror or str(e)).lower()  # "file name too long", "file exists", "not a directory"
            print(f"error: {one_line(e.filename or '')}: {why}", file=sys.stderr)
            return 2
        where = f"{e.filename}: " if getattr(e, "filename", None) else ""
        # only the training commands have checkpoints to name (evaluate, render, worlds: files)
        kept = " (the last complete checkpoint)" if args.command in ("train", "sweep", "reproduce") else ""
        print(f"error: {where}{e.strerror or e}; files written before{kept} are kept", file=sys.stderr)
        return 4
    except Interrupted as e:
        print(str(e), file=sys.stderr)
        return 130
