"""The thesis chapter 4 report: numbers per setting beside the thesis's, Tables 2 and 3, the
markdown report and Fig. 11-20 (drawn by `fedjax_nav.analysis.thesis_figures`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from fedjax_nav import rundir
from fedjax_nav.analysis.sweeps import finished
from fedjax_nav.config.sweepfile import Sweep
from fedjax_nav.configs import CONFIG_DIR, SWEEP_DIR


def experiment_dir(out: str | Path, name: str) -> Path:
    """REPORT/experiments/<name>/: the tables of one experiment (`analysis.sweeps.write_tables`)."""
    return Path(out) / "experiments" / name


# ----------------------------------------------------------------------------- numbers


def by_setting(s: Sweep, points_dir: Path) -> pd.DataFrame:
    """The sweep's last-25 numbers grouped by its `thesis.by` key (gamma: over the four methods),
    mean and std over every seed of every point in the group, with the thesis's numbers."""
    by = s.thesis.get("by") or (s.keys[0] if s.keys and s.keys[0] != "base" else "method")
    from fedjax_nav.analysis.plots import per_episode

    rows = []
    for p, js in finished(s, points_dir):
        pe = per_episode(rundir.read_metrics(points_dir / p.id))
        E = int(pe["episode"].max()) + 1
        tail = pe[pe["episode"] >= E - min(25, E)].groupby("seed")[["success", "reward"]].mean()
        key = p.cfg.method if by == "method" else p.values[by]
        for _, r in tail.iterrows():
            rows.append(
                {
                    "setting": key,
                    "success": r["success"],
                    "reward": r["reward"],
                    "n_comm": js["communication"]["n_comm"],
                    "events": js["aggregation_events"],
                }
            )
    if not rows:
        return pd.DataFrame()
    df = pd.DataFrame(rows)
    order = list(dict.fromkeys(df["setting"]))
    g = df.groupby("setting", sort=False)
    out = pd.DataFrame(
        {
            "setting": order,
            "runs": g.size().reindex(order).to_numpy(),
            "success": g["success"].mean().reindex(order).to_numpy(),
            "success_std": g["success"].std(ddof=0).reindex(order).to_numpy(),
            "reward": g["reward"].mean().reindex(order).to_numpy(),
            "reward_std": g["reward"].std(ddof=0).reindex(order).to_numpy(),
            "n_comm": g["n_comm"].first().reindex(order).to_numpy(),
            "aggregation_events": g["events"].first().reindex(order).to_numpy(),
        }
    )
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


def experiment_markdown(s: Sweep, table: pd.DataFrame) -> str:
    lines = [f"### {s.name}: {s.description}", ""]
    if table.empty:
        return "\n".join(lines + ["(not run)", ""])
    by = table["by"].iloc[0]
    lines += [
        f"| {by} | runs | success, last 25 eps | thesis | reward per step, last 25 eps | thesis |",
        "|---|---|---|---|---|---|",
    ]
    for _, r in table.iterrows():
        lines.append(
            f"| {r['setting']} | {r['runs']} | {_pm(r['success'], r['success_std'])} | "
            f"{_t(r['thesis_success'])} | {_pm(r['reward'], r['reward_std'])} | {_t(r['thesis_reward'])} |"
        )
    lines.append("")
    if s.thesis.get("note"):
        lines += [f"Thesis: {s.thesis['note']}."]
    top = table[table["success"] == table["success"].max()]["setting"].tolist()
    lines += [f"Measured best (success): {by} = {', '.join(map(str, top))}" + (" (tie)." if len(top) > 1 else "."), ""]
    return "\n".join(lines)


def table2(sweeps_dir: Path = SWEEP_DIR) -> pd.DataFrame:
    """Table 2: the paper's and the thesis's hyperparameters, read from the shipped configs."""
    from fedjax_nav.config import load_config

    thesis = {m: load_config(CONFIG_DIR / "thesis" / f"{m}.yaml") for m in ("iddpg", "seddpg", "snddpg", "flddpg")}
    paper = load_config(CONFIG_DIR / "paper" / "flddpg.yaml")
    t = thesis["flddpg"]
    rows = [
        ("robots N", paper.num_robots, t.num_robots),
        ("episodes E", paper.run.episodes, t.run.episodes),
        ("steps per episode T", paper.env.episode_length, t.env.episode_length),
        (
            "buffer |D| (IDDPG, SEDDPG, SNDDPG, FLDDPG)",
            "50 000 each",
            ", ".join(f"{thesis[m].offpolicy.buffer_size:,}".replace(",", " ") for m in thesis),
        ),
        ("T_train", paper.offpolicy.train_every, t.offpolicy.train_every),
        ("T_target", paper.ddpg.target_every, t.ddpg.target_every),
        ("epsilon start", paper.ddpg.epsilon_start, t.ddpg.epsilon_start),
        ("epsilon decay", paper.ddpg.epsilon_decay, t.ddpg.epsilon_decay),
        ("learning rate", paper.offpolicy.lr, t.offpolicy.lr),
        ("gamma", paper.offpolicy.gamma, t.offpolicy.gamma),
        ("rho", paper.ddpg.rho, t.ddpg.rho),
        ("batch |B|", paper.offpolicy.batch_size, t.offpolicy.batch_size),
        ("hidden width", paper.offpolicy.hidden, t.offpolicy.hidden),
        ("v_max (m/s)", paper.env.v_max, t.env.v_max),
        ("collision reward", paper.env.reward_collision, t.env.reward_collision),
        ("federated period", f"{paper.fed.period} {paper.fed.period_unit}", f"{t.fed.period} {t.fed.period_unit}"),
        ("tau", paper.fed.tau, t.fed.tau),
    ]
    rows = [(name, *(f"{v:g}" if isinstance(v, float) else str(v) for v in vals)) for name, *vals in rows]
    return pd.DataFrame(rows, columns=["parameter", "paper (configs/paper/flddpg.yaml)", "thesis (configs/thesis/)"])


def table3(s: Sweep, points_dir: Path) -> pd.DataFrame:
    rows = []
    for p, js in finished(s, points_dir):
        ref = (s.thesis.get("n_comm") or {}).get(p.cfg.method)
        rows.append(
            {
                "method": p.cfg.method,
                "n_comm (Eq. 25)": js["communication"]["n_comm"],
                "aggregation events counted": js["aggregation_events"],
                "thesis": ref,
                "bytes per federated round": js.get("bytes_per_fed_round", 0),
            }
        )
    return pd.DataFrame(rows)


def md_table(df: pd.DataFrame) -> str:
    cols = list(df.columns)
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for _, r in df.iterrows():
        out.append("| " + " | ".join(_v(r[c]) if isinstance(r[c], float) else str(r[c]) for c in cols) + " |")
    return "\n".join(out)


def eval_markdown(evals: pd.DataFrame, thesis: dict) -> str:
    lines = [
        "| method | agents | episodes | success (all agents) | thesis | time (s) | thesis | efficiency | thesis "
        "| success, best agent per seed* |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for _, r in evals.iterrows():
        m = r["label"]
        t = {k: (thesis.get(k) or {}).get(m) for k in ("eval_success", "eval_time", "eval_efficiency")}
        lines.append(
            f"| {m} | {r['agents']} | {r['episodes']} | {_pm(r['success'], r['success_seed_std'])} | "
            f"{_t(t['eval_success'])} | {_pm(r['time_mean'], r['time_std'], 2)} | {_t(t['eval_time'])} | "
            f"{_pm(r['efficiency_mean'], r['efficiency_std'])} | {_t(t['eval_efficiency'])} | "
            f"{_pm(r['best_success'], r['best_success_seed_std'])} |"
        )
    lines += [
        "",
        "Success: ± std over seeds; time and efficiency: ± std over successful episodes. "
        "*Selected on the evaluation episodes themselves (thesis Fig. 17; not an honest estimate).",
    ]
    return "\n".join(lines)


# ----------------------------------------------------------------------------- figures


def _runs(res: pd.DataFrame, col: str, fmt=str) -> dict:
    return {fmt(k): g for k, g in res.groupby(col, sort=False)}


def draw_figures(sweeps: dict, out: Path, evals: pd.DataFrame, tables: dict) -> list[Path]:
    """Fig. 11-20 from the experiments' results.csv and `by_setting` tables (only those whose
    experiments ran)."""
    from fedjax_nav.analysis import thesis_figures as tf

    def res(name):
        return _results(sweeps, out, name)

    paths = []
    r = res("buffer_snddpg")
    if len(r):
        paths.append(
            tf.learning_figure(
                # results.csv names a swept field as the sweep file writes it: buffer_snddpg.yaml's old name
                _runs(r, "ddpg.buffer_size", lambda v: f"|D| = {v}"),
                out / "fig11_snddpg_buffer.png",
                title="Fig. 11: SNDDPG, replay buffer size",
            )
        )
    rs, re_ = res("fed_period_steps"), res("fed_period_episodes")
    if len(rs) or len(re_):
        paths += _period_figures(sweeps, out, tables, rs, re_)
    r = res("tau")
    if len(r):
        names = {0.0: "tau = 0 (IDDPG)", 0.5: "tau = 0.5 (soft)", 1.0: "tau = 1 (hard FedAvg)"}
        paths.append(
            tf.learning_figure(
                _runs(r, "fed.tau", lambda v: names.get(v, f"tau = {v}")),
                out / "fig14_tau.png",
                title="Fig. 14: FLDDPG soft update against IDDPG and hard FedAvg",
            )
        )
    r = res("methods")
    if len(r):
        runs = _runs(r, "method")
        paths.append(
            tf.learning_figure(runs, out / "fig15_methods_reward.png", "reward", "Fig. 15: reward during learning")
        )
        paths.append(
            tf.learning_figure(runs, out / "fig16_methods_success.png", "success", "Fig. 16: success during learning")
        )
    ri = res("improvements")
    if len(ri):
        dotted = {k: v for k, v in _runs(r, "method").items() if k in ("flddpg", "snddpg")} if len(r) else {}
        paths.append(
            tf.learning_figure(
                _runs(ri, "method"),
                out / "fig19_improvements_learning.png",
                title="Fig. 19: the proposed improvements during learning",
                dotted=dotted,
            )
        )
    if len(evals):
        paths += _eval_figures(sweeps, out, evals)
    return paths


def _results(sweeps: dict, out: Path, name: str) -> pd.DataFrame:
    """The results.csv of experiment `name` (empty when it did not run or has no rows yet)."""
    f = experiment_dir(out, name) / rundir.SWEEP_RESULTS
    return pd.read_csv(f) if name in sweeps and f.exists() and f.stat().st_size > 1 else pd.DataFrame()


def _period_figures(sweeps: dict, out: Path, tables: dict, rs: pd.DataFrame, re_: pd.DataFrame) -> list[Path]:
    """Fig. 12 (learning) and Fig. 13 (success bars) of the federated update period, in steps (`rs`)
    and in episodes (`re_`)."""
    from fedjax_nav.analysis import thesis_figures as tf

    paths = []
    runs = {
        **(_runs(rs, "fed.period", lambda v: f"T_update = {v}") if len(rs) else {}),
        **(_runs(re_, "fed.period", lambda v: f"E_update = {v}") if len(re_) else {}),
    }
    paths.append(
        tf.learning_figure(
            runs, out / "fig12_fed_period_learning.png", title="Fig. 12: FLDDPG, federated update period"
        )
    )
    tabs = []
    for name, prefix in (("fed_period_steps", "T"), ("fed_period_episodes", "E")):
        if name in sweeps:
            t = tables[name].copy()
            if len(t):
                t["label"] = [f"{prefix}={v}" for v in t["setting"]]
                tabs.append(t)
    t = pd.concat(tabs)
    paths.append(
        tf.bars_figure(
            t["label"],
            t["success"],
            t["success_std"],
            out / "fig13_fed_period_success.png",
            "success, last 25 episodes",
            "Fig. 13: FLDDPG, federated update period",
        )
    )
    return paths


def _eval_figures(sweeps: dict, out: Path, evals: pd.DataFrame) -> list[Path]:
    """Fig. 17, 18 (the methods) and Fig. 20 (the improvements) from the evaluations `evals`."""
    from fedjax_nav.analysis import thesis_figures as tf

    paths = []
    em = evals[evals["experiment"] == "methods"]
    if len(em):
        best = em.assign(success=em["best_success"], success_seed_std=em["best_success_seed_std"])
        paths.append(
            tf.eval_figure(
                best,
                out / "fig17_eval_best_agents.png",
                "Fig. 17: evaluation, best agent per seed (selected on evaluation data)",
                panels=tf.EVAL_PANELS[:1],
            )
        )
        paths.append(
            tf.eval_figure(
                em,
                out / "fig18_eval_methods.png",
                "Fig. 18: evaluation, every trained agent",
                thesis=_thesis_eval(sweeps["methods"]),
            )
        )
    ei = evals[evals["experiment"] == "improvements"]
    if len(ei):
        ref = em[em["label"].isin(["flddpg", "snddpg"])] if len(em) else None
        paths.append(
            tf.eval_figure(
                ei,
                out / "fig20_eval_improvements.png",
                "Fig. 20: evaluation of the improvements (dotted: FLDDPG, SNDDPG)",
                reference=ref,
                thesis=_thesis_eval(sweeps["improvements"]),
            )
        )
    return paths


def _thesis_eval(s: Sweep) -> pd.DataFrame:
    t = s.thesis
    methods = sorted(set().union(*[set((t.get(k) or {})) for k in ("eval_success", "eval_time", "eval_efficiency")]))
    return pd.DataFrame(
        {
            "label": methods,
            "success": [(t.get("eval_success") or {}).get(m, np.nan) for m in methods],
            "time_mean": [(t.get("eval_time") or {}).get(m, np.nan) for m in methods],
            "efficiency_mean": [(t.get("eval_efficiency") or {}).get(m, np.nan) for m in methods],
        }
    )


def point_wall(d: Path) -> float:
    f = d / rundir.SUMMARY
    return float(rundir.read_json(f).get("wall_s") or 0.0) if f.exists() else 0.0


def report_markdown(sweeps, tables, t2, t3, evals, info) -> str:
    seeds = info["seeds"] or "each sweep file's count"
    lines = [
        f"# Thesis chapter 4, reproduced ({info['scale']} scale)",
        "",
        f"`fedjax-nav reproduce --scale {info['scale']}`, {info['date']}; {info['machine']}; jax {info['jax']} "
        f"({info['backend']}). Seeds per setting: {seeds}. Overrides on every run: "
        f"{', '.join(info['overrides']) or 'none'}; buffer sizes x {info['buffer_scale']:g}. "
        f"{info['distinct_runs']} distinct configs, {info['seed_runs']} seed runs; training "
        f"{info['train_compute_s']:.0f} s in all (summed over invocations: {len(info['history'])}), evaluation "
        f"{info['eval_wall_s']:.0f} s in the last one.",
        "",
        "Runs: mean ± std over seeds (population std). Success: proportion of robots that reached the goal "
        "per episode, averaged over the last 25 episodes (over all episodes when a run is shorter). "
        "A dash: the thesis printed no number.",
        "",
    ]
    if info["scale"] != "thesis":
        lines += [
            "**Reduced scale**: these numbers check the pipeline, not the science; compare the thesis-scale "
            "numbers in docs/reproduction.md.",
            "",
        ]
    lines += ["## Table 2: hyperparameters", "", md_table(t2), ""]
    lines += ["## Experiments", ""]
    for s in sweeps:
        lines.append(experiment_markdown(s, tables[s.name]))
    if len(t3):
        lines += ["## Table 3: communication rounds (Eq. 25)", "", md_table(t3), ""]
    for name in ("methods", "improvements"):
        sub = evals[evals["experiment"] == name] if len(evals) else evals
        if len(sub):
            thesis = next(s.thesis for s in sweeps if s.name == name)
            lines += [f"## Evaluation: {name}", "", eval_markdown(sub, thesis), ""]
    lines += ["## Figures", ""] + [f"![{f}]({f})" for f in info["figures"]] + [""]
    return "\n".join(lines)
