"""Hyperparameter sweeps: a grid x seeds trained as one vmapped program per static group.

A sweep file (`configs/sweeps/<name>.yaml`):

    name: tau
    description: soft vs hard FedAvg (thesis Fig. 14)
    base: ../thesis/flddpg.yaml      # relative to the sweep file
    seeds: 8
    set: [run.episodes=125]          # optional: overrides applied to every point
    grid:                            # cartesian product; `base` may also be a grid key
      fed.tau: [0.0, 0.5, 1.0]
    thesis:                          # optional: the thesis's numbers, for the report
      by: fed.tau                    # a grid key, or `method`
      success_last: {0.0: 0.30, 0.5: 0.79, 1.0: 0.41}

How it runs. Every grid point becomes a resolved `Config`. Points whose fields differ only in
`HParams` (gamma, rho, lr, T_train, T_target, epsilon, tau, beta, the federated period, the
buffer capacity) fall into one *group*: one `Trainer`, one compilation, and every (point, seed)
of the group is one row of the leading batch axis (the trainer's seed vmap). A field that is
the same in every row stays a scalar, so the T_train / period gates stay real conds; a swept
period becomes a per-row select (correct, and only the cheap federated step pays it). Buffer
capacities are allocated at the group's largest and the active capacity is traced. Any other
difference (method, episode length, networks, worlds) is a separate group.

Rows are packed into batches that fit a memory budget; every batch of a group is padded to one
size (by repeating its last row, whose results are dropped) so that the group compiles once.
Each point is saved as a normal run directory (`points/<id>/`: config.yaml, metrics.csv,
summary.json, params.npz: `fedjax-nav evaluate` reads it) as soon as its batch finishes; a
finished point is skipped when the sweep runs again, and a batch in flight resumes from its
latest checkpoint (`batches/<id>/checkpoints`). The point id hashes the resolved config, so
two sweeps (or two experiments of `reproduce`) that ask for the same run share it.
"""

from __future__ import annotations

import hashlib
import itertools
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fedjax_nav.config import (
    Config,
    ConfigError,
    DDPGConfig,
    apply_overrides,
    from_dict,
    get,
    read_yaml,
    to_dict,
    traced_fields,
)

BOOKKEEPING = ("run.seeds", "run.checkpoint_every", "run.keep_checkpoints", "ddpg.buffer_alloc", "run.tensorboard")
SWEEP_KEYS = {"name", "description", "base", "seeds", "set", "grid", "points", "thesis", "evaluate"}
STATE_BYTES_FACTOR = 3  # peak memory of a chunk per row / bytes of one TrainState row (donated)


class SweepError(ValueError):
    """A bad sweep file or option; the message names the file and the key."""


# ----------------------------------------------------------------------------- the spec


@dataclass(frozen=True)
class Point:
    values: dict  # swept key -> value as written (`base` -> the config file)
    cfg: Config  # resolved; run.seeds = the seeds this point wants

    @property
    def id(self) -> str:
        return point_id(self.cfg)

    @property
    def label(self) -> str:
        return point_label(self.values, self.cfg)


@dataclass(frozen=True)
class Sweep:
    name: str
    path: Path
    description: str
    seeds: int
    keys: tuple  # the swept keys, in file order
    points: tuple  # Point, grid order
    thesis: dict = field(default_factory=dict)
    evaluate: bool = False  # reproduce: evaluate every point with the protocol


def _flat(cfg: Config) -> dict:
    d = to_dict(cfg)
    out = {"method": d.pop("method")}
    for s, sec in d.items():
        out.update({f"{s}.{k}": v for k, v in sec.items()})
    return out


def point_id(cfg: Config) -> str:
    """12 hex digits of a hash of the config's non-default fields (bookkeeping fields aside), so
    that a field added to the config later, with a default that keeps today's behaviour, leaves
    every existing point's id unchanged."""
    defaults = _flat(Config())
    flat = {
        k: v
        for k, v in _flat(cfg).items()
        if k not in BOOKKEEPING and (k == "method" or v != defaults.get(k, object()))
    }
    return hashlib.sha1(json.dumps(flat, sort_keys=True).encode()).hexdigest()[:12]


def group_key(cfg: Config) -> str:
    """Configs with equal keys share one Trainer and one compilation."""
    flat = {
        k: v for k, v in _flat(cfg).items() if k not in BOOKKEEPING and k not in traced_fields() and k != "run.seed"
    }
    return json.dumps(flat, sort_keys=True)


def point_label(values: dict, cfg: Config) -> str:
    """'key=value, ...' of the swept values; a base config is named by its method when the file is
    the method's preset (thesis/iddpg.yaml -> method=iddpg), else by its file name, so that two
    presets of one method (generalization/iddpg-thesis.yaml, iddpg-procedural.yaml) stay apart."""
    parts = []
    for k, v in values.items():
        if k == "base":
            stem = Path(str(v)).stem
            parts.append(f"method={cfg.method}" if stem == cfg.method else f"config={stem}")
        else:
            parts.append(f"{k}={v}")
    return ", ".join(parts) or cfg.method


def _as_overrides(x: Any, where: str) -> list[str]:
    if x is None:
        return []
    if isinstance(x, dict):
        return [f"{k}={json.dumps(v)}" for k, v in x.items()]
    if isinstance(x, list) and all(isinstance(i, str) for i in x):
        return list(x)
    raise SweepError(f"{where}: must be a mapping key: value or a list of 'key=value' strings")


def load_sweep(
    path: str | Path, overrides: list[str] | tuple = (), seeds: int | None = None, buffer_scale: float = 1.0
) -> Sweep:
    """Read and validate a sweep file; `overrides` apply to every point after the grid values,
    `seeds` replaces the file's seed count; `buffer_scale` multiplies every point's buffer size
    (at least the batch size; `reproduce --scale ci` shrinks runs so that buffers still wrap).
    `path` may be a shipped experiment name (`tau`)."""
    from fedjax_nav.configs import resolve

    path = resolve(path, "sweep")
    try:
        spec = read_yaml(path, "sweep")
    except ConfigError as e:
        raise SweepError(str(e)) from None
    if not isinstance(spec, dict):
        raise SweepError(f"{path}: a sweep file is a mapping with keys {sorted(SWEEP_KEYS)}")
    unknown = set(spec) - SWEEP_KEYS
    if unknown:
        raise SweepError(f"{path}: unknown key(s) {sorted(unknown)}; allowed: {sorted(SWEEP_KEYS)}")
    name = str(spec.get("name") or path.stem)
    n_seeds = int(seeds if seeds is not None else spec.get("seeds", 1))
    if n_seeds < 1:
        raise SweepError(f"{path}: seeds must be >= 1 (got {n_seeds})")
    grid = spec.get("grid") or {}
    if not isinstance(grid, dict):
        raise SweepError(f"{path}: grid must be a mapping key: [values]")
    for k, v in grid.items():
        if not isinstance(v, list) or not v:
            raise SweepError(f"{path}: grid.{k} must be a non-empty list of values")
    extra_points = spec.get("points") or []
    if not isinstance(extra_points, list) or not all(isinstance(p, dict) for p in extra_points):
        raise SweepError(f"{path}: points must be a list of mappings key: value")
    base_default = spec.get("base")
    common = _as_overrides(spec.get("set"), f"{path}: set")
    combos = [dict(zip(grid, vals)) for vals in itertools.product(*grid.values())] if grid else []
    combos += [dict(p) for p in extra_points]
    if not combos:
        combos = [{}]
    keys = tuple(dict.fromkeys(k for c in combos for k in c))
    points = []
    for values in combos:
        base = values.get("base", base_default)
        if base is None:
            raise SweepError(f"{path}: no base config (give `base:` or a grid over base)")
        base_path = (path.parent / str(base)).resolve()
        try:
            data = read_yaml(base_path)
        except ConfigError as e:
            raise SweepError(f"{path}: base {base}: {e}") from None
        grid_over = [f"{k}={json.dumps(v)}" for k, v in values.items() if k != "base"]
        src = f"{path} (point {point_label(values, Config())})"
        try:
            data = apply_overrides(data, common + grid_over + list(overrides) + [f"run.seeds={n_seeds}"], src)
            if buffer_scale != 1.0:
                dd = data.setdefault("ddpg", {})
                size = dd.get("buffer_size", DDPGConfig().buffer_size)
                dd["buffer_size"] = max(int(dd.get("batch_size", DDPGConfig().batch_size)), round(size * buffer_scale))
            cfg = from_dict(data, src)
        except ConfigError as e:
            raise SweepError(str(e)) from None
        # the values as resolved (a buffer size after buffer_scale, a float after YAML's int)
        resolved = {k: (v if k == "base" else get(cfg, k)) for k, v in values.items()}
        points.append(Point(resolved, cfg))
    thesis = spec.get("thesis") or {}
    if thesis and thesis.get("by", keys[0] if keys else "method") not in (*keys, "method"):
        raise SweepError(f"{path}: thesis.by must be one of the grid keys {list(keys)} or 'method'")
    return Sweep(
        name,
        path,
        str(spec.get("description", "")),
        n_seeds,
        keys,
        tuple(points),
        thesis,
        bool(spec.get("evaluate", False)),
    )


# ----------------------------------------------------------------------------- planning


@dataclass(frozen=True)
class Job:
    """One point to train: its config (run.seeds = how many seeds) and where it is saved."""

    cfg: Config
    id: str
    prefixes: tuple = ()  # shorter jobs saved from this job's rows when it reaches their episodes


def merge_jobs(points) -> list[Job]:
    """One job per distinct config; a config asked for with several seed counts gets the largest."""
    by_id: dict[str, Config] = {}
    for p in points:
        old = by_id.get(p.id)
        if old is None or p.cfg.run.seeds > old.run.seeds:
            by_id[p.id] = p.cfg
    return [Job(c, i) for i, c in by_id.items()]


def fold_prefixes(jobs: list[Job]) -> list[Job]:
    """Jobs that differ only in `run.episodes` are one run: nothing the program computes depends on
    the number of episodes still to come (epsilon decays per step, rooms and federated rounds count
    from episode 0), so the shorter jobs are the longest one's first episodes. The longest job
    (with the most seeds any of them asks for) keeps the others as `prefixes`, written when it
    reaches their episode counts (`run_batch`); a budget that is not a multiple of
    `run.chunk_episodes` stays a job of its own. A grid over `run.episodes` costs its longest run."""
    from dataclasses import replace

    runs: dict[str, list[Job]] = {}
    for j in jobs:
        runs.setdefault(point_id(replace(j.cfg, run=replace(j.cfg.run, episodes=1))), []).append(j)
    out = []
    for js in runs.values():
        js = sorted(js, key=lambda j: -j.cfg.run.episodes)
        head, rest = js[0], js[1:]
        K = head.cfg.run.chunk_episodes
        pre = tuple(j for j in rest if j.cfg.run.episodes < head.cfg.run.episodes and j.cfg.run.episodes % K == 0)
        out += [j for j in rest if j not in pre]
        if pre:
            seeds = max(j.cfg.run.seeds for j in (head, *pre))
            head = Job(replace(head.cfg, run=replace(head.cfg.run, seeds=seeds)), head.id, pre)
        out.append(head)
    return out


def parse_bytes(text: str | int) -> int:
    """'4G', '512M', '1.5GB', 2e9 -> bytes."""
    if isinstance(text, (int, float)):
        return int(text)
    t = str(text).strip().upper().removesuffix("B")
    mult = {"K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}.get(t[-1:], 1)
    try:
        return int(float(t[:-1] if mult > 1 else t) * mult)
    except ValueError:
        raise SweepError(f"memory budget {text!r}: expected a size such as 4G, 512M or a number of bytes") from None
