"""Config files: YAML reading (one-line errors for any unreadable input), `--set` overrides,
loading, saving and diffing resolved configs."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import yaml

from fedjax_nav.config import SECTIONS, Config, ConfigError
from fedjax_nav.config.validate import from_dict


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
            raise ConfigError(f"{src}: {item!r} is not of the form key=value (e.g. ddpg.gamma=0.99)")
        key, raw = item.split("=", 1)
        value = parse_yaml(raw, f"{src} {key.strip()}")
        parts = key.strip().split(".")
        if parts == ["method"]:
            data["method"] = value
            continue
        if len(parts) != 2 or parts[0] not in SECTIONS:
            raise ConfigError(f"{src}: unknown key {key!r} (use section.key with section in {', '.join(SECTIONS)})")
        if not isinstance(data, dict):
            raise ConfigError(f"{src}: the config must be a mapping with keys method, env, ddpg, fed, run")
        data.setdefault(parts[0], {})
        if data[parts[0]] is None:
            data[parts[0]] = {}
        if not isinstance(data[parts[0]], dict):
            raise ConfigError(f"{src}: '{parts[0]}' must be a mapping, got {type(data[parts[0]]).__name__}")
        data[parts[0]][parts[1]] = value
    return data


def read_yaml(path: str | Path, kind: str = "config") -> dict:
    """A config (or sweep) file's mapping; `path` may also be a shipped name (`thesis/flddpg`)."""
    from fedjax_nav.configs import names, resolve

    try:
        path = resolve(path, kind)
        exists = path.exists()
    except (OSError, ValueError) as e:  # e.g. a NUL byte or an over-long name
        raise ConfigError(f"{path}: cannot be read as a {kind} file ({type(e).__name__})") from None
    if not exists:
        raise ConfigError(f"{path}: no such {kind} file (shipped {kind}s: {', '.join(names(kind))})")
    return parse_yaml(read_text(path, kind), str(path)) or {}


def read_text(path: Path, kind: str = "config") -> str:
    """A UTF-8 text file's content; any problem reading it is one ConfigError naming the file."""
    try:
        return Path(path).read_text(encoding="utf-8")
    except UnicodeDecodeError as e:
        raise ConfigError(f"{path}: not UTF-8 text (byte {e.start}); a {kind} file must be UTF-8 YAML") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a directory, not a {kind} file") from None
    except OSError as e:  # permission denied, I/O errors, ...
        raise ConfigError(f"{path}: cannot be read ({e.strerror or type(e).__name__})") from None


def parse_yaml(text: str, src: str) -> Any:
    """yaml.safe_load; a parser error is one ConfigError line naming `src`, 'line L, column C: problem'."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None) or getattr(e, "context_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        problem = " ".join(f"{where}{getattr(e, 'problem', None) or getattr(e, 'context', None) or e}".split())
        raise ConfigError(f"{src}: not valid YAML ({problem})") from None
    except Exception as e:  # e.g. RecursionError on absurd nesting
        raise ConfigError(f"{src}: not valid YAML ({type(e).__name__})") from None


def load_config(path: str | Path | None = None, overrides: list[str] | None = None) -> Config:
    """The config of a file or shipped name (`thesis/flddpg`), with `section.key=value` overrides."""
    from fedjax_nav.configs import resolve

    path = resolve(path) if path else None
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
