"""This project's PPO and SAC against brax's own `ppo.train` and `sac.train` on the same task.

    JAX_PLATFORMS=cpu nice -n 10 python scripts/compare_brax.py            # both learners, 4 seeds each side
    JAX_PLATFORMS=cpu nice -n 10 python scripts/compare_brax.py --learners ppo --frameworks brax \
        --brax-head small --evals 15                                          # the ablation (see below)
    python scripts/compare_brax.py --redraw                                   # the figure from the CSVs
    JAX_PLATFORMS=cpu python scripts/compare_brax.py --learners ppo --seeds 1 --evals 2 --chunk 1 \
        --out /tmp/cb --fig /tmp/cb/f.png                                     # a smoke run

Budgets (defaults): PPO 64 envs, 30 evaluations 2 episodes apart (1.97e6 env steps); SAC 16 envs,
24 evaluations 2 episodes apart (3.93e5 env steps, 24,576 gradient steps). On a loaded 2-core CPU the
first command took 36 min wall (21 CPU-min), most of it brax's SAC.

One robot in one room (`train-0`, start 0, goal 0), no federation (`method: iddpg`). For each learner:

1. brax: `brax.training.agents.{ppo,sac}.train` on `envs.get_environment("fedjax_nav")` (the adapter,
   fedjax_nav/env/brax_env.py) with the env's EnvParams values taken from the project config's
   HParams, one call per seed. The parameters at each of its evaluations come out through brax's
   own hooks: PPO's `policy_params_fn`, SAC's `checkpoint_logdir` (sac.train has no params hook;
   its orbax checkpoints are read back with brax's `checkpoint.load`).
2. this project: `training.Trainer` of the matched config (`learner: ppo | sac`, every seed in one
   program), run chunk by chunk; the greedy policy's parameters are copied after each chunk.
3. one evaluator for both (`evaluate`): every saved parameter set drives its greedy policy (the
   squashed mean) in the same jitted rollout of `NavEnv(mode="eval")` with the evaluation
   protocol's noise (range and action std 0.01: without noise a deterministic policy from a fixed
   start makes every episode the same), the same keys for every parameter set, `--episodes`
   episodes of at most env.episode_length steps; return = the reward summed to the episode's end,
   success = the goal reached before any collision. The two sides differ only in `policy_fn`: brax
   acts in [-1, 1]^2, mapped to the env's box as the adapter does (v / v_max = (a0 + 1) / 2).

The evaluation points are at the same env steps on both sides: a brax PPO epoch is
`chunk * episode_length / rollout` training steps of `num_envs * rollout` env steps, exactly one
chunk of the project's run; brax SAC's count also includes its `min_replay_size` prefill
(`batch_size` steps: the project's first steps before it holds a batch). `settings_table` lists
which settings match and which cannot.

Writes results/brax_comparison.csv (framework, learner, seed, env_steps, return, success),
results/brax_comparison_summary.csv (mean, std, min, max over seeds per framework at the last
evaluations and over the whole curve, and the wall times), docs/img/learners/brax_comparison.png, and
prints the settings table (docs/learners.md, "Against brax's PPO and SAC").

The ablation `--brax-head small` trains brax's PPO with the project's initialisation of the policy's
last layer (`small_head_init`) and writes results/brax_comparison_brax_small_head.csv (and its
summary); the figure draws its mean dashed.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

import fedjax_nav.env.brax_env  # noqa: F401  (registers "fedjax_nav" with brax, installs the jax shim)
from fedjax_nav import worlds
from fedjax_nav.agents import distributions as dist
from fedjax_nav.config import Config, envs
from fedjax_nav.config.validate import from_dict
from fedjax_nav.training.hparams import hparams_from_config

ROOT = Path(__file__).resolve().parents[1]
EVAL_NOISE = 0.01  # m and action units: fedjax_nav.evaluation's RANGE_NOISE and ACTION_NOISE
EVAL_SEED = 12345  # the evaluator's keys (the same for every parameter set)
ACTION_SIZE = 2
FRAMEWORKS = ("brax", "fedjax_nav")
ABLATION = "brax_small_head"  # brax's PPO with the project's initialisation of the policy's last layer


@dataclasses.dataclass(frozen=True)
class Task:
    """The task both sides train on and the evaluation schedule."""

    world: str = "train-0"
    episode_length: int = 512  # T: the env's time limit, brax's episode_length
    chunk: int = 2  # episodes of the project's run between evaluations (one brax epoch)
    evals: int = 16  # evaluations after the initial one


@dataclasses.dataclass(frozen=True)
class PPOSettings:
    num_envs: int = 64
    hidden: int = 64
    depth: int = 2
    lr: float = 3e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_eps: float = 0.2
    rollout: int = 128  # brax unroll_length
    minibatches: int = 4
    epochs: int = 4  # brax num_updates_per_batch
    ent_coef: float = 0.0  # brax entropy_cost
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5


@dataclasses.dataclass(frozen=True)
class SACSettings:
    num_envs: int = 16
    hidden: int = 64
    depth: int = 2
    lr: float = 1e-3  # actor, critics and temperature (brax has one learning rate)
    gamma: float = 0.99
    tau: float = 0.005
    batch_size: int = 256
    buffer_size: int = 100_000
    grad_steps: int = 1  # per env step of all num_envs environments (brax grad_updates_per_step)


# ----------------------------------------------------------------------------- settings mapping


def brax_initial_std() -> float:
    """The std of brax's tanh-normal policy at a raw scale output of 0: softplus(0) + min_std 0.001."""
    return math.log(2.0) + 1e-3


def brax_sac_target_entropy_box() -> float:
    """brax's SAC target entropy (-0.5 * action size, in the units of tanh's [-1, 1]^A) in this
    project's box units: a density on the box [0, 1] x [-1, 1] is the [-1, 1]^A density divided by
    the affine map's scales, so H_box = H_tanh + sum_i log scale_i."""
    _, scale = dist.affine()
    return -0.5 * ACTION_SIZE + float(jnp.sum(jnp.log(scale)))


def env_steps_per_eval(task: Task, s) -> int:
    """Env steps between two evaluations, on both sides: one chunk of the project's run."""
    return task.chunk * task.episode_length * s.num_envs


def project_config(task: Task, learner: str, s, seeds: int, seed: int = 0) -> Config:
    """The project's matched run: one robot, iddpg (no federation), `task.world`, `learner`."""
    data: dict[str, Any] = {
        "method": "iddpg",
        "learner": learner,
        "env": {"worlds": [task.world], "episode_length": task.episode_length, "envs_per_robot": s.num_envs},
        "run": {
            "episodes": task.chunk * task.evals,
            "chunk_episodes": task.chunk,
            "seeds": seeds,
            "seed": seed,
            "eval_every": 0,
            "checkpoint_every": 0,  # the trainer is driven directly: nothing is written
        },
    }
    if learner == "ppo":
        data["ppo"] = {
            "hidden": s.hidden,
            "depth": s.depth,
            "activation": "tanh",
            "rollout": s.rollout,
            "epochs": s.epochs,
            "minibatches": s.minibatches,
            "lr": s.lr,
            "gamma": s.gamma,
            "gae_lambda": s.gae_lambda,
            "clip_eps": s.clip_eps,
            "value_clip": 0.0,
            "vf_coef": s.vf_coef,
            "ent_coef": s.ent_coef,
            "max_grad_norm": s.max_grad_norm,
            "init_log_std": math.log(brax_initial_std()),
        }
    elif learner == "sac":
        data["offpolicy"] = {
            "hidden": s.hidden,
            "depth": s.depth,
            "activation": "relu",
            "buffer_size": s.buffer_size,
            "batch_size": s.batch_size,
            "gamma": s.gamma,
            "lr": s.lr,
            "train_every": 1,
            "gradient_steps": s.grad_steps,
        }
        data["sac"] = {
            "tau": s.tau,
            "alpha_lr": s.lr,
            "init_alpha": 1.0,  # brax: log_alpha = 0
            "target_entropy": brax_sac_target_entropy_box(),
        }
    else:
        raise ValueError(f"learner must be ppo or sac, got {learner!r}")
    return from_dict(data, "<compare_brax>")


def env_overrides(cfg: Config) -> dict:
    """The EnvParams values of the project's run (its HParams), for the brax env's constructor."""
    return {k: np.asarray(v).item() for k, v in envs.env_values(hparams_from_config(cfg)).items()}


def brax_env_kwargs(cfg: Config) -> dict:
    """`envs.get_environment("fedjax_nav", **kwargs)`: the project's room and robot, no time limit
    in the env (brax's EpisodeWrapper sets it), noise off as in the project's training env."""
    e = cfg.env
    return dict(
        worlds=list(e.worlds),
        num_beams=e.num_beams,
        max_range=e.max_range,
        collision_test=e.collision_test,
        noise=False,
        **env_overrides(cfg),
    )


def small_head_init(**kwargs):
    """A kernel initialiser for brax's PPO policy MLP: the project's (`networks_extra.MeanNet`):
    lecun_normal, but orthogonal(0.01) on the last layer (out = 2 x action size: loc and scale), so
    that the initial policy is the same as the project's: loc ~ 0 (the box's centre), scale ~ 0 (std
    softplus(0) + 0.001, the project's initial std) at every observation. The ablation
    `--brax-head small`; brax's MLP takes one initialiser for all its layers, told apart here by shape."""
    lecun, small = jax.nn.initializers.lecun_normal(**kwargs), jax.nn.initializers.orthogonal(0.01)

    def init(key, shape, dtype=jnp.float32):
        return small(key, shape, dtype) if shape[-1] == 2 * ACTION_SIZE else lecun(key, shape, dtype)

    return init


def brax_train_kwargs(task: Task, learner: str, s, seed: int, head: str = "brax") -> dict:
    """brax's train() keyword arguments (beside the env and the hooks), from the same numbers.
    head (PPO): "brax" = its own initialisation of the policy's last layer, "small" = the project's
    (`small_head_init`, an ablation)."""
    from brax.training.agents.ppo import networks as ppo_networks
    from brax.training.agents.sac import networks as sac_networks
    from flax import linen

    per_eval = env_steps_per_eval(task, s)
    common = dict(
        episode_length=task.episode_length,
        num_envs=s.num_envs,
        learning_rate=s.lr,
        discounting=s.gamma,
        reward_scaling=1.0,
        normalize_observations=False,
        num_evals=task.evals + 1,
        seed=seed,
    )
    lecun = jax.nn.initializers.lecun_normal  # flax Dense's default kernel init, as the project's hidden layers
    if learner == "ppo":
        if task.episode_length * task.chunk % s.rollout:
            raise ValueError("ppo: rollout must divide chunk * episode_length")
        if s.num_envs % s.minibatches:
            raise ValueError("ppo: minibatches must divide num_envs")
        net = functools.partial(
            ppo_networks.make_ppo_networks,
            policy_hidden_layer_sizes=(s.hidden,) * s.depth,
            value_hidden_layer_sizes=(s.hidden,) * s.depth,
            activation=linen.tanh,
            distribution_type="tanh_normal",
            policy_network_kernel_init_fn=small_head_init if head == "small" else lecun,
            value_network_kernel_init_fn=lecun,
        )
        return dict(
            common,
            num_timesteps=task.evals * per_eval,
            unroll_length=s.rollout,
            batch_size=s.num_envs // s.minibatches,  # sequences per minibatch: one rollout of all envs in total
            num_minibatches=s.minibatches,
            num_updates_per_batch=s.epochs,
            entropy_cost=s.ent_coef,
            clipping_epsilon=s.clip_eps,
            gae_lambda=s.gae_lambda,
            vf_loss_coefficient=s.vf_coef,
            max_grad_norm=s.max_grad_norm,
            normalize_advantage=True,
            num_resets_per_eval=0,
            run_evals=False,
            network_factory=net,
        )
    if learner == "sac":
        prefill = -(-s.batch_size // s.num_envs) * s.num_envs
        net = functools.partial(
            sac_networks.make_sac_networks,
            hidden_layer_sizes=(s.hidden,) * s.depth,
            activation=linen.relu,
            policy_network_kernel_init_fn=lecun,
            q_network_kernel_init_fn=lecun,
        )
        return dict(
            common,
            num_timesteps=prefill + task.evals * per_eval,
            tau=s.tau,
            batch_size=s.batch_size,
            min_replay_size=s.batch_size,
            max_replay_size=s.buffer_size,
            grad_updates_per_step=s.grad_steps,
            num_eval_envs=1,
            deterministic_eval=True,
            network_factory=net,
        )
    raise ValueError(f"learner must be ppo or sac, got {learner!r}")


def settings_table(task: Task, learner: str, s) -> list[tuple[str, str, str, str]]:
    """(setting, brax, fedjax_nav, "yes" / "no: why") rows, read from the two sides' actual
    arguments: brax_train_kwargs and project_config."""
    b = brax_train_kwargs(task, learner, s, seed=0)
    cfg = project_config(task, learner, s, seeds=1)
    n = b["network_factory"].keywords
    rows = [
        ("room, start, goal", f"{task.world}, 0, 0", f"{cfg.env.worlds[0]}, 0, 0", "yes"),
        ("episode length (steps)", str(b["episode_length"]), str(cfg.env.episode_length), "yes"),
        ("parallel envs", str(b["num_envs"]), str(cfg.env.envs_per_robot), "yes"),
        ("observation normalisation", str(b["normalize_observations"]).lower(), "off (none in the trainer)", "yes"),
        ("reward scaling", str(b["reward_scaling"]), "1 (none)", "yes"),
    ]
    if learner == "ppo":
        p = cfg.ppo
        hid = n["policy_hidden_layer_sizes"]
        rows += [
            (
                "policy / value MLP",
                f"{hid} tanh, {n['value_hidden_layer_sizes']} tanh",
                f"{(p.hidden,) * p.depth} {p.activation}",
                "yes",
            ),
            ("learning rate", str(b["learning_rate"]), str(p.lr), "yes"),
            ("discount", str(b["discounting"]), str(p.gamma), "yes"),
            ("GAE lambda", str(b["gae_lambda"]), str(p.gae_lambda), "yes"),
            ("ratio clip", str(b["clipping_epsilon"]), str(p.clip_eps), "yes"),
            (
                "value loss",
                f"0.5 x {b['vf_loss_coefficient']} x MSE, not clipped",
                f"0.5 x {p.vf_coef} x MSE, not clipped",
                "yes",
            ),
            ("entropy coefficient", str(b["entropy_cost"]), str(p.ent_coef), "yes"),
            ("gradient norm clip", str(b["max_grad_norm"]), str(p.max_grad_norm), "yes"),
            ("rollout (unroll) length", str(b["unroll_length"]), str(p.rollout), "yes"),
            (
                "rows per update, minibatches, epochs",
                f"{b['batch_size'] * b['num_minibatches'] * b['unroll_length']}, {b['num_minibatches']}, "
                f"{b['num_updates_per_batch']}",
                f"{p.rollout * cfg.env.envs_per_robot}, {p.minibatches}, {p.epochs}",
                "yes (brax's minibatches are whole unrolls, the project's single rows)",
            ),
            ("advantage normalisation", "per minibatch", "per minibatch", "yes"),
            (
                "policy std",
                "state-dependent softplus(x) + 0.001 (tanh_normal)",
                f"state-independent exp(log_std), log_std_0 = {p.init_log_std:.3f}",
                "no: brax's tanh_normal has no state-independent std; the initial std matches (0.694)",
            ),
            (
                "initialisation",
                "lecun_normal, heads too",
                "lecun_normal, policy mean head orthogonal(0.01)",
                "no: brax's head init is the hidden layers' one",
            ),
            (
                "GAE values",
                "recomputed each minibatch with the current value net",
                "once per rollout with the rollout's value net",
                "no: brax computes GAE inside its loss",
            ),
            (
                "time-out (truncation)",
                "its TD error masked out, recursion cut",
                "bootstrap from V(true last obs), recursion cut",
                "no, both correct: neither treats a time-out as a termination",
            ),
            (
                "time limit counts",
                "steps since the last goal / collision",
                "steps since the episode's reset (fixed 512-step episodes)",
                "no: the trainer's episodes are fixed-length",
            ),
        ]
    else:
        d, sc = cfg.offpolicy, cfg.sac
        rows += [
            (
                "actor / twin critic MLP",
                f"{n['hidden_layer_sizes']} relu",
                f"{(d.hidden,) * d.depth} {d.activation}",
                "yes",
            ),
            ("learning rate (actor, critics, alpha)", str(b["learning_rate"]), f"{d.lr}, {d.lr}, {sc.alpha_lr}", "yes"),
            ("discount", str(b["discounting"]), str(d.gamma), "yes"),
            ("target mix tau", str(b["tau"]), str(sc.tau), "yes"),
            ("batch size", str(b["batch_size"]), str(d.batch_size), "yes"),
            ("replay capacity", str(b["max_replay_size"]), str(d.buffer_size), "yes"),
            (
                "gradient steps per env step (all envs)",
                str(b["grad_updates_per_step"]),
                f"{d.gradient_steps} every {d.train_every}",
                "yes",
            ),
            ("initial temperature", "1 (log_alpha = 0)", str(sc.init_alpha), "yes"),
            (
                "target entropy",
                "-0.5 x 2 = -1 (tanh units)",
                f"{sc.target_entropy:.4f} (box units)",
                "yes (the same target: box units add log 0.5 for v)",
            ),
            (
                "learning starts",
                f"after a {b['min_replay_size']}-row prefill",
                f"once {d.batch_size} rows are stored",
                "yes",
            ),
            (
                "policy std",
                "softplus(x) + 0.001",
                "exp(log_std), log_std tanh-squashed into [-5, 2]",
                "no: fixed in each library's network",
            ),
            (
                "initialisation",
                "lecun_normal, heads too",
                "lecun_normal, actor mean head orthogonal(0.01)",
                "no: brax's head init is the hidden layers' one",
            ),
            (
                "critic action input",
                "tanh action in [-1, 1]^2",
                "box action in [0, 1] x [-1, 1]",
                "no: an affine change of the input",
            ),
            (
                "actor step against",
                "the critics before this step",
                "the critics after this step",
                "no: order of the update",
            ),
            (
                "time-out (truncation)",
                "row dropped from the critic loss",
                "bootstrap from Q(true last obs)",
                "no, both correct: neither treats a time-out as a termination",
            ),
            (
                "time limit counts",
                "steps since the last goal / collision",
                "steps since the episode's reset",
                "no: the trainer's episodes are fixed-length",
            ),
        ]
    return rows


# ----------------------------------------------------------------------------- the evaluator


def brax_to_box(a: jax.Array) -> jax.Array:
    """A brax action in [-1, 1]^2 -> the env's box (v / v_max, omega / omega_max), as BraxNavEnv.step."""
    a = jnp.clip(a, -1.0, 1.0)
    return jnp.stack([(a[..., 0] + 1.0) * 0.5, a[..., 1]], axis=-1)


def evaluate(policy_fn: Callable, stacked_params, cfg: Config, episodes: int, seed: int = EVAL_SEED):
    """(returns f32[P, episodes], success bool[P, episodes]) of the greedy policies.

    policy_fn(params, obs f32[obs]) -> box action f32[2]; stacked_params: P parameter sets stacked
    on a leading axis. Every set drives the same `episodes` episodes (the same keys) of
    `NavEnv(mode="eval")` from the run's start with the evaluation noise, each at most
    env.episode_length steps; an episode ends at the first goal, collision or time-out."""
    env = envs.make_env(cfg, "eval", noise=True)
    hp = hparams_from_config(cfg)
    world = worlds.load_many(list(cfg.env.worlds))
    params = envs.env_params(jax.tree.map(lambda x: x[0], world), hp, range_noise=EVAL_NOISE, action_noise=EVAL_NOISE)
    T = cfg.env.episode_length
    keys = jax.random.split(jax.random.PRNGKey(seed), episodes)

    def episode(p, key):
        k_reset, k_steps = jax.random.split(key)
        obs, state = env.reset(k_reset, params)

        def step(carry, k):
            obs, state, done, ret, success = carry
            obs2, state2, r, term, trunc, info = env.step(k, state, policy_fn(p, obs), params)
            live = ~done
            ret = ret + jnp.where(live, r, 0.0)
            success = success | (live & info["goal"] & ~info["collision"])
            return (obs2, state2, done | term | trunc, ret, success), None

        init = (obs, state, jnp.bool_(False), jnp.float32(0.0), jnp.bool_(False))
        (_, _, _, ret, success), _ = jax.lax.scan(step, init, jax.random.split(k_steps, T))
        return ret, success

    run = jax.jit(jax.vmap(lambda p: jax.vmap(lambda k: episode(p, k))(keys)))
    ret, success = run(stacked_params)
    return np.asarray(ret), np.asarray(success)


def stack(trees: list) -> Any:
    return jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *trees)


# ----------------------------------------------------------------------------- the two sides


def host(tree):
    return jax.tree.map(lambda x: np.array(x), tree)


def run_project(task: Task, learner: str, s, seeds: int):
    """The project's run: [(env_steps, actor params with leaves [seeds, ...])], the learner's
    greedy policy_fn, and the wall time in s."""
    from fedjax_nav.training.trainer import Trainer

    cfg = project_config(task, learner, s, seeds=seeds)
    t0 = time.time()
    tr = Trainer(cfg)
    hp = hparams_from_config(cfg)
    states = tr.init_seeds(jnp.arange(seeds, dtype=jnp.int32) + cfg.run.seed, hp)
    chunk = tr.compiled_chunk(task.chunk)
    per_eval = env_steps_per_eval(task, s)

    def policy(states):  # [seeds, n_nets = 1, ...] -> [seeds, ...]
        return host(jax.tree.map(lambda x: x[:, 0], tr.policy(states.agents)))

    snaps = [(0, policy(states))]
    for k in range(task.evals):
        states, metrics = chunk(states, hp, jnp.int32(k * task.chunk))
        jax.block_until_ready(metrics)
        snaps.append(((k + 1) * per_eval, policy(states)))
        print(f"  fedjax_nav {learner}: {(k + 1) * per_eval} steps, {time.time() - t0:.0f} s", flush=True)
    wall = time.time() - t0
    nets, learner_ = tr.nets, tr.learner
    memory = learner_.memory(nets)  # feed-forward: nothing to carry (PPO's is empty, SAC's None)
    first = None if memory is None else jnp.bool_(True)

    def policy_fn(actor, obs):
        return learner_.greedy(nets, actor, obs, memory, first)[0]

    return snaps, policy_fn, wall


def _brax_policy_fn(learner: str, network_factory, obs_size: int) -> Callable:
    """policy_fn(policy params, obs) -> box action: brax's deterministic inference function."""
    if learner == "ppo":
        from brax.training.agents.ppo import networks as nets_mod
    else:
        from brax.training.agents.sac import networks as nets_mod
    network = network_factory(obs_size, ACTION_SIZE)
    make_policy = nets_mod.make_inference_fn(network)
    key = jax.random.PRNGKey(0)  # unused by the deterministic policy

    def policy_fn(policy_params, obs):
        if learner == "ppo":  # (normalizer, policy, value); observation normalisation is off
            params = (None, policy_params, None)
        else:
            params = (None, policy_params)
        return brax_to_box(make_policy(params, deterministic=True)(obs, key)[0])

    return policy_fn


def run_brax(task: Task, learner: str, s, cfg: Config, seed: int, workdir: Path, head: str = "brax"):
    """One brax run: [(env_steps, policy params)], wall time in s."""
    from brax import envs as brax_envs
    from brax.training import checkpoint as brax_ckpt

    env = brax_envs.get_environment("fedjax_nav", **brax_env_kwargs(cfg))
    kw = brax_train_kwargs(task, learner, s, seed, head)
    snaps: list = []
    t0 = time.time()

    def progress(step, metrics):
        print(f"  brax {learner} seed {seed}: {step} steps, {time.time() - t0:.0f} s", flush=True)

    if learner == "ppo":
        from brax.training.agents.ppo import train as ppo

        def keep(step, make_policy, params):  # (normalizer, policy, value)
            snaps.append((int(step), host(params[1])))

        ppo.train(env, progress_fn=progress, policy_params_fn=keep, **kw)
    else:
        from brax.training.agents.sac import train as sac

        logdir = workdir / f"sac_seed{seed}"
        sac.train(env, progress_fn=progress, checkpoint_logdir=str(logdir), **kw)
        for d in sorted(p for p in logdir.iterdir() if p.is_dir()):
            snaps.append((int(d.name), host(brax_ckpt.load(d.resolve())[1])))
    return snaps, time.time() - t0


# ----------------------------------------------------------------------------- outputs


def tidy_rows(framework: str, learner: str, seed: int, steps: list[int], ret: np.ndarray, success: np.ndarray):
    """One row per evaluation point: means over the evaluation episodes."""
    return [
        dict(
            framework=framework,
            learner=learner,
            seed=seed,
            env_steps=int(t),
            **{"return": float(np.mean(r)), "success": float(np.mean(sc))},
        )
        for t, r, sc in zip(steps, ret, success)
    ]


def summarize(df, walls: dict, last: int = 3):
    """Per learner and framework: mean, std, min, max over seeds of the last `last` evaluations'
    mean return and success, and of the whole curve's mean (area under the curve / steps)."""
    import pandas as pd

    out = []
    for (learner, fw), g in df.groupby(["learner", "framework"]):
        steps = sorted(g.env_steps.unique())
        tail = g[g.env_steps.isin(steps[-last:])].groupby("seed")[["return", "success"]].mean()
        curve = g.groupby("seed")[["return", "success"]].mean()
        row = dict(learner=learner, framework=fw, seeds=g.seed.nunique(), final_env_steps=int(steps[-1]))
        for what, t in (("last3", tail), ("curve", curve)):
            for col in ("return", "success"):
                v = t[col].to_numpy()
                row |= {
                    f"{what}_{col}_mean": v.mean(),
                    f"{what}_{col}_std": v.std(ddof=1) if len(v) > 1 else 0.0,
                    f"{what}_{col}_min": v.min(),
                    f"{what}_{col}_max": v.max(),
                }
        row["wall_s"] = walls[(fw, learner)]
        out.append(row)
    return pd.DataFrame(out)


def draw(df, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    learners = sorted(df.learner.unique(), key=["ppo", "sac"].index)
    fig, axes = plt.subplots(2, len(learners), figsize=(5.2 * len(learners), 6.4), squeeze=False, sharex="col")
    colors = {"brax": "tab:blue", "fedjax_nav": "tab:orange", ABLATION: "tab:green"}
    for j, learner in enumerate(learners):
        for i, col in enumerate(("return", "success")):
            ax = axes[i, j]
            for fw in (*FRAMEWORKS, ABLATION):
                g = df[(df.learner == learner) & (df.framework == fw)]
                if g.empty:
                    continue
                piv = g.pivot(index="env_steps", columns="seed", values=col).sort_index()
                x = piv.index.to_numpy() / 1e6
                label = f"{fw} (mean, {piv.shape[1]} seeds)"
                if fw == ABLATION:  # the ablation: its mean only, dashed
                    ax.plot(x, piv.mean(axis=1), color=colors[fw], lw=1.5, ls="--", label=label)
                    continue
                for seed in piv.columns:
                    ax.plot(x, piv[seed], color=colors[fw], alpha=0.25, lw=0.8)
                ax.fill_between(x, piv.min(axis=1), piv.max(axis=1), color=colors[fw], alpha=0.12)
                ax.plot(x, piv.mean(axis=1), color=colors[fw], lw=2, label=label)
            ax.set_title(f"{learner.upper()}: greedy {col}")
            ax.grid(alpha=0.3)
            if i == 1:
                ax.set_xlabel("env steps (millions)")
            if j == 0:
                ax.set_ylabel("mean episode return" if col == "return" else "success rate")
            if i == 0 and j == 0:
                ax.legend(fontsize=8)
    fig.suptitle("train-0, one robot: brax's ppo.train / sac.train vs fedjax_nav's trainer (min-max band, thin: seeds)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def print_table(rows) -> None:
    print("| setting | brax | fedjax_nav | matched |")
    print("|---|---|---|---|")
    for r in rows:
        print("| " + " | ".join(r) + " |")


def keep_others(path: Path, new):
    """`new` with the rows of `path` (an earlier run's table) whose (framework, learner) this run did
    not measure: a run of some learners or frameworks never drops the others' results."""
    import pandas as pd

    if not path.exists() or new.empty:
        return new
    old = pd.read_csv(path)
    done = set(zip(new["framework"], new["learner"]))
    kept = old[[(f, lr) not in done for f, lr in zip(old["framework"], old["learner"])]]
    return pd.concat([kept, new], ignore_index=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--learners", nargs="+", default=["ppo", "sac"], choices=["ppo", "sac"])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--evals", type=int, default=None, help="evaluations after the initial one (default per learner)")
    ap.add_argument("--chunk", type=int, default=None, help="episodes between evaluations (default per learner)")
    ap.add_argument("--episodes", type=int, default=16, help="evaluation episodes per parameter set")
    ap.add_argument("--frameworks", nargs="+", default=list(FRAMEWORKS), choices=FRAMEWORKS)
    ap.add_argument("--out", type=Path, default=ROOT / "results")
    ap.add_argument("--fig", type=Path, default=ROOT / "docs/img/learners/brax_comparison.png")
    ap.add_argument(
        "--brax-head",
        choices=["brax", "small"],
        default="brax",
        help="small: the ablation, brax's PPO with the project's policy-head init; writes "
        f"OUT/brax_comparison_{ABLATION}.csv, which the figure then draws (dashed)",
    )
    ap.add_argument("--redraw", action="store_true", help="only draw the figure from the CSVs in OUT")
    args = ap.parse_args(argv)
    if args.redraw:
        return redraw(args.out, args.fig)
    if args.brax_head == "small" and (args.learners != ["ppo"] or args.frameworks != ["brax"]):
        ap.error("--brax-head small is an ablation of brax's PPO: give --learners ppo --frameworks brax")
    import pandas as pd

    defaults = {"ppo": (Task(chunk=2, evals=30), PPOSettings()), "sac": (Task(chunk=2, evals=24), SACSettings())}
    rows, walls = [], {}
    suffix = f"_{ABLATION}" if args.brax_head == "small" else ""
    with tempfile.TemporaryDirectory() as tmp:
        for learner in args.learners:
            task, s = defaults[learner]
            task = dataclasses.replace(
                task, chunk=args.chunk or task.chunk, evals=args.evals if args.evals is not None else task.evals
            )
            print(f"== {learner}: {task}, {s}")
            print_table(settings_table(task, learner, s))
            cfg = project_config(task, learner, s, seeds=args.seeds)
            if "brax" in args.frameworks:
                b = brax_train_kwargs(task, learner, s, 0, args.brax_head)
                brax_name = ABLATION if args.brax_head == "small" else "brax"
                policy_fn = _brax_policy_fn(learner, b["network_factory"], 4 + cfg.env.num_beams)
                t0 = time.time()
                for seed in range(args.seeds):
                    snaps, _ = run_brax(task, learner, s, cfg, seed, Path(tmp), args.brax_head)
                    ret, success = evaluate(policy_fn, stack([p for _, p in snaps]), cfg, args.episodes)
                    rows += tidy_rows(brax_name, learner, seed, [t for t, _ in snaps], ret, success)
                walls[(brax_name, learner)] = time.time() - t0
            if "fedjax_nav" in args.frameworks:
                snaps, policy_fn, wall = run_project(task, learner, s, args.seeds)
                walls[("fedjax_nav", learner)] = wall
                steps = [t for t, _ in snaps]
                # [evals, seeds, ...] -> one evaluation of all (eval, seed) pairs
                flat = jax.tree.map(lambda *xs: np.concatenate(xs), *[p for _, p in snaps])
                ret, success = evaluate(policy_fn, flat, cfg, args.episodes)
                ret = ret.reshape(len(steps), args.seeds, -1)
                success = success.reshape(len(steps), args.seeds, -1)
                for seed in range(args.seeds):
                    rows += tidy_rows("fedjax_nav", learner, seed, steps, ret[:, seed], success[:, seed])
            print({k: round(v) for k, v in walls.items()}, flush=True)
            args.out.mkdir(parents=True, exist_ok=True)
            tidy = args.out / f"brax_comparison{suffix}.csv"
            keep_others(tidy, pd.DataFrame(rows)).to_csv(tidy, index=False)  # after each learner
    summary_csv = args.out / f"brax_comparison{suffix}_summary.csv"
    summary = keep_others(summary_csv, summarize(pd.DataFrame(rows), walls))
    summary.to_csv(summary_csv, index=False, float_format="%.4g")
    print(summary.to_string())
    return redraw(args.out, args.fig)


def redraw(out: Path, fig: Path) -> int:
    """The figure from OUT/brax_comparison.csv and, when there, the ablation's CSV."""
    import pandas as pd

    frames = [
        pd.read_csv(p) for p in (out / "brax_comparison.csv", out / f"brax_comparison_{ABLATION}.csv") if p.exists()
    ]
    if not frames:
        print(f"error: no {out / 'brax_comparison.csv'}: run the comparison first", file=sys.stderr)
        return 2
    draw(pd.concat(frames, ignore_index=True), fig)
    return 0


if __name__ == "__main__":
    sys.exit(main())
