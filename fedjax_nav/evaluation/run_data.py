"""A run's agents and an evaluation of them, as data (here, below both the API in runs.py and the
file writing in report.py, which both use them; beside the program in rollout.py)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from fedjax_nav import rundir
from fedjax_nav.evaluation.rollout import EvalResult
from fedjax_nav.worlds import World


@dataclass
class RunAgents:
    """The trained actors of a run, flattened to one agent axis [A = seeds x nets]."""

    run_dir: Path
    cfg: Any  # fedjax_nav.config.Config
    actor_params: dict  # leaves [A, ...]
    agent_seed: np.ndarray  # i64[A] the run's PRNG seed of each agent
    agent_net: np.ndarray  # i64[A] the network index within its seed
    n_nets: int
    num_robots: int
    # what drives: None, the run's learner's greedy policy (`runs.run_policy`); else a policy
    # as `eval_program` takes it (a scripted baseline: `evaluation.baselines`)
    policy: Any = None

    @property
    def num_agents(self) -> int:
        return len(self.agent_seed)

    @property
    def agent_byzantine(self) -> np.ndarray:
        """bool[A]: the agents of the run's Byzantine robots (`fed.byzantine`: the last robots of
        each seed, as in training; docs/robustness.md). All False without them, or when the
        robots share one network."""
        byz = int(getattr(self.cfg.fed, "byzantine", 0))
        if byz == 0 or self.n_nets != self.num_robots:
            return np.zeros(self.num_agents, bool)
        return np.asarray(self.agent_net) >= self.num_robots - byz


@dataclass
class RunEvaluation:
    run: RunAgents
    result: EvalResult
    frame: pd.DataFrame
    summary: dict  # what eval.json holds
    world: World
    world_meta: dict = field(default_factory=dict)
    world_arg: str = "eval"  # the world as asked for (a shipped name or a file): names the folder

    @property
    def eval_dir(self) -> Path:
        """Where this evaluation is kept by default: RUN/eval/<world>/ (rundir.eval_dir)."""
        return rundir.eval_dir(self.run.run_dir, self.world_arg)


def run_name(run) -> str:
    """A run directory, or a `RunAgents`' own, as a line names it."""
    return str(run.run_dir) if isinstance(run, RunAgents) else str(run)
