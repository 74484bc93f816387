"""Placing a run on several devices and hosts: meshes, the sharding of the stacked TrainState,
and `jax.distributed` start-up.

The trainer's state is stacked `[seeds, clients, ...]` (clients = robots: agents, buffers, env
states, observations and reward sums carry the client axis; the exploration carry (DDPG: epsilon),
PRNG keys, reward step counts and the aggregator's state (GS's global model) do not). A mesh with an
axis named `"clients"` spreads the client axis over its devices, one named `"seeds"` the seed axis
(a 2-D mesh may name both). The trainer's program is unchanged: `jax.jit` with these shardings lets
XLA's SPMD partitioner run each client's env steps and DDPG updates on the device that holds it, and
turn the federated step's mean over the client axis into the cross-device collective.

Which leaves carry the client axis is decided by field name (`CLIENT_FIELDS`), not by shape.
"""

from __future__ import annotations

import dataclasses
import os

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

AXES = ("clients", "seeds")
# TrainState fields whose leaves are [seeds, clients, ...]; every other field is [seeds, ...].
# world: procedural rooms [robots]; memory, first: [environments] of the learners with a memory
CLIENT_FIELDS = ("agents", "buffers", "env_state", "obs", "reward_sum", "world", "memory", "first", "bank")


class ShardingError(ValueError):
    """A run cannot be placed on the mesh; the message names the numbers involved."""


def make_mesh(num_devices: int | None = None, axis: str = "clients", devices=None) -> Mesh:
    """A 1-D mesh over the first `num_devices` of `devices` (default: every device of every
    process, `jax.devices()`), with an Auto axis named `axis` ("clients" or "seeds")."""
    if axis not in AXES:
        raise ShardingError(f"mesh axis {axis!r}: allowed {', '.join(AXES)}")
    devices = list(jax.devices() if devices is None else devices)
    n = len(devices) if num_devices is None else num_devices
    if not 1 <= n <= len(devices):
        raise ShardingError(
            f"{n} devices asked for, {len(devices)} available "
            f"({jax.default_backend()}; on CPU set XLA_FLAGS=--xla_force_host_platform_device_count={n} "
            "before jax starts, e.g. `fedjax-nav train --devices N`)"
        )
    return Mesh(np.array(devices[:n]), (axis,), axis_types=(jax.sharding.AxisType.Auto,))


def _axis(mesh: Mesh | None, name: str) -> str | None:
    return name if mesh is not None and name in mesh.axis_names else None


def check_placement(mesh: Mesh, num_seeds: int, num_clients: int, shared_network: bool, shared_buffer: bool) -> None:
    """Raise ShardingError if the sharded axes do not divide evenly or cannot be split."""
    for name in mesh.axis_names:
        if name not in AXES:
            raise ShardingError(f"mesh axis {name!r}: allowed {', '.join(AXES)}")
    if _axis(mesh, "clients"):
        if shared_network or shared_buffer:
            what = "one network" if shared_network else "one replay buffer"
            raise ShardingError(
                f"the method shares {what} between every robot: its clients cannot be split over "
                "devices; shard the seeds instead (--shard seeds)"
            )
        n = mesh.shape["clients"]
        if num_clients % n:
            raise ShardingError(
                f"{num_clients} clients (robots) do not divide over {n} devices; use a device count "
                f"that divides {num_clients}, or --shard seeds"
            )
    if _axis(mesh, "seeds"):
        n = mesh.shape["seeds"]
        if num_seeds % n:
            raise ShardingError(
                f"{num_seeds} seeds do not divide over {n} devices; use a multiple of {n} seeds "
                "(--seeds), or fewer devices"
            )


def client_padding(mesh: Mesh | None, num_clients: int) -> int:
    """How many permanently masked clients make `num_clients` divide over the mesh's "clients"
    axis (0 without one): 5 robots on 2 devices run as 6 clients, one of them masked
    (`Trainer(cfg, pad=...)`; docs/robustness.md)."""
    if mesh is None or _axis(mesh, "clients") is None:
        return 0
    return -num_clients % mesh.shape["clients"]


def state_shardings(template, mesh: Mesh):
    """NamedShardings shaped like a stacked TrainState `template` (arrays or ShapeDtypeStructs)."""
    s, c = _axis(mesh, "seeds"), _axis(mesh, "clients")
    out = {}
    for f in dataclasses.fields(template):
        spec = P(s, c) if f.name in CLIENT_FIELDS and c else P(s)
        out[f.name] = jax.tree.map(lambda _, spec=spec: NamedSharding(mesh, spec), getattr(template, f.name))
    return template.replace(**out)


def seed_shardings(tree, mesh: Mesh):
    """Shardings for a tree whose leaves are scalars or [seeds, ...] (HParams, metrics)."""
    s = _axis(mesh, "seeds")
    return jax.tree.map(lambda x: NamedSharding(mesh, P(s) if np.ndim(x) else P()), tree)


def replicated(mesh: Mesh) -> NamedSharding:
    return NamedSharding(mesh, P())


def jit_chunk(fn, mesh: Mesh, states, hp):
    """jit of a chunk `fn(states, hp, first_episode)` placed on `mesh` (`Trainer.compiled_chunk`):
    the states (donated) keep their placement, the metrics come back replicated."""
    st, rep = state_shardings(states, mesh), replicated(mesh)
    return jax.jit(fn, donate_argnums=0, in_shardings=(st, seed_shardings(hp, mesh), rep), out_shardings=(st, rep))


def init_placed(init, mesh: Mesh, seeds, hp):
    """init(seeds, hp) created already placed on `mesh` (`Trainer.init_seeds`)."""
    return jax.jit(init, out_shardings=state_shardings(jax.eval_shape(init, seeds, hp), mesh))(seeds, hp)


def put(tree, shardings):
    """Place host or single-device values onto (possibly multi-process) shardings. Every process
    passes the same full values; each keeps only the shards its devices hold."""
    return jax.tree.map(_put_one, tree, shardings)


# ----------------------------------------------------------------------------- checkpoints
# One process: orbax writes the (sharded) arrays as they are, unchanged from a run without a
# mesh. Several processes: every process joins one gather of the state to host memory, then
# process 0 alone saves it (numpy arrays, PRNG keys as their raw key data) with a checkpoint
# manager that works without the others; every process can restore it into its own shards.


def _multi(mesh: Mesh | None) -> bool:
    return mesh is not None and jax.process_count() > 1


def _is_key(x) -> bool:
    return jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


def checkpoint_process(mesh: Mesh | None) -> int | None:
    """`Checkpointer(process=...)`: this process's index when several hold the run, else None."""
    return jax.process_index() if _multi(mesh) else None


def checkpoint_view(states, mesh: Mesh | None):
    """A copy of `states` to save or write out (the originals are donated to the next chunk):
    the same arrays in one process; with several, the whole state in host memory (numpy, keys
    as key data), in every process. The latter is a collective: every process must call it."""
    if not _multi(mesh):
        return jax.tree.map(lambda x: x.copy(), states)
    unkey = lambda x: jax.random.key_data(x) if _is_key(x) else x  # noqa: E731
    gathered = jax.jit(lambda s: jax.tree.map(unkey, s), out_shardings=replicated(mesh))(states)
    return jax.tree.map(np.asarray, gathered)


def checkpoint_template(states, mesh: Mesh | None):
    """What `Checkpointer.restore` restores into: `states` itself, or with several processes
    zeros shaped like `checkpoint_view` (built locally: no collective)."""
    if not _multi(mesh):
        return states
    unkey = lambda x: jax.eval_shape(jax.random.key_data, x) if _is_key(x) else x  # noqa: E731
    return jax.tree.map(lambda x: np.zeros(unkey(x).shape, unkey(x).dtype), states)


def from_checkpoint(restored, states, mesh: Mesh | None):
    """Restored states placed like `states` (the run's own shardings and PRNG key type)."""
    if not _multi(mesh):
        return restored
    rekey = lambda r, x: jax.random.wrap_key_data(r, impl=jax.random.key_impl(x)) if _is_key(x) else r  # noqa: E731
    return jax.tree.map(lambda r, x: _put_one(rekey(r, x), x.sharding), restored, states)


def _put_one(x, sharding):
    if isinstance(x, jax.Array) and _is_key(x):
        data = _put_one(jax.random.key_data(x), sharding)
        return jax.random.wrap_key_data(data, impl=jax.random.key_impl(x))
    x = np.asarray(jax.device_get(x))
    return jax.make_array_from_callback(x.shape, sharding, lambda idx: x[idx])


# ----------------------------------------------------------------------------- several processes

ENV_VARS = ("JAX_COORDINATOR_ADDRESS", "JAX_NUM_PROCESSES", "JAX_PROCESS_ID")


@dataclasses.dataclass(frozen=True)
class DistributedConfig:
    coordinator: str  # host:port of process 0's coordination service
    num_processes: int
    process_id: int


def distributed_config(
    coordinator: str | None = None, num_processes: int | None = None, process_id: int | None = None, environ=None
) -> DistributedConfig:
    """Flags, else the environment variables JAX_COORDINATOR_ADDRESS, JAX_NUM_PROCESSES and
    JAX_PROCESS_ID; raises ShardingError naming what is missing or out of range."""
    env = os.environ if environ is None else environ
    coordinator = coordinator or env.get("JAX_COORDINATOR_ADDRESS")
    missing = [
        name
        for name, v in [
            ("--coordinator / JAX_COORDINATOR_ADDRESS", coordinator),
            (
                "--num-processes / JAX_NUM_PROCESSES",
                num_processes if num_processes is not None else env.get("JAX_NUM_PROCESSES"),
            ),
            ("--process-id / JAX_PROCESS_ID", process_id if process_id is not None else env.get("JAX_PROCESS_ID")),
        ]
        if v in (None, "")
    ]
    if missing:
        raise ShardingError(f"--distributed needs {', '.join(missing)}")
    try:
        n = int(num_processes if num_processes is not None else env["JAX_NUM_PROCESSES"])
        i = int(process_id if process_id is not None else env["JAX_PROCESS_ID"])
    except ValueError as e:
        raise ShardingError(f"process count and id must be integers ({e})") from None
    if ":" not in coordinator:
        raise ShardingError(f"coordinator {coordinator!r}: expected HOST:PORT")
    if n < 1 or not 0 <= i < n:
        raise ShardingError(f"process id {i} with {n} processes: allowed 0 <= id < processes, processes >= 1")
    return DistributedConfig(coordinator, n, i)


def initialize_distributed(
    coordinator: str | None = None, num_processes: int | None = None, process_id: int | None = None
) -> DistributedConfig:
    """`jax.distributed.initialize` from flags or the usual environment variables; CPU
    collectives through gloo. Call before any other jax use. Returns what was used."""
    dc = distributed_config(coordinator, num_processes, process_id)
    jax.config.update("jax_cpu_collectives_implementation", "gloo")  # the default in jax 0.10; explicit
    jax.distributed.initialize(dc.coordinator, dc.num_processes, dc.process_id)
    return dc


def is_writer() -> bool:
    """True in the one process that writes results and checkpoints (process 0)."""
    return jax.process_index() == 0
