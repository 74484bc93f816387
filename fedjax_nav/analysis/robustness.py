"""The robustness experiment's table, verdict and figure (docs/robustness.md), from the finished
points of a sweep such as configs/sweeps/robustness.yaml: what the runs give, read from each
point's summary.json (learning) and eval/eval/eval.json (evaluation on the thesis arena, when
it exists). Nothing here trains or evaluates; `fedjax_nav.experiments.robustness` does.

    table(sweep, points_dir)      one row per finished point: setting, honest / all success, bytes
    per_seed(sweep, points_dir)   one row per point and seed
    verdict(table)                the issue's acceptance checks, one row per check
    figure(table, path)           aggregator x attack heat maps of honest success
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from fedjax_nav import rundir
from fedjax_nav.analysis.sweeps import finished
from fedjax_nav.config.sweepfile import Sweep
from fedjax_nav.federated.attacks import ATTACKS

AGGREGATOR_NAMES = {
    "method": "FedAvg",
    "mean": "mean",
    "median": "median",
    "trimmed_mean": "trimmed mean",
    "krum": "Krum",
    "geometric_median": "geometric median",
    "norm_bounded": "norm-bounded",
}
WITHIN = 0.10  # the tolerance: within 10% of the clean run (relative)
LAST = 25  # episodes: learning success is taken over the last 25 (summary.json's success_last)
ARENA = "eval"  # the thesis's evaluation world


def _eval(folder: Path) -> dict | None:
    return rundir.read_eval(folder, ARENA)


def _honest_block(ev: dict) -> dict:
    return ev.get("honest_agents", ev["all_agents"])  # no Byzantine agent: every agent is honest


def setting(cfg) -> str:
    """A short human name of a point: 'FedAvg, noise x1', 'median, clean', 'IDDPG', ..."""
    if cfg.method != "flddpg":
        return cfg.method.upper()
    agg = AGGREGATOR_NAMES.get(cfg.fed.aggregator, cfg.fed.aggregator)
    parts = [agg]
    parts.append(f"{cfg.fed.attack} x{cfg.fed.byzantine}" if cfg.fed.byzantine else "clean")
    if cfg.fed.participation < 1.0:
        parts.append(f"{1 - cfg.fed.participation:.0%} absent")
    if len(cfg.env.worlds) != 5:
        parts.append(f"{len(cfg.env.worlds)} robots")
    return ", ".join(parts)


def _success_but_last(folder: Path, last: int = LAST) -> float:
    """Success over the last `last` episodes of every robot but the last one (mean over seeds):
    in a clean run, what the robots that are honest when the last client is Byzantine reached."""
    if not (folder / rundir.METRICS).exists():
        return np.nan
    df = rundir.read_metrics(folder, ["episode", "seed", "robot", "reached_goal"])
    return float(rundir.success_last_per_seed(df[df.robot < df.robot.max()], last).mean())


def table(sweep: Sweep, points_dir: Path) -> pd.DataFrame:
    """One row per finished point: learning success over the last 25 episodes of the honest robots
    and of all robots (mean, std over seeds), evaluation success on the thesis arena (when
    evaluated), bytes actually sent per seed and rounds skipped."""
    rows = []
    for p, s in finished(sweep, Path(points_dir)):
        cfg = p.cfg
        fed = cfg.method == "flddpg"
        honest = s.get("success_last_honest", s["success_last"])
        row = {
            "point": p.id,
            "setting": setting(cfg),
            "method": cfg.method,
            "aggregator": cfg.fed.aggregator if fed else "",
            "attack": cfg.fed.attack if fed and cfg.fed.byzantine else "clean",
            "byzantine": cfg.fed.byzantine if fed else 0,
            "participation": cfg.fed.participation if fed else np.nan,
            "robots": len(cfg.env.worlds),
            "seeds": s["seeds"],
            "success_honest": honest,
            "success_honest_std": s.get("success_last_honest_std", s["success_last_std"]),
            "success_all": s["success_last"],
            "success_all_std": s["success_last_std"],
            "eval_honest": np.nan,
            "eval_honest_std": np.nan,
            "eval_all": np.nan,
            "eval_all_std": np.nan,
            # clean runs: the robots that are honest when the last client is Byzantine (like for like)
            "success_but_last": _success_but_last(points_dir / p.id) if not cfg.fed.byzantine else np.nan,
            "bytes_sent_per_seed": s.get("fed_bytes_sent", np.nan),
            "skipped_rounds": s.get("fed_skipped_rounds", np.nan),
            "diverged_seeds": len(s.get("diverged_seeds", [])),
        }
        ev = _eval(points_dir / p.id)
        if ev is not None:
            h, a = _honest_block(ev)["overall"], ev["all_agents"]["overall"]
            row.update(
                eval_honest=h["success_rate"],
                eval_honest_std=h["success_seed_std"],
                eval_all=a["success_rate"],
                eval_all_std=a["success_seed_std"],
            )
        rows.append(row)
    return pd.DataFrame(rows)


def per_seed(sweep: Sweep, points_dir: Path) -> pd.DataFrame:
    """One row per point and seed: learning success (honest, last 25 episodes) and evaluation
    success (honest agents) of that seed."""
    rows = []
    for p, s in finished(sweep, Path(points_dir)):
        learn = s.get("success_last_honest_per_seed", s["success_last_per_seed"])
        ev = _eval(points_dir / p.id)
        evs = _honest_block(ev)["success_per_seed"] if ev is not None else {}
        for seed, v in enumerate(learn):
            rows.append(
                {
                    "point": p.id,
                    "setting": setting(p.cfg),
                    "seed": seed,
                    "success_honest": v,
                    "eval_honest": evs.get(str(seed), np.nan),
                }
            )
    return pd.DataFrame(rows)


def _one(t: pd.DataFrame, **match) -> pd.Series | None:
    sel = t
    for k, v in match.items():
        sel = sel[sel[k] == v]
    return sel.iloc[0] if len(sel) else None


def verdict(t: pd.DataFrame) -> pd.DataFrame:
    """The issue's acceptance checks on what has been run, one row per check: 30% dropout within
    10% of full participation; for each attack with 1 Byzantine client, the best robust aggregator
    within 10% of clean FedAvg and at least the honest fleet alone, with FedAvg beside it.
    `reference` is the clean run's headline (all robots, the issue's reading); `clean_same_robots`
    the clean run's success over the robots that are honest under attack, shown for context."""
    fl = t[t.method == "flddpg"]
    full = _one(fl, aggregator="method", attack="clean", participation=1.0, robots=5)
    drop = _one(fl, aggregator="method", attack="clean", participation=0.7, robots=5)
    fleet = _one(fl, aggregator="method", attack="clean", participation=1.0, robots=4)
    rows = []
    if full is not None and drop is not None:
        rows.append(
            {
                "check": "30% absent every round",
                "value": drop.success_honest,
                "value_std": drop.success_honest_std,
                "reference": full.success_honest,
                "ratio": drop.success_honest / full.success_honest,
                "passes": drop.success_honest >= (1 - WITHIN) * full.success_honest,
            }
        )
    attacked = fl[(fl.byzantine == 1) & (fl.participation == 1.0) & (fl.robots == 5)]
    for attack in [a for a in ATTACKS if a in set(attacked.attack)]:
        cells = attacked[attacked.attack == attack]
        robust = cells[cells.aggregator != "method"]
        fedavg = _one(cells, aggregator="method")
        if full is None or not len(robust):
            continue
        best = robust.loc[robust.success_honest.idxmax()]
        ok = best.success_honest >= (1 - WITHIN) * full.success_honest
        if fleet is not None:
            ok = ok and best.success_honest >= fleet.success_honest
        rows.append(
            {
                "check": f"1 of 5 Byzantine, {attack}",
                "best": AGGREGATOR_NAMES[best.aggregator],
                "value": best.success_honest,
                "value_std": best.success_honest_std,
                "reference": full.success_honest,
                "ratio": best.success_honest / full.success_honest,
                "clean_same_robots": full.success_but_last,
                "honest_fleet": fleet.success_honest if fleet is not None else np.nan,
                "honest_fleet_std": fleet.success_honest_std if fleet is not None else np.nan,
                "fedavg": fedavg.success_honest if fedavg is not None else np.nan,
                "aggregators_run": len(robust),
                "passes": bool(ok),
            }
        )
    cols = ["check", "best", "value", "value_std", "reference", "ratio", "clean_same_robots", "honest_fleet"]
    cols += ["honest_fleet_std", "fedavg"]
    cols += ["aggregators_run", "passes"]
    return pd.DataFrame(rows, columns=cols)


def _grid(t: pd.DataFrame, byzantine: int, column: str) -> tuple:
    """(aggregators, attacks, mean, std, ran): the [aggregator, attack] cells of `column`."""
    fl = t[(t.method == "flddpg") & (t.robots == 5) & (t.participation == 1.0)]
    fl = fl[(fl.byzantine == byzantine) | (fl.attack == "clean")]
    aggs = [a for a in AGGREGATOR_NAMES if a in set(fl.aggregator)]
    attacks = [a for a in ("clean", *ATTACKS[1:]) if a in set(fl.attack)]
    mean = np.full((len(aggs), len(attacks)), np.nan)
    std = mean.copy()
    ran = np.zeros(mean.shape, bool)
    for _, r in fl.iterrows():
        i, j = aggs.index(r.aggregator), attacks.index(r.attack)
        mean[i, j], std[i, j], ran[i, j] = r[column], r[f"{column}_std"], True
    return aggs, attacks, mean, std, ran


def matrix(t: pd.DataFrame, column: str = "success_honest", byzantine: int = 1) -> pd.DataFrame:
    """Aggregator (rows) x attack (columns, 'clean' first) of 'mean +- std' of `column` over
    seeds, for 5 robots, everyone taking part and `byzantine` Byzantine clients; '' where not run,
    'n/a' where run without a value (not evaluated, or its actors are NaN)."""
    aggs, attacks, mean, std, ran = _grid(t, byzantine, column)
    cells = [
        [f"{m:.3f} ± {s:.3f}" if np.isfinite(m) else ("n/a" if r else "") for m, s, r in zip(mr, sr, rr)]
        for mr, sr, rr in zip(mean, std, ran)
    ]
    return pd.DataFrame(cells, index=[AGGREGATOR_NAMES[a] for a in aggs], columns=attacks)


def figure(t: pd.DataFrame, path: str | Path, column: str = "success_honest", title: str = "") -> Path:
    """Heat maps, one per Byzantine count: aggregator (rows) x attack (columns, 'clean' first),
    colour and text the mean of `column` over seeds, +- its std; cells not run are blank. The
    references without an attack (honest fleets, dropout, IDDPG) are listed under the maps."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    counts = sorted(int(b) for b in set(t.byzantine) if b > 0) or [1]
    fig, axes = plt.subplots(1, len(counts), figsize=(6.4 * len(counts), 4.6), squeeze=False)
    for ax, b in zip(axes[0], counts):
        aggs, attacks, mean, std, ran = _grid(t, b, column)
        ax.imshow(np.ma.masked_invalid(mean), cmap="viridis", vmin=0, vmax=1, aspect="auto")
        for i in range(len(aggs)):
            for j in range(len(attacks)):
                if ran[i, j] and not np.isfinite(mean[i, j]):
                    ax.text(j, i, "n/a", ha="center", va="center", fontsize=8)
                elif np.isfinite(mean[i, j]):
                    txt = f"{mean[i, j]:.2f}\n±{std[i, j]:.2f}" if np.isfinite(std[i, j]) else f"{mean[i, j]:.2f}"
                    ax.text(j, i, txt, ha="center", va="center", fontsize=8, color="w" if mean[i, j] < 0.6 else "k")
        ax.set_xticks(range(len(attacks)), attacks, rotation=30)
        ax.set_yticks(range(len(aggs)), [AGGREGATOR_NAMES[a] for a in aggs])
        ax.set_title(f"{b} of 5 Byzantine")
    refs = t[(t.method != "flddpg") | (t.robots != 5) | (t.participation < 1.0)]
    note = "; ".join(f"{r.setting}: {r[column]:.2f} ± {r[f'{column}_std']:.2f}" for _, r in refs.iterrows())
    fig.suptitle(title or f"{column.replace('_', ' ')} (mean ± std over seeds)")
    if note:
        fig.text(0.5, 0.01, "references: " + note, ha="center", fontsize=8, wrap=True)
    fig.tight_layout(rect=(0, 0.06 if note else 0, 1, 1))
    out = rundir.save_figure(fig, path)
    plt.close(fig)
    return out
