"""The traced values of a config as typed structs, generated from the `traced=True` fields (the one
declaration of sweepability, `fedjax_nav.config`): one flax.struct dataclass per config section
with traced fields, and `HParams`, a struct of those section structs.

    hp = hparams_from_config(cfg)      # HParams(env=EnvTraced(dt=f32[], ...), offpolicy=OffPolicyTraced(...), ...)
    hp.td3.tau, hp.env.v_max, hp.fed.tau
    hp.to_flat()                       # {"offpolicy.gamma": f32[], ...}: sweeps stack and compare by name
    HParams.from_flat(flat)            # back
    HParams().replace_flat({"td3.tau": 0.25})   # the config's defaults (Python scalars), one value changed
    hp | {"fed.tau": 1.0}              # the same as replace_flat

A struct is a pytree (jit, vmap, shardings take it as it is); each leaf is a scalar, or [rows] when a
sweep batches it (training.hparams). The agents read these attributes duck-typed (the agents layer
does not import config): docs/learners.md lists which. Like `config.envs`, this module imports jax;
`import fedjax_nav.config` alone does not load it.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from fedjax_nav.config.names import field_info, get, traced_fields
from fedjax_nav.config.schema import SECTIONS, Config


def dtype(name: str):
    """int32 for integer fields, float32 for the rest (the program's precision)."""
    typ = field_info(name).type
    return jnp.int32 if typ in (int, "int") else jnp.float32


def _section_struct(cls) -> type | None:
    """A flax.struct dataclass of `cls`'s traced fields, each defaulting to the config's default."""
    traced = [f for f in dataclasses.fields(cls) if f.metadata.get("traced")]
    if not traced:
        return None
    name = cls.__name__.removesuffix("Config") + "Traced"
    ns = {"__annotations__": {f.name: Any for f in traced}, "__module__": __name__, "__qualname__": name}
    ns.update({f.name: f.default for f in traced})
    ns["__doc__"] = f"The traced fields of the config's {cls.__name__} (generated: fedjax_nav/config/traced.py)."
    return struct.dataclass(type(name, (), ns))


SECTION_STRUCTS: dict[str, type] = {s: c for s, cls in SECTIONS.items() if (c := _section_struct(cls)) is not None}
globals().update({c.__name__: c for c in SECTION_STRUCTS.values()})  # picklable by name: EnvTraced, OffPolicyTraced...


def _flat(self) -> dict[str, Any]:
    """Every leaf by dotted config name ({"offpolicy.gamma": ..., ...}), in the table's order."""
    return {f"{s}.{k}": getattr(getattr(self, s), k) for s, c in SECTION_STRUCTS.items() for k in _names(c)}


def _names(c) -> tuple[str, ...]:
    return tuple(f.name for f in dataclasses.fields(c))


@classmethod
def _from_flat(cls, flat: dict[str, Any]):
    """The HParams of a {dotted name: leaf} mapping holding exactly `traced_fields()`."""
    if set(flat) != set(traced_fields()):
        extra, missing = sorted(set(flat) - set(traced_fields())), sorted(set(traced_fields()) - set(flat))
        raise ValueError(f"HParams.from_flat: unknown {extra}, missing {missing}")
    return cls(**{s: c(**{k: flat[f"{s}.{k}"] for k in _names(c)}) for s, c in SECTION_STRUCTS.items()})


def _replace_flat(self, values: dict[str, Any]):
    """A copy with the leaves of some dotted names replaced."""
    unknown = sorted(set(values) - set(traced_fields()))
    if unknown:
        raise ValueError(f"HParams.replace_flat: not traced fields: {unknown}")
    return type(self).from_flat({**self.to_flat(), **values})


HParams = struct.dataclass(
    type(
        "HParams",
        (),
        {
            "__annotations__": dict.fromkeys(SECTION_STRUCTS, Any),
            "__module__": __name__,
            "__qualname__": "HParams",
            "__doc__": "The traced config values: one struct per section (hp.td3.tau); generated from the config.",
            **{s: dataclasses.field(default_factory=c) for s, c in SECTION_STRUCTS.items()},
            "to_flat": _flat,
            "from_flat": _from_flat,
            "replace_flat": _replace_flat,
            "__or__": _replace_flat,  # hp | {"fed.tau": x}, as the dict it replaced
        },
    )
)


def hparams_from_config(cfg: Config) -> HParams:
    """The config's traced values as JAX scalars of their dtypes."""
    return HParams.from_flat({name: jnp.asarray(get(cfg, name), dtype(name)) for name in traced_fields()})


def shapes() -> HParams:
    """Every traced value as a scalar ShapeDtypeStruct (jax.eval_shape of a learner's init)."""
    return HParams.from_flat({name: jax.ShapeDtypeStruct((), dtype(name)) for name in traced_fields()})
