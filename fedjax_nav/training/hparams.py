"""HParams: the traced values of a config, keyed by their config names.

    hp = hparams_from_config(cfg)     # {"ddpg.gamma": f32[], "env.v_max": f32[], ...}
    hp["fed.tau"]

The keys are exactly `fedjax_nav.config.traced_fields()` (the fields declared `traced=True`):
one declaration, so a field marked traced is traced everywhere. Each leaf is a scalar, or
[rows] when a sweep batches it; `hp_axes` gives the matching vmap axes. A plain dict is a
pytree, so jit, vmap, shardings and checkpoints take it as it is.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from fedjax_nav.config import Config, field_info, get, traced_fields

HParams = dict  # str -> jax.Array


def dtype(name: str):
    """int32 for integer fields, float32 for the rest."""
    typ = field_info(name).type
    return jnp.int32 if typ in (int, "int") else jnp.float32


def hparams_from_config(cfg: Config) -> HParams:
    return {name: jnp.asarray(get(cfg, name), dtype(name)) for name in traced_fields()}


def hp_axes(hp: HParams):
    """vmap in_axes for HParams: 0 for leaves with a batch axis, None for scalars."""
    return jax.tree.map(lambda x: 0 if jnp.ndim(x) else None, hp)


def varying_fields(hps: list[HParams]) -> frozenset:
    """Names whose value differs between rows (they get a batch axis; the rest stay scalars, so
    that the period gates they drive stay real conds)."""
    return frozenset(
        k for k in hps[0] if any(not np.array_equal(np.asarray(h[k]), np.asarray(hps[0][k])) for h in hps[1:])
    )


def stack_hparams(hps: list[HParams], batched: frozenset | None = None) -> HParams:
    """Rows' HParams -> one HParams with leaves [rows] for the names in `batched` (default: those
    that differ between these rows) and scalars for the rest."""
    batched = varying_fields(hps) if batched is None else batched
    return {
        k: jnp.asarray(np.stack([np.asarray(h[k]) for h in hps])) if k in batched else jnp.asarray(hps[0][k])
        for k in hps[0]
    }
