"""Sweeps: a grid x seeds trained as one vmapped program per static group (see `spec` for the
file format and the rules). `spec`: files -> points -> jobs; `plan`: groups and batches;
`run`: training them into point run directories. Tables: `fedjax_nav.analysis.sweeps`; the
command: `fedjax_nav.experiments.sweeps`."""

from fedjax_nav.training.sweep.plan import Group, batch_id, batch_rows, default_memory_budget, plan, row_bytes
from fedjax_nav.training.sweep.run import Compiled, is_done, run_batch, run_jobs, write_point
from fedjax_nav.training.sweep.spec import (
    BOOKKEEPING,
    STATE_BYTES_FACTOR,
    Job,
    Point,
    Sweep,
    SweepError,
    fold_prefixes,
    group_key,
    load_sweep,
    merge_jobs,
    parse_bytes,
    point_id,
    point_label,
)

__all__ = [
    "BOOKKEEPING",
    "STATE_BYTES_FACTOR",
    "Compiled",
    "Group",
    "Job",
    "Point",
    "Sweep",
    "SweepError",
    "batch_id",
    "batch_rows",
    "default_memory_budget",
    "fold_prefixes",
    "group_key",
    "is_done",
    "load_sweep",
    "merge_jobs",
    "parse_bytes",
    "plan",
    "point_id",
    "point_label",
    "row_bytes",
    "run_batch",
    "run_jobs",
    "write_point",
]
