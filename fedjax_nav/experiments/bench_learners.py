"""`fedjax-nav bench train`'s rows of the learners beside the thesis's DDPG (docs/benchmarks.md):
feed-forward and recurrent PPO, SAC and TD3 with many environments per robot, the env alone at PPO's
batch (thesis rooms and procedural rooms), and brax's own PPO on this project's brax env at that batch."""

from __future__ import annotations

import functools

from fedjax_nav.experiments.bench import _train_config, bench_env, bench_train

# The other learners with many environments per robot (docs/learners.md): feed-forward PPO with
# 5 x 256 environments in procedural rooms (rollout 128 x 256 = 32768 rows per robot and update),
# SAC and TD3 with 5 x 64 (a buffer of 100k rows per robot, one gradient step per update event).
PROCEDURAL = ("env.rooms=procedural", "env.room_families=[mixture]")
# A third field True: the row is brax's algorithm (feed-forward PPO), divided by brax's steady rate.
LEARNER_ROWS = (
    ("ppo", ("env.envs_per_robot=256", *PROCEDURAL), True),
    # brax's setting exactly: one network over 1,280 environments of the thesis rooms (the brax env's)
    ("ppo", ("env.envs_per_robot=256", "method=snddpg"), True),
    ("ppo", ("env.envs_per_robot=256", "ppo.recurrent=gru", *PROCEDURAL)),
    ("sac", ("env.envs_per_robot=64", "offpolicy.buffer_size=100000", *PROCEDURAL)),
    ("td3", ("env.envs_per_robot=64", "offpolicy.buffer_size=100000", *PROCEDURAL)),
)


def ppo_config(method: str):
    """The PPO row's config (5 robots x 256 environments, procedural mixture rooms, one-episode
    chunks) with `method`: flddpg the federated fleet, snddpg one central network (brax's setting)."""
    over = ("run.chunk_episodes=1", "run.checkpoint_every=0", "env.envs_per_robot=256", f"method={method}")
    return _train_config([*over, *PROCEDURAL], "ppo")


def bench_brax_ppo(num_envs: int = 1280, rollout: int = 128, minibatches: int = 4, epochs: int = 4, updates=(2, 6)):
    """brax's own `ppo.train` on this project's brax env (the thesis's training rooms, one per
    environment in turn), with the batch of the PPO row: `num_envs` environments, `rollout`-step
    unrolls, `epochs` x `minibatches`, the same 64x2 tanh networks. brax's `training/sps` of an
    epoch includes a fixed cost per epoch (about 6 s here, whatever the epoch's length), so it is
    run with two epoch lengths (`updates` training steps per epoch) and the steady rate is the
    difference of steps over the difference of epoch times; brax's own figure for the longer epoch
    is reported beside it."""
    from brax import envs as brax_envs
    from brax.training.agents.ppo import networks as ppo_networks
    from brax.training.agents.ppo import train as ppo
    from flax import linen

    from fedjax_nav import worlds
    from fedjax_nav.env import brax_env  # noqa: F401  (registers the env)

    env = brax_envs.get_environment(brax_env.ENV_NAME, worlds=list(worlds.THESIS_TRAIN))
    per_update = num_envs * rollout
    net = functools.partial(
        ppo_networks.make_ppo_networks,
        policy_hidden_layer_sizes=(64, 64),
        value_hidden_layer_sizes=(64, 64),
        activation=linen.tanh,
    )
    epoch_s, sps = [], []
    for u in updates:
        walls: list[float] = []

        def progress(step, metrics, walls=walls):
            if "training/walltime" in metrics:
                walls.append(float(metrics["training/walltime"]))
                sps.append(float(metrics["training/sps"]))

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
        epoch_s.append(walls[-1] - walls[-2])  # the second epoch: compiled in the first
    steady = per_update * (updates[1] - updates[0]) / (epoch_s[1] - epoch_s[0])
    return [
        {
            "bench": "brax_ppo",
            "num_envs": num_envs,
            "rollout": rollout,
            "agent_steps_per_s": steady,
            "brax_sps": sps[-1],
            "epoch_fixed_s": epoch_s[0] - per_update * updates[0] / steady,
        }
    ]


def bench_learners(
    overrides=(), rows=LEARNER_ROWS, env_batch: int = 1280, ceiling: float | None = None, brax: bool = True
) -> list[dict]:
    """`bench train` rows of the learners beside DDPG, and at PPO's batch the env alone (in the
    thesis rooms and in the procedural rooms the learners train in) and brax's PPO."""
    out = []
    for learner, extra, *vs_brax in rows:
        got = bench_train(seeds=(1,), overrides=(*extra, *overrides), learner=learner, ceiling=ceiling)
        out += [r | {"vs_brax": bool(vs_brax and vs_brax[0])} for r in got]
    if env_batch:
        out += bench_env(batches=(env_batch,), steps=200)
        out += bench_env(batches=(env_batch,), steps=200, family="mixture")
    if env_batch and brax:
        out += bench_brax_ppo(num_envs=env_batch, updates=(2, 6) if env_batch >= 1024 else (4, 12))
        out += brax_ratios(out)
    return out


def brax_ratios(rows: list[dict]) -> list[dict]:
    """Each row of brax's algorithm (`vs_brax`) against brax's steady rate of the same run (the
    last brax row)."""
    steady = [r for r in rows if r["bench"] == "brax_ppo"][-1]["agent_steps_per_s"]
    return [
        {
            "bench": "ratio",
            "what": f"PPO {r['method']} ({r['robots']} x {r['envs_per_robot']} environments, "
            f"{'thesis' if r['rooms'] == 'fixed' else 'procedural'} rooms) / brax's steady rate",
            "value": r["agent_steps_per_s"] / steady,
        }
        for r in rows
        if r["bench"] == "train" and r.get("vs_brax")
    ]
