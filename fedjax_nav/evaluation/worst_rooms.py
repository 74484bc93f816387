"""The worst rooms of a held-out suite evaluation, drawn: how a policy fails where it fails most
(docs/evaluation.md, "Held-out suites and your own worlds"; docs/generalization.md, "Tail metrics").

    worst_rooms(RUN, "heldout")    -> RUN/eval/heldout/worst_rooms.png

From the evaluation kept in RUN/eval/<suite>/ (`fedjax-nav evaluate RUN --suite NAME` writes it, and
this figure after it): the rooms ranked by their success (the mean over the room's episodes in
suite_episodes.csv), lowest first, ties by room index (`rank_rooms`); the `rooms` worst rebuilt from
the suite (all of a suite's rooms share one padded shape) and their episodes replayed with the
evaluation's protocol, noise, time-out and evaluation seed (`suite.SuiteProtocol`: room r draws the
keys of its own index in the evaluation's layout), so the trajectories drawn are the episodes the
evaluation counted (their first `attempts` attempts). One panel per room
(`figures.room_trajectories`): the room, every agent's attempts to each goal, a colour per goal.
"""

from __future__ import annotations

import shlex
from dataclasses import dataclass
from pathlib import Path

import jax
import numpy as np
import pandas as pd

from fedjax_nav import rundir
from fedjax_nav.evaluation import figures
from fedjax_nav.evaluation.limits import EvalError, check_counts
from fedjax_nav.evaluation.runs import load_run
from fedjax_nav.evaluation.suite import suite_protocol, under_robot
from fedjax_nav.evaluation.suite_files import suite_folder, suite_world
from fedjax_nav.worlds import World, WorldError

ROOMS = 6  # rooms drawn by default
# the columns of suite_episodes.csv read here
COLUMNS = ("room", "family", "room_seed", "seed", "net", "goal", "attempt", "success", "collision", "timeout")


@dataclass
class WorstRooms:
    """The replayed episodes of a suite evaluation's worst rooms; arrays numpy, axes [room, agent,
    goal, attempt, ...] with the rooms in `rooms`' order (worst first) and all G goal rows of the
    suite's padded shape (a room's first `num_goals` are its own)."""

    folder: Path  # where the evaluation is kept
    summary: dict  # its suite.json
    rooms: pd.DataFrame  # `rank_rooms`' rows of the chosen rooms, worst first
    world: World  # their rooms, stacked [n, ...]
    num_goals: np.ndarray  # i[n]
    agent_seed: np.ndarray  # [A] each agent's training seed (suite_episodes.csv's `seed`)
    agent_net: np.ndarray  # [A] its network within the seed (`net`)
    success: np.ndarray  # bool[n, A, G, k]
    collision: np.ndarray  # bool[n, A, G, k]
    timeout: np.ndarray  # bool[n, A, G, k]
    steps: np.ndarray  # i32[n, A, G, k]
    poses: np.ndarray  # f32[n, A, G, k, T + 1, 3]; frozen after the episode's end
    obs: np.ndarray | None = None  # f32[n, A, G, k, T + 1, obs] the observation at each pose (`observations`)

    def room(self, i: int) -> World:
        """The i-th chosen room (unstacked)."""
        return jax.tree.map(lambda x: x[i], self.world)


def rank_rooms(episodes: pd.DataFrame) -> pd.DataFrame:
    """One row per room of a suite's episodes (suite_episodes.csv): room, family, room_seed and the
    means over its episodes of success, collision and time-out, with its number of episodes;
    lowest success first, ties by room index."""
    per = episodes.groupby("room", sort=True).agg(
        family=("family", "first"),
        room_seed=("room_seed", "first"),
        success=("success", "mean"),
        collision=("collision", "mean"),
        timeout=("timeout", "mean"),
        episodes=("success", "size"),
    )
    return per.reset_index().sort_values(["success", "room"], kind="stable").reset_index(drop=True)


def kept_evaluation(run_dir, suite: str, folder=None) -> tuple[Path, dict, pd.DataFrame]:
    """The evaluation of `run_dir` on `suite` kept in `folder` (default RUN/eval/<suite folder>/):
    (folder, suite.json, suite_episodes.csv). None kept, or unreadable: an EvalError (one line)."""
    folder = Path(folder) if folder is not None else rundir.eval_dir(run_dir, suite_folder(suite))
    files = folder / rundir.SUITE_JSON, folder / rundir.SUITE_EPISODES
    if not all(f.is_file() for f in files):
        cmd = f"fedjax-nav evaluate {shlex.quote(str(run_dir))} --suite {shlex.quote(suite)}"
        raise EvalError(f"{folder}: no evaluation on suite {suite!r} is kept; run `{cmd}` first")
    try:
        summary, episodes = rundir.read_json(files[0]), pd.read_csv(files[1])
    except rundir.RunDirError as e:
        raise EvalError(str(e)) from None
    except Exception as e:  # a truncated or foreign table: one line naming it
        raise EvalError(f"{files[1]}: cannot be read as a suite's episodes ({type(e).__name__}: {e})") from None
    missing = [c for c in COLUMNS if c not in episodes]
    if missing or not len(episodes):
        what = f"lacks the columns {', '.join(missing)}" if missing else "holds no episode"
        raise EvalError(f"{files[1]}: {what}; evaluate the suite again")
    return folder, summary, episodes


def replay(
    run_dir,
    suite: str = "heldout",
    rooms: int = ROOMS,
    attempts: int = 1,
    folder=None,
    choose=None,
    observations: bool = False,
) -> WorstRooms:
    """The `rooms` worst rooms (`rank_rooms`) of the kept evaluation of `run_dir` on `suite`
    (`kept_evaluation`), their episodes replayed with its protocol: every agent to every goal, the
    first `attempts` of its attempts (at most the evaluation's). `choose(episodes)`: other rooms,
    `rank_rooms`' rows in the order wanted (e.g. those with the most failed detours).
    `observations`: keep the observation at every pose too (`WorstRooms.obs`)."""
    check_counts(attempts)
    if not (isinstance(rooms, (int, np.integer)) and rooms >= 1):
        raise EvalError(f"rooms: must be an integer >= 1, got {rooms!r}")
    folder, s, episodes = kept_evaluation(run_dir, suite, folder)
    run = load_run(run_dir)
    run = under_robot(run, s.get("robot"))  # the robot the evaluation drove
    try:
        world, _, _ = suite_world(suite)
    except WorldError as e:
        raise EvalError(str(e)) from None
    R, A = int(world.goals.shape[0]), run.num_agents
    if (s.get("rooms"), s.get("agents")) != (R, A) or int(episodes["room"].max()) >= R:
        raise EvalError(
            f"{folder / rundir.SUITE_JSON}: an evaluation of {s.get('rooms')} rooms x {s.get('agents')} agents, "
            f"but suite {suite!r} has {R} rooms and the run {A} agents; evaluate the suite again"
        )
    ranked = (rank_rooms(episodes) if choose is None else choose(episodes)).head(int(rooms))
    K = int(s["attempts_per_agent"])
    asked = int(s.get("attempts_requested", K * run.n_nets // run.num_robots))
    noise = s["noise"]
    protocol = suite_protocol(
        run, world, asked, noise["range_noise"], noise["action_noise"], int(s["eval_seed"]), int(s["max_steps"])
    )
    if protocol.K != K:
        raise EvalError(f"{folder / rundir.SUITE_JSON}: {K} attempts per agent, the run drives {protocol.K}")
    k, idx = min(int(attempts), K), ranked["room"].to_numpy()
    protocol.check(len(idx), k, k, None)
    out = protocol.rollout(idx, k, observations)
    chosen = jax.device_get(jax.tree.map(lambda x: x[idx], world))
    return WorstRooms(
        folder,
        s,
        ranked,
        chosen,
        np.asarray(chosen.num_goals),
        np.asarray(run.agent_seed),
        np.asarray(run.agent_net),
        *(np.asarray(out[f]) for f in ("success", "collision", "timeout", "steps", "poses")),
        np.asarray(out["obs"]) if observations else None,
    )


def worst_rooms(
    run_dir,
    suite: str = "heldout",
    rooms: int = ROOMS,
    attempts: int = 1,
    max_agents: int | None = None,
    out=None,
    folder=None,
) -> Path:
    """Draw the `rooms` worst rooms of the kept evaluation of `run_dir` on `suite` (`replay`): one
    panel per room, every agent's first `attempts` attempts to each goal (`max_agents`: only the
    first agents). Written to `out`, by default beside the evaluation: `folder` (default
    RUN/eval/<suite folder>/) / worst_rooms.png. Returns the figure's path."""
    if max_agents is not None and not (isinstance(max_agents, (int, np.integer)) and max_agents >= 1):
        raise EvalError(f"max_agents: must be an integer >= 1, got {max_agents!r}")
    w = replay(run_dir, suite, rooms, attempts, folder)
    return figures.room_trajectories(w, Path(out) if out else w.folder / rundir.SUITE_WORST_ROOMS_FIGURE, max_agents)
