"""Configuration: frozen dataclasses that map one to one onto the YAML files.

A config file has the `method`, the `learner` and the sections `env`, `offpolicy` (the settings the
replay learners ddpg, td3 and sac share), `ddpg`, `td3`, `sac`, `ppo`, `fed`, `run`, `robot`. An
offpolicy field may still be written by its old name, `ddpg.<field>` (`LEGACY_ALIASES`). Every field has
a default, a type, an allowed range or set, and a note of whether it is *traced* (a JAX value:
it can be swept in one compiled program) or *static* (it fixes shapes or the program).

`traced=True` on a field is the one declaration of sweepability: `traced_fields()`, the trainer's
`HParams` (`fedjax_nav.training.hparams`), the sweeps' grouping and the docs are derived from it,
as rejax declares it once on the field.

    cfg = load_config("configs/thesis/flddpg.yaml", overrides=["offpolicy.gamma=0.99"])

Unknown keys, wrong types and out-of-range values raise `ConfigError`, naming the file, the key
and what is allowed.
"""

from __future__ import annotations

from fedjax_nav.config.checks import check, never_updates
from fedjax_nav.config.io import (
    apply_overrides,
    diff,
    load_config,
    parse_yaml,
    read_text,
    read_yaml,
    save_config,
    to_dict,
)
from fedjax_nav.config.names import LEGACY_ALIASES, canonical, field_info, get, traced_fields, values
from fedjax_nav.config.schema import (
    ATTACKS,
    LEARNERS,
    METHODS,
    ROBOT_MODELS,
    ROBUST_AGGREGATORS,
    ROOM_FAMILIES,
    ROOM_SOURCES,
    SECTIONS,
    TOP_LEVEL,
    Config,
    ConfigError,
    DDPGConfig,
    EnvConfig,
    FedConfig,
    OffPolicyConfig,
    PPOConfig,
    RobotConfig,
    RunConfig,
    SACConfig,
    TD3Config,
)
from fedjax_nav.config.validate import from_dict, resolve_aliases

__all__ = [
    "ATTACKS",
    "LEARNERS",
    "LEGACY_ALIASES",
    "METHODS",
    "ROBOT_MODELS",
    "ROBUST_AGGREGATORS",
    "ROOM_FAMILIES",
    "ROOM_SOURCES",
    "SECTIONS",
    "TOP_LEVEL",
    "Config",
    "ConfigError",
    "DDPGConfig",
    "EnvConfig",
    "FedConfig",
    "OffPolicyConfig",
    "PPOConfig",
    "RobotConfig",
    "RunConfig",
    "SACConfig",
    "TD3Config",
    "apply_overrides",
    "canonical",
    "check",
    "never_updates",
    "diff",
    "field_info",
    "from_dict",
    "get",
    "load_config",
    "parse_yaml",
    "read_text",
    "read_yaml",
    "resolve_aliases",
    "save_config",
    "to_dict",
    "traced_fields",
    "values",
]
