"""The sweep file: its format, its validation and the points it describes (a `Config` each).

A sweep file (`configs/sweeps/<name>.yaml`) is a format like a config file; this module reads it
and nothing else. Training the points is `fedjax_nav.training.sweep` (jobs, groups, batches);
their tables are `fedjax_nav.analysis.sweeps`, which read the finished points from disk.

    name: tau
    description: soft vs hard FedAvg (thesis Fig. 14)
    base: ../thesis/flddpg.yaml      # relative to the sweep file, or a shipped name (thesis/flddpg)
    seeds: 8
    set: [run.episodes=125]          # optional: overrides applied to every point
    grid:                            # cartesian product; `base` may also be a grid key
      fed.tau: [0.0, 0.5, 1.0]
    points:                          # optional: single points beside the grid
      - {fed.tau: 0.25}
    thesis:                          # optional: the thesis's numbers, for the report
      by: fed.tau                    # a grid key, or `method`
      success_last: {0.0: 0.30, 0.5: 0.79, 1.0: 0.41}
    evaluate: false                  # reproduce: evaluate every point with the protocol
    goal: {family: 0.95, arena: 0.95, worst10: 0.80}   # optional: the generalization report's goal

A sweep may `extends: other.yaml` (beside it, or a shipped sweep's name): it takes that sweep's
`base` (unless it gives its own), `seeds` (unless it gives its own) and `set` lines, its own `set`
lines after them; not its grid, points, thesis, evaluate or goal. Several experiments on one recipe
(docs/shared_rooms.md, the plan policy in shared rooms) then hold the recipe once.

`goal` is what the generalization report (docs/generalization.md) checks each procedurally trained
point against: success on every held-out family, in the thesis arena and over the worst 10% of
rooms, each a threshold in [0, 1] (a key left out is not checked). Without it the report checks
DEFAULT_GOAL, the first generalisation experiment's goal.

`base` (in a grid too) names a config file: a path relative to the sweep file wins when that file
exists; any other name is read as `fedjax-nav train --config` reads it (`config.io.locate`, one
resolver for both): a shipped name (`thesis/flddpg`) or a path from the current directory. A name
that is neither is one SweepError naming the sweep file and the name, listing the shipped names.

Every point is a resolved `Config` (its `run.seeds` = the seeds it wants). Its id hashes the
config's non-default fields, so two sweeps (or two experiments of `reproduce`) that ask for the
same run share one run directory, `points/<id>/`.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fedjax_nav.config import (
    LEGACY_ALIASES,
    TOP_LEVEL,
    Config,
    ConfigError,
    apply_overrides,
    canonical,
    field_info,
    from_dict,
    get,
    read_yaml,
    resolve_aliases,
    to_dict,
)
from fedjax_nav.config.io import locate
from fedjax_nav.messages import show

# Fields that say how a run is kept, not what it computes: they leave a point's id unchanged.
BOOKKEEPING = ("run.seeds", "run.checkpoint_every", "run.keep_checkpoints", "offpolicy.buffer_alloc", "run.tensorboard")
# The names point_id hashes a field under: its name when ids were first recorded. The offpolicy
# fields were the ddpg section's then (names.LEGACY_ALIASES), so that a finished run keeps its id
# and its run directory `points/<id>/` (tests/test_point_ids.py).
_ID_NAMES = {new: old for old, new in LEGACY_ALIASES.items()}
# At most this many points per sweep file (the largest shipped one has 33): 300 x 300 took
# minutes to read before anything was said, and would train for months here.
MAX_POINTS = 10_000
SWEEP_KEYS = {"name", "description", "extends", "base", "seeds", "set", "grid", "points", "thesis", "evaluate", "goal"}
MAX_EXTENDS = 8  # sweeps in one `extends` chain: more is a cycle (a extends b extends a) or a mistake
GOAL_KEYS = ("family", "arena", "worst10")  # every held-out family, the thesis arena, the worst 10% of rooms
DEFAULT_GOAL = {"family": 0.85, "arena": 0.90}  # the first generalisation experiment's (docs/generalization.md)


class SweepError(ConfigError):
    """A bad sweep file or option; the message names the file and the key (bad input: exit 2
    wherever it is raised, as every ConfigError)."""


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
    goal: dict = field(default_factory=lambda: dict(DEFAULT_GOAL))  # GOAL_KEYS -> threshold


def flat_config(cfg: Config) -> dict:
    """{"method": ..., "offpolicy.gamma": ..., ...}: every field of the config by its dotted name."""
    d = to_dict(cfg)
    out = {name: d.pop(name) for name in TOP_LEVEL}
    for s, sec in d.items():
        out.update({f"{s}.{k}": v for k, v in sec.items()})
    return out


def point_id(cfg: Config) -> str:
    """12 hex digits of a hash of the config's non-default fields (bookkeeping fields aside), so
    that a field added to the config later, with a default that keeps today's behaviour, leaves
    every existing point's id unchanged. A field moved to another section is hashed under its
    old name (`_ID_NAMES`: `offpolicy.gamma` as `ddpg.gamma`), so that the move leaves ids unchanged too."""
    defaults = flat_config(Config())
    flat = {
        _ID_NAMES.get(k, k): v
        for k, v in flat_config(cfg).items()
        if k not in BOOKKEEPING and (k == "method" or v != defaults.get(k, object()))
    }
    return hashlib.sha1(json.dumps(flat, sort_keys=True).encode()).hexdigest()[:12]


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


def _read_spec(path: Path) -> dict:
    """The file's mapping, its keys checked (SweepError naming the file)."""
    try:
        spec = read_yaml(path, "sweep")
    except ConfigError as e:
        raise SweepError(str(e)) from None
    if not isinstance(spec, dict):
        raise SweepError(f"{path}: a sweep file is a mapping with keys {sorted(SWEEP_KEYS)}")
    unknown = set(spec) - SWEEP_KEYS
    if unknown:
        raise SweepError(f"{path}: unknown key(s) {sorted(unknown)}; allowed: {sorted(SWEEP_KEYS)}")
    return spec


def _extended(path: Path, spec: dict, depth: int = 0) -> tuple[dict, list[str]]:
    """`spec` with what it `extends` (the module's docstring): the spec with the other sweep's base
    (resolved beside that file) and seeds where it gives none, and the `set` lines it inherits,
    furthest ancestor first."""
    from fedjax_nav.configs import resolve

    if spec.get("extends") is None:
        return spec, []
    if depth >= MAX_EXTENDS:
        raise SweepError(f"{path}: extends: more than {MAX_EXTENDS} sweeps in a chain (a cycle?)")
    beside = path.parent / str(spec["extends"])
    parent_path = beside if beside.is_file() else resolve(str(spec["extends"]), "sweep")
    if not parent_path.is_file():
        raise SweepError(f"{path}: extends: no sweep file {show(spec['extends'])} beside it or shipped")
    parent, inherited = _extended(parent_path, _read_spec(parent_path), depth + 1)
    merged = dict(spec)
    if "base" not in spec and parent.get("base") is not None:
        merged["base"] = str(base_file(parent_path, parent["base"]))
    if "seeds" not in spec and "seeds" in parent:
        merged["seeds"] = parent["seeds"]
    return merged, inherited + _as_overrides(parent.get("set"), f"{parent_path}: set")


def _combos(path: Path, spec: dict) -> list[dict]:
    """The swept values of every point: the grid's cartesian product, then the single `points`."""
    grid = spec.get("grid") or {}
    if not isinstance(grid, dict):
        raise SweepError(f"{path}: grid must be a mapping key: [values]")
    for k, v in grid.items():
        if not isinstance(v, list) or not v:
            raise SweepError(f"{path}: grid.{k} must be a non-empty list of values")
    extra_points = spec.get("points") or []
    if not isinstance(extra_points, list) or not all(isinstance(p, dict) for p in extra_points):
        raise SweepError(f"{path}: points must be a list of mappings key: value")
    count = math.prod(len(v) for v in grid.values()) * bool(grid) + len(extra_points)
    if count > MAX_POINTS:
        raise SweepError(
            f"{path}: the grid has {count:,} points, more than {MAX_POINTS:,} (a sweep trains every one): "
            "split it into several sweep files"
        )
    combos = [dict(zip(grid, vals)) for vals in itertools.product(*grid.values())] if grid else []
    combos += [dict(p) for p in extra_points]
    for keys in [list(grid), *extra_points]:  # one field under its two names: one value would be lost
        names: dict[str, Any] = {}
        for k in keys:
            if (first := names.setdefault(canonical(str(k)), k)) != k:
                raise SweepError(f"{path}: {first} and {k} are one field (its old and new name); sweep it under one")
    return combos or [{}]


def base_file(path: Path, base) -> Path:
    """The config file a sweep file's `base:` names: a path relative to the sweep file when that
    file exists, else what `--config` takes (`config.io.locate`, the one resolver of both: a
    path, or a shipped name such as `thesis/flddpg`). A name that is neither is one ConfigError
    naming it and listing the shipped names."""
    beside = path.parent / str(base)
    try:
        if beside.exists():
            return beside.resolve()
    except (OSError, ValueError):  # a NUL byte or an over-long name: locate names it
        pass
    return locate(str(base), "config")


def _point(path: Path, values: dict, base, before: list[str], after: list[str], buffer_scale: float) -> Point:
    """One point: its base config with the overrides `before` its grid values (the file's `set`),
    the grid values, then the overrides `after` them (the caller's, the seeds)."""
    if base is None:
        raise SweepError(f"{path}: no base config (give `base:` or a grid over base)")
    try:
        data = read_yaml(base_file(path, base))
    except ConfigError as e:  # e names the base as written (`locate`), with the shipped names when unknown
        raise SweepError(f"{path}: base: {e}") from None
    grid_over = [f"{k}={json.dumps(v)}" for k, v in values.items() if k != "base"]
    src = f"{path} (point {point_label(values, Config())})"
    try:
        data = apply_overrides(data, before + grid_over + after, src)
        if buffer_scale != 1.0:
            off, default = resolve_aliases(data, src)[0].get("offpolicy") or {}, Config().offpolicy
            size = off.get("buffer_size", default.buffer_size)
            scaled = max(int(off.get("batch_size", default.batch_size)), round(size * buffer_scale))
            data = apply_overrides(data, [f"offpolicy.buffer_size={scaled}"], src)
        cfg = from_dict(data, src)
    except ConfigError as e:
        raise SweepError(str(e)) from None
    # the values as resolved (a buffer size after buffer_scale, a float after YAML's int)
    return Point({k: (v if k == "base" else get(cfg, k)) for k, v in values.items()}, cfg)


def _goal(path: Path, value) -> dict:
    """`goal:` as {key: threshold} with keys of GOAL_KEYS and thresholds in [0, 1]; DEFAULT_GOAL when absent."""
    if value is None:
        return dict(DEFAULT_GOAL)
    if not isinstance(value, dict) or not value:
        raise SweepError(f"{path}: goal must be a mapping of {list(GOAL_KEYS)} to thresholds, got {show(value)}")
    for k, v in value.items():
        if k not in GOAL_KEYS:
            raise SweepError(f"{path}: goal.{k} is not a goal; allowed: {list(GOAL_KEYS)}")
        if isinstance(v, bool) or not isinstance(v, int | float) or not 0 <= v <= 1:
            raise SweepError(f"{path}: goal.{k} must be a success rate in [0, 1], got {show(v)}")
    return {k: float(value[k]) for k in GOAL_KEYS if k in value}


def _seed_count(path: Path, value) -> int:
    """`seeds:` as an int in run.seeds' range (not a float, a string, a list or a bool)."""
    hi = field_info("run.seeds").metadata["hi"]
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= hi:
        raise SweepError(f"{path}: seeds must be an integer in 1..{hi}, got {show(value)}")
    return value


def load_sweep(
    path: str | Path, overrides: list[str] | tuple = (), seeds: int | None = None, buffer_scale: float = 1.0
) -> Sweep:
    """Read and validate a sweep file; `overrides` apply to every point after the grid values,
    `seeds` replaces the file's seed count; `buffer_scale` multiplies every point's buffer size
    (at least the batch size; `reproduce --scale ci` shrinks runs so that buffers still wrap).
    `path` may be a shipped experiment name (`tau`)."""
    from fedjax_nav.configs import resolve

    path = resolve(path, "sweep")
    spec, inherited = _extended(path, _read_spec(path))
    name = str(spec.get("name") or path.stem)
    n_seeds = _seed_count(path, seeds if seeds is not None else spec.get("seeds", 1))
    combos = _combos(path, spec)
    keys = tuple(dict.fromkeys(k for c in combos for k in c))
    common = inherited + _as_overrides(spec.get("set"), f"{path}: set")
    after = [*overrides, f"run.seeds={n_seeds}"]
    points = tuple(_point(path, v, v.get("base", spec.get("base")), common, after, buffer_scale) for v in combos)
    thesis = spec.get("thesis") or {}
    if not isinstance(thesis, dict):
        raise SweepError(f"{path}: thesis must be a mapping (the thesis's numbers), got {show(thesis)}")
    if thesis and thesis.get("by", keys[0] if keys else "method") not in (*keys, "method"):
        raise SweepError(f"{path}: thesis.by must be one of the grid keys {list(keys)} or 'method'")
    evaluate = bool(spec.get("evaluate", False))
    description = str(spec.get("description", ""))
    return Sweep(name, path, description, n_seeds, keys, points, thesis, evaluate, _goal(path, spec.get("goal")))


def select(sweep: Sweep, only: list[str] | tuple = ()) -> tuple[Point, ...]:
    """The points of `sweep` that `only` selects (`fedjax-nav sweep --only KEY=VALUE`): values of one
    key are alternatives, different keys must all hold (`--only method=iddpg --only method=snddpg
    --only run.episodes=300`). A point matches `KEY=VALUE` when setting it changes nothing of the
    point's config, so values are read and checked as `--set` reads them; no `only`: every point.
    A bad key or value, or a selection that matches no point, raises `SweepError` naming it."""
    from fedjax_nav.config import apply_overrides, from_dict, to_dict

    by_key: dict[str, list[str]] = {}
    for item in only:
        if "=" not in item:
            raise SweepError(f"--only: {show(item)} is not of the form key=value (e.g. method=iddpg)")
        by_key.setdefault(item.split("=", 1)[0].strip(), []).append(item)

    errors: list[str] = []

    def holds(p: Point, item: str) -> bool:
        try:
            return from_dict(apply_overrides(to_dict(p.cfg), [item], src="--only"), "--only") == p.cfg
        except ConfigError as e:  # a value this point's config refuses: not this point
            errors.append(str(e))
            return False

    chosen = tuple(p for p in sweep.points if all(any(holds(p, i) for i in items) for items in by_key.values()))
    if not chosen:  # say why: the first refusal (a bad key or value, as --set names it), else no match
        none = f"--only {' '.join(only)}: matches none of the {len(sweep.points)} points of {sweep.name}"
        raise SweepError(errors[0] if errors else none)
    return chosen
