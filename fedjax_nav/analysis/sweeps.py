"""Tables of a sweep from its finished points (read through `fedjax_nav.rundir`): the tidy
results, the per-point summary, the sweep description and its learning curves."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import yaml

from fedjax_nav import rundir
from fedjax_nav.analysis.plots import learning_curves
from fedjax_nav.config.sweepfile import Sweep


def finished(sweep: Sweep, points_dir: Path):
    """(point, its summary.json) for every point of the sweep that has been trained, in grid order."""
    for p in sweep.points:
        f = Path(points_dir) / p.id / rundir.SUMMARY
        if f.exists():
            yield p, rundir.read_json(f)


def point_summaries(sweep: Sweep, points_dir: Path) -> pd.DataFrame:
    """One row per point: swept values, method, seeds, last-25 success/reward (mean, std)."""
    rows = []
    for p, s in finished(sweep, points_dir):
        row = {"point": p.id, "label": p.label, "method": p.cfg.method}
        row.update({k: (p.cfg.method if k == "base" else v) for k, v in p.values.items()})
        row.update(
            {
                k: s[k]
                for k in (
                    "seeds",
                    "episodes_done",
                    "success_last",
                    "success_last_std",
                    "reward_last",
                    "reward_last_std",
                    "aggregation_events",
                )
            }
        )
        row["n_comm"] = s["communication"]["n_comm"] if isinstance(s.get("communication"), dict) else None
        # robust federation (docs/robustness.md): honest clients' success, what was actually sent
        row.update(
            {
                k: s.get(k)
                for k in ("success_last_honest", "success_last_honest_std", "fed_bytes_sent", "fed_skipped_rounds")
            }
        )
        row["diverged_seeds"] = len(s.get("diverged_seeds", []))
        row["wall_s"] = s.get("wall_s")
        rows.append(row)
    return pd.DataFrame(rows)


def point_metrics(sweep: Sweep, points_dir: Path) -> pd.DataFrame:
    """The tidy table: grid point x seed x episode x robot, with the swept values as columns."""
    frames = []
    for p in sweep.points:
        d = Path(points_dir) / p.id
        if not (d / rundir.METRICS).exists():
            continue
        df = rundir.read_metrics(d)
        df.insert(0, "point", p.id)
        df.insert(1, "label", p.label)
        df.insert(2, "method", p.cfg.method)
        swept = [(k, v) for k, v in p.values.items() if k != "method"]  # a swept method is the column above
        for i, (k, v) in enumerate(swept):
            # a list value (env.worlds) is one cell, not a column of values
            cell = ", ".join(map(str, v)) if isinstance(v, (list, tuple)) else v
            df.insert(3 + i, "method_config" if k == "base" else k, cell)
        frames.append(df)
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def write_tables(sweep: Sweep, points_dir: Path, out_dir: Path) -> list[Path]:
    """results.csv (tidy), summary.csv (last-25 means), sweep.yaml (the description) and
    learning_curves.png for one sweep."""
    out_dir.mkdir(parents=True, exist_ok=True)
    res, summ = point_metrics(sweep, points_dir), point_summaries(sweep, points_dir)
    paths = [out_dir / rundir.SWEEP_RESULTS, out_dir / rundir.SWEEP_SUMMARY, out_dir / rundir.SWEEP_FILE]
    rundir.atomic_write(paths[0], lambda p: res.to_csv(p, index=False))
    rundir.atomic_write(paths[1], lambda p: summ.to_csv(p, index=False))
    rundir.write_text(paths[2], yaml.safe_dump(describe(sweep), sort_keys=False))
    if len(res):
        runs = {lbl: g for lbl, g in res.groupby("label", sort=False)}
        paths.append(learning_curves(runs, out_dir / rundir.CURVES, title=f"sweep {sweep.name}"))
    return paths


def describe(sweep: Sweep) -> dict:
    return {
        "name": sweep.name,
        "file": str(sweep.path),
        "description": sweep.description,
        "seeds": sweep.seeds,
        "keys": list(sweep.keys),
        "points": [{"id": p.id, "label": p.label, "values": dict(p.values)} for p in sweep.points],
    }
