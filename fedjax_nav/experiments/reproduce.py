"""`fedjax-nav reproduce`: every experiment of thesis chapter 4 from one command, into a report
folder with Fig. 11-20, Tables 2 and 3, and a markdown report putting each measured number beside
the thesis's.

    reproduce("ci", "runs/reproduce-ci")         # reduced: 10 episodes x 64 steps, 2 seeds, small rooms
    reproduce("thesis", "runs/reproduce-thesis")  # the thesis's scale: many hours on a 2-core CPU

The experiments are the sweep files of configs/sweeps/ (EXPERIMENTS). Their points are pooled and
deduplicated (the thesis FLDDPG config appears in six experiments and is trained once, with the
most seeds any of them asks for), trained with `fedjax_nav.training.sweep.run_jobs` (one compilation per
static group, resumable point by point), then the experiments with `evaluate: true` are
evaluated with the protocol of fedjax_nav.evaluation. Running the command again resumes: finished
points and evaluations are kept.

Report folder:
    report.md                    measured beside the thesis, per experiment
    reproduce.json               scale, overrides, seeds, timings, versions
    fig11_...png .. fig20_...png the figures of chapter 4
    table2_hyperparameters.{csv,md}, table3_communication.{csv,md}
    eval_summary.csv             one row per evaluated run
    experiments/<name>/          results.csv (tidy), summary.csv, sweep.yaml, learning_curves.png
    points/<id>/                 the runs: config.yaml, metrics.csv, summary.json, params.npz,
                                 eval/<arena>/eval.json (the thesis arena: eval/eval/; ci scale: eval/ci-arena/)
    ci-arena.json                the ci scale's evaluation room (written by the ci scale only)
"""

from __future__ import annotations

import json
import platform
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import pandas as pd

from fedjax_nav import rundir
from fedjax_nav.analysis.sweeps import write_tables
from fedjax_nav.config.sweepfile import Sweep, SweepError, load_sweep
from fedjax_nav.configs import SWEEP_DIR
from fedjax_nav.experiments.thesis_report import (
    by_setting,
    draw_figures,
    experiment_dir,
    md_table,
    point_wall,
    report_markdown,
    table2,
    table3,
)
from fedjax_nav.training import sweep as sw

EXPERIMENTS = (
    "gamma",
    "rho",
    "buffer_iddpg",
    "buffer_seddpg",
    "buffer_snddpg",
    "buffer_flddpg",
    "fed_period_steps",
    "fed_period_episodes",
    "tau",
    "methods",
    "pw_beta",
    "rw_beta",
    "improvements",
)


@dataclass(frozen=True)
class Scale:
    name: str
    overrides: tuple  # applied to every point
    buffer_scale: float
    seeds: int | None  # None: each sweep file's own count
    attempts: int  # evaluation attempts per agent and goal
    arena: dict | None = None  # the evaluation world: None, the thesis arena ("eval"); else a world spec


# The ci scale's evaluation room: 4 goals from one start, as in the thesis arena, but 2 cylinders
# inside 4 walls where the arena has 36 wall segments and 21 cylinders. The lidar and collision
# tests are unrolled over the obstacles, so compilation time grows with them (3x for one evaluation).
CI_ARENA = {
    "name": "ci-arena",
    "description": "the evaluation room of `reproduce --scale ci` (6 x 6 m, 2 cylinders, 4 goals)",
    "size": [6.0, 6.0],
    "circles": [[-1.0, 0.0, 0.3], [1.0, 0.0, 0.3]],
    "starts": [[0.0, -2.0, 1.5708]],
    "goals": [[-2.0, 2.0], [2.0, 2.0], [-2.0, -1.5], [2.0, -1.5]],
}

SCALES = {
    "thesis": Scale("thesis", (), 1.0, None, 4),
    # 10 episodes so that E_update = 10 still aggregates; 64 x 10 steps >= T_update = 512; buffers
    # x 0.02 so that they wrap in 640 steps as the thesis's wrap in 128k; batch 32 <= every buffer.
    # Five robots, all in the smallest training room (train-0: 4 walls, 1 cylinder; the thesis rooms
    # have up to 48 segments and 12 cylinders) and evaluated in CI_ARENA: the programme's time is
    # compilation, which grows with the obstacles of the rooms.
    "ci": Scale(
        "ci",
        (
            "run.episodes=10",
            "env.episode_length=64",
            "run.chunk_episodes=5",
            "run.checkpoint_every=0",
            "offpolicy.batch_size=32",
            "env.worlds=[train-0,train-0,train-0,train-0,train-0]",
        ),
        0.02,
        2,
        1,
        CI_ARENA,
    ),
}


def arena_world(scale: Scale, out: Path) -> str:
    """The world the scale evaluates on: "eval", or its arena written to OUT/<name>.json (a path)."""
    if scale.arena is None:
        return "eval"
    path = out / f"{scale.arena['name']}.json"
    rundir.atomic_write(path, lambda p: Path(p).write_text(json.dumps(scale.arena, indent=1) + "\n"))
    return str(path)


def load_experiments(scale: Scale, only=None, seeds: int | None = None, overrides=()) -> list[Sweep]:
    names = list(EXPERIMENTS if not only else only)
    unknown = [n for n in names if n not in EXPERIMENTS]
    if unknown:
        raise SweepError(f"--only: unknown experiment(s) {unknown}; allowed: {', '.join(EXPERIMENTS)}")
    n = seeds if seeds is not None else scale.seeds
    return [
        load_sweep(
            SWEEP_DIR / f"{name}.yaml",
            overrides=[*scale.overrides, *overrides],
            seeds=n,
            buffer_scale=scale.buffer_scale,
        )
        for name in names
    ]


# ----------------------------------------------------------------------------- evaluation


def evaluate_points(
    sweeps: list[Sweep], points_dir: Path, attempts: int, echo: Callable, world: str = "eval"
) -> pd.DataFrame:
    """Evaluate every point of the experiments marked `evaluate` on `world`, by default the thesis
    arena (kept in the point's `eval/<world>/` folder and reused when the same attempts were asked
    for). One row per point."""
    from fedjax_nav.evaluation import evaluated

    rows, seen = [], set()
    for s in sweeps:
        if not s.evaluate:
            continue
        for p in s.points:
            d = points_dir / p.id
            if p.id in seen or not (d / rundir.PARAMS).exists():
                continue
            seen.add(p.id)
            ev, now = evaluated(d, world, attempts)
            if now:
                echo(
                    f"evaluated {p.cfg.method} ({p.id}): success {ev['all_agents']['overall']['success_rate']:.3f}"
                    f" over {ev['episodes']} episodes"
                )
            a, b = ev["all_agents"]["overall"], ev["best_agent_per_seed"]["overall"]
            rows.append(
                {
                    "point": p.id,
                    "label": p.cfg.method,
                    "experiment": s.name,
                    "seeds": len(ev["seeds"]),
                    "agents": ev["agents"],
                    "episodes": ev["episodes"],
                    "success": a["success_rate"],
                    "success_seed_std": a["success_seed_std"],
                    "time_mean": a["time_mean"],
                    "time_std": a["time_std"],
                    "efficiency_mean": a["efficiency_mean"],
                    "efficiency_std": a["efficiency_std"],
                    "best_success": b["success_rate"],
                    "best_success_seed_std": b["success_seed_std"],
                }
            )
    df = pd.DataFrame(rows)
    num = [c for c in df.columns if c not in ("point", "label", "experiment", "seeds", "agents", "episodes")]
    return df.astype({c: float for c in num}) if len(df) else df  # None (no success) -> NaN


# ----------------------------------------------------------------------------- the command


def _write_tables(out: Path, by_name: dict, points: Path, tables: dict) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Tables 2 and 3 (csv and markdown) and every experiment's by_setting.csv into `out`; returns
    Tables 2 and 3 (Table 3 empty without the methods experiment)."""
    t2 = table2()
    rundir.atomic_write(out / "table2_hyperparameters.csv", lambda p: t2.to_csv(p, index=False))
    rundir.atomic_write(out / "table2_hyperparameters.md", lambda p: Path(p).write_text(md_table(t2) + "\n"))
    t3 = table3(by_name["methods"], points) if "methods" in by_name else pd.DataFrame()
    rundir.atomic_write(out / "table3_communication.csv", lambda p: t3.to_csv(p, index=False))
    rundir.atomic_write(
        out / "table3_communication.md", lambda p: Path(p).write_text(md_table(t3) + "\n" if len(t3) else "")
    )
    for name, t in tables.items():
        rundir.atomic_write(experiment_dir(out, name) / "by_setting.csv", lambda p, t=t: t.to_csv(p, index=False))
    return t2, t3


def reproduce(
    scale: str = "ci",
    out: str | Path | None = None,
    only=None,
    seeds: int | None = None,
    budget: int | None = None,
    progress: bool = True,
    echo: Callable[[str], None] = print,
    devices: int | None = None,
    overrides=(),
) -> dict:
    """Run (or resume) the experiments and write the report folder. Returns reproduce.json's dict.
    `overrides` (`section.key=value`) apply to every point, after the scale's."""
    import jax

    if scale not in SCALES:
        raise SweepError(f"--scale {scale!r}: allowed {', '.join(SCALES)}")
    sc = SCALES[scale]
    out = Path(out or f"runs/reproduce-{scale}")
    out.mkdir(parents=True, exist_ok=True)
    sweeps = load_experiments(sc, only, seeds, overrides)
    t0 = time.time()
    jobs = sw.merge_jobs([p for s in sweeps for p in s.points])
    stats = sw.run_jobs(jobs, out, budget, progress, desc=f"reproduce {scale}", echo=echo, devices=devices)
    t_train = time.time() - t0
    points = rundir.points_dir(out)
    for s in sweeps:
        write_tables(s, points, experiment_dir(out, s.name))
    t1 = time.time()
    world = arena_world(sc, out)
    evals = evaluate_points(sweeps, points, sc.attempts, echo, world)
    t_eval = time.time() - t1
    rundir.atomic_write(out / "eval_summary.csv", lambda p: evals.to_csv(p, index=False))
    by_name = {s.name: s for s in sweeps}
    tables = {s.name: by_setting(s, points) for s in sweeps}
    figs = draw_figures(by_name, out, evals, tables)
    t2, t3 = _write_tables(out, by_name, points, tables)
    info = {
        "scale": scale,
        "overrides": list(sc.overrides),
        "buffer_scale": sc.buffer_scale,
        "seeds": seeds if seeds is not None else sc.seeds,
        "experiments": [s.name for s in sweeps],
        "distinct_runs": len(jobs),
        "seed_runs": sum(j.cfg.run.seeds for j in jobs),
        "train": stats,
        "train_wall_s": t_train,
        "eval_wall_s": t_eval,
        "eval_attempts": sc.attempts,
        "eval_world": rundir.world_slug(world),
        "figures": [p.name for p in figs],
        "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
        "machine": f"{platform.machine()}, {__import__('os').cpu_count()} cores, {platform.python_version()}",
        "jax": jax.__version__,
        "backend": jax.default_backend(),
    }
    prev = out / "reproduce.json"
    history = json.loads(prev.read_text()).get("history", []) if prev.exists() else []
    history.append(
        {
            "date": info["date"],
            "trained_points": len(jobs) - stats["skipped"],
            "train_wall_s": t_train,
            "eval_wall_s": t_eval,
        }
    )
    info["history"] = history
    info["train_compute_s"] = sum(point_wall(points / j.id) for j in jobs)
    rundir.atomic_write(out / "reproduce.json", lambda p: Path(p).write_text(json.dumps(info, indent=1)))
    md = report_markdown(sweeps, tables, t2, t3, evals, info)
    rundir.atomic_write(out / "report.md", lambda p: Path(p).write_text(md))
    echo(f"wrote {out}/report.md, {len(figs)} figures, tables 2 and 3")
    return info
