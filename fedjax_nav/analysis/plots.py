"""Figures of learning curves (matplotlib, Agg)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd


def moving_average(x, n: int = 10) -> np.ndarray:
    """Simple moving average over the last n values (fewer at the start), as the thesis plots."""
    x = np.asarray(x, float)
    c = np.cumsum(np.insert(x, 0, 0.0))
    idx = np.arange(1, len(x) + 1)
    lo = np.maximum(idx - n, 0)
    return (c[idx] - c[lo]) / (idx - lo)


def per_episode(df: pd.DataFrame) -> pd.DataFrame:
    """Success proportion and mean reward per (seed, episode): the thesis's learning metrics."""
    return (df.groupby(["seed", "episode"])
              .agg(success=("reached_goal", "mean"), reward=("reward", "mean"))
              .reset_index())


def curves(df: pd.DataFrame, metric: str, window: int = 10) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(episodes, mean over seeds, std over seeds) of the smoothed per-seed curves."""
    pe = per_episode(df)
    table = pe.pivot(index="episode", columns="seed", values=metric).sort_index()
    smooth = np.stack([moving_average(table[c].to_numpy(), window) for c in table.columns], axis=1)
    return table.index.to_numpy(), smooth.mean(1), smooth.std(1)


def save_figure(fig, path: str | Path, dpi: int = 100) -> Path:
    """Save a matplotlib Figure atomically (temporary file, then rename): a reader never sees a
    half-written PNG."""
    from fedjax_nav.training.run import atomic_write

    path = Path(path)
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=dpi, format=path.suffix.lstrip(".") or "png"))
    return path


def learning_curves(runs, path: str | Path, title: str = "", window: int = 10) -> Path:
    """Success and reward curves (10-episode SMA, mean and spread over seeds).

    runs: a metrics DataFrame, or a dict label -> DataFrame to draw several methods together.
    """
    from matplotlib.figure import Figure  # no pyplot: the caller's backend is left alone

    if isinstance(runs, pd.DataFrame):
        runs = {"": runs}
    fig = Figure(figsize=(10, 3.6), layout="constrained")
    axes = fig.subplots(1, 2)
    for label, df in runs.items():
        for ax, metric, name in zip(axes, ["success", "reward"], ["success proportion", "mean reward per step"]):
            ep, mu, sd = curves(df, metric, window)
            line, = ax.plot(ep + 1, mu, label=label or None)
            ax.fill_between(ep + 1, mu - sd, mu + sd, alpha=0.2, color=line.get_color())
            ax.set_xlabel("episode")
            ax.set_ylabel(f"{name} ({window}-ep SMA)")
            ax.grid(alpha=0.3)
    if any(runs):
        axes[0].legend(fontsize=8)
    fig.suptitle(title)
    return save_figure(fig, path)
