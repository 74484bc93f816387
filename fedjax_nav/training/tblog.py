"""Live TensorBoard scalars of a training run (`run.tensorboard: true`, `--tensorboard`).

metrics.csv stays the source of truth; this mirrors it, chunk by chunk, as event files under
`RUN/tensorboard/` (or a sweep point's folder) through tensorboardX's `SummaryWriter` (a brax
dependency: nothing new to install). The x-axis (the step of every scalar) is the agent-steps
done at the end of the episode: environment steps summed over the fleet's environments,
`(episode + 1) x env.episode_length x robots x env.envs_per_robot` (one seed's fleet; seeds are
replicas), so runs of different fleet sizes or episode lengths compare on the experience they
used. Per episode:

    mean/success, mean/reward, mean/goals, mean/collisions     over seeds and robots
    mean/critic_loss, mean/actor_loss, mean/q                    over seeds and networks
    run/epsilon, run/fed_events, run/fed_bytes                   per episode (seed mean)
    run/episode                                                  the episode index (0-based)
    robot_<k>/success, robot_<k>/reward                          per robot, mean over seeds
    (+ any other numeric column of metrics.csv, under mean/)

The run's hyperparameters are logged once, when the log opens: every config field (dotted names,
`config.to_dict`) for TensorBoard's HParams dashboard, with `hparam/success_last` as its metric
(the success over the last 25 episodes, as summary.json's `success_last`:
`rundir.success_last_per_seed`, mean over seeds, written after each chunk), and the config as
YAML under the text tag `config`.

Writing happens on the host after each compiled chunk, from the rows that chunk added: the
compiled program is untouched, and the cost is a pandas group-by and a few hundred small writes
per chunk (measured in docs/benchmarks.md).
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from fedjax_nav import rundir
from fedjax_nav.config import Config

DIR = rundir.TENSORBOARD
SUCCESS_METRIC = "hparam/success_last"
_ID_COLUMNS = {"episode", "seed", "robot", "world"}
_RUN_WIDE = ("epsilon", "fed_events", "fed_bytes")
_LAST = rundir.success_last_per_seed.__defaults__[0]  # summary.json's window (25 episodes)


def agent_steps_per_episode(cfg: Config) -> int:
    """Environment steps of one episode summed over the fleet's environments (the x-axis unit)."""
    return cfg.env.episode_length * cfg.num_robots * cfg.env.envs_per_robot


def hparams_of(cfg: Config) -> dict:
    """Every config field by dotted name, as the HParams dashboard takes them (bool, number or
    string; a list such as env.worlds joined by commas, anything else as its str)."""
    from fedjax_nav.config import to_dict

    flat = {}
    for name, value in to_dict(cfg).items():
        flat.update({f"{name}.{k}": v for k, v in value.items()} if isinstance(value, dict) else {name: value})
    return {
        k: v if isinstance(v, (bool, int, float, str)) else ",".join(map(str, v)) if isinstance(v, list) else str(v)
        for k, v in flat.items()
    }


class TensorBoardLog:
    """One event-file writer for one run directory (or sweep point) of config `cfg`."""

    def __init__(self, run_dir: str | Path, cfg: Config):
        import yaml
        from tensorboardX import SummaryWriter
        from tensorboardX.summary import hparams

        from fedjax_nav.config import to_dict

        self.path = Path(run_dir) / DIR
        self.writer = SummaryWriter(str(self.path), flush_secs=30)
        self.unit = agent_steps_per_episode(cfg)
        self._tail = pd.DataFrame(columns=["episode", "seed", "reached_goal"])
        for summary in hparams(hparams_of(cfg), {SUCCESS_METRIC: 0.0}):  # experiment, session start, end
            self.writer.file_writer.add_summary(summary)
        text = yaml.safe_dump(to_dict(cfg), sort_keys=False)
        self.writer.add_text("config", "```\n" + text + "```", 0)  # markdown: kept as written

    def step(self, episode: int) -> int:
        """The x-axis value of episode `episode` (0-based): the agent-steps done at its end."""
        return (int(episode) + 1) * self.unit

    def remember(self, df: pd.DataFrame) -> None:
        """Episodes written before (a resumed run's metrics.csv): they count towards the success
        metric's window and are not written again."""
        self._keep(df)

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
            self.writer.add_scalar("run/episode", int(ep), self.step(ep))
            n += 1
            for name, value in row.items():
                if name != "reached_goal":
                    self.writer.add_scalar(f"mean/{name}", float(value), self.step(ep))
                    n += 1
        for ep, row in run_wide.iterrows():
            for name, value in row.items():
                self.writer.add_scalar(f"run/{name}", float(value), self.step(ep))
                n += 1
        for (ep, robot), row in robots.iterrows():
            for name, value in row.items():
                self.writer.add_scalar(f"robot_{int(robot)}/{name}", float(value), self.step(ep))
                n += 1
        if "reached_goal" in df:
            self._keep(df)
            success = float(rundir.success_last_per_seed(self._tail, _LAST).mean())
            self.writer.add_scalar(SUCCESS_METRIC, success, self.step(self._tail["episode"].max()))
            n += 1
        return n

    def _keep(self, df: pd.DataFrame) -> None:
        """The rows of the last `_LAST` episodes seen, for the success metric."""
        rows = df[["episode", "seed", "reached_goal"]]
        tail = pd.concat([self._tail, rows]) if len(self._tail) else rows
        self._tail = tail[tail["episode"] > tail["episode"].max() - _LAST]

    def flush(self) -> None:
        self.writer.flush()

    def close(self) -> None:
        self.writer.close()
