"""Configuration: frozen dataclasses that map one to one onto the YAML files.

A config file has four sections (`env`, `ddpg`, `fed`, `run`) and the `method`. Every field has
a default, a type, an allowed range or set, and a note of whether it is *traced* (a JAX value:
it can be swept in one compiled program) or *static* (it fixes shapes or the program).

`traced=True` on a field is the one declaration of sweepability: `traced_fields()`, the trainer's
`HParams` (`fedjax_nav.training.hparams`), the sweeps' grouping and the docs are derived from it,
as rejax declares it once on the field.

    cfg = load_config("configs/thesis/flddpg.yaml", overrides=["ddpg.gamma=0.99"])

Unknown keys, wrong types and out-of-range values raise `ConfigError`, naming the file, the key
and what is allowed.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import yaml

from fedjax_nav.methods import METHODS as _METHOD_TABLE

METHODS = tuple(_METHOD_TABLE)


class ConfigError(ValueError):
    """A config value is invalid; the message names the file, the key and what is allowed."""


def _f(default, lo=None, hi=None, choices=None, traced=False, doc=""):
    meta = {"lo": lo, "hi": hi, "choices": choices, "traced": traced, "doc": doc}
    if isinstance(default, (list, tuple)):
        return field(default_factory=lambda: tuple(default), metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class EnvConfig:
    worlds: tuple = _f(("train-0", "train-2", "train-3", "train-4", "train-5"),
                       doc="one playground per robot: shipped names or world files")
    episode_length: int = _f(1024, lo=1, doc="T, steps per episode (static)")
    num_beams: int = _f(24, lo=1, hi=1024, doc="lidar beams (static)")
    max_range: float = _f(3.5, lo=0.0, doc="m, lidar range (static)")
    collision_test: str = _f("exact", choices=("exact", "lidar"), doc="exact distance or min(lidar) (static)")
    dt: float = _f(0.1, lo=0.0, traced=True, doc="s per control step")
    v_max: float = _f(0.25, lo=0.0, traced=True, doc="m/s")
    omega_max: float = _f(1.0, lo=0.0, traced=True, doc="rad/s")
    goal_radius: float = _f(0.5, lo=0.0, traced=True, doc="m, D_g")
    collision_distance: float = _f(0.25, lo=0.0, traced=True, doc="m, D_c")
    reward_goal: float = _f(100.0, traced=True, doc="R_g")
    reward_collision: float = _f(-10.0, traced=True, doc="R_c")
    progress_scale: float = _f(40.0, traced=True, doc="R_d = progress_scale * (d_prev - d)")


@dataclass(frozen=True)
class DDPGConfig:
    hidden: int = _f(64, lo=1, doc="hidden width (static)")
    depth: int = _f(3, lo=1, hi=16, doc="hidden layers (static)")
    activation: str = _f("relu", choices=("relu", "tanh", "elu", "gelu", "silu"), doc="(static)")
    buffer_size: int = _f(10000, lo=1, traced=True, doc="replay capacity per buffer (traced up to buffer_alloc)")
    buffer_alloc: int = _f(0, lo=0, doc="allocated rows (static); 0 = buffer_size. Sweeps set the max")
    batch_size: int = _f(512, lo=1, doc="(static)")
    gamma: float = _f(0.9, lo=0.0, hi=1.0, traced=True, doc="discount")
    rho: float = _f(1.0, lo=0.0, hi=1.0, traced=True, doc="target mix: targ <- (1-rho) targ + rho net")
    lr: float = _f(1e-3, lo=0.0, hi=1.0, traced=True, doc="Adam learning rate (actor and critic)")
    train_every: int = _f(5, lo=1, traced=True, doc="T_train: steps between gradient steps")
    target_every: int = _f(5, lo=1, traced=True, doc="T_target: steps between target updates")
    epsilon_start: float = _f(0.9, lo=0.0, hi=1.0, traced=True, doc="exploration probability at step 0")
    epsilon_decay: float = _f(0.99997, lo=0.0, hi=1.0, traced=True, doc="epsilon *= decay every step")


@dataclass(frozen=True)
class FedConfig:
    tau: float = _f(0.5, lo=0.0, hi=1.0, traced=True, doc="soft mix: 0 = no sharing, 1 = hard FedAvg")
    beta: float = _f(0.5, lo=0.0, hi=100.0, traced=True, doc="PW/RW reward scale, GS global step")
    period_unit: str = _f("episodes", choices=("episodes", "steps"), doc="E_update or T_update (static)")
    period: int = _f(2, lo=1, traced=True, doc="E_update (episodes) or T_update (steps)")
    include_targets: bool = _f(False, doc="also average target networks (static)")


@dataclass(frozen=True)
class RunConfig:
    episodes: int = _f(125, lo=1, doc="E")
    seeds: int = _f(1, lo=1, hi=4096, doc="seeds trained in one program (vmap)")
    seed: int = _f(0, lo=0, doc="first PRNG seed")
    chunk_episodes: int = _f(5, lo=1, doc="episodes per compiled call (static; progress granularity)")
    checkpoint_every: int = _f(25, lo=0, doc="episodes between checkpoints (0 = only at the end)")
    keep_checkpoints: int = _f(3, lo=1, doc="checkpoints kept")


@dataclass(frozen=True)
class Config:
    method: str = _f("flddpg", choices=METHODS, doc="the method (docs/decisions.md, Methods)")
    env: EnvConfig = field(default_factory=EnvConfig)
    ddpg: DDPGConfig = field(default_factory=DDPGConfig)
    fed: FedConfig = field(default_factory=FedConfig)
    run: RunConfig = field(default_factory=RunConfig)

    @property
    def num_robots(self) -> int:
        return len(self.env.worlds)

    @property
    def buffer_rows(self) -> int:
        return self.ddpg.buffer_alloc or self.ddpg.buffer_size


SECTIONS = {"env": EnvConfig, "ddpg": DDPGConfig, "fed": FedConfig, "run": RunConfig}


def traced_fields() -> tuple[str, ...]:
    """Dotted names of the fields that are JAX values (sweepable in one compilation): exactly the
    fields declared with `traced=True`."""
    return tuple(f"{s}.{f.name}" for s, cls in SECTIONS.items() for f in fields(cls) if f.metadata.get("traced"))


def field_info(dotted: str) -> dataclasses.Field:
    """The dataclass field behind a dotted name ("ddpg.gamma"), with its metadata."""
    if dotted == "method":
        return {f.name: f for f in fields(Config)}["method"]
    section, name = dotted.split(".")
    return {f.name: f for f in fields(SECTIONS[section])}[name]


def get(cfg: Config, dotted: str):
    """The value of a dotted name ("ddpg.gamma", or "method")."""
    if dotted == "method":
        return cfg.method
    section, name = dotted.split(".")
    return getattr(getattr(cfg, section), name)


# ----------------------------------------------------------------------------- validation


def _coerce(value: Any, f: dataclasses.Field, where: str) -> Any:
    typ = f.type if isinstance(f.type, type) else {"int": int, "float": float, "str": str, "bool": bool,
                                                    "tuple": tuple}[f.type]
    meta = f.metadata
    if typ is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
    elif typ is int:
        if isinstance(value, bool) or not (isinstance(value, int) or (isinstance(value, float) and value.is_integer())):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        value = int(value)
    elif typ is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise ConfigError(f"{where}: expected a finite number, got {value!r}")
    elif typ is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
    elif typ is tuple:
        if isinstance(value, str) or not isinstance(value, (list, tuple)) or not value:
            raise ConfigError(f"{where}: expected a non-empty list, got {value!r}")
        value = tuple(str(v) for v in value)
    lo, hi, choices = meta.get("lo"), meta.get("hi"), meta.get("choices")
    if choices is not None and value not in choices:
        raise ConfigError(f"{where}: {value!r} is not one of {', '.join(map(str, choices))}")
    if lo is not None and value < lo or hi is not None and value > hi:
        rng = f"[{lo if lo is not None else '-inf'}, {hi if hi is not None else 'inf'}]"
        raise ConfigError(f"{where}: {value!r} is out of range; allowed {rng}")
    return value


def _build(cls, data: Any, src: str, prefix: str):
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{src}: '{prefix}' must be a mapping, got {type(data).__name__}")
    known = {f.name: f for f in fields(cls)}
    for k in data:
        if k not in known:
            raise ConfigError(
                f"{src}: unknown key '{prefix}.{k}' (allowed in '{prefix}': {', '.join(known)})"
            )
    return cls(**{k: _coerce(v, known[k], f"{src}: {prefix}.{k}") for k, v in data.items()})


def from_dict(data: dict, src: str = "<config>") -> Config:
    if not isinstance(data, dict):
        raise ConfigError(f"{src}: a config must be a mapping with keys method, env, ddpg, fed, run")
    allowed = {"method", *SECTIONS}
    for k in data:
        if k not in allowed:
            raise ConfigError(f"{src}: unknown key '{k}' (allowed: {', '.join(sorted(allowed))})")
    kwargs = {s: _build(cls, data.get(s), src, s) for s, cls in SECTIONS.items()}
    if "method" in data:
        kwargs["method"] = _coerce(data["method"], {f.name: f for f in fields(Config)}["method"], f"{src}: method")
    cfg = Config(**kwargs)
    check(cfg, src)
    return cfg


def check(cfg: Config, src: str = "<config>") -> None:
    """Cross-field checks (each names the fields involved)."""
    d = cfg.ddpg
    if d.buffer_alloc and d.buffer_alloc < d.buffer_size:
        raise ConfigError(f"{src}: ddpg.buffer_alloc ({d.buffer_alloc}) must be 0 or >= ddpg.buffer_size ({d.buffer_size})")
    if d.buffer_size < d.batch_size:
        raise ConfigError(
            f"{src}: ddpg.buffer_size ({d.buffer_size}) is smaller than ddpg.batch_size ({d.batch_size}); "
            "allowed: buffer_size >= batch_size"
        )
    # IDDPG, SEDDPG, SNDDPG have no federated step: their fed.period is unused, not inconsistent.
    federated = cfg.method not in ("iddpg", "seddpg", "snddpg")
    if federated and cfg.fed.period_unit == "episodes" and cfg.fed.period > cfg.run.episodes:
        raise ConfigError(
            f"{src}: fed.period ({cfg.fed.period} episodes) is longer than run.episodes ({cfg.run.episodes}); "
            "no federated step would ever happen"
        )
    if federated and cfg.fed.period_unit == "steps" and cfg.fed.period > cfg.env.episode_length * cfg.run.episodes:
        raise ConfigError(f"{src}: fed.period ({cfg.fed.period} steps) is longer than the whole run")
    if cfg.run.episodes % cfg.run.chunk_episodes:
        raise ConfigError(
            f"{src}: run.episodes ({cfg.run.episodes}) must be a multiple of run.chunk_episodes "
            f"({cfg.run.chunk_episodes})"
        )
    if cfg.run.checkpoint_every % cfg.run.chunk_episodes:
        raise ConfigError(
            f"{src}: run.checkpoint_every ({cfg.run.checkpoint_every}) must be a multiple of "
            f"run.chunk_episodes ({cfg.run.chunk_episodes})"
        )


def to_dict(cfg: Config) -> dict:
    out = {"method": cfg.method}
    for s in SECTIONS:
        sec = dataclasses.asdict(getattr(cfg, s))
        out[s] = {k: list(v) if isinstance(v, tuple) else v for k, v in sec.items()}
    return out


def apply_overrides(data: dict, overrides: list[str], src: str = "--set") -> dict:
    """Apply `section.key=value` strings (values parsed as YAML) to a config dict (a copy)."""
    import copy

    data = copy.deepcopy(data)
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"{src}: '{item}' is not of the form key=value (e.g. ddpg.gamma=0.99)")
        key, raw = item.split("=", 1)
        value = yaml.safe_load(raw)
        parts = key.strip().split(".")
        if parts == ["method"]:
            data["method"] = value
            continue
        if len(parts) != 2 or parts[0] not in SECTIONS:
            raise ConfigError(f"{src}: unknown key '{key}' (use section.key with section in {', '.join(SECTIONS)})")
        data.setdefault(parts[0], {})
        if data[parts[0]] is None:
            data[parts[0]] = {}
        data[parts[0]][parts[1]] = value
    return data


def read_yaml(path: str | Path) -> dict:
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"{path}: no such config file")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise ConfigError(f"{path}: not valid YAML ({e})") from None
    return data or {}


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> Config:
    data = read_yaml(path) if path else {}
    src = str(path) if path else "<defaults>"
    if overrides:
        data = apply_overrides(data, overrides)
        src += " (with --set)"
    return from_dict(data, src)


def save_config(cfg: Config, path: str | Path) -> None:
    Path(path).write_text(yaml.safe_dump(to_dict(cfg), sort_keys=False))


def diff(a: Config, b: Config) -> list[str]:
    """Dotted names of the fields that differ."""
    da, db = to_dict(a), to_dict(b)
    out = ["method"] if da["method"] != db["method"] else []
    for s in SECTIONS:
        out += [f"{s}.{k}" for k in da[s] if da[s][k] != db[s][k]]
    return out
