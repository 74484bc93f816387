"""The host side of a training run: chunks of compiled episodes, progress, results on disk.

A run directory holds:
    config.yaml        the resolved config
    metrics.csv        one row per episode x seed x robot
    summary.json       headline numbers (success over the last 25 episodes, mean and spread over
                       seeds; communication per Eq. 25; timings)
    params.npz         the final actor/critic parameters, leaves [seed, net, ...]
    learning_curves.png
Files are written atomically (temporary file, then rename).
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from fedjax_nav.config import Config, save_config
from fedjax_nav.federated.comm import bytes_per_round, communication
from fedjax_nav.training.trainer import HParams, Trainer, hparams_from_config


def atomic_write(path: Path, write) -> None:
    """Call write(tmp_path), then rename onto path: readers never see a half-written file."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:  # e.g. a full disk: keep the old file, leave no half-written temporary
        tmp.unlink(missing_ok=True)
        raise


def fed_bytes_per_round(trainer: Trainer) -> int:
    """Bytes on the wire of one federated round (every client's parameters up, the aggregate
    down; rewards too for PW/RW), 0 for methods without a federated step."""
    if trainer.method.aggregator == "none":
        return 0
    return bytes_per_round(trainer.num_params(), trainer.n_nets, trainer.method.sends_rewards)


def metrics_frame(metrics: dict, cfg: Config, trainer: Trainer) -> pd.DataFrame:
    """Flatten the metrics of episodes 0.. (leaves [seeds, episodes, ...]) into rows
    episode x seed x robot. `fed_bytes`: bytes of the federated steps in that episode (all
    clients, up and down: fed_events x `fed_bytes_per_round`), repeated on each robot's row."""
    m = jax.device_get(metrics)
    S, E, N = m["reward"].shape
    ep, seed, robot = np.meshgrid(np.arange(E), np.arange(S) + cfg.run.seed, np.arange(N), indexing="ij")
    net = np.zeros(N, int) if trainer.n_nets == 1 else np.arange(N)
    per_net = lambda x: np.transpose(x, (1, 0, 2))[:, :, net]  # noqa: E731  [E, S, N]
    per_seed = lambda x: np.broadcast_to(np.transpose(x, (1, 0))[:, :, None], (E, S, N))  # noqa: E731
    tr = lambda x: np.transpose(x, (1, 0, 2))  # noqa: E731
    return pd.DataFrame({
        "episode": ep.ravel(), "seed": seed.ravel(), "robot": robot.ravel(),
        "world": np.array(cfg.env.worlds)[robot.ravel()],
        "reward": tr(m["reward"]).ravel(), "goals": tr(m["goals"]).ravel(),
        "reached_goal": (tr(m["goals"]) > 0).ravel().astype(int), "collisions": tr(m["collisions"]).ravel(),
        "critic_loss": per_net(m["critic_loss"]).ravel(), "actor_loss": per_net(m["actor_loss"]).ravel(),
        "q": per_net(m["q"]).ravel(), "fed_events": per_seed(m["fed_events"]).ravel(),
        "fed_bytes": per_seed(m["fed_events"]).ravel() * fed_bytes_per_round(trainer),
        "epsilon": per_seed(m["epsilon"]).ravel(),
    })


def summarize(df: pd.DataFrame, cfg: Config, trainer: Trainer, last: int = 25) -> dict:
    """Success proportion and reward over the last `last` episodes: mean and std over seeds."""
    per_ep = df.groupby(["seed", "episode"]).agg(success=("reached_goal", "mean"), reward=("reward", "mean"))
    E = int(df["episode"].max()) + 1
    tail = per_ep[per_ep.index.get_level_values("episode") >= E - last].groupby("seed").mean()
    fed_events = df.groupby(["seed", "episode"])["fed_events"].first().groupby("seed").sum()
    comm = communication(trainer.method, cfg.run.episodes, cfg.env.episode_length, cfg.ddpg.train_every,
                         cfg.ddpg.batch_size, cfg.fed.period_unit, cfg.fed.period)
    n_params = trainer.num_params()
    bpr = fed_bytes_per_round(trainer)
    return {
        "method": cfg.method,
        "episodes_done": E,
        "seeds": int(df["seed"].nunique()),
        "last_episodes": min(last, E),
        "success_last": float(tail["success"].mean()),
        "success_last_std": float(tail["success"].std(ddof=0)),
        "success_last_per_seed": [float(x) for x in tail["success"]],
        "reward_last": float(tail["reward"].mean()),
        "reward_last_std": float(tail["reward"].std(ddof=0)),
        "aggregation_events": int(fed_events.iloc[0]) if len(fed_events) else 0,
        "communication": comm,
        "params_per_agent": n_params,
        "bytes_per_fed_round": bpr,
        "fed_bytes_total": (int(fed_events.iloc[0]) if len(fed_events) else 0) * bpr,  # per seed
    }


def save_params(path: Path, states) -> None:
    a = jax.device_get(states.agents)
    flat = {}
    for name in ("actor", "critic"):
        for kp, leaf in jax.tree_util.tree_flatten_with_path(getattr(a, name))[0]:
            flat[name + "/" + "/".join(str(getattr(k, "key", k)) for k in kp)] = np.asarray(leaf)
    atomic_write(path, lambda p: np.savez(open(p, "wb"), **flat))


class DivergenceError(RuntimeError):
    """NaN or Inf in losses or parameters; the message names episode, seed and robot."""


class Interrupted(RuntimeError):
    """Ctrl-C: a checkpoint was saved; the message says how to resume."""


def check_finite(m: dict, first_episode: int, cfg: Config, trainer: Trainer) -> None:
    """Raise DivergenceError at the first non-finite loss, reward or parameter."""
    checks = [("critic loss", m["critic_loss"], True), ("actor loss", m["actor_loss"], True),
              ("parameters", m["params_finite"], True), ("reward", m["reward"], False)]
    for name, x, per_net in checks:
        bad = ~np.asarray(x, bool) if x.dtype == bool else ~np.isfinite(x)
        if bad.any():
            s, e, k = (int(v[0]) for v in np.nonzero(bad))
            who = f"network {k} (robot {k})" if per_net and trainer.n_nets > 1 else (
                "the shared network" if per_net else f"robot {k}")
            raise DivergenceError(
                f"NaN/Inf in the {name} at episode {first_episode + e}, seed {cfg.run.seed + s}, {who}"
            )


def train(cfg: Config, out: str | Path, progress: bool = True, hp: HParams | None = None,
          resume: bool = False, mesh=None) -> dict:
    """Train `cfg.run.seeds` seeds in one program; write the run directory; return the summary.

    Checkpoints every `run.checkpoint_every` episodes and at the end; `resume=True` continues
    from the latest one. Ctrl-C finishes the current chunk, saves and raises `Interrupted`.
    `mesh` (`fedjax_nav.parallel.make_mesh`): spread the clients or seeds over its devices, in
    this process or, after `parallel.initialize_distributed`, over every process (each process
    runs this same call; only process 0 writes files).
    """
    import signal

    from tqdm.auto import tqdm

    from fedjax_nav import parallel
    from fedjax_nav.checkpoint import Checkpointer

    out = Path(out)
    writer = parallel.is_writer()
    write = atomic_write if writer else (lambda path, fn: None)
    if writer:
        out.mkdir(parents=True, exist_ok=True)
    trainer = Trainer(cfg)
    hp = hparams_from_config(cfg) if hp is None else hp
    seeds = jnp.arange(cfg.run.seeds) + cfg.run.seed
    states = trainer.init_seeds(seeds, hp, mesh=mesh)
    ckpt = Checkpointer(out, keep=cfg.run.keep_checkpoints, process=parallel.checkpoint_process(mesh))
    K, metrics, start = cfg.run.chunk_episodes, None, 0
    if resume:
        restored, metrics = ckpt.restore(parallel.checkpoint_template(states, mesh))
        states = parallel.from_checkpoint(restored, states, mesh)
        start = int(ckpt.latest())
        all_df = metrics_frame(metrics, cfg, trainer)  # also when the run had already finished
        write(out / "metrics.csv", lambda p: all_df.to_csv(p, index=False))
    elif ckpt.latest() is not None:
        raise FileExistsError(f"{out}: already holds checkpoints; resume it with --resume {out} or pick another --out")
    write(out / "config.yaml", lambda p: save_config(cfg, p))
    chunk = trainer.compiled_chunk(mesh=mesh, states=states, hp=hp)

    interrupted = []
    old_handler = signal.getsignal(signal.SIGINT)

    def on_sigint(signum, frame):
        if interrupted:  # second Ctrl-C: stop now
            signal.signal(signal.SIGINT, old_handler)
            raise KeyboardInterrupt
        interrupted.append(True)

    signal.signal(signal.SIGINT, on_sigint)
    t0, t_compile, ckpt_s = time.time(), None, 0.0
    bar = tqdm(total=cfg.run.episodes, initial=start, desc=f"{cfg.method} x{cfg.run.seeds} seeds", unit="ep",
               disable=not (progress and writer))
    try:
        for first in range(start, cfg.run.episodes, K):
            tc = time.time()
            states, m = chunk(states, hp, jnp.int32(first))
            m = jax.device_get(m)
            if t_compile is None:
                t_compile = time.time() - tc
            check_finite(m, first, cfg, trainer)
            metrics = m if metrics is None else {k: np.concatenate([metrics[k], m[k]], axis=1) for k in m}
            all_df = metrics_frame(metrics, cfg, trainer)
            write(out / "metrics.csv", lambda p: all_df.to_csv(p, index=False))
            done = first + K
            last = all_df[all_df.episode == done - 1]
            bar.set_postfix(success=f"{last.reached_goal.mean():.2f}", reward=f"{last.reward.mean():.3f}")
            bar.update(K)
            every = cfg.run.checkpoint_every
            if (every and done % every == 0) or done == cfg.run.episodes or interrupted:
                tk = time.time()
                view = parallel.checkpoint_view(states, mesh)  # a copy: states get donated next
                if writer:
                    ckpt.save(done, view, metrics)
                ckpt_s += time.time() - tk
            if interrupted and done < cfg.run.episodes:
                ckpt.wait()
                raise Interrupted(f"interrupted after episode {done}; checkpoint saved. Resume with: "
                                  f"fedjax-nav train --resume {out}")
    finally:
        bar.close()
        signal.signal(signal.SIGINT, old_handler)
        tk = time.time()
        ckpt.close()
        ckpt_s += time.time() - tk
    wall = time.time() - t0
    summary = summarize(all_df, cfg, trainer)
    summary.update({"wall_s": wall, "first_chunk_s_incl_compile": t_compile, "checkpoint_s": ckpt_s,
                    "resumed_from_episode": start, "jax_backend": jax.default_backend()})
    if mesh is not None:
        summary.update({"devices": int(mesh.size), "shard": ",".join(mesh.axis_names),
                        "processes": jax.process_count()})
    final = states if mesh is None else parallel.checkpoint_view(states, mesh)  # every process joins the gather
    if not writer:
        return summary
    atomic_write(out / "summary.json", lambda p: Path(p).write_text(json.dumps(summary, indent=1)))
    save_params(out / "params.npz", final)
    from fedjax_nav.analysis.plots import learning_curves

    learning_curves(all_df, out / "learning_curves.png", title=f"{cfg.method}, {cfg.run.seeds} seeds")
    return summary
