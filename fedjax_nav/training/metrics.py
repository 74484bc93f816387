"""A run's numbers on the host: the metrics table (one row per episode x seed x robot), the
summary (success over the last episodes, communication), and the NaN / divergence checks that
stop a run."""

from __future__ import annotations

from dataclasses import dataclass

import jax
import numpy as np
import pandas as pd

from fedjax_nav.config import Config, get
from fedjax_nav.federated.comm import bytes_per_round, communication
from fedjax_nav.learner_table import Bound
from fedjax_nav.methods import Method
from fedjax_nav.rundir import goal_share, success_last_per_seed


@dataclass(frozen=True, eq=False)
class Facts:
    """What the host's tables need of a run, fixed when it is built (`Trainer.facts()`)."""

    method: Method  # its methods row: whether it federates, whether rewards travel (communication)
    n_real: int  # clients without the ones padded in for a mesh
    n_nets: int  # networks (1 for a shared-network method)
    num_params: int  # parameters one client sends per round (the learner's shared fields)
    loss_names: tuple[str, ...]  # the learner's per-network metrics (critic_loss, ...)
    bounds: tuple[Bound, ...]  # the learner row's divergence bounds on them (`check_finite`)
    byzantine: np.ndarray  # bool[clients]: the Byzantine clients (fed.byzantine)


def fed_bytes_per_round(facts: Facts) -> int:
    """Bytes on the wire of one federated round (every client's parameters up, the aggregate
    down; rewards too for PW/RW), 0 for methods without a federated step."""
    if facts.method.aggregator == "none":
        return 0
    return bytes_per_round(facts.num_params, facts.n_real, facts.method.sends_rewards)


def fed_bytes_per_client(facts: Facts) -> int:
    """Bytes one participating client exchanges in a round (its parameters and reward up, the
    aggregate down), 0 for methods without a federated step."""
    if facts.method.aggregator == "none":
        return 0
    return bytes_per_round(facts.num_params, 1, facts.method.sends_rewards)


def metrics_frame(metrics: dict, cfg: Config, facts: Facts) -> pd.DataFrame:
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
            "fed_clients": np.asarray(m["fed_events"]) * facts.n_real * (facts.method.aggregator != "none"),
            "fed_skipped": np.zeros_like(m["fed_events"]),
        }
    S, E, N = m["reward"].shape
    ep, seed, robot = np.meshgrid(np.arange(E), np.arange(S) + cfg.run.seed, np.arange(N), indexing="ij")
    net = np.zeros(N, int) if facts.n_nets == 1 else np.arange(N)
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
            # the learner's losses, per network (DDPG/TD3: critic_loss, actor_loss, q; docs/learners.md)
            **{name: per_net(m[name]).ravel() for name in facts.loss_names},
            "fed_events": per_seed(m["fed_events"]).ravel(),
            "fed_bytes": per_seed(m["fed_clients"]).ravel() * fed_bytes_per_client(facts),
            "fed_clients": per_seed(m["fed_clients"]).ravel(),
            "fed_skipped": per_seed(m["fed_skipped"]).ravel(),
            "byzantine": facts.byzantine[robot.ravel()].astype(int),
            "epsilon": per_seed(m["epsilon"]).ravel(),
        }
    )
    if "eval_success" in m:  # run.eval_every: the robot's network on the held-out probe, NaN between
        df["eval_success"] = per_net(m["eval_success"]).ravel()
    # per robot: env.room_sampling learnability (training/rooms.py); env.shared_rooms (env/shared.py)
    for name in ("room_p", "fresh_rooms", "robot_collisions"):
        if name in m:
            df[name] = tr(m[name]).ravel()
    return df


def summarize(df: pd.DataFrame, cfg: Config, facts: Facts, last: int = 25) -> dict:
    """Success proportion and reward over the last `last` episodes: mean and std over seeds."""
    per_ep = df.groupby(["seed", "episode"]).agg(success=("reached_goal", "mean"), reward=("reward", "mean"))
    E = int(df["episode"].max()) + 1
    tail = per_ep[per_ep.index.get_level_values("episode") >= E - last].groupby("seed").mean()
    honest_df = df[df["byzantine"] == 0] if "byzantine" in df else df
    honest = success_last_per_seed(honest_df, last)
    per_seed_first = df.groupby(["seed", "episode"]).first().groupby("seed")
    sent = per_seed_first["fed_bytes"].sum() if "fed_bytes" in df else None
    skipped = per_seed_first["fed_skipped"].sum() if "fed_skipped" in df else None
    fed_events = df.groupby(["seed", "episode"])["fed_events"].first().groupby("seed").sum()
    comm = communication(
        facts.method,
        cfg.run.episodes,
        cfg.env.episode_length,
        cfg.offpolicy.train_every,
        cfg.offpolicy.batch_size,
        cfg.fed.period_unit,
        cfg.fed.period,
    )
    n_params = facts.num_params
    bpr = fed_bytes_per_round(facts)
    return {
        "method": cfg.method,
        "episodes_done": E,
        "seeds": int(df["seed"].nunique()),
        "last_episodes": min(last, E),
        "success_last": float(tail["success"].mean()),
        "success_last_std": float(tail["success"].std(ddof=0)),
        "success_last_per_seed": [float(x) for x in tail["success"]],
        # all seeds: goals / ended attempts (rundir.goal_share); null when no attempt ended
        "goal_share_last": None if np.isnan(share := goal_share(df, last)) else share,
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


class DivergenceError(RuntimeError):
    """NaN or Inf in losses or parameters, or a divergence bound of the learner's row crossed
    (learner_table.Bound: run.max_abs_q, run.max_critic_loss, ppo.max_approx_kl, ...); the message
    names the quantity, episode, seed and robot. `episode`: the first bad episode (the episodes
    before it are good)."""

    def __init__(self, msg: str, episode: int | None = None):
        super().__init__(msg)
        self.episode = episode


class Interrupted(RuntimeError):
    """Ctrl-C: a checkpoint was saved; the message says how to resume."""


def check_finite(m: dict, first_episode: int, cfg: Config, facts: Facts) -> None:
    """Raise DivergenceError at the first episode with a non-finite learner metric, reward or
    parameter, or with a metric beyond one of the learner's bounds (`facts.bounds`, each read from
    its config field; 0 = off) (host-side, after each chunk; leaves [seeds, episodes, nets or
    robots])."""
    said = {b.metric: b.said for b in facts.bounds}
    checks = [
        (f"NaN/Inf in {said.get(name, name)}", ~np.isfinite(np.asarray(m[name])), None, True)
        for name in facts.loss_names
    ]
    checks += [
        ("NaN/Inf in the parameters", ~np.asarray(m["params_finite"], bool), None, True),
        ("NaN/Inf in the reward", ~np.isfinite(m["reward"]), None, False),
    ]
    for b in facts.bounds:
        limit = get(cfg, b.field)
        if limit > 0:
            x = np.asarray(m[b.metric])
            x = np.abs(x) if b.absolute else x
            checks.append((f"{b.said} reached {{:.3g}}, above {b.field} = {limit:g},", x > limit, x, True))
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
        if per_net and facts.n_nets > 1
        else ("the shared network" if per_net else f"robot {k}")
    )
    raise DivergenceError(f"{name} at episode {first_episode + e}, seed {cfg.run.seed + s}, {who}", first_episode + e)
