"""`fedjax-nav sweep`: train a sweep's missing points, then write its tables."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import pandas as pd
import yaml

from fedjax_nav import rundir
from fedjax_nav.analysis.sweeps import point_summaries, write_tables
from fedjax_nav.config.sweepfile import Sweep
from fedjax_nav.training.sweep import merge_jobs, run_jobs


def run_sweep(
    sweep: Sweep,
    out: str | Path,
    budget: int | None = None,
    progress: bool = True,
    echo: Callable[[str], None] = print,
    devices: int | None = None,
    points: tuple | None = None,
) -> tuple[pd.DataFrame, dict]:
    """What `fedjax-nav sweep` does: train the missing points (of `points` only, where given:
    `sweepfile.select`), write the tables of the whole sweep. Returns (summary table, run stats)."""
    out = Path(out)
    todo = sweep.points if points is None else points
    stats = run_jobs(merge_jobs(todo), out, budget, progress, desc=f"sweep {sweep.name}", echo=echo, devices=devices)
    tables = tables_dir(sweep, out)
    stats["tables"] = str(tables)
    write_tables(sweep, rundir.points_dir(out), tables)
    summ = point_summaries(sweep, rundir.points_dir(out))
    rundir.write_json(tables / rundir.SWEEP_STATS, stats)
    if tables != out:
        echo(f"{out} holds the tables of sweep {sweep_in(out)!r}: this sweep's tables are in {tables}")
    return summ, stats


def sweep_in(out: Path) -> str | None:
    """The name of the sweep whose tables `out` holds (its sweep.yaml), if any."""
    f = Path(out) / rundir.SWEEP_FILE
    try:
        return (yaml.safe_load(f.read_text()) or {}).get("name") if f.exists() else None
    except (OSError, yaml.YAMLError):
        return None


def tables_dir(sweep: Sweep, out: str | Path) -> Path:
    """Where a sweep's tables go: `out`, unless `out` already holds another sweep's tables (two
    sweeps sharing one points folder, e.g. generalization and generalization_levers): then
    `out/tables/<name>/`, so that neither overwrites the other's results.csv and summary.csv."""
    out = Path(out)
    other = sweep_in(out)
    return out if other in (None, sweep.name) else out / rundir.SWEEP_TABLES / sweep.name
