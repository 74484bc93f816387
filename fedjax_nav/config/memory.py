"""The memory budget of a run or an evaluation: one rule for both (docs/reliability.md, "Resources,
checked before allocating").

    over_budget(total, budget) -> None, or "more than the memory available now, 21.2 GiB"
    available_memory() -> bytes     nbytes(tree) -> bytes     size(n) -> "21.2 GiB"

`fedjax_nav.training.resources` (train) and `fedjax_nav.evaluation.rollout` (evaluate) each
estimate their peak bytes from shapes before allocating anything and refuse with one line when
`over_budget` says so; a sweep (`fedjax_nav.training.sweep.plan`) packs its rows by train's estimate
within half of `available_memory` (or --memory-budget). It sits in the config layer, beside
`config.envs`, because both build on it and evaluation does not import training.
"""

from __future__ import annotations

import os
from pathlib import Path

import jax
import numpy as np


def available_memory() -> int:
    """The memory available now (Linux /proc/meminfo MemAvailable; else the physical memory)."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def nbytes(tree) -> int:
    """Bytes of a pytree of arrays or `jax.ShapeDtypeStruct`s (`jax.eval_shape`'s output); a PRNG
    key array counts its key data (2 x u32 per threefry key)."""
    total = 0
    for x in jax.tree.leaves(tree):
        if not hasattr(x, "dtype"):
            continue
        if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key):
            x = jax.eval_shape(jax.random.key_data, x)
        total += int(np.prod(x.shape)) * np.dtype(x.dtype).itemsize
    return total


def size(n: float) -> str:
    """Bytes for a person: '21.2 GiB', '512 B'."""
    for unit, f in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if n >= f:
            return f"{n / f:.1f} {unit}"
    return f"{int(n)} B"


def over_budget(total: int, budget: int | None = None) -> str | None:
    """None when `total` bytes fit in `budget` (bytes; None: the memory available now), else the end
    of the refusal line: 'more than the memory budget (--memory-budget), 10.0 KiB'."""
    limit = available_memory() if budget is None else int(budget)
    if total <= limit:
        return None
    what = "the memory budget (--memory-budget)" if budget is not None else "the memory available now"
    return f"more than {what}, {size(limit)}"
