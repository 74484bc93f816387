"""Live TensorBoard scalars of a training run (`run.tensorboard: true`, `--tensorboard`).

metrics.csv stays the source of truth; this mirrors it, chunk by chunk, as event files under
`RUN/tensorboard/` (or a sweep point's folder) through tensorboardX's `SummaryWriter` (a brax
dependency: nothing new to install). Per episode, with the episode index as the step:

    mean/success, mean/reward, mean/goals, mean/collisions     over seeds and robots
    mean/critic_loss, mean/actor_loss, mean/q                    over seeds and networks
    run/epsilon, run/fed_events, run/fed_bytes                   per episode (seed mean)
    robot_<k>/success, robot_<k>/reward                          per robot, mean over seeds
    (+ any other numeric column of metrics.csv, under mean/)

Writing happens on the host after each compiled chunk, from the rows that chunk added: the
compiled program is untouched, and the cost is a pandas group-by and a few hundred small writes
per chunk (measured in docs/benchmarks.md).
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from fedjax_nav import rundir

DIR = rundir.TENSORBOARD
_ID_COLUMNS = {"episode", "seed", "robot", "world"}
_RUN_WIDE = ("epsilon", "fed_events", "fed_bytes")


class TensorBoardLog:
    """One event-file writer for one run directory (or sweep point)."""

    def __init__(self, run_dir: str | Path):
        from tensorboardX import SummaryWriter

        self.path = Path(run_dir) / DIR
        self.writer = SummaryWriter(str(self.path), flush_secs=30)

    def episodes(self, df: pd.DataFrame) -> int:
        """Write the scalars of every episode in `df` (metrics.csv rows); returns scalars written."""
        if not len(df):
            return 0
        n = 0
        numeric = [c for c in df.columns if c not in _ID_COLUMNS and pd.api.types.is_numeric_dtype(df[c])]
        df = df.assign(success=df["reached_goal"]) if "reached_goal" in df else df
        per_ep = df.groupby("episode")
        means = per_ep[[c for c in numeric + ["success"] if c in df and c not in _RUN_WIDE]].mean()
        run_wide = df.groupby(["episode", "seed"])[[c for c in _RUN_WIDE if c in df]].first().groupby("episode").mean()
        robots = df.groupby(["episode", "robot"])[["success", "reward"]].mean()
        for ep, row in means.iterrows():
            for name, value in row.items():
                if name != "reached_goal":
                    self.writer.add_scalar(f"mean/{name}", float(value), int(ep))
                    n += 1
        for ep, row in run_wide.iterrows():
            for name, value in row.items():
                self.writer.add_scalar(f"run/{name}", float(value), int(ep))
                n += 1
        for (ep, robot), row in robots.iterrows():
            for name, value in row.items():
                self.writer.add_scalar(f"robot_{int(robot)}/{name}", float(value), int(ep))
                n += 1
        return n

    def flush(self) -> None:
        self.writer.flush()

    def close(self) -> None:
        self.writer.close()
