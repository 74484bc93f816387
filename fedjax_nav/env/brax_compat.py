"""Compatibility shim so that brax 0.14.2's trainers run on jax >= 0.10.

Why: brax 0.14.2 (the latest release on PyPI) calls `jax.device_put_replicated` in
`brax.training.agents.{ppo,sac,apg}.train` and in `brax.training.pmap.bcast_local_devices`.
jax deprecated that function in 0.8.1 and removed it in 0.10, so `ppo.train` / `sac.train` fail
with `AttributeError: module 'jax' has no attribute 'device_put_replicated'` as soon as training
starts (brax issue #671, https://github.com/google/brax/issues/671; fixed on brax's main branch,
not yet released). Everything else brax's training touches still works on jax 0.10.2 (checked:
the PPO and SAC trainers run end to end with this shim; see tests/test_brax.py and docs/brax.md).

We keep the current jax rather than pin `jax<0.10`: the rest of this package is written and
measured against jax 0.10, and one missing helper is cheaper to restore than a whole stack to hold
back.

TODO: delete this module (and its calls) once brax releases the fix for issue #671; after that
`ensure_device_put_replicated()` is already a no-op because `jax.device_put_replicated` exists or
brax no longer needs it.

This module does not import brax (importing brax prints a "Failed to import warp" line).
"""

from __future__ import annotations

from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

__all__ = ["device_put_replicated", "ensure_device_put_replicated"]

_AXIS = "_device_put_replicated"


def device_put_replicated(x: Any, devices: Sequence[jax.Device]) -> Any:
    """The semantics of the removed `jax.device_put_replicated(x, devices)`.

    Every leaf of the pytree `x` is broadcast along a new leading axis of size `len(devices)`;
    slice `i` of that axis lives on `devices[i]` (a `NamedSharding` over a 1-D mesh of the given
    devices, which is what jax's last implementation built too). The result feeds `jax.pmap`
    and brax's `_unpmap` (`x.addressable_shards[0].data.squeeze(0)`) exactly as before.
    """
    if isinstance(devices, (str, bytes)) or not isinstance(devices, Sequence) or len(devices) == 0:
        raise ValueError("`devices` argument to `device_put_replicated` must be a non-empty sequence of devices")
    devices = list(devices)
    n = len(devices)
    sharding = NamedSharding(Mesh(np.array(devices), (_AXIS,)), PartitionSpec(_AXIS))

    def put(leaf):
        leaf = jnp.asarray(leaf)
        return jax.device_put(jnp.broadcast_to(leaf[None], (n, *leaf.shape)), sharding)

    return jax.tree.map(put, x)


def ensure_device_put_replicated() -> bool:
    """Install `device_put_replicated` as `jax.device_put_replicated` if jax lacks it.

    Call before `brax.training.agents.ppo.train` / `sac.train`. Idempotent; never replaces a
    function jax itself provides. Returns True if it installed the shim (now or earlier).
    """
    current = getattr(jax, "device_put_replicated", None)
    if current is None:
        jax.device_put_replicated = device_put_replicated  # type: ignore[attr-defined]
        return True
    return current is device_put_replicated
