"""Config files: YAML reading (one-line errors for any unreadable input), `--set` overrides,
loading, saving and diffing resolved configs."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import yaml

from fedjax_nav.config.names import LEGACY_ALIASES, canonical
from fedjax_nav.config.schema import SECTIONS, TOP_LEVEL, Config, ConfigError
from fedjax_nav.config.validate import from_dict
from fedjax_nav.messages import shorten, show

# Bounds of what is read (docs/reliability.md, "Hostile inputs"): a config or sweep file is a few
# KiB and a few hundred values (the largest shipped ones: 1.4 KiB, 75 values).
MAX_FILE_BYTES = 2**20
MAX_NODES = 100_000  # values once YAML aliases are expanded
PATH_CHARS = 240  # a file name longer than this is cut in messages


def to_dict(cfg: Config) -> dict:
    """The config as the YAML file holds it: the top-level fields (method, learner), then each
    section."""
    out = {name: getattr(cfg, name) for name in TOP_LEVEL}
    for s in SECTIONS:
        sec = dataclasses.asdict(getattr(cfg, s))
        out[s] = {k: list(v) if isinstance(v, tuple) else v for k, v in sec.items()}
    return out


def apply_overrides(data: dict, overrides: list[str], src: str = "--set", base: str | None = None) -> dict:
    """Apply `section.key=value` strings (values parsed as YAML) to a config dict (a copy).

    `src` names the overrides in errors about them; `base` names where `data` came from (its
    file) in errors about `data` itself (not a mapping, a section that is not one): `src` if None.

    An offpolicy field's override replaces it under both its names (`offpolicy.gamma` and its old
    name `ddpg.gamma`, names.LEGACY_ALIASES) and is kept under the name it was given, which
    `from_dict` then reads and names in its messages."""
    import copy

    base = src if base is None else base
    if not isinstance(data, dict):
        raise ConfigError(f"{base}: the config must be a mapping with keys {', '.join((*TOP_LEVEL, *SECTIONS))}")
    data = copy.deepcopy(data)
    for item in overrides:
        if "=" not in item:
            raise ConfigError(f"{src}: {show(item)} is not of the form key=value (e.g. offpolicy.gamma=0.99)")
        key, raw = item.split("=", 1)
        key = key.strip()
        label = shorten(key) if key.isprintable() else show(key)  # a key with a newline: its repr (one line)
        value = parse_yaml(raw, f"{src} {label}")
        parts = key.split(".")
        if len(parts) == 1 and parts[0] in TOP_LEVEL:  # method=..., learner=...
            data[parts[0]] = value
            continue
        if len(parts) != 2 or parts[0] not in SECTIONS:
            raise ConfigError(f"{src}: unknown key {show(key)} (use section.key with section in {', '.join(SECTIONS)})")
        if data.get(parts[0]) is None:
            data[parts[0]] = {}
        if not isinstance(data[parts[0]], dict):
            raise ConfigError(f"{base}: '{parts[0]}' must be a mapping, got {type(data[parts[0]]).__name__}")
        for other in _spellings(key) - {key}:  # the field's other name: this override replaces it
            section, name = other.split(".")
            if isinstance(data.get(section), dict):
                data[section].pop(name, None)
        data[parts[0]][parts[1]] = value
    return data


def _spellings(dotted: str) -> set[str]:
    """Every name of the field `dotted` means: itself, and its old name or its new one (LEGACY_ALIASES)."""
    new = canonical(dotted)
    return {new, *(old for old, n in LEGACY_ALIASES.items() if n == new)}


def overridden_keys(overrides: list[str]) -> set[str]:
    """The dotted keys that `section.key=value` strings set ("method" included)."""
    return {item.split("=", 1)[0].strip() for item in overrides if "=" in item}


def locate(path: str | Path, kind: str = "config") -> Path:
    """The file behind a path or shipped name of `kind` ("config" or "sweep"); a name that cannot
    even be looked up (a NUL byte, longer than the system allows: an OSError of `Path.exists`)
    or does not exist is one ConfigError, its name cut to PATH_CHARS."""
    from fedjax_nav.configs import names, resolve

    try:
        found = resolve(path, kind)
        exists = found.exists()
    except (OSError, ValueError) as e:  # e.g. a NUL byte or an over-long name
        why = getattr(e, "strerror", None) or type(e).__name__
        raise ConfigError(f"{shorten(str(path), PATH_CHARS)}: cannot be read as a {kind} file ({why})") from None
    if not exists:
        if why := _input_files().missing_link(found):  # a symlink loop is not "no such file"
            raise ConfigError(f"{shorten(str(found), PATH_CHARS)}: {why}; not a {kind} file")
        raise ConfigError(
            f"{shorten(str(found), PATH_CHARS)}: no such {kind} file (shipped {kind}s: {', '.join(names(kind))})"
        )
    return found


def _input_files():
    """`worlds.input_files`, the one reader of users' files: imported when first needed (the worlds
    package imports jax; `import fedjax_nav.config` does not)."""
    from fedjax_nav.worlds import input_files

    return input_files


def read_yaml(path: str | Path, kind: str = "config") -> Any:
    """A config (or sweep) file's content (an empty file: {}); `path` may also be a shipped name
    (`thesis/flddpg`). Bounded: a regular file of at most MAX_FILE_BYTES, at most MAX_NODES values."""
    path = locate(path, kind)
    data = parse_yaml(read_text(path, kind), str(path))
    return {} if data is None else data


def read_text(path: Path, kind: str = "config") -> str:
    """A UTF-8 text file's content (a regular file of at most MAX_FILE_BYTES); any problem
    reading it is one ConfigError naming the file."""
    input_files = _input_files()
    try:
        return input_files.read_text(path, kind, MAX_FILE_BYTES)
    except input_files.InputError as e:
        raise ConfigError(f"{shorten(str(path), PATH_CHARS)}: {e}") from None


def parse_yaml(text: str, src: str) -> Any:
    """YAML (safe, bounded: `input_files.load_yaml`); a problem is one ConfigError line naming
    `src`, 'not valid YAML (line L, column C: problem)'. Refused: more than MAX_NODES values
    once aliases are expanded, recursive aliases, a key given twice in one mapping."""
    input_files = _input_files()
    try:
        return input_files.load_yaml(text, MAX_NODES)
    except input_files.InputError as e:
        raise ConfigError(f"{src}: {e}") from None


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> Config:
    """The config of a file or shipped name (`thesis/flddpg`), with `section.key=value` overrides.

    An error in a value given by `--set` names `--set` and the key as given (`--set: offpolicy.gamma: ...`,
    or `--set offpolicy.gamma: not valid YAML ...`); one in the file names the file; a cross-field error
    names the file "(with --set)"."""
    path = locate(path, "config") if path else None
    data = read_yaml(path) if path else {}
    src = str(path) if path else "<defaults>"
    if not overrides:
        return from_dict(data, src)
    data = apply_overrides(data, overrides, base=src)
    return from_dict(data, src, overridden=overridden_keys(overrides))


def save_config(cfg: Config, path: str | Path) -> None:
    Path(path).write_text(yaml.safe_dump(to_dict(cfg), sort_keys=False))


def diff(a: Config, b: Config) -> list[str]:
    """Dotted names of the fields that differ."""
    da, db = to_dict(a), to_dict(b)
    out = [name for name in TOP_LEVEL if da[name] != db[name]]
    for s in SECTIONS:
        out += [f"{s}.{k}" for k in da[s] if da[s][k] != db[s][k]]
    return out
