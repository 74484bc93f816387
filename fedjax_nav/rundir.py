"""The run directory: the one owner of its file names, formats and atomic writes.

Training, sweeps, evaluation, analysis and the CLI read and write run directories only through
this module (it imports the config and nothing above it; the lock of a directory's one writer is
`fedjax_nav.runlock`)::

    RUN/
      config.yaml        the resolved config                      write_config / read_config
      metrics.csv        one row per episode x seed x robot       write_metrics / read_metrics
      summary.json       headline numbers                         write_json / read_json
      params.npz         final actor/critic, leaves [seed, net, ...]  write_params / read_params
      learning_curves.png
      checkpoints/       orbax (fedjax_nav.training.checkpoint)
      tensorboard/       live scalars (fedjax_nav.training.tblog)
      eval/<world>/      one folder per evaluation world          eval_dir / read_eval
        eval.json, eval_episodes.csv, eval_trajectories.npz, eval_bars.png, eval_trajectories.png
      eval/<suite>/      a held-out suite: suite.json, suite_families.csv, suite_episodes.csv,
        worst_rooms.png (fedjax_nav.evaluation.worst_rooms)
      .lock              "PID HOST" of the one process writing it  fedjax_nav.runlock.RunLock

A sweep folder (`fedjax-nav sweep --out`, the report folder of `reproduce`) holds run directories::

    SWEEP/
      points/<id>/       one run directory per point (`fedjax_nav.config.sweepfile.point_id`)
      batches/<id>/      the checkpoints of a batch in flight
      batches/plan.json  the batches as first planned, until each has written its points
      results.csv, summary.csv, sweep.yaml, sweep_stats.json, learning_curves.png   its tables
      tables/<name>/     the tables of a second sweep sharing the folder

Every write goes to a temporary file that is then renamed onto its name, so a reader never sees
a half-written file and a crash leaves the previous version in place.
"""

from __future__ import annotations

import errno
import json
import os
import re
import shutil
from pathlib import Path
from typing import Any, Callable

import numpy as np

CONFIG = "config.yaml"
METRICS = "metrics.csv"
SUMMARY = "summary.json"
PARAMS = "params.npz"
CURVES = "learning_curves.png"
CHECKPOINTS = "checkpoints"
TENSORBOARD = "tensorboard"
EVAL = "eval"
FLEET_STATE = "fleet_state.npz"  # a fleet server's round state, to resume after a kill (fedjax_nav.fleet.server)
FLEET_ROUNDS = "fleet_rounds.csv"  # a fleet's rounds: clients, wall time, bytes each way (fedjax_nav.fleet.strategy)
NETWORKS = ("actor", "critic")

LOCK = ".lock"  # "PID HOST" of the one writer (fedjax_nav.runlock)
LOCK_TAKEOVER = ".lock.takeover"  # held for the moment a stale .lock is replaced
READ_LOCK = ".lock.read"  # READ_LOCK-HOST-PID-XXXXXXXX: "PID HOST" of one of any number of readers (fedjax_nav.runlock)
# What a finished or started run leaves: `train --out` refuses a folder holding any (docs/reliability.md).
RESULTS = (CONFIG, METRICS, SUMMARY, PARAMS, CURVES, CHECKPOINTS, EVAL, TENSORBOARD)

# eval/<world>/: one evaluation (written by fedjax_nav.evaluation.report)
EVAL_JSON = "eval.json"
EVAL_EPISODES = "eval_episodes.csv"
EVAL_TRAJECTORIES = "eval_trajectories.npz"
EVAL_BARS_FIGURE = "eval_bars.png"
EVAL_TRAJECTORIES_FIGURE = "eval_trajectories.png"
# eval/<suite>/: a held-out suite (written by fedjax_nav.evaluation.suite)
SUITE_JSON = "suite.json"
SUITE_FAMILIES = "suite_families.csv"
SUITE_EPISODES = "suite_episodes.csv"
SUITE_WORST_ROOMS_FIGURE = "worst_rooms.png"  # the worst rooms' episodes (fedjax_nav.evaluation.worst_rooms)
# eval/<suite>-shared/: a suite with K robots per room (written by fedjax_nav.evaluation.shared_rooms)
SHARED_SUFFIX = "-shared"
SHARED_JSON = "shared.json"
SHARED_FAMILIES = "shared_families.csv"
SHARED_EPISODES = "shared_episodes.csv"
SHARED_FIGURE = "shared_trajectories.png"  # the largest K's robots in the suite's first room

# a sweep folder
POINTS = "points"
BATCHES = "batches"
BATCH_PLAN = "plan.json"  # in batches/: the layout a resumed sweep keeps (training.sweep.layout)
SWEEP_RESULTS = "results.csv"  # tidy: point x seed x episode x robot, with the swept values
SWEEP_SUMMARY = "summary.csv"  # one row per point
SWEEP_FILE = "sweep.yaml"  # the sweep's description: names the sweep whose tables the folder holds
SWEEP_STATS = "sweep_stats.json"
SWEEP_TABLES = "tables"


# A path the user named that cannot be written as asked (too long, a file where a folder is wanted
# or the other way round, below a file, a symlink loop): bad input, exit 2, not a failed write (4).
BAD_PATH = (errno.ENAMETOOLONG, errno.EEXIST, errno.ENOTDIR, errno.EISDIR, errno.ELOOP)


class RunDirError(ValueError):
    """A run directory or one of its files is missing or unreadable; the message names the file."""


class WriteError(OSError):
    """Writing results failed (a full disk, permissions, ...); the message names the file (exit 4)."""


def make_folder(path: str | Path, what: str = "run directory") -> None:
    """Create the folder `path` (and its parents). A path that cannot be a folder is bad input, a
    RunDirError (exit 2): it exists as something else, lies below a file (ENOTDIR), is a symlink
    loop (ELOOP) or a name too long for the system (ENAMETOOLONG). Any other failure (a full disk,
    a read-only folder, permissions) is a WriteError (exit 4)."""

    try:
        Path(path).mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise RunDirError(f"{path}: exists and is not a directory") from None
    except OSError as e:
        why = f"cannot create the {what} ({e.strerror or e})"
        if e.errno in (errno.ENOTDIR, errno.ELOOP, errno.ENAMETOOLONG):
            raise RunDirError(f"{path}: {why}") from None
        raise WriteError(f"{path}: {why}") from None


# ----------------------------------------------------------------------------- the results a folder holds


def results_in(directory: str | Path) -> list[str]:
    """The result files and folders (RESULTS) that `directory` already holds."""
    d = Path(directory)
    return [name for name in RESULTS if (d / name).exists()] if d.is_dir() else []


def clear_results(directory: str | Path, names: tuple[str, ...] = RESULTS) -> None:
    """Remove the result files and folders `names` (default: every one, `train --overwrite`) that
    a run directory holds."""
    for name in results_in(directory):
        if name not in names:
            continue
        p = Path(directory) / name
        shutil.rmtree(p) if p.is_dir() and not p.is_symlink() else p.unlink()


# ----------------------------------------------------------------------------- writing


def atomic_write(path: str | Path, write: Callable[[Path], Any]) -> Path:
    """Call write(tmp_path), then rename onto path: readers never see a half-written file."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        write(tmp)
        os.replace(tmp, path)
    except OSError as e:  # e.g. a full disk: keep the old file, leave no half-written temporary
        unlink_quietly(tmp)
        raise WriteError(
            f"{path}: cannot be written ({e.strerror or e}); the previous version of the file "
            "and the last complete checkpoint are kept"
        ) from None
    except BaseException:
        unlink_quietly(tmp)
        raise
    return path


def unlink_quietly(path: Path) -> None:
    """Remove `path` if it is there; a failure to remove it is ignored (a temporary, a lock's guard)."""
    try:
        path.unlink(missing_ok=True)
    except OSError:
        pass


def write_text(path: str | Path, text: str) -> Path:
    return atomic_write(path, lambda p: Path(p).write_text(text))


def jsonable(x):
    """Plain JSON types from numpy scalars/arrays, tuples and non-string keys."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    return x


def write_json(path: str | Path, obj) -> Path:
    return write_text(path, json.dumps(jsonable(obj), indent=1))


def write_config(run_dir: str | Path, cfg) -> Path:
    from fedjax_nav.config import save_config

    return atomic_write(Path(run_dir) / CONFIG, lambda p: save_config(cfg, p))


def write_metrics(run_dir: str | Path, df) -> Path:
    return atomic_write(Path(run_dir) / METRICS, lambda p: df.to_csv(p, index=False))


def flatten_params(agents) -> dict[str, np.ndarray]:
    """{"actor/params/Dense_0/kernel": array, ...}: every leaf of a dict of pytrees (what a
    learner shares: `Learner.shared(agents)`), or of the `actor` and `critic` of an AgentState-like
    object. A bare array (PPO's log_std) is kept under its own name."""
    import jax

    trees = agents if isinstance(agents, dict) else {name: getattr(agents, name) for name in NETWORKS}
    flat = {}
    for name, tree in trees.items():
        for kp, leaf in jax.tree_util.tree_flatten_with_path(jax.device_get(tree))[0]:
            flat["/".join([name, *(str(getattr(k, "key", k)) for k in kp)])] = np.asarray(leaf)
    return flat


def write_params(run_dir: str | Path, agents) -> Path:
    """params.npz: every actor and critic leaf, [seed, net, ...] for a stacked run."""
    flat = flatten_params(agents)
    return atomic_write(Path(run_dir) / PARAMS, lambda p: np.savez(open(p, "wb"), **flat))


def copy_into(dest: str | Path, files: dict[str, str | Path]) -> list[Path]:
    """Copy files into the folder `dest` (created): {name in dest: source}, each copy atomic (a
    report's small tables to results/, its figures to docs/img/). Returns the copies."""
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    return [atomic_write(dest / name, lambda tmp, src=src: shutil.copyfile(src, tmp)) for name, src in files.items()]


def save_figure(fig, path: str | Path, dpi: int = 100) -> Path:
    """Save a matplotlib Figure atomically (a reader never sees a half-written PNG)."""
    path = Path(path)
    return atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=dpi, format=path.suffix.lstrip(".") or "png"))


# ----------------------------------------------------------------------------- reading


def require(path: str | Path, what: str = "file") -> Path:
    path = Path(path)
    if not path.exists():
        raise RunDirError(f"{path}: no such {what}")
    return path


def run_dir(path: str | Path, need: tuple[str, ...] = (CONFIG,)) -> Path:
    """The run directory `path`, checked to exist and to hold the files in `need`."""
    path = Path(path)
    if not path.is_dir():
        raise RunDirError(f"{path}: no such run directory")
    for name in need:
        if not (path / name).exists():
            raise RunDirError(f"{path}: missing {name} (is this a finished training run directory?)")
    return path


def read_config(run: str | Path):
    """The run's resolved Config (ConfigError names the file and the field)."""
    from fedjax_nav.config import load_config

    return load_config(run_dir(run) / CONFIG)


def read_metrics(run: str | Path, columns: list[str] | None = None):
    """metrics.csv as a DataFrame (only `columns`, when given)."""
    import pandas as pd

    path = run_dir(run, (METRICS,)) / METRICS
    try:
        return pd.read_csv(path, usecols=columns)
    except Exception as e:  # a truncated or foreign file: one line naming it
        raise RunDirError(f"{path}: cannot be read as a metrics table ({type(e).__name__}: {e})") from None


def read_json(path: str | Path) -> dict:
    path = require(path)
    try:
        return json.loads(Path(path).read_text())
    except Exception as e:
        raise RunDirError(f"{path}: cannot be read as JSON ({type(e).__name__}: {e})") from None


def unflatten(flat: dict[str, np.ndarray]) -> dict:
    tree: dict = {}
    for key, value in flat.items():
        node = tree
        parts = key.split("/")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        node[parts[-1]] = value
    return tree


def read_params(run: str | Path, network: str = "actor") -> dict:
    """One network's parameters as a nested dict of arrays [seed, net, ...] from params.npz."""
    path = run_dir(run, (PARAMS,)) / PARAMS
    if not path.is_file():  # a FIFO would block np.load forever, a directory fails obscurely
        raise RunDirError(f"{path}: is not a regular file")
    try:
        with np.load(path) as z:
            flat = {k[len(network) + 1 :]: np.asarray(z[k]) for k in z.files if k.startswith(network + "/")}
    except Exception as e:  # a truncated or foreign file
        raise RunDirError(f"{path}: cannot be read as a params file ({e})") from None
    if not flat:
        raise RunDirError(f"{path}: no '{network}/...' arrays")
    return unflatten(flat)


# ----------------------------------------------------------------------------- evaluations


def world_slug(world: str | Path) -> str:
    """A folder name for an evaluation world: a shipped name as it is, a file by its stem."""
    name = Path(str(world)).stem if any(c in str(world) for c in "/\\.") else str(world)
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "world"


def eval_dir(run: str | Path, world: str | Path) -> Path:
    """Where the evaluation of `run` on `world` is kept: RUN/eval/<world>/."""
    return Path(run) / EVAL / world_slug(world)


def read_eval(run: str | Path, world: str | Path) -> dict | None:
    """The eval.json of `run` on `world` (RUN/eval/<world>/), or None when it was not evaluated."""
    path = eval_dir(run, world) / EVAL_JSON
    return read_json(path) if path.exists() else None


# ----------------------------------------------------------------------------- sweep folders


def points_dir(folder: str | Path) -> Path:
    """SWEEP/points/: the run directories of a sweep's points, one per point id."""
    return Path(folder) / POINTS


def batches_dir(folder: str | Path) -> Path:
    """SWEEP/batches/: the checkpoints of the batches in flight, one folder per batch id."""
    return Path(folder) / BATCHES


def batch_plan(folder: str | Path) -> Path:
    """SWEEP/batches/plan.json: the sweep's batches as first planned (`training.sweep.layout`)."""
    return batches_dir(folder) / BATCH_PLAN


# ----------------------------------------------------------------------------- the metrics table


def success_last_per_seed(df, last: int = 25):
    """Per seed (a pandas Series indexed by seed): the share of the frame's robots that reached the
    goal, per episode, averaged over the run's last `last` episodes. `df`: rows of metrics.csv
    (pass the rows of some robots for their success alone)."""
    tail = df[df["episode"] >= int(df["episode"].max()) + 1 - last]
    return tail.groupby(["seed", "episode"])["reached_goal"].mean().groupby("seed").mean()


def goal_share(df, last: int = 25) -> float:
    """Of the attempts that ended (a goal or a collision) in the frame's last `last` episodes, the
    share that ended at the goal (NaN when none ended). With many environments per robot the
    training success (a robot reached at least one goal in the episode: `reached_goal`) is 1 as soon
    as one of its environments succeeds once; this share is what its environments actually did."""
    tail = df[df["episode"] >= int(df["episode"].max()) + 1 - last]
    return share_of_goals(tail["goals"], tail["collisions"])


def share_of_goals(goals, collisions) -> float:
    """goals / (goals + collisions) over arrays of counts (NaN when nothing ended): `goal_share`'s
    rule, also for the progress bars' raw chunk metrics."""
    g, ended = float(np.sum(goals)), float(np.sum(goals) + np.sum(collisions))
    return g / ended if ended else float("nan")
