"""Packing a sweep's jobs into compiled groups and batches within a memory budget."""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field, replace

import numpy as np

from fedjax_nav.config.memory import available_memory, size
from fedjax_nav.config.sweepfile import SweepError
from fedjax_nav.training.hparams import HParams, hparams_from_config, stack_hparams, varying_fields
from fedjax_nav.training.resources import memory_estimate
from fedjax_nav.training.sweep.spec import Job, group_key
from fedjax_nav.training.trainer import Trainer


def point_bytes(trainer: Trainer) -> tuple[int, int]:
    """(bytes per row, bytes once per batch) of the group's program, from train's own estimate
    (`training.resources.memory_estimate`, the one `train` refuses by): per row (seed) its
    TrainState x STATE_BYTES_FACTOR, one update's batches and activations of every network, its
    rooms' generation and its metrics tables; once, the worlds and the compiler. A batch of n rows
    then needs n x per row + once, and a point alone in its batch is refused exactly when `train`
    would refuse its config."""
    est = memory_estimate(trainer)
    once = est["worlds"] + est["compiler"]
    return (est["total"] - once) // trainer.cfg.run.seeds, once  # every other part is per seed


def row_cap(per_row: int, once: int, budget: int) -> int:
    """How many rows (seeds) a batch may hold within `budget` (before padding to the devices);
    0: not even one."""
    return max(budget - once, 0) // max(per_row, 1)


def default_memory_budget() -> int:
    """Half of the memory available now (`config.memory.available_memory`)."""
    return available_memory() // 2


@dataclass
class Group:
    key: str
    jobs: list  # Job
    trainer: Trainer
    batches: list = field(default_factory=list)  # lists of jobs
    batch_rows: int = 0  # padded rows per batch (one compilation)
    batched: frozenset = frozenset()  # HParams fields that differ between the group's rows


def plan(jobs: list[Job], budget: int, devices: int = 1) -> list[Group]:
    """Group jobs by static structure and pack each group into equal-size batches within budget
    (rows padded to a multiple of `devices`, over which the rows are spread)."""
    groups: dict[str, list[Job]] = {}
    for j in jobs:
        groups.setdefault(group_key(j.cfg), []).append(j)
    out = []
    for key, js in groups.items():
        alloc = max(j.cfg.buffer_rows for j in js)
        rep = js[0].cfg
        rep = replace(rep, offpolicy=replace(rep.offpolicy, buffer_alloc=alloc))
        trainer = Trainer(rep)
        per_row, once = point_bytes(trainer)
        cap = row_cap(per_row, once, budget)  # 0: not even one row fits (a single-seed point is checked too)
        batches, cur, rows = [], [], 0
        for j in js:
            n = j.cfg.run.seeds
            if n > cap:
                raise SweepError(
                    f"point {j.id} ({j.cfg.method}) needs {n} rows of ~{size(per_row)} (and {size(once)} of "
                    f"worlds), more than the memory budget {size(budget)} allows ({cap} rows); "
                    "raise --memory-budget or use fewer seeds"
                )
            if rows + n > cap:
                batches.append(cur)
                cur, rows = [], 0
            cur.append(j)
            rows += n
        if cur:
            batches.append(cur)
        rows = max(sum(j.cfg.run.seeds for j in b) for b in batches)
        rows = -(-rows // devices) * devices
        out.append(Group(key, js, trainer, batches, rows, varying_fields([hparams_from_config(j.cfg) for j in js])))
    return out


def batch_rows(
    jobs: list[Job], size: int, batched: frozenset | None = None
) -> tuple[np.ndarray, HParams, list[tuple[Job, int, int]]]:
    """Seeds i32[size], HParams (leaves scalar or [size]) and (job, first row, seeds) per job."""
    seeds, hps, spans, r = [], [], [], 0
    for j in jobs:
        n = j.cfg.run.seeds
        seeds += [j.cfg.run.seed + i for i in range(n)]
        hps += [hparams_from_config(j.cfg)] * n
        spans.append((j, r, n))
        r += n
    pad = size - len(seeds)
    seeds += [seeds[-1]] * pad
    hps += [hps[-1]] * pad
    return np.asarray(seeds, np.int32), stack_hparams(hps, batched), spans


def batch_id(jobs: list[Job], size: int) -> str:
    text = json.dumps([[j.id, j.cfg.run.seeds] for j in jobs] + [size])
    return hashlib.sha1(text.encode()).hexdigest()[:12]
