"""The config's schema: the sections' frozen dataclasses, their fields (default, type, range or
choices, `traced`), and the dotted-name helpers. `fedjax_nav.config` re-exports all of it; the
modules of the package (io, validate, traced, envs, sweepfile) import it from here, so that the
package's `__init__` imports them and none of them imports it back (tests/test_layers.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from fedjax_nav.learner_table import NAMES as LEARNERS  # the `learner` choices: the learner table's names
from fedjax_nav.methods import METHODS as _METHOD_TABLE
from fedjax_nav.robots import ROBOT_MODELS, RobotConfig, robot_problem  # noqa: F401  (the `robot` section)

METHODS = tuple(_METHOD_TABLE)
# fed.aggregator and fed.attack choices (kept equal to fedjax_nav.federated's tables by
# tests/test_robust_federation.py; config does not import jax).
ROBUST_AGGREGATORS = ("method", "mean", "median", "trimmed_mean", "krum", "geometric_median", "norm_bounded")
ATTACKS = ("none", "noise", "scale", "sign_flip", "zeros", "stale")
ROOM_SOURCES = ("fixed", "procedural")
# fedjax_nav.worlds.FAMILIES + "fixed" (tests/test_dense_families.py keeps them equal)
ROOM_FAMILIES = (
    "cylinders",
    "boxes",
    "walls",
    "mixture",
    "forest",
    "warehouse",
    "maze",
    "cave",
    "office",
    "corridors",
    "fixed",
)


class ConfigError(ValueError):
    """A config value is invalid; the message names the file, the key and what is allowed."""


def _f(default, lo=None, hi=None, choices=None, traced=False, doc=""):
    meta = {"lo": lo, "hi": hi, "choices": choices, "traced": traced, "doc": doc}
    if isinstance(default, (list, tuple)):
        return field(default_factory=lambda: tuple(default), metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class EnvConfig:
    worlds: tuple = _f(
        ("train-0", "train-2", "train-3", "train-4", "train-5"),
        doc="one playground per robot: shipped names or world files (static: loaded once per program)",
    )
    episode_length: int = _f(1024, lo=1, hi=1_000_000, doc="T, steps per episode (static)")
    num_beams: int = _f(24, lo=1, hi=1024, doc="lidar beams (static)")
    max_range: float = _f(3.5, lo=0.0, hi=1e4, doc="m, lidar range, at most 1e4 (static)")
    collision_test: str = _f("exact", choices=("exact", "lidar"), doc="exact distance or min(lidar) (static)")
    dt: float = _f(0.1, lo=0.0, hi=10.0, traced=True, doc="s per control step, at most 10")
    v_max: float = _f(0.25, lo=0.0, hi=100.0, traced=True, doc="m/s, at most 100")
    omega_max: float = _f(1.0, lo=0.0, hi=100.0, traced=True, doc="rad/s, at most 100")
    goal_radius: float = _f(0.5, lo=0.0, hi=1e4, traced=True, doc="m, D_g, at most 1e4 (a world's bound)")
    collision_distance: float = _f(0.25, lo=0.0, hi=1e4, traced=True, doc="m, D_c, at most 1e4 (a world's bound)")
    reward_goal: float = _f(100.0, lo=-1e6, hi=1e6, traced=True, doc="R_g, within +-1e6")
    reward_collision: float = _f(-10.0, lo=-1e6, hi=1e6, traced=True, doc="R_c, within +-1e6")
    progress_scale: float = _f(
        40.0, lo=-1e6, hi=1e6, traced=True, doc="R_d = progress_scale * (d_prev - d), within +-1e6"
    )
    # Rooms the robots never saw (docs/generalization.md). The defaults give today's runs.
    rooms: str = _f(
        "fixed",
        choices=ROOM_SOURCES,
        doc="fixed: the env.worlds playgrounds; procedural: fresh generated rooms in the program (static)",
    )
    room_families: tuple = _f(
        ("mixture",),
        doc="procedural rooms' family, one for every robot or one per robot: "
        "cylinders, boxes, walls, mixture, the dense forest, warehouse, maze, cave, the indoor office, corridors "
        "(docs/generator.md), "
        "or fixed = keep that robot's env.worlds room (static)",
    )
    room_every: int = _f(1, lo=1, hi=1_000_000, traced=True, doc="episodes between new procedural rooms")
    room_density_start: float = _f(
        1.0,
        lo=0.0,
        hi=1.0,
        traced=True,
        doc="curriculum: the procedural rooms' obstacle density at episode 0 (1 = full rooms)",
    )
    room_curriculum_episodes: int = _f(
        0,
        lo=0,
        hi=1_000_000,
        traced=True,
        doc="curriculum: episodes over which the density rises linearly to 1 (0 = no curriculum)",
    )
    room_spec: str = _f(
        "",
        doc="RoomSpec overrides of the procedural rooms, e.g. 'cylinders_max=4, goals_max=2' "
        "(static; docs/generator.md)",
    )
    # The learnability curriculum over procedural rooms (docs/generalization.md). The defaults give today's runs.
    room_sampling: str = _f(
        "uniform",
        choices=("uniform", "learnability"),
        doc="procedural rooms: uniform = a fresh room at every renewal; learnability = each environment keeps a "
        "bank of env.room_bank rooms and draws them with weight p(1 - p), p its recent success (static)",
    )
    room_bank: int = _f(16, lo=1, hi=4096, doc="learnability: rooms in each environment's bank (static)")
    room_fresh: float = _f(
        0.5,
        lo=0.0,
        hi=1.0,
        traced=True,
        doc="learnability: probability that a renewal draws a fresh room (it replaces the bank's least "
        "learnable room) instead of a bank room",
    )
    room_ema: float = _f(
        0.5,
        lo=0.0,
        hi=1.0,
        traced=True,
        doc="learnability: EMA rate of a bank room's success p, updated with each episode's goal share",
    )
    room_floor: float = _f(
        0.01,
        lo=1e-6,
        hi=1.0,
        traced=True,
        doc="learnability: added to every p(1 - p) weight, so that a bank of solved or hopeless rooms still samples",
    )
    placement: str = _f(
        "fixed",
        choices=("fixed", "random"),
        doc="start and goal: the room's start 0 / goal 0, or drawn at random in the free space "
        "at every episode's reset (static)",
    )
    envs_per_robot: int = _f(
        1,
        lo=1,
        hi=65536,
        doc="environments each robot (federated client) steps at once, all feeding its learner; each "
        "draws its own starts and, with procedural rooms, its own room (static; 1 = the thesis)",
    )
    shared_rooms: bool = _f(
        False,
        doc="environment j of every robot is one room: the fleet drives in it together, each robot to its own "
        "goal, seeing the others in its lidar; a contact of two robots is a collision of both "
        "(static; false = every robot alone; docs/shared_rooms.md)",
    )
    reward_robot_near: float = _f(
        0.0,
        lo=-1e6,
        hi=1e6,
        traced=True,
        doc="shared rooms: reward on every step another robot's disc is nearer than env.robot_clearance "
        "to the robot's own (0 = off; docs/shared_rooms.md, 'Keeping apart')",
    )
    robot_clearance: float = _f(
        0.3, lo=0.0, hi=1e4, traced=True, doc="shared rooms: m between two robots' discs env.reward_robot_near pays"
    )
    give_way: float = _f(
        0.0,
        lo=0.0,
        hi=1e4,
        traced=True,
        doc="shared rooms: m between two robots' discs within which a robot does not drive nearer to another: "
        "its forward speed is 0 for that step (0 = off; docs/shared_rooms.md, 'Giving way')",
    )
    # A global plan on the known map (docs/planning.md). The default gives today's mapless runs.
    plan: bool = _f(
        False,
        doc="give the policy the waypoint of a shortest safe path on the room's map in place of the goal, "
        "and the goal's distance as one more input (static; docs/planning.md)",
    )
    plan_cells: int = _f(64, lo=2, hi=1024, doc="env.plan: grid cells per side of the room (static)")
    plan_lookahead: float = _f(1.0, lo=0.0, hi=1e4, traced=True, doc="env.plan: m down the path to the waypoint")
    plan_margin: float = _f(
        0.0,
        lo=0.0,
        hi=1e4,
        traced=True,
        doc="env.plan: m beyond the collision distance within which the path's cells cost more, so that "
        "it keeps from walls where it can (0: the shortest path; docs/planning.md)",
    )
    plan_keep_right: float = _f(
        0.0,
        lo=0.0,
        hi=1e4,
        traced=True,
        doc="env.plan in shared rooms: m the waypoint moves to the right of the robot's way while another "
        "robot is near and ahead, so that two robots meeting head-on pass on opposite sides (0 = off; "
        "docs/shared_rooms.md, 'Keeping right')",
    )
    plan_keep_right_reach: float = _f(
        1.5,
        lo=0.0,
        hi=1e4,
        traced=True,
        doc="env.plan_keep_right: m between two robots' centres within which a robot keeps right of another "
        "ahead of it",
    )


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
