"""The evaluation protocol (SCENARIO.md section 5) and its metrics; figures in `.figures`."""
from fedjax_nav.evaluation.protocol import (
    ACTION_NOISE,
    ATTEMPTS,
    RANGE_NOISE,
    EvalError,
    EvalResult,
    RunAgents,
    RunEvaluation,
    actor_policy,
    best_agents,
    comparison_frame,
    comparison_markdown,
    episodes_frame,
    evaluate_policy,
    evaluate_run,
    load_run,
    summarize,
    summary_table,
    write_run,
)

__all__ = [
    "ACTION_NOISE", "ATTEMPTS", "RANGE_NOISE", "EvalError", "EvalResult", "RunAgents", "RunEvaluation",
    "actor_policy", "best_agents", "comparison_frame", "comparison_markdown", "episodes_frame",
    "evaluate_policy", "evaluate_run", "load_run", "summarize", "summary_table", "write_run",
]
