"""`fedjax-nav sweep`: train a sweep's missing points, then write its tables."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import pandas as pd

from fedjax_nav import rundir
from fedjax_nav.analysis.sweeps import point_summaries, write_tables
from fedjax_nav.training.sweep import Sweep, merge_jobs, run_jobs


def run_sweep(
    sweep: Sweep,
    out: str | Path,
    budget: int | None = None,
    progress: bool = True,
    echo: Callable[[str], None] = print,
    devices: int | None = None,
) -> tuple[pd.DataFrame, dict]:
    """What `fedjax-nav sweep` does: train the missing points, write the tables. Returns
    (summary table, run stats)."""
    out = Path(out)
    stats = run_jobs(
        merge_jobs(sweep.points), out, budget, progress, desc=f"sweep {sweep.name}", echo=echo, devices=devices
    )
    write_tables(sweep, out / "points", out)
    summ = point_summaries(sweep, out / "points")
    rundir.write_json(out / "sweep_stats.json", stats)
    return summ, stats
