"""scripts/robot_contacts.py (docs/shared_rooms.md, "How the robots touch"): the geometry of a
robot-robot contact read from hand-made trajectories whose answer is known, and the script's
contacts of a run against the robot-robot collisions of its K-robot evaluation."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("robot_contacts", ROOT / "scripts" / "robot_contacts.py")
robot_contacts = importlib.util.module_from_spec(spec)
spec.loader.exec_module(robot_contacts)

DT, V = 0.1, 0.25  # s per step, m/s


def straight(start, heading: float, speed: float, steps: int) -> np.ndarray:
    """Poses [steps + 1, 3] driving straight at `speed` from `start`."""
    t = np.arange(steps + 1)[:, None] * DT * speed
    xy = np.asarray(start, float) + t * np.array([np.cos(heading), np.sin(heading)])
    return np.concatenate([xy, np.full((steps + 1, 1), heading)], axis=1)


def test_a_head_on_meeting_is_head_on_in_front_and_near_for_the_steps_it_took():
    # 3 m apart, closing at 0.5 m/s: contact (centres < 0.5 m) after 5.0 s; within 1 m after 4.0 s
    a, b = straight((0.0, 0.0), 0.0, V, 60), straight((3.0, 0.0), np.pi, V, 60)
    poses = np.stack([a, b], axis=1)
    gap = np.linalg.norm(a[:, :2] - b[:, :2], axis=-1)
    s = int(np.argmax(gap < 0.5))
    df = robot_contacts.contacts(poses, np.array([s, s]), np.array([True, True]), DT)
    assert len(df) == 2 and set(df.other) == {0, 1}
    assert (df.kind == "head-on").all() and (df["where"] == "in front").all()
    assert df.speed.to_numpy() == pytest.approx(V) and df.other_speed.to_numpy() == pytest.approx(V)
    assert (df.near_steps == s - int(np.flatnonzero(gap[: s + 1] >= 1.0)[-1])).all()
    assert df.distance.to_numpy() == pytest.approx(gap[s])


def test_driving_into_a_robot_that_stands_still_is_the_same_way_from_both_sides_of_the_contact():
    mover = straight((0.0, 0.0), 0.0, V, 40)
    still = straight((2.0, 0.0), 0.0, 0.0, 40)
    poses = np.stack([mover, still], axis=1)
    s = int(np.argmax(np.linalg.norm(mover[:, :2] - still[:, :2], axis=-1) < 0.5))
    df = robot_contacts.contacts(poses, np.array([s, s]), np.array([True, True]), DT).set_index("robot")
    assert (df.kind == "same way").all()
    assert df.loc[0, "where"] == "in front" and df.loc[1, "where"] == "behind"
    assert df.loc[0, "other_speed"] == pytest.approx(0.0) and df.loc[1, "speed"] == pytest.approx(0.0)
    assert robot_contacts.shares(df.reset_index())["one_stood_still"] == 1.0


def test_the_partner_is_the_nearest_robot_still_in_the_room():
    # robot 2 sits beside the contact but left the room (its episode ended) before it: not the partner
    a, b = straight((0.0, 0.0), np.pi / 2, V, 30), straight((0.0, 2.0), -np.pi / 2, V, 30)
    c = straight((0.3, 1.0), 0.0, 0.0, 30)
    poses = np.stack([a, b, c], axis=1)
    s = int(np.argmax(np.linalg.norm(a[:, :2] - b[:, :2], axis=-1) < 0.5))
    df = robot_contacts.contacts(poses, np.array([s, s, s - 5]), np.array([True, True, False]), DT)
    assert sorted(zip(df.robot, df.other)) == [(0, 1), (1, 0)]
    # a crossing: robot 1 drives across robot 0's way from its left
    b = straight((-1.5, 1.5), 0.0, V, 30)
    poses = np.stack([a, b], axis=1)
    s = int(np.argmax(np.linalg.norm(a[:, :2] - b[:, :2], axis=-1) < 0.5))
    df = robot_contacts.contacts(poses, np.array([s, s]), np.array([True, False]), DT)
    assert len(df) == 1 and df.kind[0] == "crossing" and df.heading_diff_deg[0] == pytest.approx(90.0)


def test_collect_tabulates_the_folders_and_refuses_one_the_script_did_not_write(tmp_path, capsys):
    df = robot_contacts.contacts(
        np.stack([straight((0.0, 0.0), 0.0, V, 60), straight((3.0, 0.0), np.pi, V, 60)], axis=1),
        np.array([50, 50]),
        np.array([True, True]),
        DT,
    )
    summary = {"robots_per_room": 2, "robot_episodes": 8} | robot_contacts.shares(df)
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "contacts.json").write_text(__import__("json").dumps(summary))
    csv = tmp_path / "t.csv"
    assert robot_contacts.main(["--collect", f"A={tmp_path / 'a'}", "--csv", str(csv)]) == 0
    row = __import__("pandas").read_csv(csv).iloc[0]
    assert row.policy == "A" and row.robot_robot == 0.25 and row.head_on == 1.0 and row.other_in_front == 1.0
    (tmp_path / "z").mkdir()  # a fleet without contacts: its shares are none, not 0
    zero = {"robots_per_room": 2, "robot_episodes": 8} | robot_contacts.shares(df.iloc[:0])
    (tmp_path / "z" / "contacts.json").write_text(__import__("json").dumps(zero))
    assert robot_contacts.main(["--collect", f"Z={tmp_path / 'z'}", "--csv", str(csv)]) == 0
    row = __import__("pandas").read_csv(csv).iloc[0]
    assert row.robot_robot == 0.0 and np.isnan(row.head_on) and np.isnan(row.speed_median)
    assert robot_contacts.main(["--collect", f"B={tmp_path / 'none'}"]) == 2
    assert "LABEL=FOLDER" in capsys.readouterr().err


def test_the_scripts_contacts_are_the_robot_robot_collisions_of_the_evaluation(tmp_path):
    import jax.numpy as jnp
    import pandas as pd

    from fedjax_nav import rundir
    from fedjax_nav.config import load_config
    from fedjax_nav.evaluation.shared_rooms import evaluate_shared
    from fedjax_nav.training.hparams import hparams_from_config
    from fedjax_nav.training.trainer import Trainer

    run = tmp_path / "run"
    run.mkdir()
    sets = ["method=iddpg", "env.worlds=[train-0,train-0]", "offpolicy.hidden=16", "run.seeds=1", "env.v_max=1.0"]
    cfg = load_config(None, sets)
    rundir.write_config(run, cfg)
    rundir.write_params(run, Trainer(cfg).init_seeds(jnp.arange(1), hparams_from_config(cfg)).agents)
    argv = [str(run), "--suite", "mixture-50", "--robots-per-room", "3", "--max-steps", "48"]
    argv += ["--out", str(tmp_path / "c")]
    assert robot_contacts.main(argv) == 0
    got = pd.read_csv(tmp_path / "c" / "contacts.csv")
    ep = evaluate_shared(run, "mixture-50", [3], max_steps=48)["episodes"]
    assert len(got) == ep.robot_collision.sum() > 0  # untrained robots at 1 m/s do meet
    key = ["room", "robot"]
    want = ep[ep.robot_collision == 1].sort_values(["room", "net", "robot"])
    assert got.sort_values(["room", "agent", "robot"])[key].values.tolist() == want[key].values.tolist()
    walls = pd.read_csv(tmp_path / "c" / "obstacles.csv")
    assert len(walls) == ep.collision.sum()  # every obstacle contact, one row each
    assert ((walls.other >= 0) == np.isfinite(walls.other_distance)).all()  # the nearest other, where one is
    assert (tmp_path / "c" / "obstacles.png").exists() == (walls.other_distance < 1.0).any()
    assert robot_contacts.main(argv) == 2  # kept, not overwritten


def test_the_room_to_pass_is_the_midpoints_distance_to_the_nearest_wall():
    # a room 6 x 0.8 m (a corridor too narrow for two robots abreast) and one 6 x 3 m; the same
    # head-on meeting on the long axis of each: the midpoint is 0.4 m and 1.5 m from the side walls
    import jax
    import pandas as pd

    from fedjax_nav.worlds import stack
    from fedjax_nav.worlds.world import from_dict

    rooms = [from_dict({"size": [6.0, h], "starts": [[-2.0, 0.0, 0.0]], "goals": [[2.0, 0.0]]})[0] for h in (0.8, 3.0)]
    world = stack(rooms)
    a, b = straight((-1.5, 0.0), 0.0, V, 60), straight((1.5, 0.0), np.pi, V, 60)
    poses = np.stack([a, b], axis=1)  # [T + 1, 2, 3]
    s = int(np.argmax(np.linalg.norm(a[:, :2] - b[:, :2], axis=-1) < 0.5))
    frames = [
        robot_contacts.contacts(poses, np.array([s, s]), np.array([True, True]), DT).assign(room=r, agent=0)
        for r in range(2)
    ]
    all_poses = np.broadcast_to(poses, (2, 1) + poses.shape)  # [rooms, agents, T + 1, k, 3]
    df = robot_contacts.room_to_pass(pd.concat(frames, ignore_index=True), all_poses, jax.device_get(world))
    assert df.wall_clearance.to_numpy() == pytest.approx([0.4] * 2 + [1.5] * 2, abs=1e-5)
    assert df.narrow.tolist() == [True, True, False, False]
    assert robot_contacts.shares(df)["narrow"] == 0.5


def test_an_obstacle_contact_after_giving_way_near_another_robot_is_counted_as_such():
    # robot 0 stands 0.55 m from robot 1 and turns right at full rate for 5 steps (omega_max dt =
    # 0.1 rad), then drives 10 steps and touches a wall; robot 2 drives alone and touches one too
    turn, still = 0.1, np.array([[0.0, 0.0, -0.1 * t] for t in range(6)])
    drive = straight(still[-1, :2], still[-1, 2], V, 10)[1:]
    a = np.concatenate([still, drive])  # [16, 3]
    b = np.tile([0.55, 0.0, np.pi], (16, 1))
    c = straight((5.0, 5.0), 0.0, V, 15)
    poses = np.stack([a, b, c], axis=1)
    steps = np.array([15, 15, 15])
    df = robot_contacts.wall_contacts(poses, steps, np.array([True, False, True]), turn)
    assert df.robot.tolist() == [0, 2]
    assert df.gave_way_steps.tolist() == [5, 0]
    assert df.other_distance[0] == pytest.approx(np.linalg.norm(a[15, :2] - b[15, :2]))
    assert df.other_distance[1] == pytest.approx(np.linalg.norm(c[15, :2] - b[15, :2]))
    gone = robot_contacts.wall_contacts(poses, np.array([15, 3, 4]), np.array([True, False, False]), turn)
    assert df.other.tolist() == [1, 1]  # the nearest other robot of each
    assert gone.other_distance.tolist() == [np.inf] and gone.other.tolist() == [-1]  # the others left at steps 3, 4
    shares = robot_contacts.wall_shares(df)
    assert shares["obstacle_contacts"] == 2 and shares["obstacle_after_giving_way"] == 0.5
