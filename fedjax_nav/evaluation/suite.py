"""Evaluation on a held-out suite of generated rooms (`fedjax-nav evaluate RUN --suite NAME`;
docs/generalization.md).

Every agent of the run drives in every room of the suite (`fedjax_nav.worlds.suites`: rooms from
the test stream of room seeds, never used by training) from start 0 to every goal of the room,
`attempts` times, with the protocol of `rollout.py` (greedy actor, noisy ranges and actions, the
run's env settings, time-out T); all rooms run in one jitted, vmapped program.

Results per family: the success rate with a 95 % bootstrap confidence interval
(`scipy.stats.bootstrap`, percentile method, 10,000 resamples, fixed random state) over the room
seeds (the sample unit of the held-out set: each room's success averaged over its agents, goals
and attempts), and the per-training-seed success with a bootstrap interval over the training seeds
when there are at least two. Written to RUN/eval/<suite>/ through fedjax_nav.rundir:
`suite.json` (everything), `suite_families.csv` (one row per family, and "all"), `suite_episodes.csv`
(one row per room x agent x goal x attempt).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from fedjax_nav import rundir
from fedjax_nav.config import envs
from fedjax_nav.env.nav import make_params
from fedjax_nav.evaluation.limits import EvalError, check_counts, check_eval_memory
from fedjax_nav.evaluation.rollout import ACTION_NOISE, ATTEMPTS, CHUNK, RANGE_NOISE, episode_state, eval_program
from fedjax_nav.evaluation.runs import greedy_policy, load_run
from fedjax_nav.worlds import WorldError
from fedjax_nav.worlds.suites import suite_names, suite_rooms

SUITE_JSON = "suite.json"
FAMILIES_CSV = "suite_families.csv"
EPISODES_CSV = "suite_episodes.csv"
RESAMPLES = 10_000


def bootstrap_ci(x, confidence: float = 0.95, seed: int = 0) -> tuple[float, float]:
    """95 % percentile bootstrap interval of the mean of `x` (scipy.stats.bootstrap); (nan, nan)
    for fewer than two values, (m, m) when every value is m."""
    from scipy import stats

    x = np.asarray(x, np.float64)
    if len(x) < 2:
        return float("nan"), float("nan")
    if np.all(x == x[0]):
        return float(x[0]), float(x[0])
    res = stats.bootstrap(
        (x,),
        np.mean,
        confidence_level=confidence,
        n_resamples=RESAMPLES,
        method="percentile",
        random_state=np.random.default_rng(seed),
    )
    return float(res.confidence_interval.low), float(res.confidence_interval.high)


def evaluate_suite(
    run_dir,
    suite: str = "heldout",
    attempts: int = ATTEMPTS,
    range_noise: float = RANGE_NOISE,
    action_noise: float = ACTION_NOISE,
    seed: int = 0,
    max_steps: int | None = None,
    memory_budget: int | None = None,
) -> dict:
    """The protocol of a run on every room of `suite`; returns {"summary", "families", "episodes"}.
    An evaluation whose estimate (`limits.eval_memory`: rooms x agents x goals x attempts) exceeds
    `memory_budget` bytes (default: the memory available now) is refused before it is allocated."""
    check_counts(attempts, max_steps)
    try:
        suite_names(suite)
    except WorldError as e:
        raise EvalError(str(e)) from None
    run = load_run(run_dir)
    cfg, e = run.cfg, run.cfg.env
    world, families, room_seeds = suite_rooms(suite)
    R, G = world.goals.shape[:2]
    A, K = run.num_agents, int(attempts) * run.num_robots // run.n_nets
    T = int(max_steps or e.episode_length)
    values = envs.eval_values(cfg, range_noise, action_noise)  # the run's robot model, as in training
    range_noise = values["range_noise"]
    params = make_params(world, **values)
    settings = envs.env_settings(cfg, "eval", noise=True, episode_length=T)
    room = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape[1:], x.dtype), params)  # one room's shapes
    policy = greedy_policy(cfg)
    state = episode_state(settings, room, policy)
    check_eval_memory(settings, state, (R, A, G, K), min(CHUNK, T), int(attempts), memory_budget, str(run.run_dir))
    program = eval_program(settings, policy, min(CHUNK, T))
    keys = jax.random.split(jax.random.key(seed), R * A * G * K).reshape(R, A, G * K)
    t0 = time.time()
    rooms = jax.jit(jax.vmap(program, in_axes=(None, 0, None, 0)))
    out = jax.device_get(rooms(run.actor_params, params, jnp.arange(G, dtype=jnp.int32), keys))  # [R, A, G, K]
    wall = time.time() - t0
    valid = np.arange(G)[None, :] < np.asarray(world.num_goals)[:, None]  # [R, G]
    r, a, g, k = np.meshgrid(np.arange(R), np.arange(A), np.arange(G), np.arange(K), indexing="ij")
    keep = valid[r, g].ravel()
    ep = pd.DataFrame(
        {
            "room": r.ravel(),
            "family": families[r.ravel()],
            "room_seed": room_seeds[r.ravel()],
            "seed": run.agent_seed[a.ravel()],
            "net": run.agent_net[a.ravel()],
            "byzantine": run.agent_byzantine[a.ravel()].astype(int),
            "goal": g.ravel(),
            "attempt": k.ravel(),
            "success": out["success"].ravel().astype(int),
            "collision": out["collision"].ravel().astype(int),
            "timeout": out["timeout"].ravel().astype(int),
            "steps": out["steps"].ravel(),
            "path_length": out["path"].ravel(),
        }
    )[keep].reset_index(drop=True)
    fams = pd.DataFrame(
        [
            _family_row(name, part)
            for name, part in [*((f, ep[ep.family == f]) for f in dict.fromkeys(families)), ("all", ep)]
        ]
    )
    summary = {
        "run_dir": str(run.run_dir),
        "method": cfg.method,
        "suite": suite,
        "suites": list(suite_names(suite)),
        "rooms": int(R),
        "agents": int(A),
        "attempts_requested": int(attempts),  # as in eval.json; one-network methods drive K = attempts x robots
        "attempts_per_agent": int(K),
        "episodes": int(len(ep)),
        "max_steps": T,
        "eval_seed": int(seed),
        "seeds": sorted({int(s) for s in run.agent_seed}),
        "noise": {"range_noise": float(range_noise), "action_noise": float(action_noise)},
        "training_rooms": e.rooms,
        "training_families": list(e.room_families) if e.rooms == "procedural" else [],
        "ci": "95% percentile bootstrap (scipy.stats.bootstrap, 10,000 resamples) of the mean success: "
        "ci_rooms over room seeds (each room's success averaged over agents, goals, attempts), "
        "ci_seeds over training seeds (each seed's agents averaged)",
        "families": fams.to_dict(orient="records"),
        "wall_s": wall,
    }
    return {"summary": summary, "families": fams, "episodes": ep}


def _family_row(name: str, ep: pd.DataFrame) -> dict:
    per_room = ep.groupby("room_seed")["success"].mean().to_numpy()
    per_seed = ep.groupby("seed")["success"].mean().to_numpy()
    lo_r, hi_r = bootstrap_ci(per_room)
    lo_s, hi_s = bootstrap_ci(per_seed)
    return {
        "family": name,
        "rooms": int(len(per_room)),
        "episodes": int(len(ep)),
        "success": float(ep["success"].mean()),
        "ci_rooms_low": lo_r,
        "ci_rooms_high": hi_r,
        "seeds": int(len(per_seed)),
        "ci_seeds_low": lo_s,
        "ci_seeds_high": hi_s,
        "collision": float(ep["collision"].mean()),
        "timeout": float(ep["timeout"].mean()),
        # the honest agents' success when the run had Byzantine robots (fed.byzantine), else NaN
        "success_honest": float(ep.loc[ep.byzantine == 0, "success"].mean()) if ep.byzantine.any() else float("nan"),
    }


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
    f = rundir.eval_dir(run_dir, suite) / SUITE_JSON
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
    write_suite(evaluate_suite(run_dir, suite, attempts=attempts), rundir.eval_dir(run_dir, suite))
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
) -> dict:
    """What `fedjax-nav evaluate RUN... --suite NAME` does: each run into RUN/eval/<suite>/ (or
    `out` for one run), a table per run. Returns {run_dir: summary}."""
    results = {}
    for run_dir in run_dirs:
        res = evaluate_suite(run_dir, suite, attempts, range_noise, action_noise, seed, max_steps, memory_budget)
        dest = Path(out) if out is not None and len(run_dirs) == 1 else rundir.eval_dir(run_dir, suite)
        paths = write_suite(res, dest)
        s = res["summary"]
        echo(
            f"{s['method']} ({run_dir}) on suite '{suite}': {s['rooms']} rooms, {s['episodes']} episodes, "
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
                    "collision",
                    "timeout",
                ]
            ].to_string(index=False, float_format="%.3f")
        )
        echo("wrote " + ", ".join(str(p) for p in paths))
        results[str(run_dir)] = s
    return results
