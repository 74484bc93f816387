"""The tail of a held-out suite (docs/generalization.md, "Tail metrics"): the shortest safe path
(fedjax_nav/evaluation/paths.py) against hand-computed lengths, the worst 10 % of rooms and its
interval, the family rows, and the columns reaching the generalization tables
(fedjax_nav/analysis/generalization.py) without changing the existing ones."""

import math

import numpy as np
import pandas as pd
import pytest

from fedjax_nav import worlds
from fedjax_nav.analysis import generalization as gz
from fedjax_nav.evaluation import paths, suite, suite_stats

C = 0.25  # the collision distance
RES = paths.RES


def room(**spec):
    return paths.room_arrays(worlds.from_dict(spec)[0])


@pytest.mark.parametrize("goal", [(2.0, 1.2), (2.0, -1.0), (2.5, 0.57), (-2.4, 1.5)])
@pytest.mark.parametrize("radius", [0.0, 0.5])
def test_an_empty_room_gives_the_straight_line(goal, radius):
    """(2.5, 1.66) is at 22.5 deg from the start, where an 8-connected path is 8 % too long."""
    r = room(size=[6, 4], starts=[[-2.5, -1.5, 0]], goals=[list(goal)])
    want = math.dist((-2.5, -1.5), goal) - radius
    assert paths.shortest_path(r, r["starts"][0], r["goals"][0], C, radius) == pytest.approx(want, abs=RES)


def detour(start, corner, goal, c):
    """Shortest path from start to goal around a disk of radius c at `corner` that the straight
    line crosses: two tangents and the arc between their tangent points."""
    s, g = math.dist(start, corner), math.dist(goal, corner)
    angle = abs(
        math.atan2(start[1] - corner[1], start[0] - corner[0]) - math.atan2(goal[1] - corner[1], goal[0] - corner[0])
    )
    angle = min(angle, 2 * math.pi - angle)  # the angle start-corner-goal on the wall's side
    arc = 2 * math.pi - angle - math.acos(c / s) - math.acos(c / g)
    return math.sqrt(s * s - c * c) + math.sqrt(g * g - c * c) + c * arc


@pytest.mark.parametrize("radius", [0.0, 0.3])
def test_a_wall_with_a_gap_gives_the_detour_by_hand(radius):
    """A wall x = 0 from the floor (y = -2) to y = 0.5, the gap above it; start (-2, -1), goal
    (2, -1): the path rounds the wall's end inflated by C. By hand: |SP| = |GP| = 2.5, tangents
    sqrt(2.5^2 - C^2) = 2.4875 each, the arc C (2 pi - 2 atan(2 / 1.5) - 2 acos(C / 2.5)) = 0.3719:
    5.3468 m, less the goal radius."""
    r = room(size=[6, 4], segments=[[0, -2, 0, 0.5]], starts=[[-2, -1, 0]], goals=[[2, -1]])
    want = detour((-2, -1), (0, 0.5), (2, -1), C) - radius
    assert want + radius == pytest.approx(5.3468, abs=1e-4)
    got = paths.shortest_path(r, r["starts"][0], r["goals"][0], C, radius)
    assert want - 1e-9 <= got <= want + RES  # a safe path: never shorter than the true one


def test_no_safe_path_is_nan_and_a_start_in_the_disk_is_zero():
    closed = room(size=[6, 4], segments=[[0, -2, 0, 2]], starts=[[-2, -1, 0]], goals=[[2, -1]])
    assert np.isnan(paths.shortest_path(closed, closed["starts"][0], closed["goals"][0], C, 0.3))
    narrow = room(size=[6, 4], segments=[[0, -2, 0, 1.6]], starts=[[-2, -1, 0]], goals=[[2, -1]])  # gap 0.4 < 2 C
    assert np.isnan(paths.shortest_path(narrow, narrow["starts"][0], narrow["goals"][0], C, 0.3))
    assert paths.shortest_path(closed, closed["starts"][0], [-1.8, -1.0], C, 0.3) == 0.0


def test_shortest_paths_cover_every_room_and_goal_of_a_stack():
    a = worlds.from_dict({"size": [4, 4], "starts": [[-1, 0, 0]], "goals": [[1, 0], [-1, 1.5]]})[0]
    b = worlds.from_dict({"size": [4, 4], "circles": [[0, 0, 0.5]], "starts": [[-1.5, 0, 0]], "goals": [[1.5, 0]]})[0]
    sp = paths.shortest_paths(worlds.stack([a, b]), C, 0.0)
    assert sp.shape == (2, 2) and np.isnan(sp[1, 1])  # room b has one goal: its padding row is NaN
    np.testing.assert_allclose(sp[0], [2.0, 1.5], atol=1e-9)
    # around a cylinder of radius 0.5 inflated to 0.75: tangents and the arc, as for the wall's end
    s = 1.5
    want = 2 * math.sqrt(s * s - 0.75**2) + 0.75 * (math.pi - 2 * math.acos(0.75 / s))
    assert want - 1e-9 <= sp[1, 0] <= want + RES


def test_the_worst_tenth_of_rooms():
    assert suite_stats.worst_mean([0.5, 0.2, 0.9]) == 0.2  # 3 rooms: the worst one
    x = np.linspace(0, 1, 20)[::-1]
    assert suite_stats.worst_mean(x) == pytest.approx(np.mean(np.sort(x)[:2]))  # 20 rooms: the worst 2
    assert suite_stats.worst_mean(np.arange(50.0)) == pytest.approx(2.0)  # 50 rooms: the worst 5
    assert suite_stats.worst_mean(np.arange(51.0)) == pytest.approx(2.5)  # 51: ceil(5.1) = 6
    rng = np.random.default_rng(0)
    for n in range(1, 30):  # the analysis layer's copy of the statistic agrees
        v = rng.random(n)
        assert gz.worst_rooms(v) == pytest.approx(suite_stats.worst_mean(v))
    batch = rng.random((7, 30))  # vectorised along an axis, as scipy.stats.bootstrap calls it
    np.testing.assert_allclose(suite_stats.worst_mean(batch, axis=-1), [suite_stats.worst_mean(r) for r in batch])


def frame(per_room: list[list[int]], ratio=None, shortest=None) -> pd.DataFrame:
    """Episodes of rooms 0.. with the given successes (one list per room), seeds alternating; every
    goal 2 m away in a straight line, its shortest safe path 2 m unless `shortest` {(room, j): m}."""
    rows = []
    for i, successes in enumerate(per_room):
        for j, s in enumerate(successes):
            rows.append(
                {"room": i, "seed": j % 2, "byzantine": 0, "success": s, "collision": int(not s and j % 2 == 0)}
                | {"timeout": int(not s and j % 2 == 1), "path_ratio": (ratio or {}).get((i, j), np.nan)}
                | {"straight_line": 2.0, "shortest_path": (shortest or {}).get((i, j), 2.0)}
            )
    return pd.DataFrame(rows)


def test_the_family_row_has_the_tail():
    # 20 rooms x 4 episodes; rooms 0 and 1 succeed 0 / 4 and 1 / 4, the rest 3 / 4 or 4 / 4
    per_room = [[0, 0, 0, 0], [1, 0, 0, 0]] + [[1, 1, 1, i % 2] for i in range(18)]
    ep = frame(per_room, ratio={(2, 0): 1.1, (3, 0): 1.3, (4, 0): 2.0})
    row = suite_stats.family_row("walls", ep)
    assert row["worst10_rooms"] == 2 and row["worst10"] == pytest.approx(0.125)
    assert row["worst10_ci_low"] <= row["worst10"] <= row["worst10_ci_high"]
    assert row["worst10_ci_low"] == 0.0 and row["worst10_ci_high"] < row["success"]  # resampled rooms
    assert row["collision"] == pytest.approx(ep.collision.mean()) and row["timeout"] == pytest.approx(ep.timeout.mean())
    assert row["path_ratio_median"] == pytest.approx(1.3) and row["path_ratio_episodes"] == 3
    # the mean's interval is what it was (the default statistic)
    per = ep.groupby("room")["success"].mean()
    assert (row["ci_rooms_low"], row["ci_rooms_high"]) == suite_stats.bootstrap_ci(per, statistic=np.mean)


def test_the_success_splits_by_detour():
    """An episode needs a detour when its goal's shortest safe path is longer than DETOUR x the
    straight line: 2.2 m against 2 m does (1.1), 2.1 m does not (1.05, the bound itself)."""
    assert suite_stats.DETOUR == 1.05
    per_room = [[1, 1, 0, 0], [1, 0, 0, 0]]
    ep = frame(per_room, shortest={(0, 2): 2.2, (0, 3): 2.2, (1, 1): 2.2, (1, 0): 2.1})
    row = suite_stats.family_row("walls", ep)
    # detours: (0, 2), (0, 3), (1, 1), all failed; direct: (0, 0), (0, 1), (1, 0) succeed, (1, 2), (1, 3) fail
    assert row["detour_share"] == pytest.approx(3 / 8)
    assert row["success_detour"] == 0.0 and row["success_direct"] == pytest.approx(3 / 5)
    no_detour = suite_stats.family_row("walls", frame(per_room))
    assert no_detour["detour_share"] == 0.0 and np.isnan(no_detour["success_detour"])


def _tail_point(sweep, tmp_path):
    """A finished point written by hand (test_generalization_report's), its suite files with the tail."""
    from test_generalization_report import _point, _write

    p = _point(sweep, "flddpg-procedural")
    fams = {f: [0.6, 0.8] for f in ["cylinders", "boxes", "walls", "mixture"]}
    _write(tmp_path / "points" / p.id, [0.7, 0.7], [0.9, 0.9], fams)
    folder = tmp_path / "points" / p.id / "eval" / "heldout"
    fam = pd.read_csv(folder / suite.FAMILIES_CSV)
    tail = {"worst10": 0.25, "worst10_ci_low": 0.1, "worst10_ci_high": 0.4, "collision": 0.3, "timeout": 0.05}
    detour = {"detour_share": 0.5, "success_direct": 0.9, "success_detour": 0.2}
    fam.assign(**tail, **detour, path_ratio_median=1.2).to_csv(folder / suite.FAMILIES_CSV, index=False)
    rows = [  # seed s, room i of each family: success i < 8 + s, collision otherwise
        {"family": f, "seed": s, "room": i, "success": int(i < 8 + s), "collision": int(i >= 8 + s), "timeout": 0}
        for f in fams
        for s in range(2)
        for i in range(10)
    ]
    pd.DataFrame(rows).to_csv(folder / suite.EPISODES_CSV, index=False)
    return p


def test_the_tail_reaches_the_generalization_tables(tmp_path):
    from fedjax_nav.config.sweepfile import load_sweep
    from fedjax_nav.configs import SWEEP_DIR

    sweep = load_sweep(SWEEP_DIR / "generalization.yaml")
    _tail_point(sweep, tmp_path)
    t = gz.table(sweep, tmp_path / "points")
    assert {"walls", "walls_ci_seeds_low", "walls_ci_rooms_high"} <= set(t.columns)  # as they always were
    assert t.walls_worst10[0] == 0.25 and t.all_timeout[0] == 0.05 and t.mixture_path_ratio_median[0] == 1.2
    from fedjax_nav.experiments.generalization import families_of

    assert families_of(t) == ["cylinders", "boxes", "walls", "mixture"]  # the new columns name no family
    ps = gz.per_seed(sweep, tmp_path / "points").set_index("seed")
    assert ps.loc[0, "walls_worst10"] == 0.0 and ps.loc[1, "walls_worst10"] == 0.0  # 10 rooms: the worst one
    assert ps.loc[0, "walls_collision"] == pytest.approx(0.2) and ps.loc[1, "walls_collision"] == pytest.approx(0.1)
    assert ps.loc[0, "walls"] == pytest.approx(0.8)
    r = gz.readable(t, ["walls"]).iloc[0]
    assert r["walls worst 10%"] == "0.250 [0.10, 0.40]" and r["collision (all)"] == "0.300"
    assert r["time-out (all)"] == "0.050" and r["path ratio (all)"] == "1.200"
    assert t.walls_detour_share[0] == 0.5 and r["direct / detour (all)"] == "0.900 / 0.200"


def test_tables_without_the_tail_keep_their_columns(tmp_path):
    """Points evaluated before the tail existed: the same columns as before, no tail column."""
    from test_generalization_report import _point, _write

    from fedjax_nav.config.sweepfile import load_sweep
    from fedjax_nav.configs import SWEEP_DIR

    sweep = load_sweep(SWEEP_DIR / "generalization.yaml")
    p = _point(sweep, "flddpg-procedural")
    _write(tmp_path / "points" / p.id, [0.7, 0.7], [0.9, 0.9], {"walls": [0.5, 0.7]})
    t = gz.table(sweep, tmp_path / "points")
    assert not [c for c in t.columns if "worst10" in c or c.endswith(("_collision", "_timeout"))]
    assert list(gz.readable(t, ["walls"]).columns)[-2:] == ["walls", "all"]
    assert "walls_worst10" not in gz.per_seed(sweep, tmp_path / "points").columns
