"""The files and tables of an evaluation (docs/evaluation.md), written only through
fedjax_nav.rundir (atomic: a reader never sees a half-written file).

    write_run(evaluation, folder=None)   eval.json, eval_episodes.csv, eval_trajectories.npz,
                                         eval_bars.png, eval_trajectories.png; by default into
                                         RUN/eval/<world>/ (evaluation.eval_dir)
    read_evaluation(folder)              the eval.json of a folder, or None
    replacement(folder, summary)         the one line announcing that a folder's evaluation is replaced
    write_comparison(summaries, folder)  eval_comparison.csv / .md / .png of several runs
    summary_table / comparison_frame / comparison_markdown   the printed tables
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from fedjax_nav import rundir
from fedjax_nav.evaluation.metrics import SELECTED_NOTE
from fedjax_nav.evaluation.rollout import EvalError
from fedjax_nav.evaluation.run_data import RunEvaluation

EVAL_JSON = rundir.EVAL_JSON
EPISODES_CSV = rundir.EVAL_EPISODES
TRAJECTORIES_NPZ = rundir.EVAL_TRAJECTORIES
BARS_PNG = rundir.EVAL_BARS_FIGURE
TRAJECTORIES_PNG = rundir.EVAL_TRAJECTORIES_FIGURE
EVAL_FILES = (EVAL_JSON, EPISODES_CSV, TRAJECTORIES_NPZ, BARS_PNG, TRAJECTORIES_PNG)
COMPARISON_FILES = ("eval_comparison.csv", "eval_comparison.md", "eval_comparison.png")


# ----------------------------------------------------------------------------- one run's files


def json_safe(x):
    """NaN/Inf -> None (JSON has no NaN), recursively."""
    if isinstance(x, dict):
        return {k: json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_safe(v) for v in x]
    if isinstance(x, (float, np.floating)) and not math.isfinite(float(x)):
        return None
    return x


def write_run(ev: RunEvaluation, out_dir: str | Path | None = None, figures: bool = True) -> list[Path]:
    """eval.json, eval_episodes.csv, eval_trajectories.npz (+ eval_bars.png,
    eval_trajectories.png) into `out_dir`, by default the run's RUN/eval/<world>/ (`ev.eval_dir`).
    Files of an earlier evaluation in that folder are replaced (figures it had and this one does
    not draw are removed, so the folder never mixes two evaluations); eval.json, the marker of a
    complete evaluation, is written last. Returns the paths written."""
    out = Path(out_dir) if out_dir is not None else ev.eval_dir
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / EVAL_JSON, out / EPISODES_CSV, out / TRAJECTORIES_NPZ]
    rundir.atomic_write(paths[1], lambda p: ev.frame.to_csv(p, index=False))
    r = ev.result
    last = int(r.steps.max()) + 1  # poses after the longest episode are all frozen copies

    def npz(p):
        with open(p, "wb") as f:
            np.savez_compressed(
                f,
                poses=r.poses[..., :last, :],
                steps=r.steps,
                success=r.success,
                collision=r.collision,
                goals=r.goals,
                start=r.start,
                agent_seed=ev.run.agent_seed,
                agent_net=ev.run.agent_net,
            )

    rundir.atomic_write(paths[2], npz)
    if figures:
        from fedjax_nav.evaluation import figures as figs

        s = ev.summary
        paths.append(figs.bars({s["method"]: s}, out / BARS_PNG, per_goal=True, title=f"{s['method']} on {s['world']}"))
        paths.append(figs.trajectories(ev, out / TRAJECTORIES_PNG))
    else:
        for name in (BARS_PNG, TRAJECTORIES_PNG):  # an earlier evaluation's figures: now stale
            (out / name).unlink(missing_ok=True)
    rundir.write_json(paths[0], json_safe(ev.summary))
    return paths


def read_evaluation(folder: str | Path) -> dict | None:
    """The eval.json in `folder` (e.g. `rundir.eval_dir(run, world)`), or None when there is none."""
    path = Path(folder) / EVAL_JSON
    if not path.exists():
        return None
    try:
        return rundir.read_json(path)
    except rundir.RunDirError as e:
        raise EvalError(str(e)) from None


def _settings(s: dict) -> dict:
    """What makes two evaluations the same: run, world, attempts, T, noise, seed, robot model."""
    noise = s.get("noise") or {}
    run = s.get("run_dir")
    return {
        "run": str(Path(run).resolve()) if run else None,
        "world": s.get("world_source"),
        "attempts": s.get("attempts_requested"),
        "max_steps": s.get("max_steps"),
        "range_noise": noise.get("range_noise"),
        "action_noise": noise.get("action_noise"),
        "seed": s.get("eval_seed"),
        "robot": (s.get("robot") or {}).get("model", "ideal"),
    }


def replacement(folder: str | Path, summary: dict) -> str | None:
    """One line when `folder` already holds an evaluation that writing `summary` there replaces
    (None when it holds none): the same evaluation again, or which settings differ."""
    try:
        old = read_evaluation(folder)
    except EvalError:
        return f"replacing the earlier evaluation in {folder} (its {EVAL_JSON} was unreadable)"
    if old is None:
        return None
    a, b = _settings(old), _settings(summary)
    diff = [f"{k} {a[k]} -> {b[k]}" for k in a if a[k] != b[k]]
    why = "the same run, world and settings" if not diff else "it differs: " + ", ".join(diff)
    return f"replacing the earlier evaluation in {folder} ({why})"


# ----------------------------------------------------------------------------- several runs


def comparison_replacement(folder: str | Path) -> str | None:
    """One line when `folder` already holds a comparison that writing one there replaces."""
    if (Path(folder) / COMPARISON_FILES[0]).exists():
        return f"replacing the earlier comparison in {folder}"
    return None


def write_comparison(
    summaries: dict[str, dict], out_dir: str | Path, title: str = "", figures: bool = True
) -> tuple[list[Path], str]:
    """eval_comparison.csv, eval_comparison.md (+ eval_comparison.png) of several runs' eval.json
    dicts (label -> summary) into out_dir. Returns (paths written, the markdown table)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    df = comparison_frame(summaries)
    md = comparison_markdown(df)
    paths = [out / COMPARISON_FILES[0], out / COMPARISON_FILES[1]]
    rundir.atomic_write(paths[0], lambda p: df.to_csv(p, index=False))
    rundir.write_text(paths[1], md + "\n")
    if figures:
        from fedjax_nav.evaluation import figures as figs

        paths.append(figs.bars(summaries, out / COMPARISON_FILES[2], title=title))
    else:
        (out / COMPARISON_FILES[2]).unlink(missing_ok=True)
    return paths, md


# ----------------------------------------------------------------------------- tables


def _fmt(mean, std, digits=2):
    if mean is None:
        return "-"
    return f"{mean:.{digits}f} +- {std:.{digits}f}"


def summary_table(summary: dict) -> str:
    """A plain-text table of one run's evaluation: per goal and overall, then the best agents."""
    s = summary
    noise = s["noise"]
    lines = [
        f"{s['method']} ({s['run_dir']}): {s['agents']} agent(s) x {len(s['goals'])} goals x "
        f"{s['attempts_per_agent']} attempts = {s['episodes']} episodes on '{s['world']}', "
        f"T = {s['max_steps']} steps ({s['max_steps'] * s['dt']:g} s)",
        f"noise: range {noise['range_noise']:g} m, action {noise['action_noise']:g} (std, action units); "
        f"eval seed {s['eval_seed']}",
        f"{'goal':<16}{'success':>9}{'n':>6}{'time (s)':>18}{'efficiency':>18}",
    ]

    def row(name, st):
        time_s = _fmt(st["time_mean"], st["time_std"])
        eff = _fmt(st["efficiency_mean"], st["efficiency_std"], 3)
        return f"{name:<16}{st['success_rate']:>9.3f}{st['episodes']:>6}{time_s:>18}{eff:>18}"

    for g in s["all_agents"]["per_goal"]:
        lines.append(row(f"G{g['goal']} ({g['xy'][0]:g}, {g['xy'][1]:g})", g))
    lines.append(row("all agents", s["all_agents"]["overall"]))
    for key, name in (("honest_agents", "honest agents"), ("byzantine_agents", "Byzantine")):
        if key in s:  # a run with Byzantine robots (fed.byzantine)
            lines.append(row(name, s[key]["overall"]))
    lines.append(row("best per seed*", s["best_agent_per_seed"]["overall"]))
    lines.append(f"* {SELECTED_NOTE}; agents {s['best_agent_per_seed']['agents']}")
    return "\n".join(lines)


def comparison_frame(summaries: dict[str, dict]) -> pd.DataFrame:
    """One row per run (label -> eval.json dict): the headline and the best-per-seed numbers."""
    rows = []
    for label, s in summaries.items():
        o, b = s["all_agents"]["overall"], s["best_agent_per_seed"]["overall"]
        rows.append(
            {
                "run": label,
                "method": s["method"],
                "agents": s["agents"],
                "seeds": len(s["seeds"]),
                "episodes": s["episodes"],
                "success": o["success_rate"],
                "success_seed_std": o["success_seed_std"],
                "time_mean": o["time_mean"],
                "time_std": o["time_std"],
                "efficiency_mean": o["efficiency_mean"],
                "efficiency_std": o["efficiency_std"],
                "best_per_seed_success": b["success_rate"],
                "honest_success": s["honest_agents"]["overall"]["success_rate"] if "honest_agents" in s else None,
                "world": s["world"],
                "range_noise": s["noise"]["range_noise"],
                "action_noise": s["noise"]["action_noise"],
            }
        )
    return pd.DataFrame(rows)


def comparison_markdown(df: pd.DataFrame) -> str:
    def f(x, d=3):
        return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{d}f}"

    def pm(m, s, d=3):
        m, s = f(m, d), f(s, d)
        return m if m == "-" else f"{m} +- {s}"

    lines = [
        "| run | method | agents | episodes | success (+- std over seeds) | time (s) | efficiency | "
        "best agent per seed success* |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in df.itertuples():
        lines.append(
            f"| {r.run} | {r.method} | {r.agents} | {r.episodes} | {pm(r.success, r.success_seed_std)} | "
            f"{pm(r.time_mean, r.time_std, 2)} | {pm(r.efficiency_mean, r.efficiency_std)} | "
            f"{f(r.best_per_seed_success)} |"
        )
    lines.append(f"\n\\* {SELECTED_NOTE}.")
    return "\n".join(lines)
