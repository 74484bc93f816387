"""Figures of learning curves (matplotlib, Agg)."""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd

from fedjax_nav import rundir
from fedjax_nav.rundir import save_figure  # noqa: F401  (figures are saved atomically, by the run directory's owner)


def distinct_colors(n: int) -> list:
    """`n` colours, none twice up to 20 (tab10 up to 10 curves, tab20 up to 20; past 20 they cycle)."""
    cmap = matplotlib.colormaps["tab10" if n <= 10 else "tab20"]
    return [cmap(i % cmap.N) for i in range(n)]


def moving_average(x, n: int = 10) -> np.ndarray:
    """Simple moving average over the last n values (fewer at the start), as the thesis plots."""
    x = np.asarray(x, float)
    c = np.cumsum(np.insert(x, 0, 0.0))
    idx = np.arange(1, len(x) + 1)
    lo = np.maximum(idx - n, 0)
    return (c[idx] - c[lo]) / (idx - lo)


def per_episode(df: pd.DataFrame) -> pd.DataFrame:
    """Success proportion and mean reward per (seed, episode): the thesis's learning metrics."""
    return (
        df.groupby(["seed", "episode"]).agg(success=("reached_goal", "mean"), reward=("reward", "mean")).reset_index()
    )


def curves(df: pd.DataFrame, metric: str, window: int = 10) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(episodes, mean over seeds, std over seeds) of the smoothed per-seed curves."""
    pe = per_episode(df)
    table = pe.pivot(index="episode", columns="seed", values=metric).sort_index()
    smooth = np.stack([moving_average(table[c].to_numpy(), window) for c in table.columns], axis=1)
    return table.index.to_numpy(), smooth.mean(1), smooth.std(1)


def probe_per_episode(df: pd.DataFrame) -> pd.DataFrame:
    """Per episode where the held-out probe ran (`run.eval_every`): its success (each seed's mean
    over robots, then the mean over seeds), the std over seeds (ddof 0, as `curves`) and the
    training success of that episode. Index: episode."""
    pe = df.dropna(subset=["eval_success"]).groupby(["episode", "seed"])[["eval_success", "reached_goal"]].mean()
    g = pe.groupby("episode")
    probe, train = g["eval_success"], g["reached_goal"]
    return pd.DataFrame({"probe": probe.mean(), "probe_seed_std": probe.std(ddof=0), "train": train.mean()})


def learning_curves(runs, path: str | Path, title: str = "", window: int = 10) -> Path:
    """Success and reward curves (10-episode SMA, mean and spread over seeds).

    runs: a metrics DataFrame, or a dict label -> DataFrame to draw several methods together.
    """
    from matplotlib.figure import Figure  # no pyplot: the caller's backend is left alone

    if isinstance(runs, pd.DataFrame):
        runs = {"": runs}
    n = len(runs)
    below = n > 6  # many runs: the legend goes under the plots, in columns, instead of over a curve
    rows = -(-n // 3) if below else 0
    fig = Figure(figsize=(10, 3.6 + 0.2 * rows), layout="constrained")
    axes = fig.subplots(1, 2)
    colors = dict(zip(runs, distinct_colors(n)))
    for label, df in runs.items():
        for ax, metric, name in zip(axes, ["success", "reward"], ["success proportion", "mean reward per step"]):
            ax.set_xlabel("episode")
            ax.set_ylabel(f"{name} ({window}-ep SMA)")
            ax.grid(alpha=0.3)
            if df.empty:  # a run stopped before its first episode ended: say so rather than draw bare axes
                ax.text(
                    0.5, 0.5, "no finished episode: nothing to draw", ha="center", va="center", transform=ax.transAxes
                )
                continue
            ep, mu, sd = curves(df, metric, window)
            # a line through one episode draws nothing: markers show short curves, error bars their spread
            few = len(ep) < 2
            ax.plot(ep + 1, mu, marker="o" if few else None, label=label or None, color=colors[label])
            if few:
                ax.errorbar(ep + 1, mu, yerr=sd, fmt="none", capsize=4, color=colors[label])
                ax.set_xticks(ep + 1)  # whole episodes, not 0.96 ... 1.04
            else:
                ax.fill_between(ep + 1, mu - sd, mu + sd, alpha=0.2, color=colors[label])
    probe = False
    for label, df in runs.items():  # run.eval_every: greedy success on the held-out probe, beside training success
        if "eval_success" in df and df["eval_success"].notna().any():
            probe = True
            ev = probe_per_episode(df)
            x, mu, sd = ev.index.to_numpy() + 1, ev["probe"], ev["probe_seed_std"]
            name = f"{label + ': ' if label else ''}held-out probe (greedy)" if n == 1 else None
            axes[0].plot(x, mu, "o--", ms=3, label=name, color=colors[label])
            axes[0].fill_between(x, mu - sd, mu + sd, alpha=0.15, color=colors[label])
    if probe and n > 1:
        axes[0].set_title("solid: training; dashed, dots: held-out probe (greedy)", fontsize=8)
    if below:
        fig.legend(*axes[1].get_legend_handles_labels(), loc="outside lower center", ncol=3, fontsize=7)
    elif any(runs) or probe:
        axes[0].legend(fontsize=8)
    fig.suptitle(title)
    return save_figure(fig, path)


def draw_run(run: str | Path) -> Path:
    """learning_curves.png of a training run directory, from its metrics.csv and config."""
    cfg = rundir.read_config(run)
    return learning_curves(
        rundir.read_metrics(run), Path(run) / rundir.CURVES, title=f"{cfg.method}, {cfg.run.seeds} seeds"
    )
