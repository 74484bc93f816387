"""Dotted config names ("offpolicy.gamma", "method"): the old names they still answer to, the
traced fields, a field's declaration and a config's values by name (docs/learners.md,
"Configuration"). The sections themselves are declared in `config.schema`."""

from __future__ import annotations

import dataclasses
from dataclasses import fields

from fedjax_nav.config.schema import SECTIONS, TOP_LEVEL, Config, OffPolicyConfig

# The off-policy settings lived in the ddpg section until the offpolicy section held them. Each
# keeps its old name `ddpg.<field>` as an alias wherever a field is written: a config file, a run's
# saved config.yaml, `--set`, a sweep file's keys and `set:` (docs/learners.md, "Configuration").
# Derived, not listed: every field of OffPolicyConfig was a field of the ddpg section, and no field
# of DDPGConfig shares a name with one (tests/test_config.py). Point ids hash the old names
# (config.sweepfile.point_id), so that every finished run keeps its id.
LEGACY_ALIASES = {f"ddpg.{f.name}": f"offpolicy.{f.name}" for f in fields(OffPolicyConfig)}


def canonical(dotted: str) -> str:
    """The field a dotted name means: `offpolicy.<field>` for its old name `ddpg.<field>`
    (LEGACY_ALIASES); any other name as it is."""
    return LEGACY_ALIASES.get(dotted, dotted)


def traced_fields() -> tuple[str, ...]:
    """Dotted names of the fields that are JAX values (sweepable in one compilation): exactly the
    fields declared with `traced=True`."""
    return tuple(f"{s}.{f.name}" for s, cls in SECTIONS.items() for f in fields(cls) if f.metadata.get("traced"))


def field_info(dotted: str) -> dataclasses.Field:
    """The dataclass field behind a dotted name ("offpolicy.gamma", its old name "ddpg.gamma", or
    "method" / "learner")."""
    dotted = canonical(dotted)
    if dotted in TOP_LEVEL:
        return {f.name: f for f in fields(Config)}[dotted]
    section, name = dotted.split(".")
    return {f.name: f for f in fields(SECTIONS[section])}[name]


def get(cfg: Config, dotted: str):
    """The value of a dotted name ("offpolicy.gamma", its old name "ddpg.gamma", or "method" /
    "learner")."""
    dotted = canonical(dotted)
    if dotted in TOP_LEVEL:
        return getattr(cfg, dotted)
    section, name = dotted.split(".")
    return getattr(getattr(cfg, section), name)


def values(cfg: Config) -> dict:
    """Every field's value by dotted name ({"learner": "ddpg", "offpolicy.hidden": 64, ...}): what a
    learner's `make_nets` reads its static sizes from (the agents layer does not import config)."""
    out = {name: getattr(cfg, name) for name in TOP_LEVEL}
    for s, cls in SECTIONS.items():
        out.update({f"{s}.{f.name}": getattr(getattr(cfg, s), f.name) for f in fields(cls)})
    return out
