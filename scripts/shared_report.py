"""The shared-rooms experiment's table (docs/shared_rooms.md, "The experiment"): every trained point
of a sweep folder evaluated with K robots per room on a held-out suite (`evaluate --robots-per-room`,
kept in each point's eval/<suite>-shared/ and reused), then one row per (method, trained in shared
rooms or alone, K): success with its 95% bootstrap interval over training seeds, the worst 10% of
rooms, and the shares of robot-episodes ending in an obstacle collision, a robot-robot collision, a
time-out, a deadlock.

    python scripts/shared_report.py runs/sweeps/shared_1e7                       # mixture-50, K = 1, 2, 4, 8
    python scripts/shared_report.py runs/sweeps/shared_1e7 --csv results/shared_1e7.csv

Several folders pool their points' seeds (a sweep's seeds trained in two sweeps, e.g. shared_td3_1e7
and shared_td3_1e7_seeds): one row per (method, trained, budget, K) over every seed of every folder;
a seed twice for one row is refused (the same training pooled twice).

Kept evaluations (`fedjax-nav evaluate --robots-per-room`, `scripts/suite_with.py --robots-per-room`
write shared_episodes.csv) side by side, per K and family, those of one LABEL pooled:

    python scripts/shared_report.py --kept "plan, 4 seeds"=runs/x/A-dense+runs/x/B-dense --csv results/y.csv
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from fedjax_nav import rundir
from fedjax_nav.evaluation.shared_rooms import evaluate_shared, shared_dir, write_shared
from fedjax_nav.evaluation.suite_stats import bootstrap_ci, pool_seeds, worst_mean

METHODS = {"flddpg": "federated", "iddpg": "independent", "snddpg": "central"}


def episodes(point: Path, suite: str, ks: list[int], max_steps: int | None) -> pd.DataFrame:
    """The point's shared-room episodes on `suite` for `ks`: the kept ones when they hold these Ks (and T)."""
    out = shared_dir(point, suite)
    kept = out / rundir.SHARED_JSON
    same = kept.exists() and json.loads(kept.read_text())["robots_per_room"] == ks
    if not (same and (max_steps is None or json.loads(kept.read_text())["max_steps"] == max_steps)):
        write_shared(evaluate_shared(point, suite, ks, max_steps=max_steps), out)
    return pd.read_csv(out / rundir.SHARED_EPISODES)


def trained_points(folders: list[Path]) -> list[Path]:
    """The trained points of every folder (the untrained named on stderr and left out)."""
    points = []
    for folder in folders:
        for point in sorted(rundir.points_dir(folder).iterdir()):
            if (point / rundir.PARAMS).exists():
                points.append(point)
            else:
                print(f"{point.name}: not trained yet, left out", file=sys.stderr)
    return points


def outcomes(part: pd.DataFrame) -> dict:
    """Robot-episodes of one row: success with its 95% bootstrap interval over training seeds, the
    worst seed, the worst 10% of rooms, and the shares of each outcome."""
    per_seed = part.groupby("seed")["success"].mean().to_numpy()
    per_room = part.groupby("room")["success"].mean().to_numpy()
    lo, hi = bootstrap_ci(per_seed)
    return {
        "seeds": len(per_seed),
        "success": float(part["success"].mean()),
        "ci_seeds_low": lo,
        "ci_seeds_high": hi,
        "worst_seed": float(per_seed.min()),
        "worst10_rooms": float(worst_mean(per_room)),
        **{o: float(part[o].mean()) for o in ("collision", "robot_collision", "timeout", "deadlock")},
    }


def pool(named: list[tuple[str, pd.DataFrame]], what: str) -> pd.DataFrame:
    """The episodes of several evaluations of other seeds as one frame (a seed twice: refused)."""
    try:
        return pool_seeds(named)
    except ValueError:
        others = ", ".join(n for n, _ in named)
        raise SystemExit(f"error: {what}: a seed is in more than one of {others} (pooled twice?)") from None


def rows(folders, suite: str, ks: list[int], max_steps: int | None) -> pd.DataFrame:
    """One row per (method, trained, agent-steps, K), pooled over the points' seeds."""
    groups: dict[tuple, list] = {}
    for point in trained_points([Path(f) for f in ([folders] if isinstance(folders, (str, Path)) else folders)]):
        cfg = rundir.read_config(point)
        metrics = pd.read_csv(point / rundir.METRICS)
        steps = int(cfg.run.episodes * cfg.env.episode_length * cfg.env.envs_per_robot * cfg.num_robots)
        key = (METHODS.get(cfg.method, cfg.method), "shared rooms" if cfg.env.shared_rooms else "alone", steps)
        groups.setdefault(key, []).append(
            (point, episodes(point, suite, ks, max_steps), metrics[metrics.episode >= metrics.episode.max() - 4])
        )
    table = []
    for (method, trained, steps), members in groups.items():
        ep = pool([(p.name, e) for p, e, _ in members], f"{method}, {trained}")
        last = pd.concat([m for _, _, m in members], ignore_index=True)  # training's last 5 episodes
        ends = int(last["goals"].sum() + last["collisions"].sum())
        for k, part in ep.groupby("robots_per_room"):
            table.append(
                {
                    "method": method,
                    "trained": trained,
                    "robots_per_room": int(k),
                    **outcomes(part),
                    # training's last 5 episodes: the shares of attempts (ended by a goal or a
                    # collision) ended at the goal, and by touching another robot
                    "train_goal_share": float(last["goals"].sum() / max(ends, 1)),
                    "train_robot_share": float(last["robot_collisions"].sum() / max(ends, 1))
                    if "robot_collisions" in last
                    else np.nan,
                    "agent_steps": steps,
                    "point": "+".join(p.name for p, _, _ in members),
                }
            )
    return pd.DataFrame(table).sort_values(["robots_per_room", "method", "trained"]).reset_index(drop=True)


def kept_rows(pairs: list[str]) -> pd.DataFrame:
    """LABEL=FOLDER[+FOLDER...]: kept shared-room evaluations, one row per label, K and family (and
    'all'), the folders of one label pooled (their runs trained other seeds)."""
    table = []
    for pair in pairs:
        label, _, folders = pair.partition("=")
        if not folders:
            raise SystemExit(f"error: {pair!r} is not LABEL=FOLDER[+FOLDER...]")
        named = []
        for f in folders.split("+"):
            if not (Path(f) / rundir.SHARED_EPISODES).is_file():
                raise SystemExit(f"error: {f}: no kept evaluation with K robots per room ({rundir.SHARED_EPISODES})")
            named.append((f, pd.read_csv(Path(f) / rundir.SHARED_EPISODES)))
        ep = pool(named, label)
        for k, at_k in ep.groupby("robots_per_room"):
            for family, part in [*at_k.groupby("family", sort=False), ("all", at_k)]:
                table.append({"label": label, "robots_per_room": int(k), "family": family, **outcomes(part)})
    return pd.DataFrame(table)


def markdown(df: pd.DataFrame) -> str:
    first = ["label", "family"] if "label" in df else ["method", "trained"]
    lines = [
        f"| K robots per room | {first[0]} | {first[1]} | success [95% CI over seeds] | worst seed | worst 10% rooms | "
        "obstacle | robot-robot | time-out | deadlock |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in df.to_dict(orient="records"):
        lines.append(
            f"| {r['robots_per_room']} | {r[first[0]]} | {r[first[1]]} | {r['success']:.3f} "
            f"[{r['ci_seeds_low']:.3f}, {r['ci_seeds_high']:.3f}] | {r['worst_seed']:.3f} | {r['worst10_rooms']:.3f} | "
            f"{r['collision']:.3f} | {r['robot_collision']:.3f} | {r['timeout']:.3f} | {r['deadlock']:.3f} |"
        )
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("folders", type=Path, nargs="*", help="sweep folders (several: their seeds pooled)")
    ap.add_argument("--kept", action="append", default=[], metavar="LABEL=FOLDER[+FOLDER]", help="kept evaluations")
    ap.add_argument("--suite", default="mixture-50")
    ap.add_argument("--robots-per-room", default="1,2,4,8")
    ap.add_argument("--max-steps", type=int, default=None)
    ap.add_argument("--csv", default=None, help="write the table here too (e.g. results/shared_1e7.csv)")
    a = ap.parse_args(argv)
    ks = sorted({int(k) for k in a.robots_per_room.split(",")})
    if bool(a.folders) == bool(a.kept):
        ap.error("give sweep folders or --kept evaluations (not both)")
    df = rows(a.folders, a.suite, ks, a.max_steps) if a.folders else kept_rows(a.kept)
    if a.csv:
        rundir.atomic_write(Path(a.csv), lambda p: df.to_csv(p, index=False))
    print(markdown(df))
    return 0


if __name__ == "__main__":
    sys.exit(main())
