"""Sweeps: a grid x seeds trained as one vmapped program per static group. The sweep file and its
points: `fedjax_nav.config.sweepfile`; here `spec`: points -> jobs; `plan`: groups and batches;
`layout`: the batches as first planned, kept by a resumed sweep; `run`: training them into point
run directories. Tables: `fedjax_nav.analysis.sweeps`; the
command: `fedjax_nav.experiments.sweeps`."""

from fedjax_nav.training.resources import STATE_BYTES_FACTOR
from fedjax_nav.training.sweep.layout import is_done
from fedjax_nav.training.sweep.plan import Group, batch_id, batch_rows, default_memory_budget, plan, point_bytes
from fedjax_nav.training.sweep.run import Compiled, run_batch, run_jobs, write_point
from fedjax_nav.training.sweep.spec import Job, fold_prefixes, group_key, merge_jobs, parse_bytes

__all__ = [
    "STATE_BYTES_FACTOR",
    "Compiled",
    "Group",
    "Job",
    "batch_id",
    "batch_rows",
    "default_memory_budget",
    "fold_prefixes",
    "group_key",
    "is_done",
    "merge_jobs",
    "parse_bytes",
    "plan",
    "point_bytes",
    "run_batch",
    "run_jobs",
    "write_point",
]
