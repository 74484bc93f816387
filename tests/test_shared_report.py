"""scripts/shared_report.py (docs/shared_rooms.md, "The experiment"): the table of a sweep's points
evaluated with K robots per room, from the evaluations kept in each point (made here by hand, so
nothing is trained or rolled out); several folders pool their seeds, a seed twice is refused."""

import importlib.util
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from fedjax_nav import rundir
from fedjax_nav.config import from_dict
from fedjax_nav.evaluation.shared_rooms import shared_dir

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("shared_report", ROOT / "scripts" / "shared_report.py")
shared_report = importlib.util.module_from_spec(spec)
spec.loader.exec_module(shared_report)

SUITE, KS = "mixture-50", [1, 2]


def point(folder: Path, name: str, seed: int, success: list[float], shared: bool = True) -> Path:
    """A trained point of one seed whose kept evaluation has 2 rooms; `success[k]`: its share at KS[k]."""
    p = rundir.points_dir(folder) / name
    p.mkdir(parents=True)
    run = {"seeds": 1, "seed": seed, "episodes": 4, "chunk_episodes": 2, "checkpoint_every": 2}
    rundir.write_config(p, from_dict({"method": "flddpg", "env": {"shared_rooms": shared}, "run": run}))
    episodes = range(4)
    pd.DataFrame({"episode": episodes, "goals": 3, "collisions": 1, "robot_collisions": 1}).to_csv(
        p / rundir.METRICS, index=False
    )
    (p / rundir.PARAMS).write_bytes(b"")
    rows = []
    for k, share in zip(KS, success):
        for room in range(2):
            for robot in range(k):
                won = robot < round(share * k) if k > 1 else share >= (room + 1) / 2  # k = 1: room 0 first
                rows.append({"robots_per_room": k, "room": room, "seed": seed, "robot": robot, "success": int(won)})
    ep = pd.DataFrame(rows).assign(collision=lambda d: 1 - d.success, robot_collision=0, timeout=0, deadlock=0)
    out = shared_dir(p, SUITE)
    out.mkdir(parents=True)
    ep.to_csv(out / rundir.SHARED_EPISODES, index=False)
    (out / rundir.SHARED_JSON).write_text(json.dumps({"robots_per_room": KS, "max_steps": 1024}))
    return p


def test_two_folders_pool_their_seeds_and_a_seed_twice_is_refused(tmp_path):
    point(tmp_path / "a", "p0", seed=0, success=[1.0, 0.5])
    point(tmp_path / "a", "q0", seed=0, success=[0.0, 0.0], shared=False)  # the control: its own row
    point(tmp_path / "b", "p2", seed=2, success=[0.5, 1.0])
    df = shared_report.rows([tmp_path / "a", tmp_path / "b"], SUITE, KS, None)
    shared = df[df.trained == "shared rooms"].set_index("robots_per_room")
    assert list(shared.seeds) == [2, 2] and shared.loc[1, "point"] == "p0+p2"
    assert shared.loc[1, "success"] == 0.75 and shared.loc[1, "worst_seed"] == 0.5
    assert shared.loc[2, "success"] == 0.75 and shared.loc[2, "worst_seed"] == 0.5
    assert np.isclose(shared.loc[1, "train_goal_share"], 0.75)
    alone = df[df.trained == "alone"]
    assert list(alone.seeds) == [1, 1] and (alone.success == 0).all()
    one = shared_report.rows(tmp_path / "a", SUITE, KS, None)  # one folder, as before
    assert list(one[one.trained == "shared rooms"].success) == [1.0, 0.5]
    point(tmp_path / "c", "p0again", seed=0, success=[1.0, 0.5])
    with pytest.raises(SystemExit, match="seed is in more than one"):
        shared_report.rows([tmp_path / "a", tmp_path / "c"], SUITE, KS, None)


def test_kept_evaluations_are_tabulated_per_k_and_family_their_seeds_pooled(tmp_path):
    folders = []
    for name, seed, won in (("a", 0, [1, 1, 0, 0]), ("b", 1, [1, 0, 0, 0])):
        ep = pd.DataFrame(
            {
                "robots_per_room": 2,
                "room": [0, 0, 1, 1],
                "family": ["forest", "forest", "maze", "maze"],
                "seed": seed,
                "robot": [0, 1, 0, 1],
                "success": won,
            }
        ).assign(collision=0, robot_collision=lambda d: 1 - d.success, timeout=0, deadlock=0)
        (tmp_path / name).mkdir()
        ep.to_csv(tmp_path / name / rundir.SHARED_EPISODES, index=False)
        folders.append(str(tmp_path / name))
    df = shared_report.kept_rows([f"plan={'+'.join(folders)}"]).set_index("family")
    assert list(df.index) == ["forest", "maze", "all"] and (df.seeds == 2).all()
    assert df.loc["forest", "success"] == 0.75 and df.loc["maze", "success"] == 0.0
    assert df.loc["all", "success"] == 0.375 and df.loc["all", "worst_seed"] == 0.25
    assert df.loc["all", "robot_collision"] == 0.625
    assert "| 2 | plan | all | 0.375" in shared_report.markdown(df.reset_index())
    with pytest.raises(SystemExit, match="pooled twice"):
        shared_report.kept_rows([f"twice={folders[0]}+{folders[0]}"])
    other_k = pd.read_csv(Path(folders[0]) / rundir.SHARED_EPISODES).assign(robots_per_room=4)
    (tmp_path / "k4").mkdir()
    other_k.to_csv(tmp_path / "k4" / rundir.SHARED_EPISODES, index=False)
    both = shared_report.kept_rows([f"ks={folders[0]}+{tmp_path / 'k4'}"])  # one seed, K = 2 and K = 4 apart
    assert sorted(set(both.robots_per_room)) == [2, 4]
    with pytest.raises(SystemExit, match="no kept evaluation"):
        shared_report.kept_rows([f"none={tmp_path}"])
