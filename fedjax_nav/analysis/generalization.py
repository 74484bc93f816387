"""The generalization experiment's tables, goal check and figure (docs/generalization.md), from
the finished points of a sweep such as configs/sweeps/generalization.yaml: training success from
each point's summary.json, the thesis arena from eval/eval/eval.json and the held-out suite from
eval/<suite>/suite_families.csv and suite_episodes.csv. Nothing here trains or evaluates;
`fedjax_nav.experiments.generalization` does.

    table(sweep, points_dir, suite)     one row per finished point
    per_seed(sweep, points_dir, suite)  one row per point and training seed
    per_net(sweep, points_dir, suite)   one row per point and network, with the rooms it trained on
    readable(table, families)           the same as strings (mean +- std, [seed CI]) for docs
    goal(table, families)               the issue's goal per procedurally trained point
    probe_curves(sweep, points_dir)     the held-out probe during training (run.eval_every)
    robust(per_seed, families)          IQM and probability of improvement (rliable) per point

Their figures are drawn by `fedjax_nav.analysis.generalization_figures`.

The tail of the held-out suite (docs/generalization.md, "Tail metrics") rides along where the
suite's files hold it (evaluations written before it existed simply lack those columns):
`<family>_worst10` (mean success of the worst 10 % of rooms) with its interval over rooms
(`<family>_worst10_ci_low/high`), `<family>_collision`, `<family>_timeout` and
`<family>_path_ratio_median`; and so does the split by detour (`<family>_detour_share`, the share of
episodes whose goal needs a detour, `<family>_success_direct`, `<family>_success_detour`).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from fedjax_nav import rundir
from fedjax_nav.analysis.plots import probe_per_episode
from fedjax_nav.analysis.sweeps import finished
from fedjax_nav.config.sweepfile import Sweep

ARENA = "eval"  # the thesis's evaluation world
# suite_families.csv columns copied per family into `table` (the first five as they always were)
FAMILY_COLUMNS = ("success", "ci_seeds_low", "ci_seeds_high", "ci_rooms_low", "ci_rooms_high")
TAIL_COLUMNS = ("worst10", "worst10_ci_low", "worst10_ci_high", "collision", "timeout", "path_ratio_median")
# success by the goal's detour (evaluation.suite_stats.detour_split), where the suite's files hold it
DETOUR_COLUMNS = ("detour_share", "success_direct", "success_detour")
# a point's cost, from its summary.json (training.metrics.summarize, training.sweep.run): bytes the
# federated steps sent per seed (the whole fleet, up and down; 0 without an aggregator), training
# wall seconds of this run (its share of a batch of runs; after a resume, only the resumed part) and
# the episode it resumed from (0: trained in one go)
COST_COLUMNS = {"fed_bytes": "fed_bytes_sent", "wall_s": "wall_s", "resumed_from_episode": "resumed_from_episode"}


def rooms(cfg) -> str:
    """Where a point trained: 'thesis rooms', 'procedural (mixture)', 'heterogeneous (...)'."""
    if cfg.env.rooms != "procedural":
        return "thesis rooms"
    fams = tuple(cfg.env.room_families)
    if len(set(fams)) == 1:
        return f"procedural ({fams[0]})"
    return "heterogeneous (" + ", ".join(fams) + ")"


def _suite_families(folder: Path) -> pd.DataFrame | None:
    f = folder / rundir.SUITE_FAMILIES
    return pd.read_csv(f) if (folder / rundir.SUITE_JSON).exists() and f.exists() else None


def table(sweep: Sweep, points_dir: Path, suite: str = "heldout") -> pd.DataFrame:
    """One row per finished point: training success (last 25 episodes, mean and std over seeds),
    the training goal share (`rundir.goal_share`), its cost (`COST_COLUMNS`), arena success (all
    agents; std over seeds), and per
    held-out family the success with the 95% bootstrap interval over training seeds (`ci_seeds_*`)
    and over rooms (`ci_rooms_*`), and its tail (`TAIL_COLUMNS`) where the suite's files hold it."""
    rows = []
    for p, s in finished(sweep, Path(points_dir)):
        d = Path(points_dir) / p.id
        row = {
            "point": p.id,
            "label": p.label,
            "method": p.cfg.method,
            "learner": p.cfg.learner,
            "rooms": rooms(p.cfg),
            "episodes": p.cfg.run.episodes,
            "seeds": s["seeds"],
            "train_success": s["success_last"],
            "train_success_std": s["success_last_std"],
            "train_goal_share": np.nan,
            "arena": np.nan,
            "arena_seed_std": np.nan,
            # what the point cost, kept in the table because run folders may not outlive their machine
            **{col: np.nan if s.get(key) is None else s[key] for col, key in COST_COLUMNS.items()},
        }
        if (d / rundir.METRICS).exists():
            row["train_goal_share"] = rundir.goal_share(rundir.read_metrics(d, ["episode", "goals", "collisions"]))
        ev = rundir.read_eval(d, ARENA)
        if ev is not None:
            a = ev["all_agents"]["overall"]
            row.update(arena=a["success_rate"], arena_seed_std=a["success_seed_std"])
        fam = _suite_families(rundir.eval_dir(d, suite))
        if fam is not None:
            tail = [c for c in (*TAIL_COLUMNS, *DETOUR_COLUMNS) if c in fam.columns]
            for _, f in fam.iterrows():
                for col in (*FAMILY_COLUMNS, *tail):
                    row[f"{f.family}_{col}" if col != "success" else f.family] = f[col]
        rows.append(row)
    return pd.DataFrame(rows)


def per_seed(sweep: Sweep, points_dir: Path, suite: str = "heldout") -> pd.DataFrame:
    """One row per point and training seed: training success, arena success and each family's
    success of that seed's agents (the numbers the seed intervals are taken over); where the
    suite's episodes hold them, each family's worst 10 % of rooms (`<family>_worst10`, over that
    seed's agents), collision and time-out rates."""
    rows = []
    for p, s in finished(sweep, Path(points_dir)):
        d = Path(points_dir) / p.id
        arena, fams = {}, None
        ev = rundir.read_eval(d, ARENA)
        if ev is not None:
            arena = ev["all_agents"]["success_per_seed"]
        eps = rundir.eval_dir(d, suite) / rundir.SUITE_EPISODES
        if eps.exists():
            fams = _seed_families(pd.read_csv(eps))
        for seed, train in enumerate(s["success_last_per_seed"]):
            row = {"point": p.id, "label": p.label, "method": p.cfg.method, "learner": p.cfg.learner}
            row["rooms"] = rooms(p.cfg)
            row["episodes"] = p.cfg.run.episodes
            row.update(seed=seed, train_success=train, arena=arena.get(str(seed), np.nan))
            if fams is not None and seed in fams.index:
                row.update(fams.loc[seed].to_dict())
            rows.append(row)
    return pd.DataFrame(rows)


def trained_on(cfg, net: int, nets: int) -> str:
    """The rooms network `net` of `nets` trained on: its robot's family when the fleet has one
    network per robot ('fixed' for the thesis rooms), the family of every robot when they share one,
    else every robot's families (one central network)."""
    fams = tuple(cfg.env.room_families) if cfg.env.rooms == "procedural" else ("fixed",)
    if len(set(fams)) == 1:
        return fams[0]
    return fams[net] if nets == len(fams) else "+".join(dict.fromkeys(fams))


def per_net(sweep: Sweep, points_dir: Path, suite: str = "heldout") -> pd.DataFrame:
    """One row per point and network (`net` of the suite's episodes: one per robot in federated
    and independent fleets, one for a central learner): the rooms it trained on (`trained_on`) and
    its held-out success per family and over all rooms, averaged over seeds, rooms and goals. In a
    heterogeneous fleet this is where federation's gain and cost show robot by robot."""
    rows = []
    for p, _ in finished(sweep, Path(points_dir)):
        eps = rundir.eval_dir(Path(points_dir) / p.id, suite) / rundir.SUITE_EPISODES
        if not eps.exists():
            continue
        ep = pd.read_csv(eps)
        if "net" not in ep:  # a hand-written or foreign file: no network to attribute episodes to
            continue
        fam = ep.groupby(["net", "family"])["success"].mean().unstack()
        fam["all"] = ep.groupby("net")["success"].mean()
        for net, r in fam.iterrows():
            row = {"point": p.id, "label": p.label, "method": p.cfg.method, "learner": p.cfg.learner}
            row |= {"rooms": rooms(p.cfg), "episodes": p.cfg.run.episodes, "net": int(net)}
            row["trained_on"] = trained_on(p.cfg, int(net), len(fam))
            rows.append(row | r.to_dict())
    return pd.DataFrame(rows)


def worst_rooms(per_room) -> float:
    """The mean of the lowest ceil(10 %) of the rooms' success (at least one room): the statistic
    of `evaluation.suite_stats.worst_mean`, which analysis may not import (one layer); a test holds the
    two equal."""
    x = np.sort(np.asarray(per_room, np.float64))
    return float(x[: max(1, int(np.ceil(0.1 * len(x) - 1e-9)))].mean()) if len(x) else float("nan")


def _seed_families(ep: pd.DataFrame) -> pd.DataFrame:
    """Per training seed (index), per family: the success (column <family>), and where the
    episodes hold them <family>_worst10, <family>_collision, <family>_timeout."""
    out = [ep.groupby(["seed", "family"])["success"].mean().unstack()]
    for col in ("collision", "timeout"):
        if col in ep:
            out.append(ep.groupby(["seed", "family"])[col].mean().unstack().add_suffix(f"_{col}"))
    if "room" in ep:
        rooms = ep.groupby(["seed", "family", "room"])["success"].mean()
        out.append(rooms.groupby(["seed", "family"]).agg(worst_rooms).unstack().add_suffix("_worst10"))
    return pd.concat(out, axis=1)


def readable(t: pd.DataFrame, families: list[str]) -> pd.DataFrame:
    """The table as strings for docs: training success and arena as mean +- std over seeds, each
    held-out family (and all rooms) as mean [95% bootstrap interval over training seeds]; where the
    table holds the tail, each family's (and all rooms') worst 10 % of rooms as mean [95% bootstrap
    interval over rooms], and over all rooms the collision and time-out rates and the median
    path-length ratio."""

    def pm(m, sd):
        return "-" if not np.isfinite(m) else f"{m:.3f} +- {sd:.3f}"

    def ci(r, f):
        m, lo, hi = r.get(f, np.nan), r.get(f"{f}_ci_seeds_low", np.nan), r.get(f"{f}_ci_seeds_high", np.nan)
        return "-" if not np.isfinite(m) else f"{m:.3f} [{lo:.2f}, {hi:.2f}]" if np.isfinite(lo) else f"{m:.3f}"

    def worst(r, f):
        m, lo, hi = (
            r.get(f"{f}_worst10", np.nan),
            r.get(f"{f}_worst10_ci_low", np.nan),
            r.get(f"{f}_worst10_ci_high", np.nan),
        )
        return "-" if not np.isfinite(m) else f"{m:.3f} [{lo:.2f}, {hi:.2f}]" if np.isfinite(lo) else f"{m:.3f}"

    def num(x):
        return "-" if not np.isfinite(x) else f"{x:.3f}"

    tail = any(c.endswith("_worst10") for c in t.columns)
    cost = all(c in t.columns for c in COST_COLUMNS) and t[list(COST_COLUMNS)].notna().any().any()
    rows = []
    for _, r in t.iterrows():
        row = {"method": r.method.upper(), "learner": r.get("learner", "ddpg"), "rooms": r.rooms}
        row |= {"episodes": int(r.episodes), "seeds": int(r.seeds)}
        row["label"] = r.get("label", "")
        row["training, last 25"] = pm(r.train_success, r.train_success_std)
        if "train_goal_share" in r:
            row["goal share, last 25"] = "-" if not np.isfinite(r.train_goal_share) else f"{r.train_goal_share:.3f}"
        row["arena"] = pm(r.arena, r.arena_seed_std)
        row.update({f: ci(r, f) for f in [*families, "all"]})
        if tail:
            row.update({f"{f} worst 10%": worst(r, f) for f in [*families, "all"]})
            row["collision (all)"] = num(r.get("all_collision", np.nan))
            row["time-out (all)"] = num(r.get("all_timeout", np.nan))
            row["path ratio (all)"] = num(r.get("all_path_ratio_median", np.nan))
        if "all_success_detour" in r:  # goals on a clear straight line / behind a detour, all rooms
            row["direct / detour (all)"] = f"{num(r.all_success_direct)} / {num(r.all_success_detour)}"
        if cost:  # summaries written before these fields: no cost columns
            row["bytes sent per seed"] = "-" if not np.isfinite(r.fed_bytes) else f"{r.fed_bytes / 1e6:.1f} MB"
            row["wall s"] = (
                "-"
                if not np.isfinite(r.wall_s)
                else f"{r.wall_s:,.0f}"
                + (f" (from ep. {int(r.resumed_from_episode)})" if r.get("resumed_from_episode", 0) > 0 else "")
            )
        rows.append(row)
    out = pd.DataFrame(rows)
    if len(t) and not t.duplicated(["method", "learner", "rooms", "episodes"]).any():
        out = out.drop(columns="label")  # the other columns name every point
    return out


def goal_text(goal: dict) -> str:
    """'family >= 0.95, arena >= 0.95, worst10 >= 0.80': a sweep's goal (config.sweepfile.GOAL_KEYS) as read."""
    return ", ".join(f"{k} >= {v:.2f}" for k, v in goal.items())


def goal(t: pd.DataFrame, families: list[str], target: dict) -> pd.DataFrame:
    """Per procedurally trained point (the goal is for those), against the sweep's `goal:` (`target`,
    config.sweepfile.GOAL_KEYS -> threshold): every held-out family, the arena and the worst 10% of
    all rooms (means over seeds, all agents); the worst family, and whether every threshold holds."""

    def holds(v, key):
        return key not in target or (np.isfinite(v) and v >= target[key])

    rows = []
    for _, r in t[t.rooms != "thesis rooms"].iterrows():
        fam = {f: r.get(f, np.nan) for f in families}
        worst = min(fam, key=lambda f: fam[f] if np.isfinite(fam[f]) else -1.0) if fam else ""
        worst10 = r.get("all_worst10", np.nan)
        ok = holds(r.arena, "arena") and holds(worst10, "worst10") and all(holds(v, "family") for v in fam.values())
        rows.append(
            {
                "point": r.get("point", ""),
                "label": r.get("label", ""),
                "method": r.method,
                "rooms": r.rooms,
                "episodes": r.episodes,
                "seeds": r.seeds,
                "arena": r.arena,
                "worst_family": worst,
                "worst_family_success": fam.get(worst, np.nan),
                "worst10": worst10,
                "goal": goal_text(target),
                "goal_reached": bool(ok),
            }
        )
    return pd.DataFrame(rows)


def probe_curves(sweep: Sweep, points_dir: Path) -> pd.DataFrame:
    """The learning curve of generalisation: per finished point with a probe (`run.eval_every`),
    per episode where the probe ran, the held-out probe's success and the training success of that
    episode (means over seeds and robots), and the std over seeds of the probe's success."""
    rows = []
    for p, _ in finished(sweep, Path(points_dir)):
        d = Path(points_dir) / p.id
        if not (d / rundir.METRICS).exists() or not p.cfg.run.eval_every:
            continue
        c = probe_per_episode(rundir.read_metrics(d)).reset_index()
        rows.append(
            c.assign(point=p.id, label=p.label, method=p.cfg.method, rooms=rooms(p.cfg), budget=p.cfg.run.episodes)
        )
    return pd.concat(rows, ignore_index=True) if rows else pd.DataFrame()


ROBUST_NOTE = (
    "Over the score matrix training seeds x held-out families (rliable's runs x tasks): the mean, the "
    "interquartile mean (IQM, the mean of the middle 50 % of the scores) and P(> M), the probability that a "
    "seed of this point scores above a seed of method M trained with the same other settings, per family "
    "(Mann-Whitney U / (n m)), averaged over families (Agarwal et al. 2021)."
)


def _other_settings(r) -> str:
    """What a point shares with the points it is compared with: its learner, rooms and episodes and,
    where the sweep's label names the method (`method=...`), the rest of the label; a point of another
    method is compared only when it is the one point of its method with these settings."""
    rest = re.sub(r"(, )?\bmethod=\w+", "", str(r.label)).strip(", ") if "method=" in str(r.label) else ""
    return f"{r.learner}|{r.rooms}|{r.episodes}|{rest}"


def robust(ps: pd.DataFrame, families: list[str]) -> pd.DataFrame:
    """The aggregates of Agarwal et al. (2021), computed by their library rliable, per point from its
    score matrix seeds x held-out families (rliable's runs x tasks; `per_seed`'s family columns): the
    mean, the interquartile mean (`iqm`: the mean of the middle 50 % of the scores, less moved by one
    seed or family) and, against each other method trained with the same other settings
    (`_other_settings`), the probability of improvement `p_over_<method>`: per family, the chance
    that a seed of this point scores above a seed of the other (Mann-Whitney U / (n m), ties half),
    averaged over families. Points without every family's scores are left out. rliable is an extra
    (`pip install "fedjax_nav[stats]"`): ImportError without it."""
    from rliable import metrics

    cols = [f for f in families if f in ps.columns]
    scores, rows = {}, []
    for point, g in ps.groupby("point", sort=False):
        x = g.sort_values("seed")[cols].to_numpy(np.float64)
        if not cols or not np.isfinite(x).all():
            continue
        scores[point] = x
        r = g.iloc[0]
        row = {"point": r.point, "label": r.get("label", ""), "method": r.method}
        row["learner"] = r.get("learner", "ddpg")  # tables written before the column: the thesis's learner
        row |= {"rooms": r.rooms, "episodes": r.episodes}
        rows.append(row | {"seeds": len(x), "mean": float(x.mean()), "iqm": float(metrics.aggregate_iqm(x))})
    out = pd.DataFrame(rows)
    if not len(out):
        return out
    out["_group"] = out.apply(_other_settings, axis=1)
    for m in sorted(set(out.method)):
        col = f"p_over_{m}"
        out[col] = np.nan
        for i, r in out.iterrows():
            other = out[(out._group == r._group) & (out.method == m) & (out.point != r.point)]
            if r.method != m and len(other) == 1:
                y = scores[other.point.iloc[0]]
                out.loc[i, col] = float(metrics.probability_of_improvement(scores[r.point], y))
    return out.drop(columns="_group").dropna(axis=1, how="all")  # a method with no partner: no column


def robust_readable(r: pd.DataFrame) -> pd.DataFrame:
    """`robust` for docs: three decimals, '-' where a comparison has no partner, methods upper case."""
    named = r.duplicated(["method", "learner", "rooms", "episodes"]).any()  # only the label tells points apart
    out = r.drop(columns=["point"] if named else ["point", "label"])
    out["method"] = out.method.str.upper()
    for c in ["mean", "iqm", *[c for c in out.columns if c.startswith("p_over_")]]:
        out[c] = out[c].map(lambda v: "-" if not np.isfinite(v) else f"{v:.3f}")
    return out.rename(columns={c: f"P(> {c[7:].upper()})" for c in out.columns if c.startswith("p_over_")})
