"""Config validation: types, ranges and choices per field (`_coerce`), the old names of moved fields
(`resolve_aliases`), the run sizes that follow `--episodes` (`fit_run_sizes`); the cross-field
checks are `config.checks`. Each error is one line naming the file and the field."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Collection
from dataclasses import fields
from typing import Any

from fedjax_nav.config.checks import check
from fedjax_nav.config.names import LEGACY_ALIASES, canonical, field_info
from fedjax_nav.config.schema import SECTIONS, TOP_LEVEL, Config, ConfigError
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
    """A config mapping with each old name `ddpg.<field>` of an offpolicy field (names.LEGACY_ALIASES)
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
