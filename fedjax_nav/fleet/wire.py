"""What travels between a fleet's processes (docs/fleet.md): a config as YAML text, pytrees as
flat {path: numpy array} dicts (PRNG keys as their key data), rebuilt against a template."""

from __future__ import annotations

import jax
import numpy as np
import yaml

from fedjax_nav.config import Config, from_dict, to_dict


def config_text(cfg: Config) -> str:
    return yaml.safe_dump(to_dict(cfg), sort_keys=False)


def config_from_text(text: str) -> Config:
    return from_dict(yaml.safe_load(text), "<fleet config>")


def _is_key(x) -> bool:
    return jax.dtypes.issubdtype(getattr(x, "dtype", np.float32), jax.dtypes.prng_key)


def pack(tree) -> dict[str, np.ndarray]:
    """{jax.tree_util.keystr(path): numpy leaf} (PRNG keys as their key data)."""
    flat = jax.tree_util.tree_flatten_with_path(tree)[0]
    return {
        jax.tree_util.keystr(p): np.asarray(jax.random.key_data(x) if _is_key(x) else x)
        for p, x in jax.device_get(flat)
    }


def unpack(template, arrays: dict[str, np.ndarray]):
    """`pack`'s inverse: the leaves of `arrays` in `template`'s structure (a missing path is a
    one-line KeyError naming it)."""
    flat, treedef = jax.tree_util.tree_flatten_with_path(template)
    leaves = []
    for path, t in flat:
        name = jax.tree_util.keystr(path)
        if name not in arrays:
            raise KeyError(f"fleet message: no array {name!r}")
        x = arrays[name]
        leaves.append(jax.random.wrap_key_data(x) if _is_key(t) else jax.numpy.asarray(x, t.dtype))
    return jax.tree_util.tree_unflatten(treedef, leaves)


SHARED = "shared"  # the prefix of a learner's shared fields among a message's arrays


def shared_arrays(tree) -> dict[str, np.ndarray]:
    """`pack` of a tree of shared fields, each path prefixed with SHARED (a message's form)."""
    return {SHARED + k: v for k, v in pack(tree).items()}


def shared_fields(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """`shared_arrays`' inverse on a message's arrays: the shared fields by their tree paths."""
    return {k.removeprefix(SHARED): v for k, v in arrays.items() if k.startswith(SHARED)}
