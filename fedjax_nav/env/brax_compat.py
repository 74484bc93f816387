"""Compatibility shim so that brax 0.14.2's trainers run on jax >= 0.10.

Why: brax 0.14.2 (the latest release on PyPI) calls `jax.device_put_replicated` in
`brax.training.agents.{ppo,sac,apg}.train` and in `brax.training.pmap.bcast_local_devices`.
jax deprecated that function in 0.8.1 and removed it in 0.10, so `ppo.train` / `sac.train` fail
with `AttributeError: module 'jax' has no attribute 'device_put_replicated'` as soon as training
starts (the upstream report: https://github.com/google/brax/issues/671; fixed on brax's main branch,
not yet released). Everything else brax's training touches still works on jax 0.10.2 (checked:
the PPO and SAC trainers run end to end with this shim; see tests/test_brax.py and docs/brax.md).

We keep the current jax rather than pin `jax<0.10`: the rest of this package is written and
measured against jax 0.10, and one missing helper is cheaper to restore than a whole stack to hold
back.

How it is applied: `fedjax_nav.env.brax_env.register()`, which runs when that module is imported
(the import that registers "fedjax_nav" with brax), calls `ensure_device_put_replicated()`. So
`brax.envs.get_environment("fedjax_nav")` followed by brax's own `ppo.train` / `sac.train` works
with no call by the user. It installs the function only when jax lacks it, never replaces jax's
own, and a second call changes nothing. Code that uses brax's trainers on its own envs without
importing `brax_env` can call `ensure_device_put_replicated()` itself.

When to delete: once a brax release after 0.14.2 no longer calls `jax.device_put_replicated`
(check: `grep -rn device_put_replicated "$(python -c 'import brax, os; print(os.path.dirname(brax.__file__))')"`
finds nothing) and the project requires that release, delete this module, its call in
`brax_env.register` and its tests in tests/test_brax.py. Until then the install is harmless on a
jax that still has the function (it is a no-op there).

This module does not import brax (brax's import is slow and prints mjx's "Failed to import warp").
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

    `fedjax_nav.env.brax_env` calls it on import; call it yourself only before brax's trainers on
    envs of your own. Idempotent; never replaces a function jax itself provides. Returns True if
    it installed the shim (now or earlier).
    """
    current = getattr(jax, "device_put_replicated", None)
    if current is None:
        jax.device_put_replicated = device_put_replicated  # type: ignore[attr-defined]
        return True
    return current is device_put_replicated
