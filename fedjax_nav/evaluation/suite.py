"""Evaluation on a held-out suite of rooms (`fedjax-nav evaluate RUN --suite NAME`, or
`--suite DIR` / `--suite 'GLOB'` for the user's own world files; docs/generalization.md).

Every agent of the run drives in every room of the suite (a named one, `fedjax_nav.worlds.suites`:
generated rooms from the test stream of room seeds, never used by training; or every world file of
a folder or glob, padded to one shape, its file name stem as its family) from start 0 to every goal
of the room, `attempts` times, with the protocol of `rollout.py` (greedy actor, noisy ranges and
actions, the run's env settings, time-out T); all rooms run in one jitted, vmapped program.

Results per family: the success rate with a 95 % bootstrap confidence interval
(`scipy.stats.bootstrap`, percentile method, 10,000 resamples, fixed random state) over the room
seeds (the sample unit of the held-out set: each room's success averaged over its agents, goals
and attempts), and the per-training-seed success with a bootstrap interval over the training seeds
when there are at least two. The tail (docs/generalization.md, "Tail metrics"): the mean success
of the worst 10 % of rooms (rooms ranked by their success, with a bootstrap interval over rooms),
the collision and time-out rates, and the median path-length ratio of the successful episodes
(driven path / the shortest safe path into the goal disk, `evaluation.paths`, computed on the host
while the rollout runs). Written to RUN/eval/<suite>/ (a file suite: RUN/eval/<its folder's name>/)
through fedjax_nav.rundir: `suite.json` (everything), `suite_families.csv` (one row per family, and
"all"), `suite_episodes.csv` (one row per room x agent x goal x attempt).

The rooms and the folder's name: `evaluation.suite_files`. The protocol on them, room by room
(`SuiteProtocol`: the keys of room r are the same whatever rooms run beside it), is also what
`evaluation.worst_rooms` replays to draw the worst rooms of a kept evaluation.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from fedjax_nav import rundir
from fedjax_nav.config import envs
from fedjax_nav.env.nav import make_params
from fedjax_nav.evaluation import paths
from fedjax_nav.evaluation.limits import EvalError, check_counts, check_eval_memory
from fedjax_nav.evaluation.rollout import (
    ACTION_NOISE,
    ATTEMPTS,
    CHUNK,
    RANGE_NOISE,
    episode_state,
    eval_program,
    observed_program,
)
from fedjax_nav.evaluation.run_data import run_name
from fedjax_nav.evaluation.runs import RunAgents, load_run, run_policy
from fedjax_nav.evaluation.suite_files import is_file_suite, suite_folder, suite_world, world_files
from fedjax_nav.evaluation.suite_stats import TAIL, family_row
from fedjax_nav.worlds import WorldError
from fedjax_nav.worlds.suites import suite_names

SUITE_JSON = "suite.json"
FAMILIES_CSV = "suite_families.csv"
EPISODES_CSV = "suite_episodes.csv"


def _check_suite(suite: str) -> list[str]:
    """The suites of a name, or the files of a file suite; an EvalError (one line) for neither."""
    if is_file_suite(suite):
        return [str(f) for f in world_files(suite)]
    try:
        return list(suite_names(suite))
    except WorldError as e:
        raise EvalError(f"{e}; or a folder or glob of world files") from None


def _timed(fn, *args):
    t = time.time()
    return fn(*args), time.time() - t


@dataclass
class SuiteProtocol:
    """The protocol of a run on the stacked rooms of a suite, room by room: what `evaluate_suite`
    drives and `worst_rooms` replays. Room r's episodes draw their keys from `keys()[r]` whatever
    rooms run beside it, so a replay of some rooms repeats their episodes."""

    run: RunAgents
    values: dict  # envs.eval_values: the env's traced values, the protocol's noise included
    settings: dict  # NavEnv's static settings; episode_length is the time-out T
    params: object  # EnvParams [R, ...]
    seed: int  # the evaluation seed
    T: int
    K: int  # attempts per agent

    @property
    def shape(self) -> tuple[int, int, int, int]:
        """(rooms R, agents A, goal rows G, attempts K)."""
        R, G = self.params.world.goals.shape[:2]
        return int(R), self.run.num_agents, int(G), self.K

    def keys(self) -> jax.Array:
        """The episodes' keys [R, A, G * K] (an agent's episode e: attempt e // G, goal e % G);
        made only when the rollout runs, after `check`."""
        R, A, G, K = self.shape
        return jax.random.split(jax.random.key(self.seed), R * A * G * K).reshape(R, A, G * K)

    def check(self, rooms: int, k: int, asked: int, budget: int | None) -> None:
        """`limits.check_eval_memory` of `rooms` x agents x goals x `k` attempts (`asked`: --attempts)."""
        room = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape[1:], x.dtype), self.params)  # one room's shapes
        state = episode_state(self.settings, room, run_policy(self.run))
        shape = (rooms, self.run.num_agents, self.shape[2], k)
        check_eval_memory(self.settings, state, shape, min(CHUNK, self.T), asked, budget, str(self.run.run_dir))

    def rollout(self, rooms=None, k: int | None = None, observations: bool = False) -> dict:
        """The episodes of `rooms` (indices of the suite's rooms; None: all), their first `k`
        attempts (None: all K), in one jitted, vmapped program: success, collision, timeout, steps,
        path [rooms, A, G, k] and poses [rooms, A, G, k, T + 1, 3], numpy; with `observations` also
        obs [rooms, A, G, k, T + 1, obs], the observation at each pose (`rollout.observed_program`)."""
        G = self.shape[2]
        pick = (lambda x: x) if rooms is None else (lambda x: x[np.asarray(rooms)])
        params, keys = jax.tree.map(pick, self.params), pick(self.keys())[:, :, : G * (k or self.K)]
        make = observed_program if observations else eval_program
        program = _rooms_program(make(self.settings, run_policy(self.run), min(CHUNK, self.T)))
        return jax.device_get(program(self.run.actor_params, params, jnp.arange(G, dtype=jnp.int32), keys))


@functools.lru_cache(maxsize=16)
def _rooms_program(program):
    """The evaluation program vmapped over rooms, jitted once per program (a replay reuses it)."""
    return jax.jit(jax.vmap(program, (None, 0, None, 0)))


def under_robot(run: RunAgents, robot) -> RunAgents:
    """`run` evaluated under the robot model `robot` (a `RobotConfig`, or its fields as kept in
    suite.json's "robot"; None: the run's own, docs/robot.md)."""
    if robot is None:
        return run
    if isinstance(robot, dict):
        from fedjax_nav.config import RobotConfig

        robot = RobotConfig(**robot)
    return dataclasses.replace(run, cfg=dataclasses.replace(run.cfg, robot=robot))


def robot_folder(run_dir, suite: str, robot) -> Path:
    """Where a suite evaluation is kept: RUN/eval/<suite folder>/, or <suite folder>-robot-<model>/
    under a robot model other than the run's own (as `evaluate --world --robot`)."""
    own = rundir.read_config(run_dir).robot  # the config only: the parameters are not needed here
    name = suite_folder(suite) if robot is None or robot == own else f"{suite_folder(suite)}-robot-{robot.model}"
    return rundir.eval_dir(run_dir, name)


def suite_protocol(run: RunAgents, world, attempts: int, range_noise, action_noise, seed, max_steps) -> SuiteProtocol:
    """The protocol of `run` on the stacked `world` [R, ...]: the run's env values with the noise
    (`envs.eval_values`: the run's robot model, as in training), T (`max_steps` or the run's), K
    (`attempts` x robots / networks) and evaluation seed `seed`. Nothing of the episodes' size is
    allocated (`check` first)."""
    K, T = int(attempts) * run.num_robots // run.n_nets, int(max_steps or run.cfg.env.episode_length)
    values = envs.eval_values(run.cfg, range_noise, action_noise)
    settings = envs.env_settings(run.cfg, "eval", noise=True, episode_length=T)
    return SuiteProtocol(run, values, settings, make_params(world, **values), int(seed), T, K)


def evaluate_suite(
    run_dir,
    suite: str = "heldout",
    attempts: int = ATTEMPTS,
    range_noise: float = RANGE_NOISE,
    action_noise: float = ACTION_NOISE,
    seed: int = 0,
    max_steps: int | None = None,
    memory_budget: int | None = None,
    robot=None,
) -> dict:
    """The protocol of a run (under the robot model `robot`: `under_robot`) on every room of `suite`
    (a suite or group name, or a folder / glob of world files: `is_file_suite`); returns
    {"summary", "families", "episodes"}. `run_dir`: a run's folder, or its `RunAgents` (a scripted
    baseline's: `evaluation.baselines`).
    An evaluation whose estimate (`limits.eval_memory`: rooms x agents x goals x attempts) exceeds
    `memory_budget` bytes (default: the memory available now) is refused before it is allocated.
    The shortest safe paths (`paths.shortest_paths`) are computed on the host in a thread while the
    rollout runs."""
    check_counts(attempts, max_steps)
    members = _check_suite(suite)
    run = under_robot(load_run(run_dir), robot)
    cfg, e = run.cfg, run.cfg.env
    world, families, room_seeds = suite_world(suite)
    R, G = world.goals.shape[:2]
    protocol = suite_protocol(run, world, attempts, range_noise, action_noise, seed, max_steps)
    A, K, T, values, settings = run.num_agents, protocol.K, protocol.T, protocol.values, protocol.settings
    range_noise = values["range_noise"]
    protocol.check(R, K, int(attempts), memory_budget)
    # the collision distance the env tests (a modelled robot's footprint replaces it when set)
    clearance = float(
        values["footprint"] if settings.get("robot") and values["footprint"] > 0 else values["collision_distance"]
    )
    with ThreadPoolExecutor(1) as pool:
        shortest = pool.submit(
            _timed, paths.shortest_paths, jax.device_get(world), clearance, float(values["goal_radius"])
        )
        t0 = time.time()
        out = protocol.rollout()  # [R, A, G, K]
        wall = time.time() - t0
        (sp, sp_s), waited = shortest.result(), time.time() - t0 - wall
    valid = np.arange(G)[None, :] < np.asarray(world.num_goals)[:, None]  # [R, G]
    ep = _suite_episodes(run, world, families, room_seeds, out, sp, valid, float(values["goal_radius"]))
    fams = suite_families(ep, families)
    summary = {
        "run_dir": str(run.run_dir),
        "method": cfg.method,
        "suite": suite,
        "suites": members,
        "rooms": int(R),
        "agents": int(A),
        "attempts_requested": int(attempts),  # as in eval.json; one-network methods drive K = attempts x robots
        "attempts_per_agent": int(K),
        "episodes": int(len(ep)),
        "max_steps": T,
        "eval_seed": int(seed),
        "seeds": sorted({int(s) for s in run.agent_seed}),
        "noise": {"range_noise": float(range_noise), "action_noise": float(action_noise)},
        "robot": dataclasses.asdict(cfg.robot),
        "training_rooms": e.rooms,
        "training_families": list(e.room_families) if e.rooms == "procedural" else [],
        "ci": "95% percentile bootstrap (scipy.stats.bootstrap, 10,000 resamples) of the mean success: "
        "ci_rooms over room seeds (each room's success averaged over agents, goals, attempts), "
        "ci_seeds over training seeds (each seed's agents averaged)",
        "tail": TAIL,
        "shortest_path": {
            "clearance": clearance,
            "goal_radius": float(values["goal_radius"]),
            "grid_m": paths.RES,
            "no_path": int(np.sum(valid & ~np.isfinite(sp))),  # (room, goal) pairs without a safe grid path
            "host_s": sp_s,  # seconds of the search, in a thread beside the rollout
            "waited_s": waited,  # what it added to the evaluation after the rollout ended
        },
        "families": fams.to_dict(orient="records"),
        "wall_s": wall,
    }
    return {"summary": summary, "families": fams, "episodes": ep}


def _suite_episodes(
    run: RunAgents, world, families, room_seeds, out: dict, sp, valid, goal_radius: float
) -> pd.DataFrame:
    """suite_episodes.csv: one row per episode of the rollout `out` [R, A, G, K] on a valid goal
    (`valid` [R, G]), with its room, agent, the shortest safe path `sp` [R, G] and the ratio to it."""
    R, A, G, K = out["success"].shape
    r, a, g, k = np.meshgrid(np.arange(R), np.arange(A), np.arange(G), np.arange(K), indexing="ij")
    keep = valid[r, g].ravel()
    success = out["success"].ravel().astype(int)
    path = out["path"].ravel().astype(np.float64)
    shortest_m = sp[r.ravel(), g.ravel()]
    starts, goals = np.asarray(world.starts)[:, 0, :2], np.asarray(world.goals)
    straight = np.linalg.norm(goals - starts[:, None], axis=-1)[r.ravel(), g.ravel()] - goal_radius
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where((success == 1) & (shortest_m > 0), path / shortest_m, np.nan)
    return pd.DataFrame(
        {
            "room": r.ravel(),
            "family": families[r.ravel()],
            "room_seed": room_seeds[r.ravel()],
            "seed": run.agent_seed[a.ravel()],
            "net": run.agent_net[a.ravel()],
            "byzantine": run.agent_byzantine[a.ravel()].astype(int),
            "goal": g.ravel(),
            "attempt": k.ravel(),
            "success": success,
            "collision": out["collision"].ravel().astype(int),
            "timeout": out["timeout"].ravel().astype(int),
            "steps": out["steps"].ravel(),
            "path_length": out["path"].ravel(),
            "shortest_path": shortest_m,
            "straight_line": straight,
            "path_ratio": ratio,
        }
    )[keep].reset_index(drop=True)


def suite_families(ep: pd.DataFrame, families) -> pd.DataFrame:
    """suite_families.csv: `family_row` of each family of the suite (in the suite's order), then of all."""
    return pd.DataFrame(
        [
            family_row(name, part)
            for name, part in [*((f, ep[ep.family == f]) for f in dict.fromkeys(families)), ("all", ep)]
        ]
    )


def write_suite(result: dict, out: str | Path) -> list[Path]:
    """suite_episodes.csv, suite_families.csv, then suite.json (the marker of a complete one)."""
    from fedjax_nav.evaluation.report import json_safe

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / EPISODES_CSV, out / FAMILIES_CSV, out / SUITE_JSON]
    rundir.atomic_write(paths[0], lambda p: result["episodes"].to_csv(p, index=False))
    rundir.atomic_write(paths[1], lambda p: result["families"].to_csv(p, index=False))
    rundir.write_json(paths[2], json_safe(result["summary"]))
    return paths


def kept_suite(run_dir: str | Path, suite: str, attempts: int = ATTEMPTS) -> dict | None:
    """RUN/eval/<suite>/suite.json if it was evaluated with `attempts` asked (files written before
    `attempts_requested` was kept: their attempts per agent), else None."""
    f = rundir.eval_dir(run_dir, suite_folder(suite)) / SUITE_JSON
    if not f.exists():
        return None
    s = json.loads(f.read_text())
    return s if s.get("attempts_requested", s.get("attempts_per_agent")) == attempts else None


def evaluated_suite(run_dir: str | Path, suite: str, attempts: int = ATTEMPTS) -> tuple[dict, bool]:
    """The run's evaluation on `suite`, evaluated first unless `kept_suite` holds it (the suite's
    counterpart of `evaluation.evaluated`). Returns (suite.json's dict, whether it was evaluated now)."""
    kept = kept_suite(run_dir, suite, attempts)
    if kept is not None:
        return kept, False
    write_suite(evaluate_suite(run_dir, suite, attempts=attempts), rundir.eval_dir(run_dir, suite_folder(suite)))
    return kept_suite(run_dir, suite, attempts), True


def evaluate_suite_runs(
    run_dirs,
    suite: str,
    attempts: int = ATTEMPTS,
    range_noise: float = RANGE_NOISE,
    action_noise: float = ACTION_NOISE,
    seed: int = 0,
    max_steps: int | None = None,
    out: str | Path | None = None,
    echo: Callable[[str], None] = print,
    memory_budget: int | None = None,
    then: Callable[[str | Path, Path], None] | None = None,
    robot=None,
) -> dict:
    """What `fedjax-nav evaluate RUN... --suite NAME|DIR|GLOB` does: each run into
    RUN/eval/<suite_folder(suite)>/ (or `out` for one run), a table per run; `then(run_dir, folder)`
    after each run's files are written (the CLI draws its worst rooms there). Returns {run_dir: summary}."""
    results = {}
    _check_suite(suite)  # a bad name or an empty folder: one line before any run is loaded
    for run_dir in run_dirs:
        res = evaluate_suite(run_dir, suite, attempts, range_noise, action_noise, seed, max_steps, memory_budget, robot)
        dest = Path(out) if out is not None and len(run_dirs) == 1 else robot_folder(run_dir, suite, robot)
        paths = write_suite(res, dest)
        s = res["summary"]
        echo(
            f"{s['method']} ({run_name(run_dir)}) on suite '{suite}': {s['rooms']} rooms, {s['episodes']} episodes, "
            f"{s['wall_s']:.1f} s"
        )
        echo(
            res["families"][
                [
                    "family",
                    "rooms",
                    "success",
                    "ci_rooms_low",
                    "ci_rooms_high",
                    "ci_seeds_low",
                    "ci_seeds_high",
                    "worst10",
                    "collision",
                    "timeout",
                    "path_ratio_median",
                ]
            ].to_string(index=False, float_format="%.3f")
        )
        echo("wrote " + ", ".join(str(p) for p in paths))
        if then is not None:
            then(run_dir, dest)
        results[run_name(run_dir)] = s
    return results
