"""`fedjax-nav export`: one trained actor of a run -> a folder a robot can use without JAX.

    fedjax-nav export RUN_DIR [--seed S] [--agent K] --format numpy|onnx --out DIR [--force]

--seed S: the run's PRNG seed (the `seed` column of eval_episodes.csv / eval.json's per_agent;
default: the run's first seed, config run.seed). --agent K: the network within that seed (the
`net` column; 0..n_nets-1, a shared-network method has only 0; default 0).

numpy: DIR/weights.npz + DIR/policy.py (policy_template.py: the actor in numpy, no JAX) +
DIR/policy_inputs.py (the observation functions, which policy.py loads) + DIR/meta.json.
onnx:  DIR/policy.onnx (input "obs" float32[batch, num_beams + 4], + 5 with the plan, output "action"
float32[batch, 2]; a recurrent policy also takes "h" float32[batch, gru] and returns "h_out")
+ DIR/meta.json + DIR/policy.py and DIR/policy_inputs.py (for the observation functions; its
`Policy` class needs the numpy format's weights.npz).

Every learner exports its greedy action, as `agents.learners.Learner.greedy` computes it: how is
data, the learner's row of fedjax_nav/learner_table.py (`actor_section`: the config section of its
actor's sizes; `export`, `recurrent`: the network kind that policy_template.py runs, `actor_kind`):
DDPG's and TD3's actor ("heads"), SAC's and feed-forward PPO's squashed mean ("squashed"),
recurrent PPO's GRU with its hidden state ("gru").

The ONNX graph is built by `fedjax_nav.deploy.onnx_graph` (why not jax2onnx: there).

Errors the user can fix end with one line on stderr naming the file or flag, exit code 2.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import numpy as np

from fedjax_nav.deploy.onnx_graph import ONNX_OPSET, onnx_model


def _project():
    """Every import of project code, in one place (imported lazily so that `fedjax-nav --help`
    stays instant; re-point this line when the module moves)."""
    from fedjax_nav.agents.ppo import input_affine
    from fedjax_nav.evaluation import EvalError, load_run

    return load_run, EvalError, input_affine


FORMATS = ("numpy", "onnx")


def actor_kind(cfg) -> str:
    """The network kind of policy_template.py that runs the run's greedy actor ("heads", "squashed"
    or "gru"), from its learner's row (export_run reads this, never the learner's name)."""
    from fedjax_nav.config import get
    from fedjax_nav.learner_table import get as learner_row

    row = learner_row(cfg.learner)
    return "gru" if row.recurrent and get(cfg, row.recurrent) != "none" else row.export


TEMPLATE = Path(__file__).with_name("policy_template.py")  # written as DIR/policy.py
INPUTS = Path(__file__).with_name("policy_inputs.py")  # written beside it under its own name (policy.py loads it)


class ExportError(ValueError):
    """An export input (run directory, seed, agent, format, output folder) is invalid; the message says which."""


# ----------------------------------------------------------------------------- weights


def actor_weights(actor_params: dict, depth: int) -> dict[str, np.ndarray]:
    """A flax Actor's params ({"params": {"Dense_i", "v_head", "omega_head"}}, one agent, no
    leading axes) -> the flat float32 arrays of weights.npz (names of policy_template.actor_forward)."""
    p = actor_params["params"] if "params" in actor_params else actor_params
    out = {}
    for i in range(depth):
        out[f"hidden_{i}/kernel"] = np.asarray(p[f"Dense_{i}"]["kernel"], np.float32)
        out[f"hidden_{i}/bias"] = np.asarray(p[f"Dense_{i}"]["bias"], np.float32)
    for head in ("v_head", "omega_head"):
        out[f"{head}/kernel"] = np.asarray(p[head]["kernel"], np.float32)
        out[f"{head}/bias"] = np.asarray(p[head]["bias"], np.float32)
    return out


def _dense(p: dict, name: str) -> dict[str, np.ndarray]:
    """One flax Dense layer's arrays under `name`/kernel (and `name`/bias when it has one)."""
    out = {f"{name}/kernel": np.asarray(p["kernel"], np.float32)}
    if "bias" in p:
        out[f"{name}/bias"] = np.asarray(p["bias"], np.float32)
    return out


def squashed_weights(actor_params: dict, depth: int) -> dict[str, np.ndarray]:
    """A squashed-Gaussian actor's params (SquashedGaussianActor or MeanNet: Dense_i, "mean"; a
    "log_std" head is left out, the greedy action does not use it) -> the arrays of
    policy_template.squashed_forward: hidden_{i}/kernel, hidden_{i}/bias, mean/kernel, mean/bias."""
    p = actor_params["params"] if "params" in actor_params else actor_params
    out = {}
    for i in range(depth):
        out.update(_dense(p[f"Dense_{i}"], f"hidden_{i}"))
    return {**out, **_dense(p["mean"], "mean")}


def gru_weights(actor_params: dict, depth: int) -> dict[str, np.ndarray]:
    """A RecurrentMLP's params (embed, gru/GRUCell_0/{ir,iz,in,hr,hz,hn}, Dense_i for i < depth - 1,
    head) -> the arrays of policy_template.gru_forward."""
    p = actor_params["params"] if "params" in actor_params else actor_params
    out = _dense(p["embed"], "embed")
    cell = p["gru"]["GRUCell_0"]
    for gate in ("ir", "iz", "in", "hr", "hz", "hn"):
        out.update(_dense(cell[gate], f"gru/{gate}"))
    for i in range(depth - 1):
        out.update(_dense(p[f"Dense_{i}"], f"hidden_{i}"))
    return {**out, **_dense(p["head"], "head")}


def input_weights(actor_params: dict, input_affine) -> dict[str, np.ndarray]:
    """The observation normaliser of an actor that has one (PPO with ppo.normalize_obs:
    `input_affine(actor)` = (mean, std, clip), agents.ppo) -> "obs_norm/mean", "obs_norm/std",
    "obs_norm/clip" of policy_template.normalize_input; {} for an actor without one."""
    affine = input_affine(actor_params)
    if affine is None:
        return {}
    mean, std, clip = affine
    return {
        "obs_norm/mean": np.asarray(mean, np.float32),
        "obs_norm/std": np.asarray(std, np.float32),
        "obs_norm/clip": np.asarray(clip, np.float32),
    }


WEIGHTS = {"heads": actor_weights, "squashed": squashed_weights, "gru": gru_weights}
ACTION_DOC = {
    "heads": ["v / v_max in [0, 1] (sigmoid)", "omega / omega_max in [-1, 1] (tanh)"],
    "squashed": ["v / v_max in [0, 1] (0.5 + 0.5 tanh(mean_v))", "omega / omega_max in [-1, 1] (tanh(mean_omega))"],
}
ACTION_DOC["gru"] = ACTION_DOC["squashed"]
ENTRY_DOC = {  # meta.json's words for each entry of the env's observation layout (env/plan.py's `layout`)
    "goal_distance": "goal distance (m)",
    "goal_bearing": "goal bearing relative to the heading (rad, [-pi, pi], ccw positive)",
    "waypoint_distance": "the plan's waypoint's distance (m)",
    "waypoint_bearing": "the plan's waypoint's bearing relative to the heading (rad, [-pi, pi], ccw positive)",
    "previous_v": "previous action v / v_max in [0, 1]",
    "previous_omega": "previous action omega / omega_max in [-1, 1]",
}


# ----------------------------------------------------------------------------- export


def select(run, seed: int | None, agent: int | None) -> tuple[int, int, int]:
    """(flat agent index of load_run's axis, seed, net) for --seed / --agent."""
    from fedjax_nav import rundir

    seeds = sorted({int(s) for s in run.agent_seed})
    seed = seeds[0] if seed is None else int(seed)
    agent = 0 if agent is None else int(agent)
    if seed not in seeds:
        raise ExportError(
            f"{run.run_dir / rundir.PARAMS}: --seed {seed} is not a seed of this run "
            f"(seeds: {', '.join(map(str, seeds))})"
        )
    if not 0 <= agent < run.n_nets:
        raise ExportError(
            f"{run.run_dir / rundir.PARAMS}: --agent {agent} out of range: {run.cfg.method} has "
            f"{run.n_nets} network(s) per seed (0..{run.n_nets - 1})"
        )
    flat = int(np.flatnonzero((run.agent_seed == seed) & (run.agent_net == agent))[0])
    return flat, seed, agent


def export_run(
    run_dir: str | Path,
    out: str | Path,
    fmt: str = "numpy",
    seed: int | None = None,
    agent: int | None = None,
    force: bool = False,
) -> list[Path]:
    """Export one actor of a run; returns the files written. Raises ExportError (one-line message)."""
    load_run, EvalError, input_affine = _project()
    out = _checked_out(fmt, Path(out), force)
    try:
        run = load_run(run_dir)
    except EvalError as e:
        raise ExportError(str(e)) from None
    flat, seed, agent = select(run, seed, agent)
    cfg = run.cfg
    from fedjax_nav.learner_table import get as learner_row

    kind = actor_kind(cfg)
    if kind not in WEIGHTS:
        raise ExportError(f"{run.run_dir}: learner {cfg.learner}: export supports the actors {', '.join(WEIGHTS)}")
    d = getattr(cfg, learner_row(cfg.learner).actor_section)
    actor = _tree_map_index(run.actor_params, flat)
    weights = {**WEIGHTS[kind](actor, d.depth), **input_weights(actor, input_affine)}
    meta = _export_meta(cfg, d, run_dir, fmt, seed, agent, flat, kind, weights)
    return _write_export(out, fmt, meta, weights, kind, d.activation)


def _checked_out(fmt: str, out: Path, force: bool) -> Path:
    """`out` after checking --format (and that onnx is installed for it) and --out (a folder, empty
    unless --force); ExportError otherwise."""
    if fmt not in FORMATS:
        raise ExportError(f"--format {fmt!r}: unknown format (choose from {', '.join(FORMATS)})")
    if fmt == "onnx":
        try:
            import onnx  # noqa: F401
        except ImportError:
            raise ExportError(
                '--format onnx needs the onnx package: pip install "fedjax_nav[onnx]"; '
                "--format numpy needs nothing more"
            ) from None
    if out.exists() and not out.is_dir():
        raise ExportError(f"{out}: exists and is not a directory (--out)")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise ExportError(f"{out}: exists and is not empty (--out); choose another folder or pass --force")
    return out


def _export_meta(cfg, d, run_dir, fmt: str, seed: int, agent: int, flat: int, kind: str, weights: dict) -> dict:
    """meta.json of an export (without its "files" and "onnx" entries, which the writing adds); `d`
    the config section of the actor's sizes."""
    from fedjax_nav.env.plan import layout

    e = cfg.env
    entries = layout(bool(e.plan))  # the env's own order (docs/export.md, "Exporting a plan run")
    meta = {
        "format": fmt,
        "num_beams": int(e.num_beams),
        "max_range": float(e.max_range),
        "v_max": float(e.v_max),
        "omega_max": float(e.omega_max),
        "dt": float(e.dt),
        "goal_radius": float(e.goal_radius),
        "collision_distance": float(e.collision_distance),
        "run_dir": str(Path(run_dir).resolve()),
        "method": cfg.method,
        "learner": cfg.learner,
        "seed": seed,
        "agent": agent,
        "agent_index": flat,
        "network": {
            "kind": kind,
            "obs_size": int(e.num_beams) + len(entries),
            "hidden": int(d.hidden),
            "depth": int(d.depth),
            "activation": d.activation,
            "action_size": 2,
            "layers": [[int(n) for n in w.shape] for k, w in weights.items() if k.endswith("/kernel")],
            **({"gru": int(weights["gru/hn/kernel"].shape[0])} if kind == "gru" else {}),
        },
        "observation": [
            "ranges[num_beams] (m, beam i at heading + 2 pi i / num_beams, clipped to max_range)",
            *(ENTRY_DOC[name] for name in entries),
        ],
        "observation_layout": list(entries),
        "action": ACTION_DOC[kind],
    }
    if e.plan:
        meta["plan"] = {
            "lookahead": float(e.plan_lookahead),
            "cells": int(e.plan_cells),
            "waypoint": "the first pose of the planner's path at least lookahead m along it from the robot, else "
            "its last pose (policy.py's path_waypoint, Policy.follow); the simulator's grid had cells x cells cells",
        }
    if "obs_norm/mean" in weights:
        meta["observation_normalization"] = (
            "the network's input is clip((obs - mean) / std, -clip, clip), weights obs_norm/mean, obs_norm/std, "
            "obs_norm/clip: the running statistics of training (ppo.normalize_obs); policy.py and the ONNX graph "
            "apply it"
        )
    if kind == "gru":
        meta["memory"] = (
            "a GRU state h float32[gru]: zeros at an episode's start (a new goal: Policy.reset()), "
            "carried from one control step to the next (Policy keeps it; ONNX: input h, output h_out)"
        )
    return meta


def _write_export(out: Path, fmt: str, meta: dict, weights: dict, kind: str, activation: str) -> list[Path]:
    """Write the export's files into `out` (the other format's files removed); returns them."""
    out.mkdir(parents=True, exist_ok=True)
    # --force: no stale files of another format
    for name in ("weights.npz", "policy.onnx", "policy.py", INPUTS.name, "meta.json"):
        (out / name).unlink(missing_ok=True)
    written = []
    if fmt == "numpy":
        meta["files"] = ["weights.npz", "policy.py", INPUTS.name, "meta.json"]
        np.savez(out / "weights.npz", **weights)
        written.append(out / "weights.npz")
    else:
        meta["files"] = ["policy.onnx", "policy.py", INPUTS.name, "meta.json"]
        meta["onnx"] = {
            "input": "obs",
            "input_shape": ["batch", meta["network"]["obs_size"]],
            "output": "action",
            "output_shape": ["batch", 2],
            "opset": ONNX_OPSET,
        }
        if kind == "gru":
            gru = meta["network"]["gru"]
            meta["onnx"].update(state_input="h", state_output="h_out", state_shape=["batch", gru])
        model = onnx_model(
            weights,
            activation,
            {
                k: meta[k]
                for k in ("num_beams", "max_range", "v_max", "omega_max", "dt", "run_dir", "seed", "agent", "network")
            },
            kind,
        )
        (out / "policy.onnx").write_bytes(model.SerializeToString())
        written.append(out / "policy.onnx")
    shutil.copyfile(TEMPLATE, out / "policy.py")
    shutil.copyfile(INPUTS, out / INPUTS.name)
    (out / "meta.json").write_text(json.dumps(meta, indent=1) + "\n")
    written += [out / "policy.py", out / INPUTS.name, out / "meta.json"]
    return written


def _tree_map_index(tree: dict, i: int) -> dict:
    return {k: _tree_map_index(v, i) if isinstance(v, dict) else np.asarray(v[i]) for k, v in tree.items()}


# ----------------------------------------------------------------------------- CLI


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add `export` to an argparse subparsers object; dispatch the parsed args to run_cli."""
    p = subparsers.add_parser(
        "export",
        help="export one trained actor for a robot (numpy + policy.py, or ONNX)",
        description="Export one actor of a training run as a folder usable without JAX: numpy "
        "(weights.npz + policy.py) or onnx (policy.onnx), with meta.json. See docs/export.md.",
    )
    p.add_argument("run_dir", metavar="RUN_DIR", help="a training run directory (config.yaml, params.npz)")
    p.add_argument(
        "--seed",
        type=str,
        default=None,
        help="the run's PRNG seed to take the actor from (default: the run's first seed)",
    )
    p.add_argument("--agent", type=str, default=None, help="the network within that seed, 0..n_nets-1 (default 0)")
    p.add_argument("--format", dest="format", default="numpy", help="numpy (default) or onnx")
    p.add_argument("--out", required=True, help="output folder (created; must be empty unless --force)")
    p.add_argument("--force", action="store_true", help="write into a non-empty --out folder")
    p.set_defaults(func=run_cli)
    return p


def _int_flag(value: str | None, flag: str) -> int | None:
    if value is None:
        return None
    try:
        return int(value)
    except ValueError:
        raise ExportError(f"{flag} {value!r}: not an integer") from None


def run_cli(args: argparse.Namespace) -> int:
    """Run `export` for parsed args; 0 on success, 2 (one line on stderr) on bad input."""
    try:
        seed, agent = _int_flag(args.seed, "--seed"), _int_flag(args.agent, "--agent")
        if args.format not in FORMATS:
            raise ExportError(f"--format {args.format!r}: unknown format (choose from {', '.join(FORMATS)})")
        written = export_run(args.run_dir, args.out, args.format, seed, agent, getattr(args, "force", False))
    except ExportError as e:
        from fedjax_nav.messages import one_line

        print(f"error: {one_line(e)}", file=sys.stderr)
        return 2
    except OSError as e:  # a path that cannot be a folder: 2; a full or read-only disk: 4 (docs/reliability.md)
        from fedjax_nav.messages import one_line
        from fedjax_nav.rundir import BAD_PATH

        print(f"error: {one_line(f'{e.filename or args.out}: {e.strerror or e}')}", file=sys.stderr)
        return 2 if e.errno in BAD_PATH else 4
    meta = json.loads(Path(args.out, "meta.json").read_text())
    print(
        f"exported {meta['method']} seed {meta['seed']} agent {meta['agent']} ({args.format}) -> "
        f"{', '.join(str(p) for p in written)}"
    )
    return 0


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry point (python -m fedjax_nav.deploy.export ...), until cli.py wires it."""
    parser = argparse.ArgumentParser(prog="fedjax-nav")
    sub = parser.add_subparsers(dest="command", required=True)
    add_parser(sub)
    args = parser.parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
