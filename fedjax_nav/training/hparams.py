"""HParams: the traced values of a config, typed (`fedjax_nav.config.traced`: one struct per
section, generated from the `traced=True` fields), and their stacking for sweeps.

    hp = hparams_from_config(cfg)     # hp.offpolicy.gamma: f32[], hp.env.v_max: f32[], ...
    hp.fed.tau

Each leaf is a scalar, or [rows] when a sweep batches it; `hp_axes` gives the matching vmap axes.
Sweeps compare and stack rows by dotted name (`HParams.to_flat` / `from_flat`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from fedjax_nav.config.traced import HParams, dtype, hparams_from_config

__all__ = ["HParams", "dtype", "hp_axes", "hparams_from_config", "stack_hparams", "varying_fields"]


def hp_axes(hp: HParams):
    """vmap in_axes for HParams: 0 for leaves with a batch axis, None for scalars."""
    return jax.tree.map(lambda x: 0 if jnp.ndim(x) else None, hp)


def varying_fields(hps: list[HParams]) -> frozenset:
    """Dotted names whose value differs between rows (they get a batch axis; the rest stay
    scalars, so that the period gates they drive stay real conds)."""
    flat = [h.to_flat() for h in hps]
    return frozenset(
        k for k in flat[0] if any(not np.array_equal(np.asarray(f[k]), np.asarray(flat[0][k])) for f in flat[1:])
    )


def stack_hparams(hps: list[HParams], batched: frozenset | None = None) -> HParams:
    """Rows' HParams -> one HParams with leaves [rows] for the names in `batched` (default: those
    that differ between these rows) and scalars for the rest."""
    batched = varying_fields(hps) if batched is None else batched
    flat = [h.to_flat() for h in hps]
    return HParams.from_flat(
        {
            k: jnp.asarray(np.stack([np.asarray(f[k]) for f in flat])) if k in batched else jnp.asarray(flat[0][k])
            for k in flat[0]
        }
    )
