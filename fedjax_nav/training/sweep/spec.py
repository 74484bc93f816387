"""From a sweep's points to the jobs to train: one job per distinct config, shorter budgets folded
into the longest, and the static group key that decides which jobs share one compilation. (The
sweep file itself, its points and their ids: `fedjax_nav.config.sweepfile`.)

How it runs. Every grid point is a resolved `Config`. Points whose fields differ only in
`HParams` (gamma, rho, lr, T_train, T_target, epsilon, tau, beta, the federated period, the
buffer capacity) fall into one *group*: one `Trainer`, one compilation, and every (point, seed)
of the group is one row of the leading batch axis (the trainer's seed vmap). A field that is
the same in every row stays a scalar, so the T_train / period gates stay real conds; a swept
period becomes a per-row select (correct, and only the cheap federated step pays it). Buffer
capacities are allocated at the group's largest and the active capacity is traced. Any other
difference (method, episode length, networks, worlds) is a separate group.

Rows are packed into batches that fit a memory budget; every batch of a group is padded to one
size (by repeating its last row, whose results are dropped) so that the group compiles once.
Each point is saved as a normal run directory (`points/<id>/`: config.yaml, metrics.csv,
summary.json, params.npz: `fedjax-nav evaluate` reads it) as soon as its batch finishes; a
finished point is skipped when the sweep runs again, and a batch in flight resumes from its
latest checkpoint (`batches/<id>/checkpoints`) in the layout it was first planned in
(`batches/plan.json`, `layout`: docs/reliability.md, "Resume"). The point id hashes the resolved config, so
two sweeps (or two experiments of `reproduce`) that ask for the same run share it.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

from fedjax_nav.config import Config, traced_fields
from fedjax_nav.config.sweepfile import BOOKKEEPING, SweepError, flat_config, point_id


def group_key(cfg: Config) -> str:
    """Configs with equal keys share one Trainer and one compilation."""
    flat = {
        k: v
        for k, v in flat_config(cfg).items()
        if k not in BOOKKEEPING and k not in traced_fields() and k != "run.seed"
    }
    return json.dumps(flat, sort_keys=True)


@dataclass(frozen=True)
class Job:
    """One point to train: its config (run.seeds = how many seeds) and where it is saved."""

    cfg: Config
    id: str
    prefixes: tuple = ()  # shorter jobs saved from this job's rows when it reaches their episodes


def merge_jobs(points) -> list[Job]:
    """One job per distinct config; a config asked for with several seed counts gets the largest."""
    by_id: dict[str, Config] = {}
    for p in points:
        old = by_id.get(p.id)
        if old is None or p.cfg.run.seeds > old.run.seeds:
            by_id[p.id] = p.cfg
    return [Job(c, i) for i, c in by_id.items()]


def fold_prefixes(jobs: list[Job]) -> list[Job]:
    """Jobs that differ only in `run.episodes` are one run: nothing the program computes depends on
    the number of episodes still to come (epsilon decays per step, rooms and federated rounds count
    from episode 0), so the shorter jobs are the longest one's first episodes. The longest job
    (with the most seeds any of them asks for) keeps the others as `prefixes`, written when it
    reaches their episode counts (`run_batch`); a budget that is not a multiple of
    `run.chunk_episodes` stays a job of its own. A grid over `run.episodes` costs its longest run."""
    from dataclasses import replace

    runs: dict[str, list[Job]] = {}
    for j in jobs:
        runs.setdefault(point_id(replace(j.cfg, run=replace(j.cfg.run, episodes=1))), []).append(j)
    out = []
    for js in runs.values():
        js = sorted(js, key=lambda j: -j.cfg.run.episodes)
        head, rest = js[0], js[1:]
        K = head.cfg.run.chunk_episodes
        pre = tuple(j for j in rest if j.cfg.run.episodes < head.cfg.run.episodes and j.cfg.run.episodes % K == 0)
        out += [j for j in rest if j not in pre]
        if pre:
            seeds = max(j.cfg.run.seeds for j in (head, *pre))
            head = Job(replace(head.cfg, run=replace(head.cfg.run, seeds=seeds)), head.id, pre)
        out.append(head)
    return out


def parse_bytes(text: str | int) -> int:
    """'4G', '512M', '1.5GB', 2e9 -> bytes."""
    bad = SweepError(f"memory budget {text!r}: expected a positive size such as 4G, 512M or a number of bytes")
    if isinstance(text, (int, float)):
        value = float(text)
    else:
        t = str(text).strip().upper().removesuffix("B")
        mult = {"K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}.get(t[-1:], 1)
        try:
            value = float(t[:-1] if mult > 1 else t) * mult
        except ValueError:
            raise bad from None
    if not (math.isfinite(value) and value >= 1):  # inf, nan, 0 and negative budgets are not sizes
        raise bad
    return int(value)
