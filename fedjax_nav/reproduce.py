"""`fedjax-nav reproduce`: every experiment of thesis chapter 4 from one command, into a report
folder with Fig. 11-20, Tables 2 and 3, and a markdown report putting each measured number beside
the thesis's.

    reproduce("ci", "runs/reproduce-ci")         # reduced: 10 episodes x 64 steps, 2 seeds
    reproduce("thesis", "runs/reproduce-thesis")  # the thesis's scale: many hours on a 2-core CPU

The experiments are the sweep files of configs/sweeps/ (EXPERIMENTS). Their points are pooled and
deduplicated (the thesis FLDDPG config appears in six experiments and is trained once, with the
most seeds any of them asks for), trained with `fedjax_nav.sweep.run_jobs` (one compilation per
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
    points/<id>/                 the runs: config.yaml, metrics.csv, summary.json, params.npz, eval.json
"""
from __future__ import annotations

import json
import platform
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from fedjax_nav import sweep as sw
from fedjax_nav.training.run import atomic_write

ROOT = Path(__file__).resolve().parents[1]
SWEEP_DIR = ROOT / "configs" / "sweeps"
EXPERIMENTS = ("gamma", "rho", "buffer_iddpg", "buffer_seddpg", "buffer_snddpg", "buffer_flddpg",
               "fed_period_steps", "fed_period_episodes", "tau", "methods", "pw_beta", "rw_beta", "improvements")


@dataclass(frozen=True)
class Scale:
    name: str
    overrides: tuple  # applied to every point
    buffer_scale: float
    seeds: int | None  # None: each sweep file's own count
    attempts: int  # evaluation attempts per agent and goal


SCALES = {
    "thesis": Scale("thesis", (), 1.0, None, 4),
    # 10 episodes so that E_update = 10 still aggregates; 64 x 10 steps >= T_update = 512; buffers
    # x 0.02 so that they wrap in 640 steps as the thesis's wrap in 128k; batch 32 <= every buffer.
    "ci": Scale("ci", ("run.episodes=10", "env.episode_length=64", "run.chunk_episodes=5",
                       "run.checkpoint_every=0", "ddpg.batch_size=32"), 0.02, 2, 1),
}


def load_experiments(scale: Scale, only=None, seeds: int | None = None) -> list[sw.Sweep]:
    names = list(EXPERIMENTS if not only else only)
    unknown = [n for n in names if n not in EXPERIMENTS]
    if unknown:
        raise sw.SweepError(f"--only: unknown experiment(s) {unknown}; allowed: {', '.join(EXPERIMENTS)}")
    n = seeds if seeds is not None else scale.seeds
    return [sw.load_sweep(SWEEP_DIR / f"{name}.yaml", overrides=list(scale.overrides), seeds=n,
                          buffer_scale=scale.buffer_scale) for name in names]


# ----------------------------------------------------------------------------- evaluation


def evaluate_points(sweeps: list[sw.Sweep], points_dir: Path, attempts: int, echo: Callable) -> pd.DataFrame:
    """Evaluate every point of the experiments marked `evaluate` (eval.json kept in the point's
    folder and reused when the same attempts were asked for). One row per point."""
    from fedjax_nav.evaluation.protocol import evaluate_run, write_run

    rows, seen = [], set()
    for s in sweeps:
        if not s.evaluate:
            continue
        for p in s.points:
            d = points_dir / p.id
            if p.id in seen or not (d / "params.npz").exists():
                continue
            seen.add(p.id)
            f = d / "eval.json"
            ev = json.loads(f.read_text()) if f.exists() else None
            if ev is None or ev.get("attempts_requested") != attempts:
                result = evaluate_run(d, attempts=attempts)
                write_run(result, figures=False)
                ev = json.loads(f.read_text())
                echo(f"evaluated {p.cfg.method} ({p.id}): success {ev['all_agents']['overall']['success_rate']:.3f}"
                     f" over {ev['episodes']} episodes")
            a, b = ev["all_agents"]["overall"], ev["best_agent_per_seed"]["overall"]
            rows.append({"point": p.id, "label": p.cfg.method, "experiment": s.name, "seeds": len(ev["seeds"]),
                         "agents": ev["agents"], "episodes": ev["episodes"], "success": a["success_rate"],
                         "success_seed_std": a["success_seed_std"], "time_mean": a["time_mean"],
                         "time_std": a["time_std"], "efficiency_mean": a["efficiency_mean"],
                         "efficiency_std": a["efficiency_std"], "best_success": b["success_rate"],
                         "best_success_seed_std": b["success_seed_std"]})
    df = pd.DataFrame(rows)
    num = [c for c in df.columns if c not in ("point", "label", "experiment", "seeds", "agents", "episodes")]
    return df.astype({c: float for c in num}) if len(df) else df  # None (no success) -> NaN


# ----------------------------------------------------------------------------- numbers


def by_setting(s: sw.Sweep, points_dir: Path) -> pd.DataFrame:
    """The sweep's last-25 numbers grouped by its `thesis.by` key (gamma: over the four methods),
    mean and std over every seed of every point in the group, with the thesis's numbers."""
    by = s.thesis.get("by") or (s.keys[0] if s.keys and s.keys[0] != "base" else "method")
    from fedjax_nav.analysis.plots import per_episode

    rows = []
    for p, js in sw.finished(s, points_dir):
        pe = per_episode(pd.read_csv(points_dir / p.id / "metrics.csv"))
        E = int(pe["episode"].max()) + 1
        tail = pe[pe["episode"] >= E - min(25, E)].groupby("seed")[["success", "reward"]].mean()
        key = p.cfg.method if by == "method" else p.values[by]
        for _, r in tail.iterrows():
            rows.append({"setting": key, "success": r["success"], "reward": r["reward"],
                         "n_comm": js["communication"]["n_comm"], "events": js["aggregation_events"]})
    if not rows:
        return pd.DataFrame()
    df = pd.DataFrame(rows)
    order = list(dict.fromkeys(df["setting"]))
    g = df.groupby("setting", sort=False)
    out = pd.DataFrame({"setting": order, "runs": g.size().reindex(order).to_numpy(),
                        "success": g["success"].mean().reindex(order).to_numpy(),
                        "success_std": g["success"].std(ddof=0).reindex(order).to_numpy(),
                        "reward": g["reward"].mean().reindex(order).to_numpy(),
                        "reward_std": g["reward"].std(ddof=0).reindex(order).to_numpy(),
                        "n_comm": g["n_comm"].first().reindex(order).to_numpy(),
                        "aggregation_events": g["events"].first().reindex(order).to_numpy()})
    for k in ("success_last", "reward_last"):
        ref = s.thesis.get(k, {}) or {}
        out[f"thesis_{k.split('_')[0]}"] = [ref.get(v, ref.get(str(v))) for v in out["setting"]]
    out.insert(0, "by", by)
    return out


def _pm(m, s, d=3) -> str:
    if m is None or not np.isfinite(m):
        return "-"
    return f"{m:.{d}f} ± {s:.{d}f}" if s is not None and np.isfinite(s) else f"{m:.{d}f}"


def _v(x, d=3) -> str:
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return "-"
    if isinstance(x, float):
        return str(int(x)) if x.is_integer() else f"{x:.{d}f}"
    return str(x)


def _t(x) -> str:
    """A thesis number as the thesis printed it."""
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f"{x:g}"


def experiment_markdown(s: sw.Sweep, table: pd.DataFrame) -> str:
    lines = [f"### {s.name}: {s.description}", ""]
    if table.empty:
        return "\n".join(lines + ["(not run)", ""])
    by = table["by"].iloc[0]
    lines += [f"| {by} | runs | success, last 25 eps | thesis | reward per step, last 25 eps | thesis |",
              "|---|---|---|---|---|---|"]
    for _, r in table.iterrows():
        lines.append(f"| {r['setting']} | {r['runs']} | {_pm(r['success'], r['success_std'])} | "
                     f"{_t(r['thesis_success'])} | {_pm(r['reward'], r['reward_std'])} | {_t(r['thesis_reward'])} |")
    lines.append("")
    if s.thesis.get("note"):
        lines += [f"Thesis: {s.thesis['note']}."]
    top = table[table["success"] == table["success"].max()]["setting"].tolist()
    lines += [f"Measured best (success): {by} = {', '.join(map(str, top))}" + (" (tie)." if len(top) > 1 else "."), ""]
    return "\n".join(lines)


def table2(sweeps_dir: Path = SWEEP_DIR) -> pd.DataFrame:
    """Table 2: the paper's and the thesis's hyperparameters, read from the shipped configs."""
    from fedjax_nav.config import load_config

    thesis = {m: load_config(ROOT / "configs" / "thesis" / f"{m}.yaml") for m in ("iddpg", "seddpg", "snddpg", "flddpg")}
    paper = load_config(ROOT / "configs" / "paper" / "flddpg.yaml")
    t = thesis["flddpg"]
    rows = [
        ("robots N", paper.num_robots, t.num_robots),
        ("episodes E", paper.run.episodes, t.run.episodes),
        ("steps per episode T", paper.env.episode_length, t.env.episode_length),
        ("buffer |D| (IDDPG, SEDDPG, SNDDPG, FLDDPG)", "50 000 each",
         ", ".join(f"{thesis[m].ddpg.buffer_size:,}".replace(",", " ") for m in thesis)),
        ("T_train", paper.ddpg.train_every, t.ddpg.train_every),
        ("T_target", paper.ddpg.target_every, t.ddpg.target_every),
        ("epsilon start", paper.ddpg.epsilon_start, t.ddpg.epsilon_start),
        ("epsilon decay", paper.ddpg.epsilon_decay, t.ddpg.epsilon_decay),
        ("learning rate", paper.ddpg.lr, t.ddpg.lr),
        ("gamma", paper.ddpg.gamma, t.ddpg.gamma),
        ("rho", paper.ddpg.rho, t.ddpg.rho),
        ("batch |B|", paper.ddpg.batch_size, t.ddpg.batch_size),
        ("hidden width", paper.ddpg.hidden, t.ddpg.hidden),
        ("v_max (m/s)", paper.env.v_max, t.env.v_max),
        ("collision reward", paper.env.reward_collision, t.env.reward_collision),
        ("federated period", f"{paper.fed.period} {paper.fed.period_unit}", f"{t.fed.period} {t.fed.period_unit}"),
        ("tau", paper.fed.tau, t.fed.tau),
    ]
    rows = [(name, *(f"{v:g}" if isinstance(v, float) else str(v) for v in vals)) for name, *vals in rows]
    return pd.DataFrame(rows, columns=["parameter", "paper (configs/paper/flddpg.yaml)", "thesis (configs/thesis/)"])


def table3(s: sw.Sweep, points_dir: Path) -> pd.DataFrame:
    rows = []
    for p, js in sw.finished(s, points_dir):
        ref = (s.thesis.get("n_comm") or {}).get(p.cfg.method)
        rows.append({"method": p.cfg.method, "n_comm (Eq. 25)": js["communication"]["n_comm"],
                     "aggregation events counted": js["aggregation_events"], "thesis": ref,
                     "bytes per federated round": js.get("bytes_per_fed_round", 0)})
    return pd.DataFrame(rows)


def _md_table(df: pd.DataFrame) -> str:
    cols = list(df.columns)
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for _, r in df.iterrows():
        out.append("| " + " | ".join(_v(r[c]) if isinstance(r[c], float) else str(r[c]) for c in cols) + " |")
    return "\n".join(out)


def eval_markdown(evals: pd.DataFrame, thesis: dict) -> str:
    lines = ["| method | agents | episodes | success (all agents) | thesis | time (s) | thesis | efficiency | thesis "
             "| success, best agent per seed* |", "|---|---|---|---|---|---|---|---|---|---|"]
    for _, r in evals.iterrows():
        m = r["label"]
        t = {k: (thesis.get(k) or {}).get(m) for k in ("eval_success", "eval_time", "eval_efficiency")}
        lines.append(f"| {m} | {r['agents']} | {r['episodes']} | {_pm(r['success'], r['success_seed_std'])} | "
                     f"{_t(t['eval_success'])} | {_pm(r['time_mean'], r['time_std'], 2)} | {_t(t['eval_time'])} | "
                     f"{_pm(r['efficiency_mean'], r['efficiency_std'])} | {_t(t['eval_efficiency'])} | "
                     f"{_pm(r['best_success'], r['best_success_seed_std'])} |")
    lines += ["", "Success: ± std over seeds; time and efficiency: ± std over successful episodes. "
              "*Selected on the evaluation episodes themselves (thesis Fig. 17; not an honest estimate)."]
    return "\n".join(lines)


# ----------------------------------------------------------------------------- figures


def _runs(res: pd.DataFrame, col: str, fmt=str) -> dict:
    return {fmt(k): g for k, g in res.groupby(col, sort=False)}


def draw_figures(sweeps: dict, out: Path, evals: pd.DataFrame, tables: dict) -> list[Path]:
    """Fig. 11-20 from the experiments' results.csv and `by_setting` tables (only those whose
    experiments ran)."""
    from fedjax_nav.analysis import thesis_figures as tf

    def res(name):
        f = out / "experiments" / name / "results.csv"
        return pd.read_csv(f) if name in sweeps and f.exists() and f.stat().st_size > 1 else pd.DataFrame()

    paths = []
    r = res("buffer_snddpg")
    if len(r):
        paths.append(tf.learning_figure(_runs(r, "ddpg.buffer_size", lambda v: f"|D| = {v}"), out / "fig11_snddpg_buffer.png",
                                        title="Fig. 11: SNDDPG, replay buffer size"))
    rs, re_ = res("fed_period_steps"), res("fed_period_episodes")
    if len(rs) or len(re_):
        runs = {**(_runs(rs, "fed.period", lambda v: f"T_update = {v}") if len(rs) else {}),
                **(_runs(re_, "fed.period", lambda v: f"E_update = {v}") if len(re_) else {})}
        paths.append(tf.learning_figure(runs, out / "fig12_fed_period_learning.png",
                                        title="Fig. 12: FLDDPG, federated update period"))
        tabs = []
        for name, prefix in (("fed_period_steps", "T"), ("fed_period_episodes", "E")):
            if name in sweeps:
                t = tables[name].copy()
                if len(t):
                    t["label"] = [f"{prefix}={v}" for v in t["setting"]]
                    tabs.append(t)
        t = pd.concat(tabs)
        paths.append(tf.bars_figure(t["label"], t["success"], t["success_std"], out / "fig13_fed_period_success.png",
                                    "success, last 25 episodes", "Fig. 13: FLDDPG, federated update period"))
    r = res("tau")
    if len(r):
        names = {0.0: "tau = 0 (IDDPG)", 0.5: "tau = 0.5 (soft)", 1.0: "tau = 1 (hard FedAvg)"}
        paths.append(tf.learning_figure(_runs(r, "fed.tau", lambda v: names.get(v, f"tau = {v}")), out / "fig14_tau.png",
                                        title="Fig. 14: FLDDPG soft update against IDDPG and hard FedAvg"))
    r = res("methods")
    if len(r):
        runs = _runs(r, "method")
        paths.append(tf.learning_figure(runs, out / "fig15_methods_reward.png", "reward", "Fig. 15: reward during learning"))
        paths.append(tf.learning_figure(runs, out / "fig16_methods_success.png", "success",
                                        "Fig. 16: success during learning"))
    ri = res("improvements")
    if len(ri):
        dotted = {k: v for k, v in _runs(r, "method").items() if k in ("flddpg", "snddpg")} if len(r) else {}
        paths.append(tf.learning_figure(_runs(ri, "method"), out / "fig19_improvements_learning.png",
                                        title="Fig. 19: the proposed improvements during learning", dotted=dotted))
    if len(evals):
        em = evals[evals["experiment"] == "methods"]
        if len(em):
            best = em.assign(success=em["best_success"], success_seed_std=em["best_success_seed_std"])
            paths.append(tf.eval_figure(best, out / "fig17_eval_best_agents.png",
                                        "Fig. 17: evaluation, best agent per seed (selected on evaluation data)",
                                        panels=tf.EVAL_PANELS[:1]))
            paths.append(tf.eval_figure(em, out / "fig18_eval_methods.png", "Fig. 18: evaluation, every trained agent",
                                        thesis=_thesis_eval(sweeps["methods"])))
        ei = evals[evals["experiment"] == "improvements"]
        if len(ei):
            ref = em[em["label"].isin(["flddpg", "snddpg"])] if len(em) else None
            paths.append(tf.eval_figure(ei, out / "fig20_eval_improvements.png",
                                        "Fig. 20: evaluation of the improvements (dotted: FLDDPG, SNDDPG)",
                                        reference=ref, thesis=_thesis_eval(sweeps["improvements"])))
    return paths


def _thesis_eval(s: sw.Sweep) -> pd.DataFrame:
    t = s.thesis
    methods = sorted(set().union(*[set((t.get(k) or {})) for k in ("eval_success", "eval_time", "eval_efficiency")]))
    return pd.DataFrame({"label": methods,
                         "success": [(t.get("eval_success") or {}).get(m, np.nan) for m in methods],
                         "time_mean": [(t.get("eval_time") or {}).get(m, np.nan) for m in methods],
                         "efficiency_mean": [(t.get("eval_efficiency") or {}).get(m, np.nan) for m in methods]})


# ----------------------------------------------------------------------------- the command


def reproduce(scale: str = "ci", out: str | Path | None = None, only=None, seeds: int | None = None,
              budget: int | None = None, progress: bool = True, echo: Callable[[str], None] = print,
              devices: int | None = None) -> dict:
    """Run (or resume) the experiments and write the report folder. Returns reproduce.json's dict."""
    import jax

    if scale not in SCALES:
        raise sw.SweepError(f"--scale {scale!r}: allowed {', '.join(SCALES)}")
    sc = SCALES[scale]
    out = Path(out or f"runs/reproduce-{scale}")
    out.mkdir(parents=True, exist_ok=True)
    sweeps = load_experiments(sc, only, seeds)
    t0 = time.time()
    jobs = sw.merge_jobs([p for s in sweeps for p in s.points])
    stats = sw.run_jobs(jobs, out, budget, progress, desc=f"reproduce {scale}", echo=echo, devices=devices)
    t_train = time.time() - t0
    points = out / "points"
    for s in sweeps:
        sw.write_tables(s, points, out / "experiments" / s.name)
    t1 = time.time()
    evals = evaluate_points(sweeps, points, sc.attempts, echo)
    t_eval = time.time() - t1
    atomic_write(out / "eval_summary.csv", lambda p: evals.to_csv(p, index=False))
    by_name = {s.name: s for s in sweeps}
    tables = {s.name: by_setting(s, points) for s in sweeps}
    figs = draw_figures(by_name, out, evals, tables)
    t2 = table2()
    atomic_write(out / "table2_hyperparameters.csv", lambda p: t2.to_csv(p, index=False))
    atomic_write(out / "table2_hyperparameters.md", lambda p: Path(p).write_text(_md_table(t2) + "\n"))
    t3 = table3(by_name["methods"], points) if "methods" in by_name else pd.DataFrame()
    atomic_write(out / "table3_communication.csv", lambda p: t3.to_csv(p, index=False))
    atomic_write(out / "table3_communication.md", lambda p: Path(p).write_text(_md_table(t3) + "\n" if len(t3) else ""))
    for name, t in tables.items():
        atomic_write(out / "experiments" / name / "by_setting.csv", lambda p, t=t: t.to_csv(p, index=False))
    info = {
        "scale": scale, "overrides": list(sc.overrides), "buffer_scale": sc.buffer_scale,
        "seeds": seeds if seeds is not None else sc.seeds, "experiments": [s.name for s in sweeps],
        "distinct_runs": len(jobs), "seed_runs": sum(j.cfg.run.seeds for j in jobs), "train": stats,
        "train_wall_s": t_train, "eval_wall_s": t_eval, "eval_attempts": sc.attempts,
        "figures": [p.name for p in figs], "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
        "machine": f"{platform.machine()}, {__import__('os').cpu_count()} cores, {platform.python_version()}",
        "jax": jax.__version__, "backend": jax.default_backend(),
    }
    prev = out / "reproduce.json"
    history = json.loads(prev.read_text()).get("history", []) if prev.exists() else []
    history.append({"date": info["date"], "trained_points": len(jobs) - stats["skipped"],
                    "train_wall_s": t_train, "eval_wall_s": t_eval})
    info["history"] = history
    info["train_compute_s"] = sum(_point_wall(points / j.id) for j in jobs)
    atomic_write(out / "reproduce.json", lambda p: Path(p).write_text(json.dumps(info, indent=1)))
    md = report_markdown(sweeps, tables, t2, t3, evals, info)
    atomic_write(out / "report.md", lambda p: Path(p).write_text(md))
    echo(f"wrote {out}/report.md, {len(figs)} figures, tables 2 and 3")
    return info


def _point_wall(d: Path) -> float:
    f = d / "summary.json"
    return float(json.loads(f.read_text()).get("wall_s") or 0.0) if f.exists() else 0.0


def report_markdown(sweeps, tables, t2, t3, evals, info) -> str:
    seeds = info["seeds"] or "each sweep file's count"
    lines = [f"# Thesis chapter 4, reproduced ({info['scale']} scale)", "",
             f"`fedjax-nav reproduce --scale {info['scale']}`, {info['date']}; {info['machine']}; jax {info['jax']} "
             f"({info['backend']}). Seeds per setting: {seeds}. Overrides on every run: "
             f"{', '.join(info['overrides']) or 'none'}; buffer sizes x {info['buffer_scale']:g}. "
             f"{info['distinct_runs']} distinct configs, {info['seed_runs']} seed runs; training "
             f"{info['train_compute_s']:.0f} s in all (summed over invocations: {len(info['history'])}), evaluation "
             f"{info['eval_wall_s']:.0f} s in the last one.", "",
             "Runs: mean ± std over seeds (population std). Success: proportion of robots that reached the goal "
             "per episode, averaged over the last 25 episodes (over all episodes when a run is shorter). "
             "A dash: the thesis printed no number.", ""]
    if info["scale"] != "thesis":
        lines += ["**Reduced scale**: these numbers check the pipeline, not the science; compare the thesis-scale "
                  "numbers in docs/reproduction.md.", ""]
    lines += ["## Table 2: hyperparameters", "", _md_table(t2), ""]
    lines += ["## Experiments", ""]
    for s in sweeps:
        lines.append(experiment_markdown(s, tables[s.name]))
    if len(t3):
        lines += ["## Table 3: communication rounds (Eq. 25)", "", _md_table(t3), ""]
    for name in ("methods", "improvements"):
        sub = evals[evals["experiment"] == name] if len(evals) else evals
        if len(sub):
            thesis = next(s.thesis for s in sweeps if s.name == name)
            lines += [f"## Evaluation: {name}", "", eval_markdown(sub, thesis), ""]
    lines += ["## Figures", ""] + [f"![{f}]({f})" for f in info["figures"]] + [""]
    return "\n".join(lines)
