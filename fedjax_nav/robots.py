"""Robot models as data: the config's `robot:` section and the named presets (docs/robot.md).

`model` names a preset; every other field the file (or `--set robot.x=...`) does not give takes
the preset's value, so one feature can be switched off or changed at a time:

    robot: {model: turtlebot3_burger, delay_steps: 0}      # the TurtleBot3 model without latency

"ideal" is the thesis's robot (instant velocities, exact fresh beams, D_c collisions) and runs
exactly the program that existed before the robot model: the simulator's model code is left out
(`NavEnv(robot=False)`). A config naming "ideal" but giving any non-ideal value becomes "custom"
(the ideal numbers, the model code switched on), so `model` always says which program runs.

Layer 0 (no jax, no config import): `fedjax_nav.config` adds `RobotConfig` as its `robot` section
and reports `robot_problem`'s message as a `ConfigError`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

# Every field's ideal value: with these the robot is the thesis's.
IDEAL = {
    "accel_lin": 0.0,
    "accel_ang": 0.0,
    "max_delay": 0,
    "delay_steps": 0,
    "substeps": 1,
    "range_noise": 0.0,
    "range_resolution": 0.0,
    "range_min": 0.0,
    "dropout": 0.0,
    "dropout_value": "max",
    "scan_samples": 0,
    "footprint": 0.0,
    "lidar_offset": 0.0,
}

# TurtleBot3 Burger in Gazebo with its LDS-01 lidar. Sources (docs/robot.md has the details):
# model.sdf = turtlebot3_simulations/turtlebot3_gazebo/models/turtlebot3_burger/model.sdf;
# the assumptions are marked.
TURTLEBOT3_BURGER = {
    "accel_lin": 1.0,  # m/s^2: model.sdf DiffDrive <max_linear_acceleration>1.0
    "accel_ang": 12.5,  # rad/s^2: derived, 2 x 1.0 m/s^2 per wheel / 0.160 m wheel separation (assumption)
    "max_delay": 2,  # command ring; room for 0.2 s of latency at dt = 0.1 s
    "delay_steps": 1,  # 0.1 s of ROS latency (assumption: a 5 Hz scan is 0.1 s old on average)
    "substeps": 3,  # 30 Hz physics at dt = 0.1 s: the diff drive's 30 Hz update (model.sdf odom 30 Hz)
    "range_noise": 0.01,  # m: model.sdf lidar <noise> gaussian stddev 0.01
    "range_resolution": 0.015,  # m: model.sdf lidar <range><resolution>0.015
    "range_min": 0.12,  # m: model.sdf <range><min>0.120; LDS-01 datasheet 120 mm
    "dropout": 0.01,  # per sample (assumption: a real LDS-01 drops dark/glossy returns; Gazebo has none)
    "dropout_value": "zero",  # the LDS driver reports an invalid sample as 0
    "scan_samples": 360,  # model.sdf <samples>360; LDS-01 datasheet 1 degree angular resolution
    # The preset keeps the task's termination rule (env.collision_distance, the thesis's D_c): a
    # transfer comparison then measures dynamics and sensing, not a changed success criterion.
    # The Burger's radius, 0.105 m (turtlebot3_navigation2 burger.yaml robot_radius, as commonly
    # quoted), is one `--set robot.footprint=0.105` away (docs/robot.md).
    "footprint": 0.0,
    "lidar_offset": -0.032,  # m: model.sdf lidar_joint pose x = -0.032 (behind the wheel axis)
}

# The ideal robot whose 24 beams are each the nearest return of its sector of a 360-sample scan
# (the LDS-01's count), nothing else changed: what the pooling alone does to obstacles thinner
# than the gap between two ideal rays (docs/clutter.md, "Thin obstacles between the beams").
POOLED_360 = IDEAL | {"scan_samples": 360}

ROBOT_MODELS = {"ideal": IDEAL, "custom": IDEAL, "turtlebot3_burger": TURTLEBOT3_BURGER, "pooled_360": POOLED_360}


def _f(lo=None, hi=None, choices=None, traced=False, doc=""):
    """A field whose default (None) is filled from the model's preset (metadata as config's `_f`)."""
    return field(default=None, metadata={"lo": lo, "hi": hi, "choices": choices, "traced": traced, "doc": doc})


@dataclass(frozen=True)
class RobotConfig:
    model: str = field(
        default="ideal",
        metadata={
            "lo": None,
            "hi": None,
            "choices": tuple(ROBOT_MODELS),
            "traced": False,
            "doc": "robot model (static): ideal (the thesis's), turtlebot3_burger, custom; fills the fields not given",
        },
    )
    accel_lin: float = _f(lo=0.0, traced=True, doc="m/s^2, linear acceleration limit (0 = unlimited)")
    accel_ang: float = _f(lo=0.0, traced=True, doc="rad/s^2, angular acceleration limit (0 = unlimited)")
    max_delay: int = _f(lo=0, hi=64, doc="control steps the command ring holds (static; bounds delay_steps)")
    delay_steps: int = _f(lo=0, hi=64, traced=True, doc="control steps between a command and its execution")
    substeps: int = _f(lo=1, hi=20, doc="physics steps per control step of env.dt (static)")
    range_noise: float = _f(lo=0.0, traced=True, doc="m, std of Gaussian noise on each lidar sample")
    range_resolution: float = _f(lo=0.0, traced=True, doc="m, ranges rounded to multiples of it (0 = exact)")
    range_min: float = _f(lo=0.0, traced=True, doc="m, a return nearer than this reads 0 (invalid, left out)")
    dropout: float = _f(lo=0.0, hi=1.0, traced=True, doc="probability that a lidar sample drops out")
    dropout_value: str = _f(choices=("max", "zero"), doc="what a dropped sample reads: max range or 0 (static)")
    scan_samples: int = _f(
        lo=0, hi=4096, doc="dense scan pooled to env.num_beams by sector minimum; 0 = exact beams (static)"
    )
    footprint: float = _f(lo=0.0, traced=True, doc="m, collision radius; replaces env.collision_distance when > 0")
    lidar_offset: float = _f(
        lo=-1.0, hi=1.0, traced=True, doc="m, the lidar ahead of the wheel axis (negative: behind)"
    )

    def __post_init__(self):
        preset = ROBOT_MODELS.get(self.model, IDEAL)
        for f in fields(self):
            if f.name != "model" and getattr(self, f.name) is None:
                object.__setattr__(self, f.name, preset[f.name])
        if self.model == "ideal" and any(getattr(self, k) != v for k, v in IDEAL.items()):
            object.__setattr__(self, "model", "custom")

    @property
    def enabled(self) -> bool:
        """Whether the simulator runs the model code (`NavEnv(robot=...)`; also draws noise)."""
        return self.model != "ideal"

    def traced_values(self) -> dict:
        """The traced fields by name: each is an `EnvParams` field of the same name."""
        return {f.name: getattr(self, f.name) for f in fields(self) if f.metadata["traced"]}

    def env_settings(self) -> dict:
        """The static `NavEnv` keyword arguments of this model (training: with noise on)."""
        return {
            "robot": self.enabled,
            "noise": self.enabled,
            "substeps": self.substeps,
            "max_delay": self.max_delay,
            "scan_samples": self.scan_samples,
            "dropout_value": self.dropout_value,
        }


def robot_problem(r: RobotConfig, num_beams: int) -> str:
    """The cross-field problem of a robot section, or "" (config raises it as a ConfigError)."""
    if r.delay_steps > r.max_delay:
        return (
            f"robot.delay_steps ({r.delay_steps}) must be <= robot.max_delay ({r.max_delay}, static: "
            "the size of the command ring)"
        )
    if 0 < r.scan_samples < num_beams:
        return f"robot.scan_samples ({r.scan_samples}) must be 0 or >= env.num_beams ({num_beams})"
    return ""
