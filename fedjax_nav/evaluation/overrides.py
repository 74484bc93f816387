"""A run's agents evaluated under changed env values (`fedjax-nav evaluate --set`,
`scripts/suite_with.py --set`): the run's config with overrides, its trained actors unchanged.

    run = run_with(run_dir, ["env.plan_keep_right=0.45"])   RunAgents, its cfg overridden

Only what leaves the networks as they were built may change: the traced values
(`config.traced_fields`, read by the compiled program as data) and PROGRAM_ONLY (static settings
that change the program, not the observation); anything else is one EvalError naming the key.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from fedjax_nav.evaluation.limits import EvalError
from fedjax_nav.evaluation.run_data import RunAgents

# static settings a run's agents may be evaluated under: they change the compiled program, not the
# observation the networks were built for (the plan's grid: a finer one for rooms larger than trained in)
PROGRAM_ONLY = ("env.plan_cells",)


def check_keys(sets: list[str]) -> None:
    """An EvalError naming the first override a run's agents cannot be evaluated under."""
    from fedjax_nav.config import traced_fields
    from fedjax_nav.config.io import overridden_keys

    fixed = sorted(k for k in overridden_keys(sets) if k not in (*traced_fields(), *PROGRAM_ONLY))
    if fixed:  # a run's networks were built for its static settings
        also = ", ".join(PROGRAM_ONLY)
        raise EvalError(f"--set {fixed[0]}: not a traced value; a run's agents take traced values only (and {also})")


def run_with(run_dir: str | Path, sets: list[str]) -> RunAgents:
    """The run's agents (`runs.load_run`) with its config.yaml read under `sets` (KEY=VALUE, as
    `fedjax-nav train --set`); a bad key or value is an EvalError naming it."""
    from fedjax_nav import rundir
    from fedjax_nav.config import ConfigError, load_config
    from fedjax_nav.evaluation.runs import load_run

    check_keys(sets)
    run = load_run(run_dir)
    try:
        cfg = load_config(Path(run.run_dir) / rundir.CONFIG, sets)
    except ConfigError as e:
        raise EvalError(str(e)) from None
    return dataclasses.replace(run, cfg=cfg)
