"""Resource checks before a run allocates anything: the memory its state will take, by part.

`jax.eval_shape` of the trainer's `init` gives the exact bytes of one seed's `TrainState` without
allocating it (as the sweeps' `row_bytes` does); `check_memory` refuses a run whose estimate
exceeds the budget, with one line naming the config field that dominates (docs/reliability.md).
"""

from __future__ import annotations

import os
from pathlib import Path

import jax
import numpy as np

from fedjax_nav.config import ConfigError
from fedjax_nav.training.hparams import hparams_from_config
from fedjax_nav.training.sweep.spec import STATE_BYTES_FACTOR
from fedjax_nav.training.trainer import Trainer

# Host bytes per metrics row (episode x seed x robot): the arrays, the pandas frame and its CSV text.
METRICS_ROW_BYTES = 16 * 8 * 3


class ResourceError(ConfigError):
    """The run would need more memory than the budget; the message names the field (exit 2)."""


def available_memory() -> int:
    """The memory available now (Linux /proc/meminfo MemAvailable; else the physical memory)."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def _nbytes(tree) -> int:
    return int(
        sum(
            int(np.prod(x.shape)) * x.dtype.itemsize
            for x in jax.tree.leaves(tree)
            if hasattr(x, "dtype") and not jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)
        )
    )


def memory_estimate(trainer: Trainer) -> dict[str, int]:
    """Bytes of a run of `trainer.cfg` by part (every seed): "buffers" (replay), "networks"
    (actors, critics, targets, Adam states, the aggregator's models), "env" (env states,
    observations, counters), "metrics" (host tables of every episode), "worlds", and "total":
    the state parts times STATE_BYTES_FACTOR (a chunk's peak: donated state, outputs, copies)
    plus the others."""
    cfg = trainer.cfg
    hp = hparams_from_config(cfg)
    shapes = jax.eval_shape(lambda k: trainer.init(k, hp), jax.random.key(0))
    S = cfg.run.seeds
    buffers = _nbytes(shapes.buffers) * S
    networks = (_nbytes(shapes.agents) + _nbytes(shapes.agg_state)) * S
    env = _nbytes(shapes) * S - buffers - networks
    metrics = cfg.run.episodes * S * cfg.num_robots * METRICS_ROW_BYTES
    worlds = _nbytes(trainer.world)
    total = STATE_BYTES_FACTOR * (buffers + networks + env) + metrics + worlds
    return {
        "buffers": buffers,
        "networks": networks,
        "env": env,
        "metrics": metrics,
        "worlds": worlds,
        "total": total,
    }


def _size(n: float) -> str:
    for unit, f in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= f:
            return f"{n / f:.1f} {unit}"
    return f"{int(n)} B"


def check_memory(trainer: Trainer, budget: int | None = None, src: str = "config") -> dict[str, int]:
    """Raise ResourceError when the run's estimate exceeds `budget` bytes (default: the memory
    available now), naming the field behind the largest part; return the estimate."""
    est = memory_estimate(trainer)
    limit = available_memory() if budget is None else int(budget)
    if est["total"] <= limit:
        return est
    cfg = trainer.cfg
    buffer_field = "ddpg.buffer_alloc" if cfg.ddpg.buffer_alloc else "ddpg.buffer_size"
    fields = {
        "buffers": buffer_field,
        "networks": "ddpg.hidden",
        "env": "run.seeds",
        "metrics": "run.episodes",
        "worlds": "env.worlds",
    }
    part = max(fields, key=lambda k: est[k])
    name = fields[part]
    section, key = name.split(".")
    value = getattr(getattr(cfg, section), key)
    parts = ", ".join(f"{k} {_size(est[k])}" for k in fields if est[k] >= est["total"] / 100)
    what = "the memory budget (--memory-budget)" if budget is not None else "the memory available now"
    raise ResourceError(
        f"{src}: {name} = {value if part != 'worlds' else len(value)}: the run needs about {_size(est['total'])} "
        f"({parts}; {cfg.run.seeds} seed(s)), more than {what}, {_size(limit)}; lower {name} or run.seeds"
    )
