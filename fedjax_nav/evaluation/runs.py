"""The evaluation of training runs (docs/evaluation.md): load a run's agents, run the protocol on
them, and what `fedjax-nav evaluate` does.

    load_run(run_dir) -> RunAgents           the trained actors of a run (read through fedjax_nav.rundir)
    evaluate_run(run_dir, world, ...) -> RunEvaluation   the protocol on one run
    evaluate_runs(run_dirs, world, ...)      the command: evaluate, write, print, compare

Where the files go (docs/evaluation.md, "Where the files go"): the evaluation of RUN on world W
into `rundir.eval_dir(RUN, W)` = RUN/eval/<world>/, one folder per world; `out` instead for a
single run. Re-running an evaluation replaces its own folder's files and says so; another
world's folder, and a legacy RUN/eval.json of the old layout, are never touched.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

from fedjax_nav import rundir
from fedjax_nav import worlds as _worlds
from fedjax_nav.config import envs
from fedjax_nav.env.nav import make_params
from fedjax_nav.evaluation import report
from fedjax_nav.evaluation.limits import check_counts, check_eval_memory
from fedjax_nav.evaluation.metrics import STRAIGHT_LINE_NOTE, episodes_frame, summarize
from fedjax_nav.evaluation.rollout import (
    ACTION_NOISE,
    ATTEMPTS,
    CHUNK,
    RANGE_NOISE,
    EvalError,
    MemoryPolicy,
    episode_state,
    evaluate_policy,
)
from fedjax_nav.evaluation.run_data import RunAgents, RunEvaluation


@functools.lru_cache(maxsize=16)
def actor_policy(hidden: int, depth: int, activation: str) -> Callable:
    """The greedy actor as `policy(actor_params, obs)` (one function object per architecture,
    so that runs with the same networks share one compiled evaluation)."""
    from fedjax_nav.agents import ddpg

    nets = ddpg.make_nets(hidden, depth, activation)

    def policy(params, obs):
        return ddpg.act(nets, params, obs)

    return policy


@functools.lru_cache(maxsize=16)
def _learner_policy(learner_name: str, frozen_values: tuple) -> MemoryPolicy:
    from fedjax_nav.agents import learners

    learner = learners.get(learner_name)
    nets = learner.make_nets(dict(frozen_values))

    def init():
        return learner.memory(nets)

    def step(params, obs, memory, first):
        return learner.greedy(nets, params, obs, memory, first)

    return MemoryPolicy(init, step)


def greedy_policy(cfg) -> Callable | MemoryPolicy:
    """The run's greedy policy: DDPG's actor as `policy(actor_params, obs)` (`actor_policy`, the
    thesis's evaluation program), or the learner's greedy action as a `MemoryPolicy`
    (agents.learners' `memory` and `greedy`; TD3: DDPG's actor, SAC/PPO: the squashed Gaussian's
    mode; a recurrent PPO's GRU state starts at `memory(nets)` (zeros) with `first` set at each
    episode's first step and is carried step to step, as in the trainer's probe). One object per
    learner and network settings, so that runs alike share one compiled evaluation."""
    from fedjax_nav.config import values
    from fedjax_nav.learner_table import get

    row = get(cfg.learner)
    if row.plain_actor:
        d = getattr(cfg, row.actor_section)
        return actor_policy(d.hidden, d.depth, d.activation)
    mine = {k: v for k, v in values(cfg).items() if k.split(".")[0] in ("learner", *row.sections)}
    return _learner_policy(cfg.learner, tuple(sorted(mine.items())))


def run_policy(run: RunAgents) -> Callable | MemoryPolicy:
    """The policy an evaluation of `run` drives: its `policy` (a scripted baseline's), else the
    run's learner's greedy one (`greedy_policy`)."""
    return run.policy if run.policy is not None else greedy_policy(run.cfg)


def _expected_actor(cfg, obs_size: int):
    """The actor's parameter shapes for the run's learner (jax.eval_shape: nothing computed)."""
    from fedjax_nav.learner_table import get

    row = get(cfg.learner)
    if row.plain_actor:
        from fedjax_nav.agents import ddpg

        d = getattr(cfg, row.actor_section)
        nets = ddpg.make_nets(d.hidden, d.depth, d.activation)
        return jax.eval_shape(nets.actor.init, jax.random.key(0), jnp.zeros((obs_size,)))
    from fedjax_nav.agents import learners
    from fedjax_nav.config import traced, values

    learner = learners.get(cfg.learner)
    nets = learner.make_nets(values(cfg))
    # only shapes are asked: every traced value as an f32 scalar (evaluation does not import
    # training, which builds the real HParams)
    hp = traced.shapes()
    return jax.eval_shape(lambda k, h: learner.policy(learner.init(nets, k, obs_size, h)), jax.random.key(0), hp)


def _flat_shapes(tree) -> dict[str, tuple]:
    return {
        "/".join(str(getattr(k, "key", k)) for k in kp): tuple(v.shape)
        for kp, v in jax.tree_util.tree_flatten_with_path(tree)[0]
    }


def load_run(run_dir: str | Path | RunAgents) -> RunAgents:
    """Read config.yaml and params.npz (actor leaves [seed, net, ...]) of a training run, through
    fedjax_nav.rundir; any problem is an EvalError naming the file. A RunAgents passes through as
    it is (a run under changed values, `fedjax-nav evaluate --set`)."""
    from fedjax_nav import methods
    from fedjax_nav.config import ConfigError
    from fedjax_nav.env import NavEnv as _Env
    from fedjax_nav.learner_table import get as learner_row

    if isinstance(run_dir, RunAgents):
        return run_dir
    try:
        run_dir = rundir.run_dir(run_dir, (rundir.CONFIG, rundir.PARAMS))
        cfg = rundir.read_config(run_dir)
        actor = rundir.read_params(run_dir, "actor")
    except (rundir.RunDirError, ConfigError) as e:
        raise EvalError(str(e)) from None
    params_file = run_dir / rundir.PARAMS
    got_shapes = _flat_shapes(actor)

    method = methods.get(cfg.method)
    n_robots = cfg.num_robots
    n_nets = 1 if method.shared_network else n_robots
    section = learner_row(cfg.learner).actor_section  # where the actor's hidden and depth are
    d = getattr(cfg, section)
    obs_size = _Env(cfg.env.num_beams, plan=cfg.env.plan).obs_size
    exp_flat = _flat_shapes(_expected_actor(cfg, obs_size))
    if set(exp_flat) != set(got_shapes):
        raise EvalError(
            f"{params_file}: actor arrays {sorted(got_shapes)} do not match the network of "
            f"config.yaml ({section}.hidden={d.hidden}, depth={d.depth}): expected {sorted(exp_flat)}"
        )
    lead = None
    for k, shape in exp_flat.items():
        got = got_shapes[k]
        if len(got) != len(shape) + 2 or tuple(got[2:]) != tuple(shape) or got[1] != n_nets:
            raise EvalError(
                f"{params_file}: actor/{k} has shape {list(got)}, expected "
                f"[seeds, {n_nets}, {', '.join(map(str, shape))}] for {cfg.method} with "
                f"{section}.hidden={d.hidden}, depth={d.depth}"
            )
        lead = got[:2] if lead is None else lead
        if got[:2] != lead:
            raise EvalError(f"{params_file}: inconsistent leading axes {list(got[:2])} vs {list(lead)}")
    S = int(lead[0])
    if S == 0:
        raise EvalError(
            f"{params_file}: the actor arrays have no seeds (shape [0, {n_nets}, ...]); nothing to evaluate"
        )
    bad = sorted(
        {
            (int(s), int(k))
            for leaf in jax.tree.leaves(actor)
            for s, k in zip(*np.nonzero(~np.isfinite(leaf.reshape(*leaf.shape[:2], -1)).all(-1)))
        }
    )
    if bad:
        s, k = bad[0]
        raise EvalError(
            f"{params_file}: the actor of seed {cfg.run.seed + s}, network {k} holds NaN/Inf "
            f"parameters ({len(bad)} of {S * n_nets} actors; a diverged run?); nothing to evaluate"
        )
    actor = jax.tree.map(lambda x: jnp.asarray(x.reshape(S * n_nets, *x.shape[2:]), jnp.float32), actor)
    seeds = np.repeat(np.arange(S) + cfg.run.seed, n_nets)
    nets_idx = np.tile(np.arange(n_nets), S)
    return RunAgents(run_dir, cfg, actor, seeds, nets_idx, n_nets, n_robots)


def check_run_memory(run: RunAgents, world, attempts: int, max_steps: int | None, robot=None, budget=None) -> dict:
    """The memory check of `evaluate_run(run, world, attempts, max_steps=max_steps, robot=robot)`
    (`limits.check_eval_memory`: one line naming --attempts and --max-steps, EvalError), from
    shapes; `world` a World or a name / file. Returns the estimate."""
    w = world if isinstance(world, _worlds.World) else _worlds.load(world)
    cfg = run.cfg
    under = dataclasses.replace(cfg, robot=cfg.robot if robot is None else robot)
    T = int(max_steps or cfg.env.episode_length)
    settings = envs.env_settings(under, "eval", noise=True, episode_length=T)
    params = make_params(w, **envs.eval_values(under, RANGE_NOISE, ACTION_NOISE))
    shape = (run.num_agents, int(w.num_goals), int(attempts) * run.num_robots // run.n_nets)
    state = episode_state(settings, params, greedy_policy(cfg))
    return check_eval_memory(settings, state, shape, CHUNK, int(attempts), budget, str(run.run_dir))


def evaluate_run(
    run_dir: str | Path | RunAgents,
    world: str | Path = "eval",
    attempts: int = ATTEMPTS,
    range_noise: float = RANGE_NOISE,
    action_noise: float = ACTION_NOISE,
    seed: int = 0,
    max_steps: int | None = None,
    robot=None,
    memory_budget: int | None = None,
) -> RunEvaluation:
    """The protocol on a run: its agents, the run's env settings (dt, speeds, radii, beams,
    collision test, T = env.episode_length unless `max_steps`), on `world` and its goals.

    `attempts` is per agent of a per-robot method; a shared-network method (SNDDPG, one agent per
    seed) gets attempts * num_robots so that the total number of episodes is the same.
    Nothing is written: `write_run(evaluation)` writes to `evaluation.eval_dir` (or a folder).
    robot: a `RobotConfig` to evaluate under (default: the run's own `robot` section). With a
    model other than the ideal one, its `range_noise` replaces `range_noise`, and an evaluation
    under a model other than the run's is kept in RUN/eval/<world>-robot-<model>/.
    memory_budget: bytes the evaluation may take (default: the memory available now); beyond it,
    an EvalError naming --attempts and --max-steps, before anything is allocated (`check_run_memory`).
    """
    check_counts(attempts, max_steps)
    run = load_run(run_dir)
    cfg = run.cfg
    robot = cfg.robot if robot is None else robot
    under = dataclasses.replace(cfg, robot=robot)  # the run under the robot it is evaluated with
    values = envs.eval_values(under, range_noise, action_noise)
    range_noise, action_noise = values.pop("range_noise"), values.pop("action_noise")
    w, meta = _worlds.load_with_meta(world)
    k_eff = int(attempts) * run.num_robots // run.n_nets
    e = cfg.env
    T = int(max_steps or e.episode_length)
    check_run_memory(run, w, attempts, max_steps, robot, memory_budget)
    result = evaluate_policy(
        greedy_policy(cfg),
        w,
        run.actor_params,
        attempts=k_eff,
        max_steps=T,
        range_noise=range_noise,
        action_noise=action_noise,
        seed=seed,
        env_settings=envs.env_settings(under, "eval", noise=True, episode_length=T),
        memory_budget=memory_budget,
        **values,
    )
    frame = episodes_frame(result, run.agent_seed, run.agent_net, run.agent_byzantine)
    noise = (range_noise, action_noise)
    summary = _run_summary(run, result, frame, world, meta, attempts, k_eff, T, noise, robot, seed)
    world_arg = str(world) if robot == cfg.robot else f"{rundir.world_slug(world)}-robot-{robot.model}"
    return RunEvaluation(run, result, frame, summary, w, meta, world_arg)


def _run_summary(
    run: RunAgents,
    result,
    frame,
    world,
    meta: dict,
    attempts: int,
    k_eff: int,
    T: int,
    noise: tuple[float, float],
    robot,
    seed: int,
) -> dict:
    """eval.json's summary of `evaluate_run`: what was evaluated, how, and `summarize(frame)`."""
    cfg, e = run.cfg, run.cfg.env
    range_noise, action_noise = noise
    return {
        "run_dir": str(run.run_dir),
        "method": cfg.method,
        "world": str(meta.get("name", world)),
        "world_source": str(meta.get("source", world)),
        "start": [float(x) for x in result.start],
        "goals": [[float(x) for x in g] for g in result.goals],
        "agents": run.num_agents,
        "seeds": sorted({int(s) for s in run.agent_seed}),
        "nets_per_seed": run.n_nets,
        "attempts_requested": int(attempts),
        "attempts_per_agent": k_eff,
        "episodes": int(result.success.size),
        "max_steps": T,
        "dt": result.dt,
        "goal_radius": result.goal_radius,
        "v_max": float(e.v_max),
        "noise": {
            "range_noise": float(range_noise),
            "action_noise": float(action_noise),
            "units": "range_noise in m; action_noise in action units (v/v_max, omega/omega_max)",
        },
        "robot": dataclasses.asdict(robot),
        "eval_seed": int(seed),
        "policy": "greedy actor (no exploration)",
        "straight_line": STRAIGHT_LINE_NOTE,
        "std": "population std (ddof=0) over successful episodes; success_seed_std over seeds",
        **summarize(frame),
        "wall_s": result.wall_s,
        "jax_backend": jax.default_backend(),
    }


def evaluated(run_dir: str | Path, world: str | Path = "eval", attempts: int = ATTEMPTS, figures: bool = False):
    """The run's evaluation on `world` (eval.json's dict), evaluated first unless one asked with the
    same attempts is kept in RUN/eval/<world>/ (the reports over many runs: reproduce, robustness,
    generalization). Returns (that dict, whether it was evaluated now)."""
    folder = rundir.eval_dir(run_dir, world)
    ev = report.read_evaluation(folder)
    if ev is not None and ev.get("attempts_requested") == attempts:
        return ev, False
    report.write_run(evaluate_run(run_dir, world, attempts=attempts), figures=figures)
    return report.read_evaluation(folder), True


def evaluate_runs(
    run_dirs: list[str | Path],
    world: str | Path = "eval",
    attempts: int = ATTEMPTS,
    range_noise: float = RANGE_NOISE,
    action_noise: float = ACTION_NOISE,
    seed: int = 0,
    max_steps: int | None = None,
    out: str | Path | None = None,
    figures: bool = True,
    echo: Callable[[str], None] = print,
    robot=None,
    memory_budget: int | None = None,
) -> dict[str, Any]:
    """What `fedjax-nav evaluate` does: evaluate each run and print its table.

    One run: its files into `out`, or by default into RUN/eval/<world>/. Several runs: each run's
    files into its RUN/eval/<world>/, and a comparison table (CSV + markdown) and figure into
    `out`, or by default into PARENT/eval/<world>/ (PARENT: the first run's parent directory).
    A folder that already holds an evaluation (or a comparison) is replaced, with one line saying
    so. Returns {label: summary, "_paths": [...]}.

    Every run is loaded and checked before any evaluation starts (a bad path fails early, and so
    does an evaluation beyond `memory_budget`: bytes, default the memory available now).
    robot: a `RobotConfig` to evaluate every run under (default: each run's own; see evaluate_run).
    """
    check_counts(attempts, max_steps)
    for flag, std in (("--range-noise", range_noise), ("--action-noise", action_noise)):
        if not 0 <= std < float("inf"):  # NaN fails too
            raise EvalError(f"{flag}: the noise std must be finite and >= 0, got {std}")
    runs = [load_run(d) for d in run_dirs]
    w, _ = _worlds.load_with_meta(world)  # a bad world (WorldError) fails before any compilation
    for run in runs:
        check_run_memory(run, w, attempts, max_steps, robot, memory_budget)
    echo(
        f"evaluating on '{world}': noise std range {range_noise:g} m, action {action_noise:g} "
        f"(action units); {attempts} attempts per agent and goal (x num_robots for a shared network)"
    )
    single_out = Path(out) if out is not None and len(runs) == 1 else None
    summaries: dict[str, dict] = {}
    written: list[Path] = []
    for run in runs:
        ev = evaluate_run(run, world, attempts, range_noise, action_noise, seed, max_steps, robot, memory_budget)
        if ev.summary["robot"]["model"] != "ideal":
            echo(
                f"robot model {ev.summary['robot']['model']}: lidar noise std {ev.summary['noise']['range_noise']:g} m"
            )
        dest = single_out or ev.eval_dir
        note = report.replacement(dest, ev.summary)
        paths = report.write_run(ev, dest, figures=figures)
        written += paths
        echo("")
        echo(report.summary_table(ev.summary))
        if note:
            echo(note)
        echo(
            f"{ev.summary['episodes']} episodes in {ev.result.wall_s:.1f} s; wrote " + ", ".join(str(p) for p in paths)
        )
        label = ev.summary["method"]
        if label in summaries:
            label = f"{label} ({run.run_dir.name})"
        summaries[label] = ev.summary
    if len(runs) > 1:
        out_dir = Path(out) if out else rundir.eval_dir(Path(run_dirs[0]).resolve().parent, world)
        note = report.comparison_replacement(out_dir)
        paths, md = report.write_comparison(summaries, out_dir, title=f"evaluation on {world}", figures=figures)
        written += paths
        echo("")
        echo(md)
        if note:
            echo(note)
        echo("wrote " + ", ".join(str(p) for p in paths))
    return {**summaries, "_paths": written}
