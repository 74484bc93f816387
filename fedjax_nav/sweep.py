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

import dataclasses
import hashlib
import itertools
import json
import os
import shutil
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import yaml

from fedjax_nav.config import (Config, ConfigError, DDPGConfig, apply_overrides, from_dict, read_yaml, save_config,
                               to_dict)
from fedjax_nav.training.run import atomic_write, metrics_frame, save_params, summarize
from fedjax_nav.config import traced_fields
from fedjax_nav.training.hparams import HParams, hparams_from_config, stack_hparams, varying_fields
from fedjax_nav.training.trainer import Trainer

# Fields that change neither the results nor the program: left out of point ids and groups.
BOOKKEEPING = ("run.seeds", "run.checkpoint_every", "run.keep_checkpoints", "ddpg.buffer_alloc")
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


def _get(cfg: Config, dotted: str):
    if dotted == "method":
        return cfg.method
    section, name = dotted.split(".")
    return getattr(getattr(cfg, section), name)


def point_id(cfg: Config) -> str:
    """12 hex digits of the config's hash, without bookkeeping fields (seeds count included)."""
    flat = {k: v for k, v in _flat(cfg).items() if k not in BOOKKEEPING}
    return hashlib.sha1(json.dumps(flat, sort_keys=True).encode()).hexdigest()[:12]


def group_key(cfg: Config) -> str:
    """Configs with equal keys share one Trainer and one compilation."""
    flat = {k: v for k, v in _flat(cfg).items() if k not in BOOKKEEPING and k not in traced_fields()
            and k != "run.seed"}
    return json.dumps(flat, sort_keys=True)


def point_label(values: dict, cfg: Config) -> str:
    parts = []
    for k, v in values.items():
        parts.append(f"method={cfg.method}" if k == "base" else f"{k}={v}")
    return ", ".join(parts) or cfg.method


def _as_overrides(x: Any, where: str) -> list[str]:
    if x is None:
        return []
    if isinstance(x, dict):
        return [f"{k}={json.dumps(v)}" for k, v in x.items()]
    if isinstance(x, list) and all(isinstance(i, str) for i in x):
        return list(x)
    raise SweepError(f"{where}: must be a mapping key: value or a list of 'key=value' strings")


def load_sweep(path: str | Path, overrides: list[str] | tuple = (), seeds: int | None = None,
               buffer_scale: float = 1.0) -> Sweep:
    """Read and validate a sweep file; `overrides` apply to every point after the grid values,
    `seeds` replaces the file's seed count; `buffer_scale` multiplies every point's buffer size
    (at least the batch size; `reproduce --scale ci` shrinks runs so that buffers still wrap)."""
    path = Path(path)
    try:
        spec = read_yaml(path)
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
        resolved = {k: (v if k == "base" else _get(cfg, k)) for k, v in values.items()}
        points.append(Point(resolved, cfg))
    thesis = spec.get("thesis") or {}
    if thesis and thesis.get("by", keys[0] if keys else "method") not in (*keys, "method"):
        raise SweepError(f"{path}: thesis.by must be one of the grid keys {list(keys)} or 'method'")
    return Sweep(name, path, str(spec.get("description", "")), n_seeds, keys, tuple(points), thesis,
                 bool(spec.get("evaluate", False)))


# ----------------------------------------------------------------------------- planning


@dataclass(frozen=True)
class Job:
    """One point to train: its config (run.seeds = how many seeds) and where it is saved."""

    cfg: Config
    id: str


def merge_jobs(points) -> list[Job]:
    """One job per distinct config; a config asked for with several seed counts gets the largest."""
    by_id: dict[str, Config] = {}
    for p in points:
        old = by_id.get(p.id)
        if old is None or p.cfg.run.seeds > old.run.seeds:
            by_id[p.id] = p.cfg
    return [Job(c, i) for i, c in by_id.items()]


def is_done(points_dir: Path, job: Job) -> bool:
    f = points_dir / job.id / "summary.json"
    if not f.exists():
        return False
    try:
        s = json.loads(f.read_text())
    except (OSError, json.JSONDecodeError):
        return False
    return s.get("seeds", 0) >= job.cfg.run.seeds and s.get("episodes_done") == job.cfg.run.episodes


def row_bytes(trainer: Trainer) -> int:
    """Bytes of one row's TrainState (replay buffers dominate)."""
    hp = hparams_from_config(trainer.cfg)
    shapes = jax.eval_shape(lambda k: trainer.init(k, hp), jax.random.key(0))
    return int(sum(np.prod(x.shape) * x.dtype.itemsize for x in jax.tree.leaves(shapes)
                   if hasattr(x, "dtype") and not jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)))


def default_memory_budget() -> int:
    """Half of the memory available now (Linux /proc/meminfo; else half of the physical memory)."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024 // 2
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") // 2


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


@dataclass
class Group:
    key: str
    jobs: list  # Job
    trainer: Trainer
    batches: list = field(default_factory=list)  # lists of jobs
    batch_rows: int = 0  # padded rows per batch (one compilation)
    batched: frozenset = frozenset()  # HParams fields that differ between the group's rows


def plan(jobs: list[Job], budget: int, devices: int = 1) -> list[Group]:
    """Group jobs by static structure and pack each group into equal-size batches within budget
    (rows padded to a multiple of `devices`, over which the rows are spread)."""
    groups: dict[str, list[Job]] = {}
    for j in jobs:
        groups.setdefault(group_key(j.cfg), []).append(j)
    out = []
    for key, js in groups.items():
        alloc = max(j.cfg.buffer_rows for j in js)
        rep = js[0].cfg
        rep = replace(rep, ddpg=replace(rep.ddpg, buffer_alloc=alloc))
        trainer = Trainer(rep)
        per_row = row_bytes(trainer) * STATE_BYTES_FACTOR
        cap = max(1, budget // max(per_row, 1))
        batches, cur, rows = [], [], 0
        for j in js:
            n = j.cfg.run.seeds
            if n > cap:
                raise SweepError(
                    f"point {j.id} ({j.cfg.method}) needs {n} rows of ~{per_row / 2**20:.0f} MiB, more than the "
                    f"memory budget {budget / 2**30:.2f} GiB allows ({cap} rows); raise --memory-budget or use fewer seeds"
                )
            if rows + n > cap:
                batches.append(cur)
                cur, rows = [], 0
            cur.append(j)
            rows += n
        if cur:
            batches.append(cur)
        rows = max(sum(j.cfg.run.seeds for j in b) for b in batches)
        rows = -(-rows // devices) * devices
        out.append(Group(key, js, trainer, batches, rows, varying_fields([hparams_from_config(j.cfg) for j in js])))
    return out


def batch_rows(jobs: list[Job], size: int, batched: frozenset | None = None
               ) -> tuple[np.ndarray, HParams, list[tuple[Job, int, int]]]:
    """Seeds i32[size], HParams (leaves scalar or [size]) and (job, first row, seeds) per job."""
    seeds, hps, spans, r = [], [], [], 0
    for j in jobs:
        n = j.cfg.run.seeds
        seeds += [j.cfg.run.seed + i for i in range(n)]
        hps += [hparams_from_config(j.cfg)] * n
        spans.append((j, r, n))
        r += n
    pad = size - len(seeds)
    seeds += [seeds[-1]] * pad
    hps += [hps[-1]] * pad
    return np.asarray(seeds, np.int32), stack_hparams(hps, batched), spans


def batch_id(jobs: list[Job], size: int) -> str:
    text = json.dumps([[j.id, j.cfg.run.seeds] for j in jobs] + [size])
    return hashlib.sha1(text.encode()).hexdigest()[:12]


# ----------------------------------------------------------------------------- running


@dataclass
class Compiled:
    """One jitted chunk per group, with a count of its traces (a sweep should trace once); with a
    mesh the rows (the trainer's seed axis) are spread over its devices."""

    trainer: Trainer
    num_episodes: int
    mesh: Any = None
    traces: int = 0
    fn: Callable | None = None

    def __post_init__(self):
        if self.mesh is None:  # else built on the first batch, from its states' shapes
            self.fn = self.trainer.compiled_chunk(self.num_episodes, on_trace=self._count)

    def _count(self):
        self.traces += 1

    def init(self, seeds: np.ndarray, hp: HParams):
        states = self.trainer.init_seeds(jnp.asarray(seeds), hp, mesh=self.mesh)
        if self.fn is None:
            self.fn = self.trainer.compiled_chunk(self.num_episodes, mesh=self.mesh, states=states, hp=hp,
                                                  on_trace=self._count)
        return states


def _slice(tree, lo: int, n: int):
    return jax.tree.map(lambda x: x[lo:lo + n], tree)


def write_point(points_dir: Path, job: Job, trainer: Trainer, states, metrics: dict, extra: dict) -> dict:
    """Save one job as a run directory (what `fedjax-nav train` writes, checkpoints aside)."""
    d = points_dir / job.id
    d.mkdir(parents=True, exist_ok=True)
    cfg = job.cfg
    df = metrics_frame(metrics, cfg, trainer)
    summary = summarize(df, cfg, trainer)
    finite = np.asarray(metrics["params_finite"]).all(axis=(1, 2)) & np.isfinite(np.asarray(metrics["reward"])).all(axis=(1, 2))
    summary.update({"diverged_seeds": [int(cfg.run.seed + i) for i in np.nonzero(~finite)[0]],
                    "point_id": job.id, **extra})
    atomic_write(d / "config.yaml", lambda p: save_config(cfg, p))
    atomic_write(d / "metrics.csv", lambda p: df.to_csv(p, index=False))
    save_params(d / "params.npz", states)
    atomic_write(d / "summary.json", lambda p: Path(p).write_text(json.dumps(summary, indent=1)))  # last: marks done
    return summary


def run_batch(group: Group, compiled: Compiled, jobs: list[Job], batches_dir: Path, points_dir: Path,
              progress: bool, desc: str) -> float:
    """Train one batch (resuming its checkpoint if any), save its points, return its wall time."""
    from tqdm.auto import tqdm

    from fedjax_nav.checkpoint import Checkpointer

    trainer = group.trainer
    cfg = trainer.cfg
    seeds, hp, spans = batch_rows(jobs, group.batch_rows, group.batched)
    bdir = batches_dir / batch_id(jobs, group.batch_rows)
    states = compiled.init(seeds, hp)
    ckpt = Checkpointer(bdir, keep=2)
    E, K, every = cfg.run.episodes, cfg.run.chunk_episodes, cfg.run.checkpoint_every
    start, metrics = 0, None
    if ckpt.latest() is not None:  # orbax restores into the template's shardings
        states, metrics = ckpt.restore(states)
        start = int(ckpt.latest())
    t0 = time.time()
    bar = tqdm(total=E, initial=start, desc=desc, unit="ep", leave=False, disable=not progress)
    try:
        for first in range(start, E, K):
            states, m = compiled.fn(states, hp, jnp.int32(first))
            m = jax.device_get(m)
            metrics = m if metrics is None else {k: np.concatenate([metrics[k], m[k]], axis=1) for k in m}
            done = first + K
            bar.update(K)
            bar.set_postfix(success=f"{(np.asarray(m['goals'][:, -1]) > 0).mean():.2f}")
            if every and done % every == 0 and done < E:
                ckpt.save(done, jax.tree.map(jnp.copy, states), metrics)  # a copy: states get donated next
    finally:
        bar.close()
        ckpt.close()
    wall = time.time() - t0
    for job, lo, n in spans:
        extra = {"sweep_batch_rows": group.batch_rows, "sweep_batch_wall_s": wall,
                 "wall_s": wall * n / group.batch_rows, "resumed_from_episode": start}
        write_point(points_dir, job, trainer, _slice(states, lo, n), {k: v[lo:lo + n] for k, v in metrics.items()},
                    extra)
    shutil.rmtree(bdir, ignore_errors=True)
    return wall


def run_jobs(jobs: list[Job], out: str | Path, budget: int | None = None, progress: bool = True,
             desc: str = "sweep", echo: Callable[[str], None] = print, devices: int | None = None) -> dict:
    """Train every job not already saved under `out/points/`. Returns timings and trace counts.

    `devices` (default: every local device): the rows of a batch are spread over that many
    devices (`fedjax-nav sweep` on CPU forces one host device per core: both cores busy)."""
    from tqdm.auto import tqdm

    from fedjax_nav import parallel

    devices = jax.local_device_count() if devices is None else devices
    mesh = parallel.make_mesh(devices, "seeds", jax.local_devices()) if devices > 1 else None

    out = Path(out)
    points_dir, batches_dir = out / "points", out / "batches"
    points_dir.mkdir(parents=True, exist_ok=True)
    todo = [j for j in jobs if not is_done(points_dir, j)]
    skipped = len(jobs) - len(todo)
    budget = budget or default_memory_budget()
    groups = plan(todo, budget, devices) if todo else []
    n_batches = sum(len(g.batches) for g in groups)
    echo(f"{desc}: {len(jobs)} point(s), {skipped} already done; {len(todo)} to train in {len(groups)} "
         f"compiled group(s), {n_batches} batch(es) (memory budget {budget / 2**30:.1f} GiB, {devices} device(s))")
    stats = {"points": len(jobs), "skipped": skipped, "groups": [], "wall_s": 0.0, "devices": devices}
    t0 = time.time()
    outer = tqdm(total=n_batches, desc=desc, unit="batch", disable=not progress or n_batches < 2)
    try:
        for gi, g in enumerate(groups):
            compiled = Compiled(g.trainer, g.trainer.cfg.run.chunk_episodes, mesh)
            walls = []
            for bi, b in enumerate(g.batches):
                what = f"{g.trainer.cfg.method} [{gi + 1}/{len(groups)}] batch {bi + 1}/{len(g.batches)}"
                walls.append(run_batch(g, compiled, b, batches_dir, points_dir, progress, what))
                outer.update(1)
            stats["groups"].append({"method": g.trainer.cfg.method, "jobs": len(g.jobs), "batches": len(g.batches),
                                    "batch_rows": g.batch_rows, "traces": compiled.traces, "wall_s": sum(walls)})
    finally:
        outer.close()
    stats["wall_s"] = time.time() - t0
    if batches_dir.exists() and not any(batches_dir.iterdir()):
        batches_dir.rmdir()
    return stats


# ----------------------------------------------------------------------------- tables


def finished(sweep: Sweep, points_dir: Path):
    """(point, its summary.json) for every point of the sweep that has been trained, in grid order."""
    for p in sweep.points:
        f = Path(points_dir) / p.id / "summary.json"
        if f.exists():
            yield p, json.loads(f.read_text())


def point_summaries(sweep: Sweep, points_dir: Path) -> pd.DataFrame:
    """One row per point: swept values, method, seeds, last-25 success/reward (mean, std)."""
    rows = []
    for p, s in finished(sweep, points_dir):
        row = {"point": p.id, "label": p.label, "method": p.cfg.method}
        row.update({k: (p.cfg.method if k == "base" else v) for k, v in p.values.items()})
        row.update({k: s[k] for k in ("seeds", "episodes_done", "success_last", "success_last_std", "reward_last",
                                      "reward_last_std", "aggregation_events")})
        row["n_comm"] = s["communication"]["n_comm"] if isinstance(s.get("communication"), dict) else None
        row["diverged_seeds"] = len(s.get("diverged_seeds", []))
        row["wall_s"] = s.get("wall_s")
        rows.append(row)
    return pd.DataFrame(rows)


def point_metrics(sweep: Sweep, points_dir: Path) -> pd.DataFrame:
    """The tidy table: grid point x seed x episode x robot, with the swept values as columns."""
    frames = []
    for p in sweep.points:
        f = points_dir / p.id / "metrics.csv"
        if not f.exists():
            continue
        df = pd.read_csv(f)
        df.insert(0, "point", p.id)
        df.insert(1, "label", p.label)
        df.insert(2, "method", p.cfg.method)
        for i, (k, v) in enumerate(p.values.items()):
            df.insert(3 + i, "method_config" if k == "base" else k, v)
        frames.append(df)
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def write_tables(sweep: Sweep, points_dir: Path, out_dir: Path) -> list[Path]:
    """results.csv (tidy), summary.csv (last-25 means) and success.png for one sweep."""
    out_dir.mkdir(parents=True, exist_ok=True)
    res, summ = point_metrics(sweep, points_dir), point_summaries(sweep, points_dir)
    paths = [out_dir / "results.csv", out_dir / "summary.csv"]
    atomic_write(paths[0], lambda p: res.to_csv(p, index=False))
    atomic_write(paths[1], lambda p: summ.to_csv(p, index=False))
    atomic_write(out_dir / "sweep.yaml", lambda p: Path(p).write_text(yaml.safe_dump(describe(sweep), sort_keys=False)))
    paths.append(out_dir / "sweep.yaml")
    if len(res):
        from fedjax_nav.analysis.plots import learning_curves

        runs = {lbl: g for lbl, g in res.groupby("label", sort=False)}
        paths.append(learning_curves(runs, out_dir / "learning_curves.png", title=f"sweep {sweep.name}"))
    return paths


def describe(sweep: Sweep) -> dict:
    return {"name": sweep.name, "file": str(sweep.path), "description": sweep.description, "seeds": sweep.seeds,
            "keys": list(sweep.keys),
            "points": [{"id": p.id, "label": p.label, "values": dict(p.values)}
                       for p in sweep.points]}


def run_sweep(sweep: Sweep, out: str | Path, budget: int | None = None, progress: bool = True,
              echo: Callable[[str], None] = print, devices: int | None = None) -> tuple[pd.DataFrame, dict]:
    """What `fedjax-nav sweep` does: train the missing points, write the tables. Returns
    (summary table, run stats)."""
    out = Path(out)
    stats = run_jobs(merge_jobs(sweep.points), out, budget, progress, desc=f"sweep {sweep.name}", echo=echo,
                     devices=devices)
    write_tables(sweep, out / "points", out)
    summ = point_summaries(sweep, out / "points")
    atomic_write(out / "sweep_stats.json", lambda p: Path(p).write_text(json.dumps(stats, indent=1)))
    return summ, stats


__all__ = ["Sweep", "Point", "SweepError", "load_sweep", "run_sweep", "run_jobs", "merge_jobs", "plan",
           "point_id", "group_key", "write_tables", "point_summaries", "point_metrics", "parse_bytes",
           ]
