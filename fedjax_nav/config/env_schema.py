"""The `env` section of the config (`EnvConfig`): the simulator, the rooms, shared rooms and the
global plan, each field with its default, range or choices and whether it is traced
(`fields._f`). Its own module because it is the largest section; `schema.py` assembles it with
the others into `Config`, and `fedjax_nav.config` re-exports it.
"""

from __future__ import annotations

from dataclasses import dataclass

from fedjax_nav.config.fields import _f

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
        "it stops and turns right in place for that step (0 = off; docs/shared_rooms.md, 'Giving way')",
    )
    give_way_door: float = _f(
        0.0,
        lo=0.0,
        hi=1e4,
        traced=True,
        doc="shared rooms: m across (between the walls either side) under which a place counts as a door: a "
        "robot not in one stops while another robot in sight, ahead and within env.give_way_reach stands "
        "in one (0 = off; docs/shared_rooms.md, 'Waiting at doors')",
    )
    give_way_reach: float = _f(
        1.5,
        lo=0.0,
        hi=1e4,
        traced=True,
        doc="env.give_way_door: m between two robots' centres within which a robot waits",
    )
    # A global plan on the known map (docs/planning.md). The default gives today's mapless runs.
    plan: bool = _f(
        False,
        doc="give the policy the waypoint of a shortest safe path on the room's map in place of the goal, "
        "and the goal's distance as one more input (static; docs/planning.md)",
    )
    plan_cells: int = _f(64, lo=2, hi=1024, doc="env.plan, env.path_progress: grid cells per side of the room (static)")
    path_progress: bool = _f(
        False,
        doc="pay the progress reward along the shortest safe path on the room's map (the plan's field) in "
        "place of the straight line; the observation stays as it is (static; docs/clutter.md, 'Paid along "
        "the path')",
    )
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
