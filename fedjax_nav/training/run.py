"""The host side of a training run: chunks of compiled episodes, progress, results on disk.

The run directory's files (config.yaml, metrics.csv, summary.json, params.npz, checkpoints/) are
written through `fedjax_nav.rundir`, atomically. The learning-curve figure is drawn by the
layer above (`fedjax_nav.analysis.plots.draw_run`, called by `fedjax-nav train`).
"""

from __future__ import annotations

import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from fedjax_nav import rundir
from fedjax_nav.config import Config
from fedjax_nav.federated.comm import bytes_per_round, communication
from fedjax_nav.training.hparams import HParams, hparams_from_config
from fedjax_nav.training.tblog import TensorBoardLog
from fedjax_nav.training.trainer import Trainer


def fed_bytes_per_round(trainer: Trainer) -> int:
    """Bytes on the wire of one federated round (every client's parameters up, the aggregate
    down; rewards too for PW/RW), 0 for methods without a federated step."""
    if trainer.method.aggregator == "none":
        return 0
    return bytes_per_round(trainer.num_params(), trainer.n_real, trainer.method.sends_rewards)


def fed_bytes_per_client(trainer: Trainer) -> int:
    """Bytes one participating client exchanges in a round (its parameters and reward up, the
    aggregate down), 0 for methods without a federated step."""
    if trainer.method.aggregator == "none":
        return 0
    return bytes_per_round(trainer.num_params(), 1, trainer.method.sends_rewards)


def metrics_frame(metrics: dict, cfg: Config, trainer: Trainer) -> pd.DataFrame:
    """Flatten the metrics of episodes 0.. (leaves [seeds, episodes, ...]) into rows
    episode x seed x robot. `fed_bytes`: bytes of the federated steps in that episode (what was
    actually sent, up and down: fed_clients x `fed_bytes_per_client`; every client of every
    round when all take part), repeated on each robot's row; `fed_clients` / `fed_skipped`:
    clients that exchanged models / rounds skipped for too few participants; `byzantine`: 1 on
    a Byzantine robot's rows (fed.byzantine)."""
    m = jax.device_get(metrics)
    if "fed_clients" not in m:  # metrics of a checkpoint written before partial participation
        m = {
            **m,
            "fed_clients": np.asarray(m["fed_events"]) * trainer.n_real * (trainer.method.aggregator != "none"),
            "fed_skipped": np.zeros_like(m["fed_events"]),
        }
    S, E, N = m["reward"].shape
    ep, seed, robot = np.meshgrid(np.arange(E), np.arange(S) + cfg.run.seed, np.arange(N), indexing="ij")
    net = np.zeros(N, int) if trainer.n_nets == 1 else np.arange(N)
    per_net = lambda x: np.transpose(x, (1, 0, 2))[:, :, net]  # noqa: E731  [E, S, N]
    per_seed = lambda x: np.broadcast_to(np.transpose(x, (1, 0))[:, :, None], (E, S, N))  # noqa: E731
    tr = lambda x: np.transpose(x, (1, 0, 2))  # noqa: E731
    df = pd.DataFrame(
        {
            "episode": ep.ravel(),
            "seed": seed.ravel(),
            "robot": robot.ravel(),
            "world": np.array(cfg.env.worlds)[robot.ravel()],
            "reward": tr(m["reward"]).ravel(),
            "goals": tr(m["goals"]).ravel(),
            "reached_goal": (tr(m["goals"]) > 0).ravel().astype(int),
            "collisions": tr(m["collisions"]).ravel(),
            "critic_loss": per_net(m["critic_loss"]).ravel(),
            "actor_loss": per_net(m["actor_loss"]).ravel(),
            "q": per_net(m["q"]).ravel(),
            "fed_events": per_seed(m["fed_events"]).ravel(),
            "fed_bytes": per_seed(m["fed_clients"]).ravel() * fed_bytes_per_client(trainer),
            "fed_clients": per_seed(m["fed_clients"]).ravel(),
            "fed_skipped": per_seed(m["fed_skipped"]).ravel(),
            "byzantine": trainer.byzantine[robot.ravel()].astype(int),
            "epsilon": per_seed(m["epsilon"]).ravel(),
        }
    )
    if "eval_success" in m:  # run.eval_every: the robot's network on the held-out probe, NaN between
        df["eval_success"] = per_net(m["eval_success"]).ravel()
    return df


def summarize(df: pd.DataFrame, cfg: Config, trainer: Trainer, last: int = 25) -> dict:
    """Success proportion and reward over the last `last` episodes: mean and std over seeds."""
    per_ep = df.groupby(["seed", "episode"]).agg(success=("reached_goal", "mean"), reward=("reward", "mean"))
    E = int(df["episode"].max()) + 1
    tail = per_ep[per_ep.index.get_level_values("episode") >= E - last].groupby("seed").mean()
    honest_df = df[df["byzantine"] == 0] if "byzantine" in df else df
    honest = honest_df[honest_df["episode"] >= E - last].groupby(["seed", "episode"])["reached_goal"].mean()
    honest = honest.groupby("seed").mean()
    per_seed_first = df.groupby(["seed", "episode"]).first().groupby("seed")
    sent = per_seed_first["fed_bytes"].sum() if "fed_bytes" in df else None
    skipped = per_seed_first["fed_skipped"].sum() if "fed_skipped" in df else None
    fed_events = df.groupby(["seed", "episode"])["fed_events"].first().groupby("seed").sum()
    comm = communication(
        trainer.method,
        cfg.run.episodes,
        cfg.env.episode_length,
        cfg.ddpg.train_every,
        cfg.ddpg.batch_size,
        cfg.fed.period_unit,
        cfg.fed.period,
    )
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
        "fed_bytes_total": (int(fed_events.iloc[0]) if len(fed_events) else 0) * bpr,  # per seed, everyone sending
        "success_last_honest": float(honest.mean()),  # clients outside fed.byzantine
        "success_last_honest_std": float(honest.std(ddof=0)),
        "success_last_honest_per_seed": [float(x) for x in honest],
        "fed_bytes_sent": float(sent.mean()) if sent is not None else 0.0,  # per seed, what was actually sent
        "fed_skipped_rounds": float(skipped.mean()) if skipped is not None else 0.0,  # per seed
    }


# Fields `train --resume RUN --allow-config-change` may change against the config fingerprinted in
# the run's checkpoint (none changes the program or the numbers of a finished episode).
RESUME_CHANGEABLE = (
    "run.episodes",
    "run.checkpoint_every",
    "run.keep_checkpoints",
    "run.max_abs_q",
    "run.max_critic_loss",
    "run.tensorboard",
)


class DivergenceError(RuntimeError):
    """NaN or Inf in losses or parameters, or a divergence bound crossed (run.max_abs_q,
    run.max_critic_loss); the message names the quantity, episode, seed and robot. `episode`: the
    first bad episode (the episodes before it are good)."""

    def __init__(self, msg: str, episode: int | None = None):
        super().__init__(msg)
        self.episode = episode


class Interrupted(RuntimeError):
    """Ctrl-C: a checkpoint was saved; the message says how to resume."""


def check_finite(m: dict, first_episode: int, cfg: Config, trainer: Trainer) -> None:
    """Raise DivergenceError at the first episode with a non-finite loss, Q estimate, reward or
    parameter, or with a mean |Q| estimate above run.max_abs_q or a critic loss above
    run.max_critic_loss (host-side, after each chunk; leaves [seeds, episodes, nets or robots])."""
    r = cfg.run
    q, loss = np.abs(np.asarray(m["q"])), np.asarray(m["critic_loss"])
    checks = [
        ("NaN/Inf in the critic loss", ~np.isfinite(loss), None, True),
        ("NaN/Inf in the actor loss", ~np.isfinite(m["actor_loss"]), None, True),
        ("NaN/Inf in the Q estimate", ~np.isfinite(q), None, True),
        ("NaN/Inf in the parameters", ~np.asarray(m["params_finite"], bool), None, True),
        ("NaN/Inf in the reward", ~np.isfinite(m["reward"]), None, False),
    ]
    if r.max_abs_q > 0:
        checks.append(
            (
                f"the mean |Q| estimate reached {{:.3g}}, above run.max_abs_q = {r.max_abs_q:g},",
                q > r.max_abs_q,
                q,
                True,
            )
        )
    if r.max_critic_loss > 0:
        checks.append(
            (
                f"the critic loss reached {{:.3g}}, above run.max_critic_loss = {r.max_critic_loss:g},",
                loss > r.max_critic_loss,
                loss,
                True,
            )
        )
    found = []
    for name, bad, values, per_net in checks:
        if bad.any():
            idx = np.argwhere(bad)  # rows (seed, episode, net or robot): the earliest episode first
            s, e, k = (int(v) for v in idx[np.lexsort((idx[:, 2], idx[:, 0], idx[:, 1]))[0]])
            found.append((e, s, k, name if values is None else name.format(values[s, e, k]), per_net))
    if not found:
        return
    e, s, k, name, per_net = min(found, key=lambda t: t[0])
    who = (
        f"network {k} (robot {k})"
        if per_net and trainer.n_nets > 1
        else ("the shared network" if per_net else f"robot {k}")
    )
    raise DivergenceError(f"{name} at episode {first_episode + e}, seed {r.seed + s}, {who}", first_episode + e)


def train(
    cfg: Config,
    out: str | Path,
    progress: bool = True,
    hp: HParams | None = None,
    resume: bool = False,
    mesh=None,
    overwrite: bool = False,
    allow_config_change: bool = False,
    memory_budget: int | None = None,
    src: str = "config",
) -> dict:
    """Train `cfg.run.seeds` seeds in one program; write the run directory; return the summary.

    Checkpoints every `run.checkpoint_every` episodes and at the end; `resume=True` continues
    from the latest one. Ctrl-C finishes the current chunk, saves and raises `Interrupted`.
    `mesh` (`fedjax_nav.training.parallel.make_mesh`): spread the clients or seeds over its devices, in
    this process or, after `parallel.initialize_distributed`, over every process (each process
    runs this same call; only process 0 writes files).

    Before allocating anything: the memory estimate against `memory_budget` (bytes; default the
    available memory; `ResourceError` naming the field), then `out` is locked (`rundir.RunLock`)
    for the whole run. A new run refuses a folder holding results unless `overwrite` (they are
    removed first); a resumed one refuses a config that differs from the one saved in the
    checkpoint, except `RESUME_CHANGEABLE` fields with `allow_config_change`.
    """
    from fedjax_nav.training import parallel
    from fedjax_nav.training.resources import check_memory

    out = Path(out)
    trainer = Trainer(cfg, pad=parallel.client_padding(mesh, cfg.num_robots))  # masked clients fill the devices
    check_memory(trainer, memory_budget, src)
    writer = parallel.is_writer()
    if not writer:
        return _train(cfg, out, trainer, progress, hp, resume, mesh, overwrite, allow_config_change, writer)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise rundir.RunDirError(f"{out}: exists and is not a directory") from None
    except OSError as e:
        raise rundir.WriteError(f"{out}: cannot create the run directory ({e.strerror or e})") from None
    with rundir.RunLock(out):
        return _train(cfg, out, trainer, progress, hp, resume, mesh, overwrite, allow_config_change, writer)


def _check_resumable(ckpt, cfg: Config, out: Path, allow_config_change: bool) -> None:
    """The config to resume with against the one fingerprinted in the latest checkpoint."""
    from fedjax_nav.config import ConfigError, diff, from_dict
    from fedjax_nav.training.checkpoint import CheckpointError, fingerprint

    step = ckpt.latest()
    saved = ckpt.saved_config(step)  # CheckpointError when there is no checkpoint
    if saved is not None:
        src = f"{ckpt.dir / str(step)}"
        try:
            changed = diff(from_dict(saved, src), cfg)
        except ConfigError:  # saved by another version of the code: compare what it holds
            now = to_dict_flat(cfg)
            changed = [k for k, v in to_dict_flat(saved).items() if k in now and now[k] != v]
        refused = [k for k in changed if not (allow_config_change and k in RESUME_CHANGEABLE)]
        if refused:
            hint = (
                f"--allow-config-change permits only {', '.join(RESUME_CHANGEABLE)}"
                if allow_config_change
                else f"restore the file, start a new run, or pass --allow-config-change (only for "
                f"{', '.join(RESUME_CHANGEABLE)})"
            )
            sha = fingerprint(saved)[:12]
            raise CheckpointError(
                f"{out / rundir.CONFIG}: differs from the config saved in {src} (sha1 {sha}) in "
                f"{', '.join(refused)}; resuming would mix two runs: {hint}"
            )
    if cfg.run.episodes < step:
        raise ConfigError(
            f"{out / rundir.CONFIG}: run.episodes ({cfg.run.episodes}) is below the {step} episodes already done"
        )


def to_dict_flat(cfg) -> dict:
    """{"ddpg.gamma": 0.9, ...} of a Config or of its to_dict mapping."""
    from fedjax_nav.config import to_dict

    d = cfg if isinstance(cfg, dict) else to_dict(cfg)
    return {
        f"{s}.{k}" if isinstance(v, dict) else s: v
        for s, sec in d.items()
        for k, v in (sec.items() if isinstance(sec, dict) else [(s, sec)])
    }


def _train(
    cfg: Config,
    out: Path,
    trainer: Trainer,
    progress: bool,
    hp: HParams | None,
    resume: bool,
    mesh,
    overwrite: bool,
    allow_config_change: bool,
    writer: bool,
) -> dict:
    import signal

    from tqdm.auto import tqdm

    from fedjax_nav.config import to_dict
    from fedjax_nav.training import parallel
    from fedjax_nav.training.checkpoint import Checkpointer

    write = rundir.atomic_write if writer else (lambda path, fn: None)
    if writer and not resume and rundir.results_in(out):  # (other processes: process 0 may have begun)
        if not overwrite:
            raise FileExistsError(
                f"{out}: already holds results ({', '.join(rundir.results_in(out))}); resume it with --resume "
                f"{out}, pick another --out, or pass --overwrite to replace them"
            )
        rundir.clear_results(out)
    ckpt = Checkpointer(out, keep=cfg.run.keep_checkpoints, process=parallel.checkpoint_process(mesh))
    if resume:
        _check_resumable(ckpt, cfg, out, allow_config_change)
    hp = hparams_from_config(cfg) if hp is None else hp
    seeds = jnp.arange(cfg.run.seeds) + cfg.run.seed
    states = trainer.init_seeds(seeds, hp, mesh=mesh)
    K, metrics, start = cfg.run.chunk_episodes, None, 0
    if resume:
        restored, metrics = ckpt.restore(parallel.checkpoint_template(states, mesh))
        states = parallel.from_checkpoint(restored, states, mesh)
        start = int(ckpt.latest())
        all_df = metrics_frame(metrics, cfg, trainer)  # also when the run had already finished
        write(out / rundir.METRICS, lambda p: all_df.to_csv(p, index=False))
    elif ckpt.latest() is not None:
        raise FileExistsError(f"{out}: already holds checkpoints; resume it with --resume {out} or pick another --out")
    if writer:
        rundir.write_config(out, cfg)
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
    bar = tqdm(
        total=cfg.run.episodes,
        initial=start,
        desc=f"{cfg.method} x{cfg.run.seeds} seeds",
        unit="ep",
        disable=not (progress and writer),
    )
    tb = TensorBoardLog(out) if cfg.run.tensorboard and writer else None
    try:
        for first in range(start, cfg.run.episodes, K):
            tc = time.time()
            states, m = chunk(states, hp, jnp.int32(first))
            m = jax.device_get(m)
            if t_compile is None:
                t_compile = time.time() - tc
            try:
                check_finite(m, first, cfg, trainer)
            except DivergenceError as err:  # keep every good episode, say what is kept
                good = err.episode - first  # episodes of this chunk before the bad one
                if good > 0:
                    m = {k: v[:, :good] for k, v in m.items()}
                    metrics = m if metrics is None else {k: np.concatenate([metrics[k], m[k]], axis=1) for k in m}
                n = 0 if metrics is None else int(metrics["reward"].shape[1])
                if n:
                    good_df = metrics_frame(metrics, cfg, trainer)
                    write(out / rundir.METRICS, lambda p, d=good_df: d.to_csv(p, index=False))
                ckpt.wait()
                step = ckpt.latest()
                kept = (
                    f"the last good checkpoint (episode {step}) is kept"
                    if step is not None
                    else "no checkpoint was saved yet (nothing to resume)"
                )
                kept += f"; metrics.csv holds episodes 0-{n - 1}" if n else "; no episode finished"
                raise DivergenceError(f"{err}; {kept}", err.episode) from None
            metrics = m if metrics is None else {k: np.concatenate([metrics[k], m[k]], axis=1) for k in m}
            all_df = metrics_frame(metrics, cfg, trainer)
            write(out / rundir.METRICS, lambda p, d=all_df: d.to_csv(p, index=False))
            done = first + K
            if tb is not None:  # live scalars of this chunk's episodes
                tb.episodes(all_df[all_df.episode >= first])
            last = all_df[all_df.episode == done - 1]
            bar.set_postfix(success=f"{last.reached_goal.mean():.2f}", reward=f"{last.reward.mean():.3f}")
            bar.update(K)
            every = cfg.run.checkpoint_every
            if (every and done % every == 0) or done == cfg.run.episodes or interrupted:
                tk = time.time()
                view = parallel.checkpoint_view(states, mesh)  # a copy: states get donated next
                if writer:
                    ckpt.save(done, view, metrics, config=to_dict(cfg))
                ckpt_s += time.time() - tk
            if interrupted and done < cfg.run.episodes:
                ckpt.wait()
                raise Interrupted(
                    f"interrupted after episode {done}; checkpoint saved. Resume with: fedjax-nav train --resume {out}"
                )
    finally:
        bar.close()
        if tb is not None:
            tb.close()
        signal.signal(signal.SIGINT, old_handler)
        tk = time.time()
        ckpt.close()
        ckpt_s += time.time() - tk
    wall = time.time() - t0
    summary = summarize(all_df, cfg, trainer)
    summary.update(
        {
            "wall_s": wall,
            "first_chunk_s_incl_compile": t_compile,
            "checkpoint_s": ckpt_s,
            "resumed_from_episode": start,
            "jax_backend": jax.default_backend(),
        }
    )
    if mesh is not None:
        summary.update(
            {"devices": int(mesh.size), "shard": ",".join(mesh.axis_names), "processes": jax.process_count()}
        )
    final = states if mesh is None else parallel.checkpoint_view(states, mesh)  # every process joins the gather
    if not writer:
        return summary
    rundir.write_json(out / rundir.SUMMARY, summary)
    rundir.write_params(
        out, jax.tree.map(lambda x: x[:, : trainer.n_real], final.agents) if trainer.pad else final.agents
    )  # without the padding clients
    return summary
