"""The figures of thesis chapter 4 (Fig. 11-20), drawn from the tidy tables a sweep or
`fedjax-nav reproduce` writes, so that the report and notebooks/analysis.ipynb draw the same
pictures from the same files.

    runs:    label -> metrics DataFrame (rows episode x seed x robot; results.csv filtered)
    summary: one row per grid point (summary.csv)
    evals:   one row per evaluated run (eval_summary.csv of the report)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from fedjax_nav.analysis.plots import curves, save_figure

METRIC_NAMES = {"success": "proportion of successful runs", "reward": "mean reward per step"}


def _fig(w: float, h: float, ncols: int = 1):
    from matplotlib.figure import Figure  # no pyplot: the caller's backend is left alone

    fig = Figure(figsize=(w, h), layout="constrained")
    return fig, fig.subplots(1, ncols)


def learning_figure(
    runs: dict, path: str | Path, metric: str = "success", title: str = "", dotted: dict | None = None, window: int = 10
) -> Path:
    """Fig. 11, 12, 14, 15, 16, 19: the 10-episode SMA of `metric` per label, mean over seeds with
    a band of one std; `dotted` runs (references) as dotted lines without bands."""
    fig, ax = _fig(7.5, 4.0)
    if len(runs) > 10:  # the default cycle repeats after 10 colours
        from matplotlib import colormaps

        ax.set_prop_cycle(color=colormaps["tab20"].colors)
    for label, df in runs.items():
        ep, mu, sd = curves(df, metric, window)
        (line,) = ax.plot(ep + 1, mu, label=f"{label} ({df['seed'].nunique()} seeds)")
        ax.fill_between(ep + 1, mu - sd, mu + sd, alpha=0.15, color=line.get_color())
    for label, df in (dotted or {}).items():
        ep, mu, _ = curves(df, metric, window)
        ax.plot(ep + 1, mu, ls=":", lw=2, label=f"{label} (reference)")
    ax.set_xlabel("episode")
    ax.set_ylabel(f"{METRIC_NAMES.get(metric, metric)}\n({window}-episode SMA; band: std over seeds)")
    if metric == "success":
        ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2 if len(runs) + len(dotted or {}) > 5 else 1)
    ax.set_title(title, fontsize=10)
    return save_figure(fig, path)


def bars_figure(
    labels, means, stds, path: str | Path, ylabel: str, title: str = "", thesis: list | None = None
) -> Path:
    """Fig. 13-style bars of one number per setting (mean and std over seeds), with the thesis's
    value as a marker where it printed one."""
    fig, ax = _fig(max(5.0, 0.7 * len(labels) + 2), 3.6)
    x = np.arange(len(labels))
    ax.bar(x, means, 0.6, yerr=stds, capsize=3, color="#1f77b4", edgecolor="black", lw=0.5, label="measured")
    if thesis is not None and any(v is not None and np.isfinite(v) for v in thesis):
        t = np.array([np.nan if v is None else v for v in thesis], float)
        ax.plot(x, t, "D", color="#d62728", label="thesis")
    for xi, m in zip(x, means):
        ax.annotate(f"{m:.2f}", (xi, m), xytext=(0, 2), textcoords="offset points", ha="center", fontsize=7)
    ax.set_xticks(x, labels, fontsize=8, rotation=30 if len(labels) > 6 else 0)
    ax.set_ylabel(ylabel)
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(title, fontsize=10)
    return save_figure(fig, path)


EVAL_PANELS = [
    ("success", "success_seed_std", "success rate"),
    ("time_mean", "time_std", "time to goal (s)\n(successful runs)"),
    ("efficiency_mean", "efficiency_std", "trajectory efficiency\n(successful runs)"),
]


def eval_figure(
    evals: pd.DataFrame,
    path: str | Path,
    title: str = "",
    reference: pd.DataFrame | None = None,
    panels=EVAL_PANELS,
    thesis: pd.DataFrame | None = None,
) -> Path:
    """Fig. 17, 18, 20: bars per method (evals rows: label + the panel columns); `reference` rows
    are drawn as dotted horizontal lines (Fig. 20's FLDDPG and SNDDPG); `thesis` (label + the
    same columns) as red markers."""
    fig, axes = _fig(3.3 * len(panels) + 1, 3.6, len(panels))
    axes = np.atleast_1d(axes)
    x = np.arange(len(evals))
    for ax, (col, err, name) in zip(axes, panels):
        vals = evals[col].to_numpy(float)
        errs = evals[err].to_numpy(float) if err in evals else None
        ax.bar(x, np.nan_to_num(vals), 0.6, color="#1f77b4", edgecolor="black", lw=0.5, label="measured")
        if errs is not None:
            ok = np.isfinite(vals) & np.isfinite(errs)
            ax.errorbar(x[ok], vals[ok], yerr=errs[ok], fmt="none", ecolor="black", capsize=3, lw=1)
        if thesis is not None and col in thesis:
            t = thesis.set_index("label").reindex(evals["label"])[col].to_numpy(float)
            if np.isfinite(t).any():
                ax.plot(x, t, "D", color="#d62728", label="thesis")
        for _, r in reference.iterrows() if reference is not None else []:
            if np.isfinite(r[col]):
                line = ax.axhline(r[col], ls=":", lw=1.5, color="gray")
                ax.annotate(r["label"], (x[-1] + 0.4, r[col]), fontsize=6, color=line.get_color(), va="bottom")
        ax.set_xticks(x, evals["label"], fontsize=8, rotation=20 if len(evals) > 4 else 0)
        ax.set_ylabel(name, fontsize=9)
        if col in ("success", "best_success", "efficiency_mean"):
            ax.set_ylim(0, 1.05)
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    return save_figure(fig, path)


def settings_figure(by_setting: str | Path, path: str | Path) -> Path:
    """The bars of one experiment's committed table (`results/reproduction_<experiment>.csv`: one
    row per setting, success over the last 25 episodes, mean and std over seed runs, and the
    thesis's number where it printed one): the figure a fresh clone can redraw without runs/."""
    t = pd.read_csv(by_setting)
    name = Path(by_setting).stem.removeprefix("reproduction_")
    thesis = t["thesis_success"].tolist() if "thesis_success" in t else None
    labels = [f"{t['by'].iloc[0].split('.')[-1]}={v}" for v in t["setting"]]
    title = f"{name}: success, last 25 episodes ({int(t['runs'].min())}-{int(t['runs'].max())} runs per setting)"
    return bars_figure(labels, t["success"], t["success_std"], path, "success, last 25 episodes", title, thesis)
