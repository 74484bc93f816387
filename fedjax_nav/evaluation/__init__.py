"""The evaluation protocol (docs/evaluation.md; thesis 4.2), one job per module:

    rollout   the jitted program: every agent x goal x attempt of a policy (evaluate_policy)
    policies  a policy with a memory (MemoryPolicy: a recurrent policy's state through each episode)
    metrics   per-episode rows and their aggregation (episodes_frame, summarize, best_agents)
    runs      training runs: load_run, evaluate_run, evaluate_runs (what `fedjax-nav evaluate` does)
    report    files and tables: write_run (into RUN/eval/<world>/), comparisons, summary_table
    figures   Figure 18-style bars and trajectories

Runs are read and files written only through fedjax_nav.rundir.
"""

from fedjax_nav.evaluation.metrics import (
    SELECTED_NOTE,
    STRAIGHT_LINE_NOTE,
    best_agents,
    episodes_frame,
    summarize,
)
from fedjax_nav.evaluation.report import (
    EVAL_FILES,
    comparison_frame,
    comparison_markdown,
    read_evaluation,
    replacement,
    summary_table,
    write_comparison,
    write_run,
)
from fedjax_nav.evaluation.rollout import (
    ACTION_NOISE,
    ATTEMPTS,
    RANGE_NOISE,
    EvalError,
    EvalResult,
    MemoryPolicy,
    evaluate_policy,
)
from fedjax_nav.evaluation.runs import (
    RunAgents,
    RunEvaluation,
    actor_policy,
    evaluate_run,
    evaluate_runs,
    evaluated,
    load_run,
)

__all__ = [
    "ACTION_NOISE",
    "ATTEMPTS",
    "EVAL_FILES",
    "RANGE_NOISE",
    "SELECTED_NOTE",
    "STRAIGHT_LINE_NOTE",
    "EvalError",
    "EvalResult",
    "MemoryPolicy",
    "RunAgents",
    "RunEvaluation",
    "actor_policy",
    "best_agents",
    "comparison_frame",
    "comparison_markdown",
    "episodes_frame",
    "evaluate_policy",
    "evaluate_run",
    "evaluate_runs",
    "evaluated",
    "load_run",
    "read_evaluation",
    "replacement",
    "summarize",
    "summary_table",
    "write_comparison",
    "write_run",
]
