"""The config's schema: the sections' frozen dataclasses, their fields (default, type, range or
choices, `traced`), and the dotted-name helpers. `fedjax_nav.config` re-exports all of it; the
modules of the package (io, validate, traced, envs, sweepfile) import it from here, so that the
package's `__init__` imports them and none of them imports it back (tests/test_layers.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from fedjax_nav.config.env_schema import ROOM_FAMILIES, ROOM_SOURCES, EnvConfig  # noqa: F401  (the `env` section)
from fedjax_nav.config.fields import ConfigError, _f  # noqa: F401  (re-exported: the package's error)
from fedjax_nav.learner_table import NAMES as LEARNERS  # the `learner` choices: the learner table's names
from fedjax_nav.methods import METHODS as _METHOD_TABLE
from fedjax_nav.robots import ROBOT_MODELS, RobotConfig, robot_problem  # noqa: F401  (the `robot` section)

METHODS = tuple(_METHOD_TABLE)
# fed.aggregator and fed.attack choices (kept equal to fedjax_nav.federated's tables by
# tests/test_robust_federation.py; config does not import jax).
ROBUST_AGGREGATORS = ("method", "mean", "median", "trimmed_mean", "krum", "geometric_median", "norm_bounded")
ATTACKS = ("none", "noise", "scale", "sign_flip", "zeros", "stale")


@dataclass(frozen=True)
class OffPolicyConfig:
    """The off-policy settings that the replay learners (ddpg, td3, sac) share: the networks (hidden,
    depth, activation), the replay buffer (buffer_size, buffer_alloc, batch_size, gradient_steps),
    gamma, n_step, lr (actor and critic), train_every and the random warm-up. Every field was the
    ddpg section's before this section held it; `ddpg.<field>` still reads as `offpolicy.<field>`
    (LEGACY_ALIASES; docs/learners.md, "Configuration")."""

    hidden: int = _f(64, lo=1, hi=65536, doc="hidden width (static)")
    depth: int = _f(3, lo=1, hi=16, doc="hidden layers (static)")
    activation: str = _f("relu", choices=("relu", "tanh", "elu", "gelu", "silu"), doc="(static)")
    buffer_size: int = _f(
        10000, lo=1, hi=100_000_000, traced=True, doc="replay capacity per buffer (traced up to buffer_alloc)"
    )
    buffer_alloc: int = _f(0, lo=0, hi=100_000_000, doc="allocated rows (static); 0 = buffer_size. Sweeps set the max")
    batch_size: int = _f(512, lo=1, hi=1_000_000, doc="(static)")
    gamma: float = _f(0.9, lo=0.0, hi=1.0, traced=True, doc="discount")
    lr: float = _f(1e-3, lo=0.0, hi=1.0, traced=True, doc="Adam learning rate (actor and critic)")
    train_every: int = _f(
        5, lo=1, hi=2**31 - 1, traced=True, doc="T_train: steps between gradient steps (an int32: < 2^31)"
    )
    random_steps: int = _f(
        0, lo=0, hi=2**31 - 1, traced=True, doc="off-policy warm-up: steps of uniform random actions, per environment"
    )
    gradient_steps: int = _f(
        1,
        lo=1,
        hi=4096,
        doc="gradient steps per update event, each on its own batch (static): the update-to-data ratio "
        "is gradient_steps / (train_every x rows per step); raise it with env.envs_per_robot",
    )
    n_step: int = _f(
        1,
        lo=1,
        hi=1000,
        doc="n-step returns of ddpg, td3, sac (static): the target sums n rewards of one environment "
        "and bootstraps with gamma^n, cut at an episode's end; 1 = the 1-step target",
    )


@dataclass(frozen=True)
class DDPGConfig:
    """DDPG's own settings: the target mix and period, and its epsilon-greedy exploration; the rest
    are the offpolicy section's (OffPolicyConfig)."""

    rho: float = _f(1.0, lo=0.0, hi=1.0, traced=True, doc="target mix: targ <- (1-rho) targ + rho net")
    target_every: int = _f(
        5, lo=1, hi=2**31 - 1, traced=True, doc="T_target: steps between target updates (an int32: < 2^31)"
    )
    epsilon_start: float = _f(0.9, lo=0.0, hi=1.0, traced=True, doc="exploration probability at step 0")
    epsilon_decay: float = _f(0.99997, lo=0.0, hi=1.0, traced=True, doc="epsilon *= decay every step")


@dataclass(frozen=True)
class TD3Config:
    """TD3's own settings (Fujimoto et al. 2018); the rest are the offpolicy section's (OffPolicyConfig)."""

    tau: float = _f(0.005, lo=0.0, hi=1.0, traced=True, doc="target mix on every actor step")
    policy_delay: int = _f(2, lo=1, hi=2**31 - 1, traced=True, doc="gradient steps per actor step (an int32)")
    policy_noise: float = _f(0.2, lo=0.0, hi=100.0, traced=True, doc="target smoothing std, box half-widths")
    noise_clip: float = _f(0.5, lo=0.0, hi=100.0, traced=True, doc="|target smoothing noise| bound, half-widths")
    expl_noise: float = _f(0.1, lo=0.0, hi=100.0, traced=True, doc="exploration noise std, box half-widths")


@dataclass(frozen=True)
class SACConfig:
    """SAC's own settings (Haarnoja et al. 2018); the rest are the offpolicy section's (OffPolicyConfig)."""

    tau: float = _f(0.005, lo=0.0, hi=1.0, traced=True, doc="critic target mix on every gradient step")
    alpha_lr: float = _f(3e-4, lo=0.0, hi=1.0, traced=True, doc="Adam learning rate of the temperature")
    init_alpha: float = _f(1.0, lo=1e-8, hi=1e6, traced=True, doc="initial temperature")
    target_entropy: float = _f(-2.0, lo=-1e3, hi=1e3, traced=True, doc="in box units; -2 = -action size")


@dataclass(frozen=True)
class PPOConfig:
    """PPO's settings (Schulman et al. 2017; docs/learners.md). Its rollout is [rollout, envs_per_robot]
    per robot, updated every `rollout` steps."""

    hidden: int = _f(64, lo=1, hi=65536, doc="hidden width (static)")
    depth: int = _f(2, lo=1, hi=16, doc="hidden layers (static)")
    activation: str = _f("tanh", choices=("relu", "tanh", "elu", "gelu", "silu"), doc="(static)")
    recurrent: str = _f("none", choices=("none", "gru"), doc="a GRU in the policy and the value (static)")
    gru_hidden: int = _f(64, lo=1, hi=65536, doc="GRU state size with recurrent: gru (static)")
    rollout: int = _f(128, lo=1, hi=1_000_000, doc="T_roll, steps per rollout and update (static)")
    epochs: int = _f(4, lo=1, hi=1000, doc="passes over each rollout (static)")
    minibatches: int = _f(
        4, lo=1, hi=1_000_000, doc="per epoch; divides rollout x envs_per_robot (a GRU: envs_per_robot) (static)"
    )
    lr: float = _f(3e-4, lo=0.0, hi=1.0, traced=True, doc="Adam learning rate")
    gamma: float = _f(0.99, lo=0.0, hi=1.0, traced=True, doc="discount")
    gae_lambda: float = _f(0.95, lo=0.0, hi=1.0, traced=True, doc="GAE lambda")
    clip_eps: float = _f(0.2, lo=0.0, hi=10.0, traced=True, doc="ratio clip")
    value_clip: float = _f(0.0, lo=0.0, hi=1e6, traced=True, doc="value-change clip; 0 = not clipped")
    vf_coef: float = _f(0.5, lo=0.0, hi=1e3, traced=True, doc="value loss weight")
    ent_coef: float = _f(0.0, lo=0.0, hi=1e3, traced=True, doc="entropy bonus weight")
    max_grad_norm: float = _f(0.5, lo=0.0, hi=1e6, traced=True, doc="global gradient norm clip")
    init_log_std: float = _f(0.0, lo=-20.0, hi=5.0, traced=True, doc="initial log-std of the raw action")
    normalize_obs: bool = _f(
        False,
        doc="normalise observations with running statistics, updated from each rollout and part of the "
        "actor: federated with it, evaluated and exported with it (static)",
    )
    # Divergence guard (docs/reliability.md; the value loss answers to run.max_critic_loss): healthy
    # runs reach approx_kl 0.03 and |entropy| 7.6 (its true value is at most log 2 on the box);
    # ppo.lr = 1 (the thesis preset) gives approx_kl 4.7e7 and |entropy| 1.4e3 or more in episode 0.
    max_approx_kl: float = _f(1e3, lo=0.0, doc="stop when an update's mean approx_kl exceeds this (0 = off)")
    max_abs_entropy: float = _f(1e3, lo=0.0, doc="stop when the |entropy| estimate exceeds this (0 = off)")


@dataclass(frozen=True)
class FedConfig:
    tau: float = _f(0.5, lo=0.0, hi=1.0, traced=True, doc="soft mix: 0 = no sharing, 1 = hard FedAvg")
    beta: float = _f(0.5, lo=0.0, hi=100.0, traced=True, doc="PW/RW reward scale, GS global step")
    period_unit: str = _f("episodes", choices=("episodes", "steps"), doc="E_update or T_update (static)")
    period: int = _f(
        2, lo=1, hi=2**31 - 1, traced=True, doc="E_update (episodes) or T_update (steps) (an int32: < 2^31)"
    )
    include_targets: bool = _f(False, doc="also average target networks (static)")
    # Robust federation (docs/robustness.md). The defaults give today's runs bit for bit.
    participation: float = _f(
        1.0,
        lo=0.0,
        hi=1.0,
        traced=True,
        doc="probability that a client takes part in a federated round (1 = every round)",
    )
    min_clients: int = _f(
        1,
        lo=0,
        hi=2**31 - 1,
        traced=True,
        doc="a round with fewer participants is skipped (and counted in fed_skipped) (an int32: < 2^31)",
    )
    aggregator: str = _f(
        "method",
        choices=ROBUST_AGGREGATORS,
        doc="the server's rule: 'method' = the method's own, or a robust center (static)",
    )
    trim: float = _f(0.2, lo=0.0, hi=0.5, traced=True, doc="trimmed_mean: fraction dropped at each end")
    krum_f: int = _f(
        1, lo=0, hi=2**31 - 1, traced=True, doc="krum: Byzantine clients tolerated, f (2f + 2 <= robots; an int32)"
    )
    krum_m: int = _f(
        1, lo=1, hi=2**31 - 1, traced=True, doc="krum: clients averaged (1 = Krum, > 1 = Multi-Krum; an int32)"
    )
    max_norm: float = _f(
        1.0,
        lo=0.0,
        hi=1e6,
        traced=True,
        doc="norm_bounded: L2 bound of an update relative to the previous global model, at most 1e6",
    )
    byzantine: int = _f(0, lo=0, doc="how many clients are Byzantine: the last ones (static)")
    attack: str = _f("none", choices=ATTACKS, doc="what Byzantine clients send (static; docs/robustness.md)")
    attack_scale: float = _f(
        -10.0,
        lo=-1e6,
        hi=1e6,
        traced=True,
        doc="scale attack: factor on the update; noise attack: std |attack_scale|; within +-1e6",
    )


@dataclass(frozen=True)
class RunConfig:
    episodes: int = _f(125, lo=1, hi=1_000_000, doc="E")
    seeds: int = _f(1, lo=1, hi=4096, doc="seeds trained in one program (vmap)")
    seed: int = _f(0, lo=0, hi=2**31 - 4097, doc="first PRNG seed")
    chunk_episodes: int = _f(5, lo=1, hi=1_000_000, doc="episodes per compiled call (static; progress granularity)")
    checkpoint_every: int = _f(25, lo=0, hi=1_000_000, doc="episodes between checkpoints (0 = only at the end)")
    keep_checkpoints: int = _f(3, lo=1, hi=1000, doc="checkpoints kept")
    tensorboard: bool = _f(
        False, doc="also write per-episode scalars to RUN/tensorboard/ (metrics.csv stays the record)"
    )
    # Divergence guard (docs/reliability.md): healthy thesis runs reach |Q| ~ 14 and critic losses
    # ~ 11; no return of the task exceeds ~1e5. Crossing a bound stops the run like NaN (exit 3).
    # Each learner's row names the bounds it answers to (learner_table.Bound); PPO's are in `ppo`.
    max_abs_q: float = _f(1e6, lo=0.0, doc="stop when a network's mean |Q| estimate exceeds this (0 = off)")
    max_critic_loss: float = _f(1e12, lo=0.0, doc="stop when a critic loss (PPO's value loss) exceeds this (0 = off)")
    # Periodic evaluation (docs/generalization.md): the eval_success column of metrics.csv.
    eval_every: int = _f(
        0, lo=0, hi=1_000_000, doc="episodes between greedy evaluations on run.eval_suite (0 = never; static)"
    )
    eval_suite: str = _f("probe", doc="held-out suite or group of the periodic evaluation (static)")


@dataclass(frozen=True)
class Config:
    method: str = _f("flddpg", choices=METHODS, doc="the method (docs/decisions.md, Methods)")
    learner: str = _f("ddpg", choices=LEARNERS, doc="what each agent learns with (docs/learners.md) (static)")
    env: EnvConfig = field(default_factory=EnvConfig)
    offpolicy: OffPolicyConfig = field(default_factory=OffPolicyConfig)
    ddpg: DDPGConfig = field(default_factory=DDPGConfig)
    td3: TD3Config = field(default_factory=TD3Config)
    sac: SACConfig = field(default_factory=SACConfig)
    ppo: PPOConfig = field(default_factory=PPOConfig)
    fed: FedConfig = field(default_factory=FedConfig)
    run: RunConfig = field(default_factory=RunConfig)
    robot: RobotConfig = field(default_factory=RobotConfig)

    @property
    def num_robots(self) -> int:
        return len(self.env.worlds)

    @property
    def buffer_rows(self) -> int:
        return self.offpolicy.buffer_alloc or self.offpolicy.buffer_size


SECTIONS = {
    "env": EnvConfig,
    "offpolicy": OffPolicyConfig,
    "ddpg": DDPGConfig,
    "td3": TD3Config,
    "sac": SACConfig,
    "ppo": PPOConfig,
    "fed": FedConfig,
    "run": RunConfig,
    "robot": RobotConfig,
}
TOP_LEVEL = ("method", "learner")  # the fields outside the sections
