"""Config validation: types, ranges and choices per field (`_coerce`), cross-field checks
(`check`), each error one line naming the file and the field."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Collection
from dataclasses import fields
from typing import Any

from fedjax_nav.config.schema import (
    LEGACY_ALIASES,
    ROOM_FAMILIES,
    SECTIONS,
    TOP_LEVEL,
    Config,
    ConfigError,
    canonical,
    field_info,
    get,
    robot_problem,
)
from fedjax_nav.learner_table import get as learner_row
from fedjax_nav.learner_table import off_policy
from fedjax_nav.messages import show

# ----------------------------------------------------------------------------- validation


# The program's JAX values are int32 and float32 (training.hparams): a value beyond them would
# overflow there, long after validation. Every int and float field is held to them.
INT32 = (-(2**31), 2**31 - 1)
FLOAT32_MAX = 3.4028234663852886e38


def _coerce(value: Any, f: dataclasses.Field, where: str) -> Any:
    typ = (
        f.type
        if isinstance(f.type, type)
        else {"int": int, "float": float, "str": str, "bool": bool, "tuple": tuple}[f.type]
    )
    meta = f.metadata
    if typ in (int, float) and isinstance(value, str):
        value = _number(value)  # YAML 1.1 reads 1e8 and 1.0e8 as strings
    lo, hi, choices = meta.get("lo"), meta.get("hi"), meta.get("choices")
    if typ is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {show(value)}")
    elif typ is int:
        if isinstance(value, bool) or not (isinstance(value, int) or (isinstance(value, float) and value.is_integer())):
            raise ConfigError(f"{where}: expected an integer, got {show(value)}")
        value = int(value)
        lo, hi = max(INT32[0], -math.inf if lo is None else lo), min(INT32[1], math.inf if hi is None else hi)
    elif typ is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {show(value)}")
        if isinstance(value, float) and not math.isfinite(value):
            raise ConfigError(f"{where}: expected a finite number, got {show(value)}")
        lo = -FLOAT32_MAX if lo is None else lo  # finite in float32, the program's precision
        hi = FLOAT32_MAX if hi is None else hi
        if not lo <= value <= hi:  # before float(): an int of 400 digits has no float
            raise ConfigError(f"{where}: {show(value)} is out of range; allowed {_range(lo, hi)}")
        value = float(value)
    elif typ is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {show(value)}")
    elif typ is tuple:
        if isinstance(value, str) or not isinstance(value, (list, tuple)) or not value:
            raise ConfigError(f"{where}: expected a non-empty list, got {show(value)}")
        value = tuple(str(v) for v in value)
    if choices is not None and value not in choices:
        raise ConfigError(f"{where}: {show(value)} is not one of {', '.join(map(str, choices))}")
    if lo is not None and value < lo or hi is not None and value > hi:
        raise ConfigError(f"{where}: {show(value)} is out of range; allowed {_range(lo, hi)}")
    return value


def _range(lo, hi) -> str:
    def num(v):
        if v == FLOAT32_MAX:
            return "3.4e38 (float32)"
        if v == -FLOAT32_MAX:
            return "-3.4e38 (float32)"
        return f"{v:.6g}" if isinstance(v, float) and abs(v) >= 1e6 else str(v)

    return f"[{num(lo)}, {num(hi)}]"


def _number(text: str) -> Any:
    """A float from a number in exponent notation that YAML 1.1 reads as a string ("1e8",
    "1.0e8", "1e-3"); anything else (e.g. a quoted "0.9") stays a string and is rejected."""
    import re

    s = text.strip()
    if re.fullmatch(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+", s):
        return float(s)
    return text


def _build(cls, data: Any, src: str, prefix: str, where, written=None):
    """A section's dataclass from its mapping; `written` (a dotted name -> the name as the user
    wrote it: an alias, `resolve_aliases`) names each field in messages as it was written."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{src}: '{prefix}' must be a mapping, got {type(data).__name__}")
    known = {f.name: f for f in fields(cls)}

    def name(k: str) -> str:  # the field as the user wrote it
        return (written or {}).get(f"{prefix}.{k}", f"{prefix}.{k}")

    for k in data:
        if k not in known:
            dotted = f"{prefix}.{k}"
            old = [a.split(".", 1)[1] for a in LEGACY_ALIASES if a.startswith(f"{prefix}.")]
            also = f"; and the old names of the offpolicy fields: {', '.join(old)}" if old else ""
            raise ConfigError(
                f"{where(dotted)}: unknown key {show(dotted)} (allowed in '{prefix}': {', '.join(known)}{also})"
            )
    return cls(**{k: _coerce(v, known[k], f"{where(f'{prefix}.{k}')}: {name(k)}") for k, v in data.items()})


def resolve_aliases(data: Any, src: str = "<config>", where=None) -> tuple[Any, dict]:
    """A config mapping with each old name `ddpg.<field>` of an offpolicy field (schema.LEGACY_ALIASES)
    moved to `offpolicy.<field>` (a copy; `data` is left as it is), and {"offpolicy.<field>": the name
    as written} of the fields moved, so that messages name what the user wrote. A field given under
    both names with different values is one ConfigError naming both (`where(dotted)`: where a
    value came from, `src` by default). Anything that is not a mapping comes back unchanged, for
    `from_dict` to refuse."""
    where = where or (lambda dotted: src)
    if not isinstance(data, dict):
        return data, {}

    def given(dotted: str) -> bool:
        section, key = dotted.split(".")
        return isinstance(data.get(section), dict) and key in data[section]

    moved = {old: new for old, new in LEGACY_ALIASES.items() if given(old)}
    if not moved:
        return data, {}
    out = {k: (dict(v) if isinstance(v, dict) else v) for k, v in data.items()}
    written = {}
    for old, new in moved.items():
        (s_old, k_old), (s_new, k_new) = old.split("."), new.split(".")
        value = out[s_old].pop(k_old)
        if out.get(s_new) is None:
            out[s_new] = {}
        target = out[s_new]
        if not isinstance(target, dict):
            raise ConfigError(f"{src}: '{s_new}' must be a mapping, got {type(target).__name__}")
        if k_new not in target:
            target[k_new], written[new] = value, old
            continue
        f = field_info(new)
        if _coerce(value, f, f"{where(old)}: {old}") != _coerce(target[k_new], f, f"{where(new)}: {new}"):
            raise ConfigError(
                f"{src}: {old} ({show(value)}) and {new} ({show(target[k_new])}) are one field ({old} is the "
                f"old name of {new}) given two values; give {new} only"
            )
    return out, written


def from_dict(data: dict, src: str = "<config>", overridden: Collection[str] = ()) -> Config:
    """A validated Config from a config mapping read from `src`.

    `overridden`: the dotted keys given by `--set` (`io.load_config`); an error in one of their
    values names `--set`, one in any other value names `src`, and a cross-field error names
    `src (with --set)`."""
    if not isinstance(data, dict):
        raise ConfigError(f"{src}: a config must be a mapping with keys {', '.join((*TOP_LEVEL, *SECTIONS))}")
    overridden = {canonical(k) for k in overridden}

    def where(dotted: str) -> str:
        return "--set" if canonical(dotted) in overridden else src

    allowed = {*TOP_LEVEL, *SECTIONS}
    for k in data:
        if k not in allowed:
            raise ConfigError(f"{src}: unknown key {show(str(k))} (allowed: {', '.join(sorted(allowed))})")
    data, written = resolve_aliases(data, src, where)
    kwargs = {s: _build(cls, data.get(s), src, s, where, written) for s, cls in SECTIONS.items()}
    top = {f.name: f for f in fields(Config)}
    for name in TOP_LEVEL:
        if name in data:
            kwargs[name] = _coerce(data[name], top[name], f"{where(name)}: {name}")
    cfg = fit_run_sizes(Config(**kwargs), overridden)
    check(cfg, f"{src} (with --set)" if overridden else src)
    return cfg


def fit_run_sizes(cfg: Config, overridden: Collection[str]) -> Config:
    """The run's chunk and checkpoint sizes after a command line that changed `run.episodes` or
    `run.chunk_episodes` (`--episodes N`, `--set`): a size it did not set follows (docs/reliability.md,
    "Chunks and checkpoints"): `run.chunk_episodes` becomes the largest divisor of `run.episodes`
    not above the configured chunk (one compiled program, as before), `run.checkpoint_every` the
    largest multiple of the chunk not above the configured one (at least one chunk; 0 stays 0).
    A size the command line set itself and that conflicts is refused in one line naming it; a
    file whose own sizes conflict is refused by `check`. A config that passes `check` unchanged
    is returned unchanged: no shipped config or sweep point moves."""
    r, given = cfg.run, set(overridden)
    chunk, every = r.chunk_episodes, r.checkpoint_every
    if r.episodes % chunk and "run.chunk_episodes" in given:
        raise ConfigError(
            f"--set run.chunk_episodes={chunk}: run.episodes ({r.episodes}) must be a multiple of it; "
            f"give a divisor of {r.episodes}, or leave it unset (it then follows run.episodes)"
        )
    if r.episodes % chunk and "run.episodes" in given:
        chunk = next(d for d in range(min(chunk, r.episodes), 0, -1) if r.episodes % d == 0)
    if every % chunk and "run.checkpoint_every" in given:
        raise ConfigError(
            f"--set run.checkpoint_every={every}: must be 0 or a multiple of run.chunk_episodes ({chunk}); "
            "leave it unset to have it follow the chunk"
        )
    if every % chunk and given & {"run.episodes", "run.chunk_episodes"}:
        every = max(chunk, every // chunk * chunk)
    if (chunk, every) == (r.chunk_episodes, r.checkpoint_every):
        return cfg
    return dataclasses.replace(cfg, run=dataclasses.replace(r, chunk_episodes=chunk, checkpoint_every=every))


def check(cfg: Config, src: str = "<config>") -> None:
    """Cross-field checks (each names the fields involved)."""
    if msg := robot_problem(cfg.robot, cfg.env.num_beams):
        raise ConfigError(f"{src}: {msg}")
    d = cfg.offpolicy
    if d.buffer_alloc and d.buffer_alloc < d.buffer_size:
        raise ConfigError(
            f"{src}: offpolicy.buffer_alloc ({d.buffer_alloc}) must be 0 or >= offpolicy.buffer_size ({d.buffer_size})"
        )
    if d.buffer_size < d.batch_size:
        raise ConfigError(
            f"{src}: offpolicy.buffer_size ({d.buffer_size}) is smaller than offpolicy.batch_size ({d.batch_size}); "
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
    rows = cfg.run.episodes * cfg.env.episode_length * cfg.num_robots * cfg.env.envs_per_robot
    if rows >= 2**31:  # the int32 step counters
        raise ConfigError(
            f"{src}: run.episodes x env.episode_length x robots x env.envs_per_robot = "
            f"{rows:,} transitions; at most 2^31 - 1"
        )
    _check_fed(cfg, src, federated)
    _check_learner(cfg, src)
    _check_rooms(cfg, src)
    _check_learnability(cfg, src)
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


def _check_learner(cfg: Config, src: str) -> None:
    """The learner against the method and its own loop sizes (docs/learners.md)."""
    from fedjax_nav.methods import METHODS

    p, method, row = cfg.ppo, METHODS[cfg.method], learner_row(cfg.learner)
    # One shared network with its one buffer (snddpg) is one central on-policy learner over every
    # robot's environments; a shared buffer under separate networks (seddpg) would train each
    # network on the others' actions, which an on-policy learner cannot.
    if row.on_policy and method.shared_buffer and not method.shared_network:
        raise ConfigError(
            f"{src}: method {cfg.method} shares one replay buffer between the robots' own networks; learner "
            f"{cfg.learner} learns on-policy from its own policy's rollout and cannot (use iddpg, snddpg or a "
            "federated method)"
        )
    if p.recurrent != "none" and "ppo" not in row.sections:
        raise ConfigError(f"{src}: ppo.recurrent ({p.recurrent!r}) needs learner: ppo (learner is {cfg.learner!r})")
    if p.normalize_obs and "ppo" not in row.sections:
        raise ConfigError(f"{src}: ppo.normalize_obs needs learner: ppo (learner is {cfg.learner!r})")
    _check_n_step(cfg, src, method, row.on_policy)
    if "ppo" in row.sections:
        # the environments of one rollout: a robot's, or every robot's under one shared network
        n = cfg.env.envs_per_robot * (cfg.num_robots if method.shared_network else 1)
        # a GRU's minibatches are whole sequences: they split the environments, not the rows
        recurrent = p.recurrent != "none"
        per = "env.envs_per_robot" + (" x robots" if method.shared_network else "")
        rows, what = (n, per) if recurrent else (p.rollout * n, f"ppo.rollout x {per}")
        if rows % p.minibatches:
            raise ConfigError(f"{src}: ppo.minibatches ({p.minibatches}) must divide {what} ({rows})")


def never_updates(cfg: Config) -> str | None:
    """Why the learner of this run could never update its networks, or None (docs/reliability.md,
    "Runs that cannot learn"): a warning, not a refusal, since a run that only drives (a smoke run
    of the pipeline) is a use; `training.run.train` prints it before training. From its row of
    the learner table: an update event follows step g (0-based,
    per environment) when g + 1 is a multiple of the row's `update_every` field (ppo.rollout,
    offpolicy.train_every: `due` in agents/learners.py and agents/learner_ppo.py), and, for a
    learner with a replay buffer, once that buffer has received a batch, (g + 1) x rows per step
    >= offpolicy.batch_size (`_ready`). The run has run.episodes x env.episode_length steps."""
    from fedjax_nav.methods import METHODS

    row = learner_row(cfg.learner)
    steps = cfg.run.episodes * cfg.env.episode_length
    whole = f"run.episodes x env.episode_length = {steps:,} steps per environment"
    every = get(cfg, row.update_every)
    if every > steps:
        return (
            f"{row.update_every} ({every:,} steps) is longer than the whole run ({whole}); "
            f"no update will happen: lower {row.update_every} or raise run.episodes"
        )
    if row.on_policy:
        return None
    shared = METHODS[cfg.method].shared_buffer
    rows = cfg.env.envs_per_robot * (cfg.num_robots if shared else 1)
    last = steps // every * every  # steps done at the run's last update event
    if last * rows < cfg.offpolicy.batch_size:
        per = "env.envs_per_robot" + (" x robots, one shared buffer" if shared else "")
        return (
            f"offpolicy.batch_size ({cfg.offpolicy.batch_size:,}) is more than the rows a replay buffer "
            f"has received at the run's last update event ({last:,} steps x {rows} per step ({per}) = "
            f"{last * rows:,}; {whole}, an update every {row.update_every} = {every}); "
            "no update will happen: lower offpolicy.batch_size or raise run.episodes"
        )
    return None


def _check_n_step(cfg: Config, src: str, method, on_policy: bool) -> None:
    """offpolicy.n_step: an off-policy learner's, and a window of n steps of every environment writing
    into one buffer must fit in it."""
    d = cfg.offpolicy
    if d.random_steps and on_policy:  # PPO learns from its own policy's actions
        raise ConfigError(
            f"{src}: offpolicy.random_steps ({d.random_steps}) needs an off-policy learner: {', '.join(off_policy())}"
        )
    if d.n_step == 1:
        return
    if on_policy:
        raise ConfigError(
            f"{src}: offpolicy.n_step ({d.n_step}) needs an off-policy learner: {', '.join(off_policy())} "
            f"(learner is {cfg.learner!r})"
        )
    rows = cfg.env.envs_per_robot * (cfg.num_robots if method.shared_buffer else 1)
    if d.n_step * rows > d.buffer_size:
        raise ConfigError(
            f"{src}: offpolicy.n_step ({d.n_step}) x rows written per step into one buffer ({rows}) is more than "
            f"offpolicy.buffer_size ({d.buffer_size}): a window of n steps must fit in the buffer"
        )


def _check_rooms(cfg: Config, src: str) -> None:
    """env.room_families against the families and the robot count (RoomSpec overrides are checked
    by the trainer, which imports the generator)."""
    fams, n = cfg.env.room_families, cfg.num_robots
    e = cfg.env
    if e.rooms != "procedural" and (e.room_curriculum_episodes or e.room_density_start != 1.0):
        field = "room_curriculum_episodes" if e.room_curriculum_episodes else "room_density_start"
        raise ConfigError(f"{src}: env.{field} thins procedural rooms; it needs env.rooms = procedural")
    if e.rooms != "procedural" and e.room_spec.strip():
        raise ConfigError(
            f"{src}: env.room_spec ({show(e.room_spec)}) shapes procedural rooms; it needs env.rooms = procedural "
            f"(env.rooms is {e.rooms!r})"
        )
    bad = [f for f in fams if f not in ROOM_FAMILIES]
    if bad:
        raise ConfigError(f"{src}: env.room_families: {show(bad[0])} is not one of {', '.join(ROOM_FAMILIES)}")
    if len(fams) not in (1, n):
        raise ConfigError(
            f"{src}: env.room_families has {len(fams)} entries; allowed: 1 (every robot) or one per "
            f"robot ({n}, env.worlds)"
        )


def _check_learnability(cfg: Config, src: str) -> None:
    """The learnability curriculum's fields (docs/generalization.md): they act on procedural rooms
    sampled by learnability only, and need at least one robot of a generated family."""
    e = cfg.env
    if e.room_sampling == "learnability":
        if e.rooms != "procedural":
            raise ConfigError(
                f"{src}: env.room_sampling = learnability draws procedural rooms; it needs env.rooms = procedural "
                f"(env.rooms is {e.rooms!r})"
            )
        if all(f == "fixed" for f in e.room_families):
            raise ConfigError(
                f"{src}: env.room_sampling = learnability needs a generated family in env.room_families "
                "(every robot keeps its fixed room)"
            )
        return
    defaults = {f.name: f.default for f in fields(type(e))}
    for name in ("room_bank", "room_fresh", "room_ema", "room_floor"):
        if getattr(e, name) != defaults[name]:
            raise ConfigError(
                f"{src}: env.{name} ({getattr(e, name)!r}) sets the learnability curriculum; it needs "
                f"env.room_sampling = learnability (env.room_sampling is {e.room_sampling!r})"
            )


def _check_fed(cfg: Config, src: str, federated: bool) -> None:
    """The robust-federation fields against each other, the method and the robot count."""
    f, n = cfg.fed, cfg.num_robots
    if not federated:
        for name, value, default in [
            ("aggregator", f.aggregator, "method"),
            ("byzantine", f.byzantine, 0),
            ("participation", f.participation, 1.0),
        ]:
            if value != default:
                raise ConfigError(
                    f"{src}: fed.{name} ({value!r}) needs a federated method; {cfg.method} has no "
                    f"federated step (allowed: {default!r})"
                )
    if f.byzantine >= n:
        raise ConfigError(
            f"{src}: fed.byzantine ({f.byzantine}) must be smaller than the number of robots ({n}, env.worlds)"
        )
    if f.min_clients > n:
        raise ConfigError(
            f"{src}: fed.min_clients ({f.min_clients}) is larger than the number of robots ({n}, "
            "env.worlds): every round would be skipped"
        )
    if (f.byzantine > 0) != (f.attack != "none"):
        raise ConfigError(
            f"{src}: fed.byzantine ({f.byzantine}) and fed.attack ({f.attack!r}) go together: "
            "set both (byzantine >= 1 and an attack) or neither"
        )
    if f.aggregator == "krum":
        if 2 * f.krum_f + 2 > n:
            raise ConfigError(
                f"{src}: fed.krum_f ({f.krum_f}) is too large for {n} robots: Krum needs "
                f"2 * fed.krum_f + 2 <= robots ({2 * f.krum_f + 2} > {n})"
            )
        if f.krum_m > n - f.krum_f:
            raise ConfigError(f"{src}: fed.krum_m ({f.krum_m}) must be <= robots - fed.krum_f ({n - f.krum_f})")
