"""The scripted follower (fedjax_nav/evaluation/baselines.py, docs/planning.md "The margin, and a
scripted follower") and `scripts/suite_with.py`: the follower's action from the observation's
bearing, and through the suite protocol on a room whose straight way is walled: with the plan it
goes round the wall's end and arrives, without it it drives into the wall; a run's own agents
under a traced env value changed, a static one refused."""

import importlib.util
import json
import math
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

from fedjax_nav.config import from_dict
from fedjax_nav.evaluation.baselines import TURN_GAIN, TURN_IN_PLACE, follower, follower_run
from fedjax_nav.evaluation.suite import evaluate_suite

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("suite_with", ROOT / "scripts" / "suite_with.py")
suite_with = importlib.util.module_from_spec(spec)
spec.loader.exec_module(suite_with)

BEAMS = 24
# start 0 faces +x towards the goal; a wall across the straight way leaves a 1 m gap at the top
WALLED = {"size": [3, 3], "segments": [[0, -1.5, 0, 0.5]], "starts": [[-1, 0, 0]], "goals": [[1, 0]]}


@pytest.mark.parametrize("plan", [True, False])
def test_the_action_turns_to_the_bearing_and_drives_when_facing_it(plan):
    policy = follower(BEAMS, plan)
    at = BEAMS + 1  # the bearing after the distance, the waypoint's or the goal's (plan.layout)
    for bearing in (0.0, -0.25, 0.6, math.pi / 2, -3.0):
        obs = jnp.zeros(BEAMS + (5 if plan else 4)).at[at].set(bearing)
        v, omega = np.asarray(policy(None, obs))
        assert v == pytest.approx(max(0.0, 1.0 - abs(bearing) / TURN_IN_PLACE), abs=1e-6)
        assert omega == pytest.approx(float(np.clip(TURN_GAIN * bearing, -1, 1)), abs=1e-6)
    assert follower(BEAMS, plan) is policy  # one function object: evaluations share a program


def _cfg(plan: bool):
    env = {"episode_length": 300, "plan": plan, "plan_cells": 32, "plan_margin": 0.3, "plan_lookahead": 0.5}
    return from_dict({"learner": "ppo", "method": "snddpg", "env": env, "run": {"seeds": 1}})


@pytest.fixture(scope="module")
def walled(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rooms")
    (folder / "walled.json").write_text(json.dumps(WALLED))
    return folder


@pytest.mark.parametrize("plan", [True, False])
def test_with_the_plan_it_goes_round_the_wall_without_it_drives_into_it(walled, tmp_path, plan):
    res = evaluate_suite(follower_run(_cfg(plan), tmp_path), str(walled), attempts=2)
    ep = res["episodes"]
    assert len(ep) == 2 and res["summary"]["agents"] == 1
    if plan:
        assert ep["success"].all() and ep["path_ratio"].max() < 1.5
    else:
        assert ep["collision"].all()


def test_the_script_writes_the_suite_tables_and_keeps_them(walled, tmp_path, capsys):
    cfg_file = tmp_path / "plan.yaml"
    cfg_file.write_text(json.dumps({"learner": "ppo", "method": "snddpg", "env": {"episode_length": 300}}))
    out = tmp_path / "f"
    sets = ["--set", "env.plan=true", "--set", "env.plan_cells=32", "--set", "env.plan_margin=0.3"]
    args = [str(cfg_file), "--follower", *sets, "--suite", str(walled), "--out", str(out)]
    assert suite_with.main(args) == 0
    fams = pd.read_csv(out / "suite_families.csv")
    assert fams.loc[fams.family == "all", "success"].item() == 1.0
    assert suite_with.main(args) == 2  # a kept evaluation is not overwritten
    assert "exists" in capsys.readouterr().err
    assert (
        suite_with.main(
            [
                str(cfg_file),
                "--follower",
                "--set",
                "env.plan_margin=-1",
                "--suite",
                str(walled),
                "--out",
                str(tmp_path / "g"),
            ]
        )
        == 2
    )
    assert "plan_margin" in capsys.readouterr().err


def test_a_runs_agents_under_a_traced_value_changed(tmp_path, capsys):
    from test_suite_dir import ROOMS, STEPS, constant_run

    rooms = tmp_path / "rooms"
    rooms.mkdir()
    (rooms / "far.json").write_text(json.dumps(ROOMS["far.yml"]))  # 3.5 m ahead: 1.5 m driven in time
    run = constant_run(tmp_path / "run")  # full speed straight on
    base = [str(run), "--suite", str(rooms)]
    assert suite_with.main([*base, "--out", str(tmp_path / "a")]) == 0
    assert suite_with.main([*base, "--set", "env.v_max=1.0", "--out", str(tmp_path / "b")]) == 0
    ep = {k: pd.read_csv(tmp_path / k / "suite_episodes.csv") for k in "ab"}
    assert ep["a"]["timeout"].all() and ep["b"]["success"].all()  # 4x the speed: 6 m in time
    assert suite_with.main([*base, "--max-steps", str(4 * STEPS), "--out", str(tmp_path / "t")]) == 0
    assert pd.read_csv(tmp_path / "t" / "suite_episodes.csv")["success"].all()  # 4x the time: 6 m in time
    assert suite_with.main([*base, "--set", "env.num_beams=12", "--out", str(tmp_path / "c")]) == 2
    assert "env.num_beams: not a traced value" in capsys.readouterr().err


def test_suite_table_pools_the_evaluations_of_other_seeds(walled, tmp_path):
    spec = importlib.util.spec_from_file_location("suite_table", ROOT / "scripts" / "suite_table.py")
    suite_table = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(suite_table)
    from fedjax_nav.evaluation.suite import write_suite

    folders = []
    for seed, plan in ((0, True), (2, False)):  # one arrives, one drives into the wall
        env = {"episode_length": 300, "plan": plan, "plan_cells": 32, "plan_margin": 0.3}
        cfg = from_dict({"learner": "ppo", "method": "snddpg", "env": env, "run": {"seeds": 1, "seed": seed}})
        write_suite(evaluate_suite(follower_run(cfg, tmp_path), str(walled), attempts=2), tmp_path / f"s{seed}")
        folders.append(str(tmp_path / f"s{seed}"))
    t = suite_table.table([f"both={'+'.join(folders)}"])
    row = t[t.family == "all"].iloc[0]
    assert row.success == 0.5 and row.collision == 0.5  # 2 episodes of each seed
    fams = suite_table.pooled(folders)
    assert fams.loc[fams.family == "all", "seeds"].item() == 2
    with pytest.raises(SystemExit, match="pooled already"):
        suite_table.pooled([folders[0], folders[0]])


def test_a_runs_agents_under_a_traced_value_changed_with_k_robots_per_room(tmp_path, capsys):
    from test_suite_dir import ROOMS, constant_run

    rooms = tmp_path / "rooms"
    rooms.mkdir()
    (rooms / "far.json").write_text(json.dumps(ROOMS["far.yml"]))
    run = constant_run(tmp_path / "run")  # full speed straight on
    base = [str(run), "--suite", str(rooms), "--robots-per-room", "1"]
    assert suite_with.main([*base, "--out", str(tmp_path / "a")]) == 0
    assert suite_with.main([*base, "--set", "env.v_max=1.0", "--out", str(tmp_path / "b")]) == 0
    fams = {k: pd.read_csv(tmp_path / k / "shared_families.csv") for k in "ab"}
    assert (fams["a"]["timeout"] == 1.0).all() and (fams["b"]["success"] == 1.0).all()
    assert json.loads((tmp_path / "b" / "shared.json").read_text())["robots_per_room"] == [1]
    assert suite_with.main([*base, "--out", str(tmp_path / "b")]) == 2  # kept, not overwritten
    assert "shared.json exists" in capsys.readouterr().err
    bad = [str(run), "--suite", str(rooms), "--robots-per-room", "two", "--out", str(tmp_path / "c")]
    assert suite_with.main(bad) == 2
    assert "--robots-per-room" in capsys.readouterr().err


def test_the_script_drives_a_fleet_in_a_world_and_draws_it(tmp_path, capsys):
    """--world with --robots-per-room: robot i from the world's start i to its goal i (the arena
    crossing), written as `fedjax-nav evaluate --world W --robots-per-room K` writes it."""
    cfg_file = tmp_path / "plan.yaml"
    cfg_file.write_text(json.dumps({"learner": "ppo", "method": "snddpg", "env": {"episode_length": 64}}))
    out = tmp_path / "crossing"
    base = [str(cfg_file), "--follower", "--set", "env.plan=true", "--set", "env.plan_cells=32"]
    assert suite_with.main([*base, "--robots-per-room", "2", "--world", "eval-crossing", "--out", str(out)]) == 0
    ep = pd.read_csv(out / "shared_episodes.csv")
    assert set(ep.robots_per_room) == {2} and len(ep) == 2 and (out / "shared_trajectories.png").stat().st_size > 0
    assert suite_with.main([*base, "--world", "eval-crossing", "--out", str(tmp_path / "one")]) == 2
    assert "--world: only with --robots-per-room" in capsys.readouterr().err
