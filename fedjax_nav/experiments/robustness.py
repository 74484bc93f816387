"""The robustness experiment's report (docs/robustness.md): evaluate the finished points of a
robustness sweep on the thesis arena (kept in each point's eval/eval/ and reused), then write
the table, the per-seed table, the acceptance verdict and the figures.

    report(load_sweep("configs/sweeps/robustness.yaml"), "runs/sweeps/robustness")

Report folder (the sweep's --out): robustness.csv, robustness_per_seed.csv, robustness_verdict.csv,
robustness.md, robustness_learning.png, robustness_eval.png. Points not trained yet are left out
(the tables say how many seeds each point has).
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from fedjax_nav import rundir
from fedjax_nav.analysis import robustness as rb
from fedjax_nav.analysis.sweeps import finished
from fedjax_nav.config.sweepfile import Sweep
from fedjax_nav.experiments.thesis_report import md_table

TABLES = ("robustness.csv", "robustness_per_seed.csv", "robustness_verdict.csv")
FIGURES = ("robustness_learning.png", "robustness_eval.png")


def evaluate_arena(sweep: Sweep, points: Path, attempts: int, echo: Callable) -> dict[str, str]:
    """Evaluate every finished point on the thesis arena (kept in its eval/eval/ and reused when
    the same attempts were asked for). A point that cannot be evaluated (a diverged run's NaN
    actors) is reported, not fatal: returns {point id: why}."""
    from fedjax_nav.evaluation import EvalError, evaluated

    notes = {}
    for p, _ in finished(sweep, points):
        d = points / p.id
        if not (d / rundir.PARAMS).exists():
            continue
        try:
            if evaluated(d, rb.ARENA, attempts)[1]:
                echo(f"evaluated {rb.setting(p.cfg)} ({p.id})")
        except EvalError as e:
            notes[p.id] = str(e).split(": ", 1)[-1]
            echo(f"not evaluated {rb.setting(p.cfg)} ({p.id}): {notes[p.id]}")
    return notes


def markdown(t, v) -> str:
    cols = ["setting", "seeds", "success_honest", "success_honest_std", "success_all", "eval_honest"]
    cols += ["eval_honest_std", "eval_all", "bytes_sent_per_seed", "skipped_rounds", "diverged_seeds", "eval_note"]
    lines = ["# Robustness (docs/robustness.md)", "", "## Acceptance checks on what has been run", ""]
    lines += [md_table(v) if len(v) else "(nothing to check yet)", ""]
    for col, what in (("success_honest", "learning success of honest robots"), ("eval_honest", "arena, honest agents")):
        for b in sorted(int(x) for x in set(t.byzantine) if x > 0) if len(t) else []:
            m = rb.matrix(t, col, b)
            lines += [f"## {what}, {b} of 5 Byzantine (mean ± std over seeds)", ""]
            lines += [md_table(m.reset_index(names="aggregator")), ""]
    lines += ["## Every point", ""]
    lines += [md_table(t[cols].round(3)) if len(t) else "(no finished point)", ""]
    return "\n".join(lines)


def report(
    sweep: Sweep,
    out: str | Path,
    attempts: int = 4,
    evaluate: bool = True,
    copy_tables: str | Path | None = None,
    copy_figures: str | Path | None = None,
    echo: Callable[[str], None] = print,
) -> dict:
    """Evaluate (unless `evaluate` is False), then write the report into `out`; copy the small
    tables and the figures where asked (results/, docs/img/robustness/). Returns the paths."""
    out = Path(out)
    points = rundir.points_dir(out)
    notes = evaluate_arena(sweep, points, attempts, echo) if evaluate else {}
    t, ps = rb.table(sweep, points), rb.per_seed(sweep, points)
    if len(t):
        t["eval_note"] = [notes.get(p, "") for p in t.point]
    v = rb.verdict(t) if len(t) else t
    for name, df in zip(TABLES, (t, ps, v)):
        rundir.atomic_write(out / name, lambda p, df=df: df.to_csv(p, index=False))
    rundir.atomic_write(out / "robustness.md", lambda p: Path(p).write_text(markdown(t, v)))
    figs = []
    if len(t):
        learn = "learning success of honest robots, last 25 episodes"
        figs.append(rb.figure(t, out / FIGURES[0], "success_honest", learn))
        if t.eval_honest.notna().any():
            arena = "evaluation success of honest agents, thesis arena"
            figs.append(rb.figure(t, out / FIGURES[1], "eval_honest", arena))
    copied = []
    if copy_tables is not None:
        copied += rundir.copy_into(copy_tables, {n: out / n for n in TABLES})
    if copy_figures is not None:
        copied += rundir.copy_into(copy_figures, {f.name: f for f in figs})
    echo(f"robustness report: {len(t)} point(s) in {out}/robustness.md; {len(figs)} figure(s)")
    return {"points": len(t), "tables": [out / n for n in TABLES], "figures": figs, "copied": copied}
