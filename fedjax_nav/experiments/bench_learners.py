"""`fedjax-nav bench train`'s rows of the learners beside the thesis's DDPG (docs/benchmarks.md):
feed-forward and recurrent PPO, SAC and TD3 with many environments per robot, the env alone at PPO's
batch (thesis rooms and procedural rooms), and brax's own PPO and SAC on this project's brax env at
their rows' batches."""

from __future__ import annotations

import functools

from fedjax_nav.experiments.bench import _train_config, bench_env, bench_train

# The other learners with many environments per robot (docs/learners.md): feed-forward PPO with
# 5 x 256 environments in procedural rooms (rollout 128 x 256 = 32768 rows per robot and update),
# SAC and TD3 with 5 x 64 (a buffer of 100k rows per robot, one gradient step per update event).
PROCEDURAL = ("env.rooms=procedural", "env.room_families=[mixture]")
# brax's SAC setting (bench_brax_sac): one gradient step of 512 rows per environment step of 64
# environments, gamma 0.99, in the thesis rooms (the brax env's).
SAC_AS_BRAX = (
    "env.envs_per_robot=64",
    "offpolicy.buffer_size=100000",
    "offpolicy.train_every=1",
    "offpolicy.gamma=0.99",
)
# A third field names brax's algorithm the row runs ("ppo", "sac"): the row is divided by brax's
# steady rate of that algorithm in the same run (brax_ratios).
LEARNER_ROWS = (
    ("ppo", ("env.envs_per_robot=256", *PROCEDURAL), "ppo"),
    # brax's setting exactly: one network over 1,280 environments of the thesis rooms (the brax env's)
    ("ppo", ("env.envs_per_robot=256", "method=snddpg"), "ppo"),
    ("ppo", ("env.envs_per_robot=256", "ppo.recurrent=gru", *PROCEDURAL)),
    ("sac", ("env.envs_per_robot=64", "offpolicy.buffer_size=100000", *PROCEDURAL)),
    ("td3", ("env.envs_per_robot=64", "offpolicy.buffer_size=100000", *PROCEDURAL)),
    # brax's SAC setting exactly (one robot: one network over 64 environments), and the fleet of 5 x 64
    ("sac", (*SAC_AS_BRAX, "env.worlds=[train-0]", "method=iddpg"), "sac"),
    ("sac", SAC_AS_BRAX, "sac"),
)


def ppo_config(method: str):
    """The PPO row's config (5 robots x 256 environments, procedural mixture rooms, one-episode
    chunks) with `method`: flddpg the federated fleet, snddpg one central network (brax's setting)."""
    over = ("run.chunk_episodes=1", "run.checkpoint_every=0", "env.envs_per_robot=256", f"method={method}")
    return _train_config([*over, *PROCEDURAL], "ppo")


def _brax_env():
    """This project's brax env in the thesis's training rooms (one per environment in turn)."""
    from brax import envs as brax_envs

    from fedjax_nav import worlds
    from fedjax_nav.env import brax_env  # noqa: F401  (registers the env)

    return brax_envs.get_environment(brax_env.ENV_NAME, worlds=list(worlds.THESIS_TRAIN))


def _steady_rate(train, per_update: int, updates) -> dict:
    """brax's steady rate of a trainer whose epochs also pay a fixed cost: `train(u, progress_fn)`
    runs two epochs of u training steps of `per_update` agent-steps each, for each u of `updates`;
    the second epoch of each (compiled in the first) is timed by brax's `training/walltime`, and
    the steady rate is the difference of steps over the difference of those epochs' times.
    Returns it with brax's own `training/sps` of the last epoch and the fixed cost per epoch."""
    epoch_s, sps = [], []
    for u in updates:
        walls: list[float] = []

        def progress(step, metrics, walls=walls):
            if "training/walltime" in metrics:
                walls.append(float(metrics["training/walltime"]))
                sps.append(float(metrics["training/sps"]))

        train(u, progress)
        epoch_s.append(walls[-1] - walls[-2])
    steady = per_update * (updates[1] - updates[0]) / (epoch_s[1] - epoch_s[0])
    return {
        "agent_steps_per_s": steady,
        "brax_sps": sps[-1],
        "epoch_fixed_s": epoch_s[0] - per_update * updates[0] / steady,
    }


def bench_brax_ppo(num_envs: int = 1280, rollout: int = 128, minibatches: int = 4, epochs: int = 4, updates=(2, 16)):
    """brax's own `ppo.train` on this project's brax env (the thesis's training rooms, one per
    environment in turn), with the batch of the PPO row: `num_envs` environments, `rollout`-step
    unrolls, `epochs` x `minibatches`, the same 64x2 tanh networks. brax's `training/sps` of an
    epoch includes a fixed cost per epoch (about 5-6 s here, whatever the epoch's length), so it is
    run with two epoch lengths (`updates` training steps per epoch, `_steady_rate`); brax's own
    figure for the longer epoch is reported beside it."""
    from brax.training.agents.ppo import networks as ppo_networks
    from brax.training.agents.ppo import train as ppo
    from flax import linen

    env, per_update = _brax_env(), num_envs * rollout
    net = functools.partial(
        ppo_networks.make_ppo_networks,
        policy_hidden_layer_sizes=(64, 64),
        value_hidden_layer_sizes=(64, 64),
        activation=linen.tanh,
    )

    def train(u, progress):
        ppo.train(
            env,
            num_timesteps=per_update * u * 2,  # two epochs of u training steps (num_evals - 1)
            num_evals=3,
            episode_length=1024,
            num_envs=num_envs,
            unroll_length=rollout,
            batch_size=num_envs // minibatches,
            num_minibatches=minibatches,
            num_updates_per_batch=epochs,
            normalize_observations=False,
            run_evals=False,
            num_resets_per_eval=0,
            network_factory=net,
            progress_fn=progress,
        )

    return [{"bench": "brax_ppo", "num_envs": num_envs, "rollout": rollout, **_steady_rate(train, per_update, updates)}]


def bench_brax_sac(
    num_envs: int = 64, batch: int = 512, hidden=(64, 64, 64), buffer: int = 100_000, updates=(64, 192)
) -> list[dict]:
    """brax's own `sac.train` on this project's brax env (the thesis's training rooms), with one
    network of the SAC row: `num_envs` environments, one gradient step of `batch` rows per
    environment step (the row's update-to-data ratio), the same relu networks (`hidden`: the
    row's width x depth), gamma 0.99, lr 1e-3, tau 0.005, a `buffer`-row replay. As for PPO the
    steady rate is two epoch lengths differenced (`_steady_rate`); brax also evaluates after each
    epoch, outside its timed epoch (one evaluation environment here)."""
    from brax.training.agents.sac import networks as sac_networks
    from brax.training.agents.sac import train as sac

    env = _brax_env()
    net = functools.partial(sac_networks.make_sac_networks, hidden_layer_sizes=tuple(hidden))

    def train(u, progress):
        sac.train(
            env,
            num_timesteps=batch + num_envs * u * 2,  # the prefill, then two epochs of u training steps
            num_evals=3,
            episode_length=1024,
            num_envs=num_envs,
            num_eval_envs=1,
            learning_rate=1e-3,
            discounting=0.99,
            batch_size=batch,
            min_replay_size=batch,
            max_replay_size=buffer,
            grad_updates_per_step=1,
            tau=0.005,
            network_factory=net,
            progress_fn=progress,
        )

    return [{"bench": "brax_sac", "num_envs": num_envs, "batch": batch, **_steady_rate(train, num_envs, updates)}]


def bench_learners(
    overrides=(), rows=LEARNER_ROWS, env_batch: int = 1280, ceiling: float | None = None, brax: bool = True
) -> list[dict]:
    """`bench train` rows of the learners beside DDPG, and at PPO's batch the env alone (in the
    thesis rooms and in the procedural rooms the learners train in), brax's PPO, and brax's SAC
    where a row runs its setting."""
    out = []
    for learner, extra, *vs_brax in rows:
        got = bench_train(seeds=(1,), overrides=(*extra, *overrides), learner=learner, ceiling=ceiling)
        out += [r | {"vs_brax": vs_brax[0] if vs_brax else None} for r in got]
    if env_batch:
        out += bench_env(batches=(env_batch,), steps=200)
        out += bench_env(batches=(env_batch,), steps=200, family="mixture")
    if env_batch and brax:
        # brax's trainer of each algorithm some row runs (LEARNER_ROWS' third field), once
        for algo in dict.fromkeys(r["vs_brax"] for r in out if r.get("vs_brax")):
            out += BRAX_TRAINERS[algo](env_batch)
        out += brax_ratios(out)
    return out


# brax's own trainer of each algorithm a row may be compared with, given the env batch of the PPO rows
BRAX_TRAINERS = {
    "ppo": lambda env_batch: bench_brax_ppo(num_envs=env_batch, updates=(2, 16) if env_batch >= 1024 else (4, 12)),
    "sac": lambda env_batch: bench_brax_sac(),  # its own batch: one network x 64 environments (SAC_AS_BRAX)
}


def brax_ratios(rows: list[dict]) -> list[dict]:
    """Each row of one of brax's algorithms (`vs_brax`: "ppo", "sac") against brax's steady rate of
    that algorithm in the same run (its last `brax_<algorithm>` row)."""
    steady = {r["bench"].removeprefix("brax_"): r["agent_steps_per_s"] for r in rows if r["bench"].startswith("brax_")}
    return [
        {
            "bench": "ratio",
            "what": f"{algo.upper()} {r['method']} ({r['robots']} x {r['envs_per_robot']} environments, "
            f"{'thesis' if r['rooms'] == 'fixed' else 'procedural'} rooms) / brax's steady rate",
            "value": r["agent_steps_per_s"] / steady[algo],
        }
        for r in rows
        if r["bench"] == "train" and (algo := r.get("vs_brax")) in steady
    ]
