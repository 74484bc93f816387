"""Why detours fail (fedjax_nav.evaluation.detours): a crash into a trunk thinner than the gap
between two beams is read as unseen (analytic geometry), the rooms are chosen by their failed
detours, and the replayed episodes are the kept evaluation's, read consistently with the exact
collision test, with the learned value at the observations the replay recorded (the worst-rooms
run of tests/test_worst_rooms.py, full tier)."""

import jax
import numpy as np
import pandas as pd
import pytest
from test_worst_rooms import evaluated  # noqa: F401  (the fixture: a steered run evaluated on `probe`)

from fedjax_nav.evaluation import detours

NO_SEGMENTS = np.zeros((1, 4), np.float32)


def test_a_trunk_between_two_beams_is_not_seen_and_a_wall_ahead_blocks_the_goal():
    # 24 beams: 15 deg apart. A 2 cm trunk 0.2 m away at 7.5 deg sits between beams 0 and 1.
    a = np.radians(7.5)
    trunk = np.array([[0.2 * np.cos(a), 0.2 * np.sin(a), 0.02]], np.float32)
    pose, goal = np.zeros(3, np.float32), np.array([3.0, 0.0], np.float32)
    blocked, front, bearing, nearest = detours._seen(NO_SEGMENTS, trunk, pose, goal, 24, 3.5)
    assert not bool(blocked) and float(nearest) == pytest.approx(3.5) and float(bearing) == pytest.approx(0.0)
    # the true clearance is 0.18 m (< D_c 0.25) while every beam reads the max range: unseen
    # the same trunk on the beam at 0 deg: seen at 0.18 m, and the straight way to the goal blocked
    on_beam = np.array([[0.2, 0.0, 0.02]], np.float32)
    blocked, front, _, nearest = detours._seen(NO_SEGMENTS, on_beam, pose, goal, 24, 3.5)
    assert bool(blocked) and float(front) == pytest.approx(0.18, abs=1e-5) and float(nearest) == pytest.approx(0.18)


def test_rooms_with_the_most_failed_detours_come_first():
    ep = pd.DataFrame(
        {
            "room": [0, 0, 1, 1, 2, 2],
            "family": ["a"] * 6,
            "room_seed": [10, 10, 11, 11, 12, 12],
            "success": [0, 0, 0, 1, 1, 1],
            "collision": [1, 1, 0, 0, 0, 0],
            "timeout": [0, 0, 1, 0, 0, 0],
            "shortest_path": [1.0, 1.0, 3.0, 3.0, 3.0, 3.0],  # room 0: direct goals; 1, 2: detours
            "straight_line": [1.0, 1.0, 1.0, 1.0, 1.0, 1.0],
        }
    )
    ranked = detours.most_failed_detours(ep)
    assert list(ranked["room"]) == [1, 0, 2] and list(ranked["failed_detours"]) == [1, 0, 0]


def test_the_replayed_episodes_are_the_kept_evaluations_and_crashes_touch(evaluated):  # noqa: F811
    run, _ = evaluated
    table, w = detours.read(run, "probe", rooms=4)
    assert len(table) == int(np.sum(w.num_goals)) * w.success.shape[1] * w.success.shape[3]
    kept = pd.read_csv(run / "eval" / "probe" / "suite_episodes.csv")
    keys = ["room", "seed", "net", "goal", "attempt"]
    both = table.merge(kept[keys + ["success", "collision"]], on=keys, validate="one_to_one")
    assert (both["outcome"].eq("success") == both["success"].astype(bool)).all()
    assert (both["outcome"].eq("collision") == both["collision"].astype(bool)).all()
    crashed = table[table["outcome"] == "collision"]
    assert len(crashed) and (crashed["crash_clearance_m"] < 0.25 + 1e-6).all()
    assert (table["progress"] >= -1e-6).all() and (table["closest"] <= table["steps"]).all()
    # the most given back, by brute force over each episode's live steps
    for r in table.head(8).itertuples():
        d = np.linalg.norm(
            w.poses[r.i, r.agent, r.goal, r.attempt, : r.steps + 1, :2] - w.world.goals[r.i, r.goal], axis=1
        )
        assert r.gave_back_m == pytest.approx(max(d[t] - d[: t + 1].min() for t in range(len(d))), abs=1e-5)
    assert detours.summary(table)["episodes"].sum() == 2 * int(table["detour"].astype(bool).sum())  # family + all
    # the value (DDPG: Q(s, mu(s))) at each episode's first observation, from params.npz by flax
    from fedjax_nav import rundir
    from fedjax_nav.agents import ddpg

    actor, critic = (rundir.read_params(run, n) for n in ("actor", "critic"))
    nets = ddpg.make_nets(8, 1, "relu")  # test_worst_rooms.TINY's offpolicy network
    for r in table.head(8).itertuples():
        at = lambda x, r=r: x[w.agent_seed[r.agent] - w.agent_seed.min(), w.agent_net[r.agent]]  # noqa: E731
        obs = w.obs[r.i, r.agent, r.goal, r.attempt, 0]
        q = nets.critic.apply(jax.tree.map(at, critic), obs, ddpg.act(nets, jax.tree.map(at, actor), obs))
        assert r.v_start == pytest.approx(float(q), rel=1e-5, abs=1e-5)
    assert table[detours.VALUES].notna().all().all()
