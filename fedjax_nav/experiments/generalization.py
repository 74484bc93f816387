"""The generalization experiment's report (docs/generalization.md): evaluate the finished points
of a generalization sweep on the thesis arena (with trajectory figures) and on a held-out suite
(kept in each point's eval/ folders and reused), then write the tables, the goal check and the
figures.

    report(load_sweep("configs/sweeps/generalization.yaml"), "runs/sweeps/generalization")

Report folder (the sweep's --out), named after the sweep (`generalization` here): <name>.csv,
<name>_per_seed.csv, <name>_goal.csv, <name>_iqm.csv (IQM and probability of improvement,
`analysis.generalization.robust`; needs the `stats` extra), <name>.md, <name>_<episodes>.png per training budget,
<sweep>_probe.csv / .png (the held-out probe during training, named after the sweep whatever the
suite: one file for the curves of every report); so the
report of another sweep over the same points folder (generalization_levers) writes beside it.
Each point's suite evaluation gets its worst rooms drawn (RUN/eval/<suite>/worst_rooms.png,
`evaluation.worst_rooms`), copied with the figures as <name>_worst_rooms_<point label>.png.
The tables copied to results/ (the probe curves with them) keep the rows of the sweep's points the
folder lacks (`with_kept_rows`), and the bar and probe figures are then drawn from those merged
tables: a report from a folder holding only the newest points neither drops the older points'
rows nor redraws their figures without them.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Callable

from fedjax_nav import rundir
from fedjax_nav.analysis import generalization as gz
from fedjax_nav.analysis import generalization_figures as gf
from fedjax_nav.analysis.sweeps import finished
from fedjax_nav.config.sweepfile import Sweep
from fedjax_nav.experiments.thesis_report import md_table


def _slug(text: str) -> str:
    """`text` as part of a file name: runs of other characters than letters, digits, '.' and '-'
    become one '_', none at either end."""
    return re.sub(r"[^A-Za-z0-9.-]+", "_", text).strip("_")


def report_name(sweep_name: str, suite: str = "heldout") -> str:
    """The stem of a report's files: the sweep's name on the default `heldout` suite, the sweep's
    name and the suite's folder on any other (generalization_1e8_dense-heldout), so that a report on
    a second suite writes beside the first instead of over it."""
    from fedjax_nav.evaluation.suite_files import suite_folder

    if suite == "heldout":
        return sweep_name
    return f"{sweep_name}_{_slug(suite_folder(suite))}"


def tables(name: str) -> tuple[str, str, str, str]:
    """The report's table files for the report stem `name` (`report_name`)."""
    return f"{name}.csv", f"{name}_per_seed.csv", f"{name}_goal.csv", f"{name}_per_net.csv"


ROW_KEYS = (("point",), ("point", "seed"), ("point",), ("point", "net"))  # a row's identity, per table of `tables`
PROBE_KEYS = ("point", "episode")  # a row's identity in <sweep>_probe.csv


def with_kept_rows(new, old_path: Path, keys: tuple, sweep: Sweep, echo: Callable[[str], None] = print):
    """`new` (a report table of the points in this folder) with the rows of the copy at `old_path`
    whose points `new` lacks but the sweep still holds: a table copied to results/ keeps the points
    trained on another machine, whose run folders are gone, instead of losing them. Rows in the
    sweep's point order; returns (table, rows kept, rows dropped: points no longer in the sweep)."""
    import pandas as pd

    order = {p.id: i for i, p in enumerate(sweep.points)}
    if not Path(old_path).exists() or Path(old_path).stat().st_size <= 1:
        return new, 0, 0
    old = pd.read_csv(old_path)
    if not set(keys) <= set(old.columns):  # a copy written before the column: nothing to keep by
        if not len(new):  # and nothing to replace it with
            return old, 0, 0
        echo(
            f"{old_path}: replaced; its rows cannot be matched to points (written before its {', '.join(keys)} column)"
        )
        return new, 0, 0
    if not len(new):  # a folder with no finished point: the copy is what results/ holds
        new = old.iloc[:0]
    gone = old[~old.point.isin(set(new.point))]
    kept = gone[gone.point.isin(order)]
    out = pd.concat([new, kept], ignore_index=True) if len(kept) else new
    out = out.iloc[out.point.map(order).fillna(len(order)).argsort(kind="stable")].reset_index(drop=True)
    return out, len(kept), len(gone) - len(kept)


def evaluate_point(folder: Path, suite: str, suite_attempts: int, arena_attempts: int, echo: Callable) -> None:
    """The arena (protocol of docs/evaluation.md, figures drawn) and the suite, unless already
    evaluated with the same attempts; the suite's worst rooms drawn (`evaluation.worst_rooms`)
    after a new evaluation, or where their figure is missing (one line instead where it cannot be)."""
    from fedjax_nav.evaluation import EvalError, evaluated
    from fedjax_nav.evaluation.suite import evaluated_suite
    from fedjax_nav.evaluation.worst_rooms import worst_rooms

    if evaluated(folder, gz.ARENA, arena_attempts, figures=True)[1]:
        echo(f"evaluated {folder.name} on the arena")
    fresh = evaluated_suite(folder, suite, suite_attempts)[1]
    if fresh:
        echo(f"evaluated {folder.name} on suite {suite}")
    if fresh or not worst_figure(folder, suite).exists():
        try:
            echo(f"drew {folder.name}'s worst rooms of suite {suite}: {worst_rooms(folder, suite)}")
        except EvalError as e:  # an evaluation kept from before the figure (other columns): the tables still stand
            echo(f"no worst rooms drawn for {folder.name}: {e}")


def worst_figure(folder: Path, suite: str) -> Path:
    """The worst rooms' figure of a point's evaluation on `suite` (RUN/eval/<suite>/worst_rooms.png)."""
    from fedjax_nav.evaluation.suite_files import suite_folder

    return rundir.eval_dir(folder, suite_folder(suite)) / rundir.SUITE_WORST_ROOMS_FIGURE


def families_of(t) -> list[str]:
    """The held-out families present in the table (its per-family columns), 'all' excluded."""
    return [c[: -len("_ci_seeds_low")] for c in t.columns if c.endswith("_ci_seeds_low") and not c.startswith("all_")]


def _robust(ps, fams: list[str], echo: Callable[[str], None]):
    """`gz.robust` of the per-seed table, or None with one line when rliable is not installed."""
    try:
        return gz.robust(ps, fams) if len(ps) else None
    except ImportError:
        echo('no IQM / probability of improvement: rliable is not installed (pip install "fedjax_nav[stats]")')
        return None


def _markdown(sweep: Sweep, name: str, t, g, fams: list[str], rb) -> list[str]:
    """The report's markdown lines: the goal check `g`, every point of `t`, and the IQM table `rb`
    (None: rliable not installed)."""
    md = [f"# {name} (docs/generalization.md)", "", "## The goal, per procedurally trained point", ""]
    md += [f"Goal: {gz.goal_text(sweep.goal)} (the sweep file's `goal:`).", ""]
    md += [md_table(g) if len(g) else "(none yet)", "", "## Every point", ""]
    md += ["Success: training (last 25 episodes) and arena as mean +- std over seeds; held-out families as"]
    md += ["mean [95% bootstrap interval over training seeds].", ""]
    md += [md_table(gz.readable(t, fams)) if len(t) else "(no finished point)", ""]
    if rb is not None:
        md += ["## IQM and probability of improvement", "", gz.ROBUST_NOTE, ""]
        md += [md_table(gz.robust_readable(rb)) if len(rb) else "(no point with every family evaluated)", ""]
    return md


def report(
    sweep: Sweep,
    out: str | Path,
    suite: str = "heldout",
    suite_attempts: int = 1,
    arena_attempts: int = 4,
    evaluate: bool = True,
    copy_tables: str | Path | None = None,
    copy_figures: str | Path | None = None,
    echo: Callable[[str], None] = print,
) -> dict:
    """Evaluate (unless `evaluate` is False), then write the report into `out`; copy the small
    tables and the figures (with the FLDDPG points' arena trajectories and every point's worst
    rooms of the suite) where asked."""
    out = Path(out)
    if not out.is_dir():
        raise rundir.RunDirError(f"{out}: no such sweep folder (fedjax-nav sweep {sweep.name} --out {out} trains it)")
    points = rundir.points_dir(out)
    if evaluate:
        for p, _ in finished(sweep, points):
            if (points / p.id / rundir.PARAMS).exists():
                evaluate_point(points / p.id, suite, suite_attempts, arena_attempts, echo)
    t, ps, nets = gz.table(sweep, points, suite), gz.per_seed(sweep, points, suite), gz.per_net(sweep, points, suite)
    fams = families_of(t)
    g = gz.goal(t, fams, sweep.goal) if len(t) else t
    name = report_name(sweep.name, suite)
    files = tables(name)
    for fname, df in zip(files, (t, ps, g, nets)):
        rundir.atomic_write(out / fname, lambda p, df=df: df.to_csv(p, index=False))
    rb = _robust(ps, fams, echo)
    if rb is not None:
        rundir.atomic_write(out / f"{name}_iqm.csv", lambda p: rb.to_csv(p, index=False))
    md = _markdown(sweep, name, t, g, fams, rb)
    rundir.atomic_write(out / f"{name}.md", lambda p: Path(p).write_text("\n".join(md)))
    curves, probe = gz.probe_curves(sweep, points), f"{sweep.name}_probe"  # the probe ran in training: no suite
    if len(curves):
        rundir.atomic_write(out / f"{probe}.csv", lambda p: curves.to_csv(p, index=False))
    copied = []
    if copy_tables is not None:
        res = Path(copy_tables)
        res.mkdir(parents=True, exist_ok=True)

        def write(df, fname: str):
            if len(df) or (res / fname).exists():  # e.g. no per-network rows: no empty file in results/
                copied.append(rundir.atomic_write(res / fname, lambda p: df.to_csv(p, index=False)))
            return df

        def keep(df, fname: str, keys: tuple):
            merged, kept, dropped = with_kept_rows(df, res / fname, keys, sweep, echo)
            if kept or dropped:
                echo(
                    f"{res / fname}: kept {kept} row(s) of points not in {points} (trained elsewhere)"
                    + (f"; dropped {dropped} of points no longer in the sweep" if dropped else "")
                )
            return write(merged, fname)

        t_all = keep(t, files[0], ROW_KEYS[0])  # the goal check and figures of every kept point derive from it
        ps_all = keep(ps, files[1], ROW_KEYS[1])
        rb_all = _robust(ps_all, families_of(t_all), lambda line: None) if rb is not None else None
        if rb_all is not None:  # from the per-seed rows of every kept point, as the goal check below
            write(rb_all, f"{name}_iqm.csv")
        write(gz.goal(t_all, families_of(t_all), sweep.goal) if len(t_all) else g, files[2])
        keep(nets, files[3], ROW_KEYS[3])
        curves = keep(curves, f"{probe}.csv", PROBE_KEYS)
    else:
        t_all = t
    fams_all = families_of(t_all)
    episodes = sorted(set(t_all.episodes)) if len(t_all) else []
    figs = [gf.figure(t_all, fams_all, out / f"{name}_{e}.png", sweep.goal, e) for e in episodes]
    if len(curves):
        figs.append(gf.probe_figure(curves, out / f"{probe}.png"))
    if copy_figures is not None:
        copied += rundir.copy_into(copy_figures, _figures_to_copy(figs, t, points, suite, name))
    echo(f"{name} report: {len(t)} point(s) in {out}/{name}.md; {len(figs)} figure(s)")
    return {"points": len(t), "figures": figs, "copied": copied}


def _figures_to_copy(figs: list[Path], t, points: Path, suite: str, name: str) -> dict[str, Path]:
    """The report's figures `figs`, the FLDDPG points' arena trajectories and every point's worst
    rooms of `suite`, by the name each gets in the figures folder."""
    figures = {f.name: f for f in figs}
    for _, r in t[t.method == "flddpg"].iterrows():  # failures drawn: every attempt in the arena
        src = rundir.eval_dir(points / r.point, gz.ARENA) / rundir.EVAL_TRAJECTORIES_FIGURE
        if src.exists():
            key = f"{name}_arena_flddpg_{r.rooms.split(' ')[0]}_{r.episodes}"
            figures[key + (f"_{r.point}" if key + ".png" in figures else "") + ".png"] = src
    for _, r in t.iterrows():  # the worst rooms of every point's suite evaluation
        src = worst_figure(points / r.point, suite)
        if src.exists():
            figures[f"{name}_worst_rooms_{_slug(r.label)}.png"] = src
    return figures
