"""A sweep's batches, frozen when they are first planned: `SWEEP/batches/plan.json`.

Why frozen (docs/reliability.md, "Resume", the sweep paragraph). A point's numbers depend on its
batch, not only on its config: the group's program is compiled for the batch's rows (padded to
the group's largest batch), its buffers are allocated at the group's largest capacity, and a field
equal in every row of the group stays a scalar (spec.py). A resumed sweep that planned its
unfinished points afresh changed all three: a point trained again in another layout ended up to
6e-6 away from the uninterrupted sweep's, its results.csv rows too, and a batch checkpoint was
restored into a smaller buffer allocation (a CheckpointError). Making the numbers
independent of the layout would cost every sweep (every field per row, buffers per point) and
would still leave XLA free to order a sum by the shapes it compiles for; freezing the layout costs
one small file. So the whole plan is recorded before its first batch trains, and a resumed sweep
re-forms the same batches from it, each in its own group's program: a point is trained again only
in the batch it started in, from that batch's latest checkpoint, and one already written is not
written again. A batch leaves the plan, with its checkpoints, once all its points are written.

A recorded batch is re-formed when it holds an unfinished point this run asks for, and writes
every unfinished point it holds (asked for or not: they cost nothing more); its group is
planned again, with one line saying so, only when it cannot be run as recorded (another device
count, or a memory budget it no longer fits): its points may then differ in the last bits.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

from fedjax_nav import rundir
from fedjax_nav.config import Config, ConfigError, from_dict, to_dict
from fedjax_nav.config.memory import size
from fedjax_nav.config.sweepfile import SweepError, point_id
from fedjax_nav.training.sweep.plan import Group, batch_id, plan, point_bytes, row_cap
from fedjax_nav.training.sweep.spec import Job, fold_prefixes, group_key
from fedjax_nav.training.trainer import Trainer

FORMAT = 1  # plan.json's layout; another one is refused


def is_done(points_dir: Path, job: Job) -> bool:
    """Whether `points_dir/<id>/` holds the job's finished run (as many seeds or more)."""
    f = points_dir / job.id / rundir.SUMMARY
    if not f.exists():
        return False
    try:
        s = rundir.read_json(f)
    except rundir.RunDirError:  # unreadable (a foreign or damaged file): train the point again
        return False
    return s.get("seeds", 0) >= job.cfg.run.seeds and s.get("episodes_done") == job.cfg.run.episodes


def points_of(jobs: list[Job]) -> list[Job]:
    """Every point a batch's jobs write: each job and the shorter runs folded into it."""
    return [p for j in jobs for p in (j, *j.prefixes)]


# ----------------------------------------------------------------------------- plan.json


def _job_json(j: Job) -> dict:
    return {"id": j.id, "config": to_dict(j.cfg), "prefixes": [_job_json(p) for p in j.prefixes]}


def group_json(g: Group, devices: int) -> dict:
    """One planned group as plan.json holds it: everything its program and batches depend on."""
    return {
        "devices": devices,
        "rows": g.batch_rows,
        "batched": sorted(g.batched),
        "trainer": to_dict(g.trainer.cfg),
        "batches": [{"id": batch_id(b, g.batch_rows), "jobs": [_job_json(j) for j in b]} for b in g.batches],
    }


def _job(d: dict, src: str) -> Job:
    cfg = from_dict(d["config"], src)
    if point_id(cfg) != d["id"]:
        raise ValueError(f"point {d['id']}: its config hashes to {point_id(cfg)}")
    return Job(cfg, d["id"], tuple(_job(p, src) for p in d["prefixes"]))


@dataclass(frozen=True)
class Recorded:
    """A group of plan.json, read: `raw` as the file holds it, its trainer's config, its batches' jobs."""

    raw: dict
    trainer: Config
    batches: tuple  # (batch id, [Job]) per batch, in the plan's order


def read(folder: Path) -> list[Recorded]:
    """The recorded groups of the sweep folder (none without plan.json); a file that cannot be
    read as a plan (damaged, or another format) is one SweepError naming it."""
    f = rundir.batch_plan(folder)
    if not f.exists():
        return []
    try:
        data = rundir.read_json(f)
        if data.get("format") != FORMAT:
            raise ValueError(f"format {data.get('format')!r}, not {FORMAT}")
        out = []
        for g in data["groups"]:
            int(g["devices"]), int(g["rows"]), frozenset(g["batched"])  # read by plan_batches: checked here
            batches = tuple((str(b["id"]), [_job(d, str(f)) for d in b["jobs"]]) for b in g["batches"])
            out.append(Recorded(g, from_dict(g["trainer"], str(f)), batches))
    except (ConfigError, rundir.RunDirError, KeyError, TypeError, ValueError, AttributeError) as e:
        raise SweepError(
            f"{f}: cannot be read as the sweep's batch plan ({e}); remove it to plan the unfinished points "
            "again (they may then differ in the last bits from an uninterrupted sweep)"
        ) from None
    return out


def write(folder: Path, groups: list[dict]) -> None:
    """plan.json holding `groups` (atomic); none: the file goes, and batches/ if nothing else is there."""
    f = rundir.batch_plan(folder)
    if groups:
        rundir.make_folder(f.parent, "sweep's batches folder")
        rundir.write_json(f, {"format": FORMAT, "groups": groups})
        return
    rundir.unlink_quietly(f)
    if f.parent.exists() and not any(f.parent.iterdir()):
        f.parent.rmdir()


def finish(folder: Path, groups: list[dict], bid: str) -> list[dict]:
    """Batch `bid` has written all its points: its checkpoints go, then its entry in plan.json (a
    kill in between leaves an entry whose points are all done, dropped at the next start)."""
    shutil.rmtree(rundir.batches_dir(folder) / bid, ignore_errors=True)
    left = [{**g, "batches": [b for b in g["batches"] if b["id"] != bid]} for g in groups]
    left = [g for g in left if g["batches"]]
    write(folder, left)
    return left


# ----------------------------------------------------------------------------- planning


def plan_batches(
    todo: list[Job], folder: Path, budget: int, devices: int, echo, desc: str
) -> tuple[list[Group], list[dict]]:
    """The groups that train `todo` (the unfinished points asked for, shorter runs not yet folded):
    the recorded batches holding one of them, as recorded, then the rest planned afresh. plan.json
    is written (recorded batches whose points are all done leave it, with their checkpoints) before
    anything trains; checkpoint folders it does not name are removed. Returns (groups, plan.json's groups)."""
    points_dir, src = rundir.points_dir(folder), str(rundir.batch_plan(folder))
    asked = {j.id: j.cfg.run.seeds for j in todo}

    def wanted(p: Job) -> bool:
        return p.id in asked and p.cfg.run.seeds >= asked[p.id]

    record, frozen, covered, moved = [], [], set(), 0
    for g in read(folder):
        left, batches = [], []
        for bid, jobs in g.batches:
            unfinished = [p for p in points_of(jobs) if not is_done(points_dir, p)]
            if not unfinished:  # every point written: its checkpoints go (a kill came before `finish`)
                shutil.rmtree(rundir.batches_dir(folder) / bid, ignore_errors=True)
                continue
            left.append(bid)
            if any(wanted(p) for p in unfinished):
                batches.append(jobs)
        if left:
            record.append({**g.raw, "batches": [b for b in g.raw["batches"] if b["id"] in left]})
        if not batches:
            continue
        trainer = Trainer(g.trainer)
        cap = row_cap(*point_bytes(trainer), budget)  # as `plan` packs: the rows before padding
        if g.raw["devices"] != devices or any(sum(j.cfg.run.seeds for j in b) > cap for b in batches):
            moved += len(batches)
            continue
        jobs = [j for b in batches for j in b]
        frozen.append(Group(group_key(g.trainer), jobs, trainer, batches, g.raw["rows"], frozenset(g.raw["batched"])))
        covered |= {p.id for p in points_of(jobs) if wanted(p)}
    if moved:
        echo(
            f"{desc}: {moved} unfinished batch(es) of {src} cannot run as planned ({devices} device(s) now, "
            f"memory budget {size(budget)}): their points are planned again and may differ in the last bits "
            "from an uninterrupted sweep"
        )
    rest = fold_prefixes([j for j in todo if j.id not in covered])
    fresh = plan(rest, budget, devices) if rest else []
    record += [group_json(g, devices) for g in fresh]
    _remove_strays(folder, record, echo, desc)
    write(folder, record)
    return frozen + fresh, record


def _remove_strays(folder: Path, record: list[dict], echo, desc: str) -> None:
    """Checkpoint folders of batches plan.json does not name: finished, or left by a version that
    kept no plan (nothing can resume them in their layout)."""
    named = {b["id"] for g in record for b in g["batches"]}
    bdir = rundir.batches_dir(folder)
    strays = [d for d in bdir.iterdir() if d.is_dir() and d.name not in named] if bdir.is_dir() else []
    for d in strays:
        shutil.rmtree(d, ignore_errors=True)
    if strays:
        echo(f"{desc}: removed {len(strays)} checkpoint folder(s) of batches no plan names ({bdir})")
