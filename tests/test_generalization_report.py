"""The generalization report (docs/generalization.md): the table reads each point's summary.json,
arena eval.json and suite files; the goal check applies the sweep's `goal:`; the figures are
drawn. Points are written by hand (no training, no evaluation): the report only reads files."""

import json

import numpy as np
import pandas as pd
import pytest

from fedjax_nav.analysis import generalization as gz
from fedjax_nav.analysis import generalization_figures as gf
from fedjax_nav.config.sweepfile import load_sweep
from fedjax_nav.configs import SWEEP_DIR
from fedjax_nav.experiments.generalization import report
from fedjax_nav.rundir import RunDirError

FAMILIES = ["cylinders", "boxes", "walls", "mixture"]


@pytest.fixture(scope="module")
def sweep():
    return load_sweep(SWEEP_DIR / "generalization.yaml")


def _point(sweep, stem, episodes=125):
    for p in sweep.points:
        if str(p.values["base"]).endswith(f"/{stem}.yaml") and p.cfg.run.episodes == episodes:
            return p
    raise KeyError(stem)


def _write(folder, train, arena_per_seed, family_per_seed):
    """A finished, evaluated point: 2 seeds; family_per_seed: family -> [seed 0, seed 1]."""
    folder.mkdir(parents=True)
    s = {"seeds": 2, "episodes_done": 125, "success_last": np.mean(train), "success_last_std": np.std(train)}
    s["success_last_per_seed"] = train
    (folder / "summary.json").write_text(json.dumps(s))
    ev = folder / "eval" / "eval"
    ev.mkdir(parents=True)
    overall = {"success_rate": float(np.mean(arena_per_seed)), "success_seed_std": float(np.std(arena_per_seed))}
    per = {str(i): v for i, v in enumerate(arena_per_seed)}
    (ev / "eval.json").write_text(json.dumps({"all_agents": {"overall": overall, "success_per_seed": per}}))
    suite = folder / "eval" / "heldout"
    suite.mkdir(parents=True)
    rows = [
        {"family": f, "success": np.mean(v), "ci_seeds_low": min(v), "ci_seeds_high": max(v)}
        for f, v in family_per_seed.items()
    ]
    rows.append({"family": "all", "success": np.mean([np.mean(v) for v in family_per_seed.values()])})
    fam = pd.DataFrame(rows).assign(ci_rooms_low=0.0, ci_rooms_high=1.0)
    fam.to_csv(suite / "suite_families.csv", index=False)
    eps = [
        {"family": f, "seed": seed, "success": int(k < round(10 * v[seed]))}
        for f, v in family_per_seed.items()
        for seed in range(2)
        for k in range(10)
    ]
    pd.DataFrame(eps).to_csv(suite / "suite_episodes.csv", index=False)
    (suite / "suite.json").write_text(json.dumps({"attempts_per_agent": 1}))


def test_the_report_reads_points_and_checks_the_goal(sweep, tmp_path):
    fixed, proc = _point(sweep, "flddpg-thesis"), _point(sweep, "flddpg-procedural")
    _write(tmp_path / "points" / fixed.id, [0.9, 0.8], [0.5, 0.3], {f: [0.6, 0.4] for f in FAMILIES})
    # episodes 0-99 (outside the last 25) all collisions; 100-124: 3 goals and 1 collision each
    ep = np.arange(125)
    metrics = pd.DataFrame({"episode": ep, "seed": 0, "goals": np.where(ep >= 100, 3, 0)})
    metrics = metrics.assign(collisions=np.where(ep >= 100, 1, 5), reached_goal=ep >= 100, eval_success=np.nan)
    metrics.to_csv(tmp_path / "points" / fixed.id / "metrics.csv", index=False)
    good = {"cylinders": [0.9, 1.0], "boxes": [0.9, 0.9], "walls": [0.8, 0.8], "mixture": [0.9, 0.8]}
    _write(tmp_path / "points" / proc.id, [0.7, 0.7], [1.0, 0.9], good)
    out = report(sweep, tmp_path, evaluate=False, copy_tables=tmp_path / "res", echo=lambda s: None)
    t = pd.read_csv(tmp_path / "generalization.csv").set_index("rooms")
    assert list(t.index) == ["thesis rooms", "procedural (mixture)"]  # grid order of the file
    assert t.loc["procedural (mixture)", "arena"] == pytest.approx(0.95)
    assert t.loc["procedural (mixture)", "walls"] == pytest.approx(0.8)
    assert t.loc["procedural (mixture)", "cylinders_ci_seeds_high"] == pytest.approx(1.0)
    assert t.loc["thesis rooms", "train_success"] == pytest.approx(0.85)
    assert t.loc["thesis rooms", "train_goal_share"] == pytest.approx(0.75)  # 75 goals of 100 ended attempts
    assert np.isnan(t.loc["procedural (mixture)", "train_goal_share"])  # no metrics.csv written
    assert list(t.learner) == ["ddpg", "ddpg"]  # a sweep over learners (configs/sweeps/learners.yaml) names each
    g = pd.read_csv(tmp_path / "generalization_goal.csv")
    assert len(g) == 1 and g.rooms[0] == "procedural (mixture)"  # the goal concerns procedural training
    assert g.worst_family[0] == "walls" and not g.goal_reached[0]  # 0.80 < 0.85
    ps = pd.read_csv(tmp_path / "generalization_per_seed.csv")
    row = ps[(ps.rooms == "procedural (mixture)") & (ps.seed == 0)].iloc[0]
    assert row.cylinders == pytest.approx(0.9) and row.arena == pytest.approx(1.0)
    assert [p.name for p in out["figures"]] == ["generalization_125.png"]
    assert (tmp_path / "res" / "generalization_goal.csv").exists()
    md = (tmp_path / "generalization.md").read_text()  # mean [seed interval], mean +- seed std
    assert "| 0.800 [0.80, 0.80] |" in md and "| 0.950 +- 0.050 |" in md and "label" not in md.split("## Every")[1]


def test_the_table_keeps_what_each_point_cost_from_its_summary(sweep, tmp_path):
    """Bytes sent, wall time and the resume episode ride in the table (results/ outlives the run
    folders); a summary without them (an older run) leaves them missing, not zero."""
    fixed, proc = _point(sweep, "flddpg-thesis"), _point(sweep, "flddpg-procedural")
    fams = {f: [0.5, 0.5] for f in FAMILIES}
    _write(tmp_path / "points" / fixed.id, [0.9, 0.8], [0.5, 0.3], fams)
    _write(tmp_path / "points" / proc.id, [0.7, 0.7], [1.0, 0.9], fams)
    f = tmp_path / "points" / proc.id / "summary.json"
    s = json.loads(f.read_text()) | {"fed_bytes_sent": 7.3e6, "wall_s": 1234.5, "resumed_from_episode": 20}
    f.write_text(json.dumps(s))
    report(sweep, tmp_path, evaluate=False, echo=lambda s: None)
    t = pd.read_csv(tmp_path / "generalization.csv").set_index("rooms")
    assert t.loc["procedural (mixture)", ["fed_bytes", "wall_s", "resumed_from_episode"]].tolist() == [
        7.3e6,
        1234.5,
        20,
    ]
    assert t.loc["thesis rooms", ["fed_bytes", "wall_s"]].isna().all()
    md = (tmp_path / "generalization.md").read_text()
    assert "| 7.3 MB | 1,234 (from ep. 20) |" in md


def test_the_goal_holds_only_when_every_family_the_arena_and_the_worst_tenth_pass():
    row = {"method": "flddpg", "rooms": "procedural (mixture)", "episodes": 125, "seeds": 4}
    t = pd.DataFrame(
        [
            row | {"arena": 0.91, "all_worst10": 0.5} | {f: 0.86 for f in FAMILIES},
            row | {"arena": 0.89, "all_worst10": 0.9} | {f: 0.99 for f in FAMILIES},
            row | {"arena": 0.99, "rooms": "thesis rooms"} | {f: 0.99 for f in FAMILIES},
            row | {"arena": 0.96, "all_worst10": 0.81} | {f: 0.96 for f in FAMILIES},
            row | {"arena": 0.96, "all_worst10": 0.81} | {f: 0.96 for f in FAMILIES} | {"walls": 0.94},
        ]
    )
    first = gz.goal(t, FAMILIES, {"family": 0.85, "arena": 0.90})  # the worst tenth not asked
    assert first.goal_reached.tolist() == [True, False, True, True]
    scale = gz.goal(t, FAMILIES, {"family": 0.95, "arena": 0.95, "worst10": 0.80})
    assert scale.goal_reached.tolist() == [False, False, True, False]
    assert scale.worst_family.tolist()[3] == "walls" and scale.worst10.tolist()[2] == pytest.approx(0.81)
    assert scale.goal[0] == "family >= 0.95, arena >= 0.95, worst10 >= 0.80"
    assert gz.goal(t, FAMILIES, {"worst10": 0.5}).goal_reached.tolist() == [True, True, True, True]


def test_each_sweep_names_its_goal_and_a_sweep_without_one_keeps_the_first_experiments():
    assert load_sweep(SWEEP_DIR / "generalization_1e8.yaml").goal == {"family": 0.95, "arena": 0.95, "worst10": 0.8}
    assert load_sweep(SWEEP_DIR / "learners.yaml").goal == {"family": 0.85, "arena": 0.90}


def test_rooms_are_named_from_the_config(sweep):
    names = {gz.rooms(p.cfg) for p in sweep.points}
    assert names == {
        "thesis rooms",
        "procedural (mixture)",
        "heterogeneous (cylinders, boxes, walls, mixture, mixture)",
    }


def test_another_sweep_over_the_same_points_reports_beside_it_named_by_its_points(sweep, tmp_path):
    """generalization_levers shares its first point with the generalization sweep: its report
    writes generalization_levers*.csv next to generalization*.csv, rows named by their labels."""
    levers = load_sweep(SWEEP_DIR / "generalization_levers.yaml")
    assert levers.points[0].id == _point(sweep, "flddpg-procedural").id
    fams = {f: [0.5, 0.6] for f in FAMILIES}
    for p in levers.points[:2]:
        _write(tmp_path / "points" / p.id, [0.4, 0.5], [0.2, 0.3], fams)
    report(sweep, tmp_path, evaluate=False, echo=lambda s: None)
    out = report(levers, tmp_path, evaluate=False, copy_tables=tmp_path / "res", echo=lambda s: None)
    assert len(pd.read_csv(tmp_path / "generalization.csv")) == 1
    t = pd.read_csv(tmp_path / "generalization_levers.csv")
    assert t.label.tolist() == [p.label for p in levers.points[:2]]
    assert pd.read_csv(tmp_path / "res" / "generalization_levers_goal.csv").label.tolist() == t.label.tolist()
    assert [p.name for p in out["figures"]] == ["generalization_levers_125.png"]


def test_the_probe_curve_averages_the_probe_episodes_over_robots_and_seeds(sweep, tmp_path):
    p = _point(sweep, "flddpg-procedural")
    _write(tmp_path / "points" / p.id, [0.4, 0.5], [0.2, 0.3], {f: [0.5, 0.6] for f in FAMILIES})
    rows = []
    for ep in range(10):
        for seed in range(2):
            for robot in range(5):
                probe = (0.2 * seed + 0.1 * robot) if ep % 5 == 4 else np.nan  # the probe every 5 episodes
                rows.append(
                    {"episode": ep, "seed": seed, "robot": robot, "reached_goal": robot % 2, "eval_success": probe}
                )
    pd.DataFrame(rows).to_csv(tmp_path / "points" / p.id / "metrics.csv", index=False)
    c = gz.probe_curves(sweep, tmp_path / "points")
    assert c.episode.tolist() == [4, 9]
    np.testing.assert_allclose(c.probe, [0.3, 0.3])  # robots 0.2 on average, seeds 0.2 apart
    np.testing.assert_allclose(c.probe_seed_std, [0.1, 0.1])
    np.testing.assert_allclose(c.train, [0.4, 0.4])
    assert gf.probe_figure(c, tmp_path / "probe.png").stat().st_size > 0


def _probe_metrics(folder, probe):
    """metrics.csv of a point whose held-out probe ran at episodes 4 and 9 with success `probe`."""
    rows = [
        {"episode": ep, "seed": 0, "robot": 0, "goals": 1, "collisions": 0, "reached_goal": 1}
        | {"eval_success": probe if ep % 5 == 4 else np.nan}
        for ep in range(10)
    ]
    pd.DataFrame(rows).to_csv(folder / "metrics.csv", index=False)


def test_figures_of_a_report_from_a_partial_folder_draw_every_point_results_keeps(sweep, tmp_path, monkeypatch):
    """A report from a folder holding only the newest point (the older ones trained on a machine
    whose run folders are gone) draws its bars and probe curves from the merged tables in results/,
    so the figures copied to docs keep the older points; the probe curves are kept in results/."""
    first, second = _point(sweep, "iddpg-procedural"), _point(sweep, "flddpg-procedural")
    a, b, res = tmp_path / "a", tmp_path / "b", tmp_path / "res"
    for folder, p, probe in ((a, first, 0.25), (a, second, 0.5), (b, second, 0.75)):
        _write(folder / "points" / p.id, [0.4, 0.5], [0.2, 0.3], {f: [probe, probe] for f in FAMILIES})
        _probe_metrics(folder / "points" / p.id, probe)
    report(sweep, a, evaluate=False, copy_tables=res, echo=lambda s: None)
    drawn = {}
    monkeypatch.setattr(gf, "figure", lambda t, fams, path, goal, e: drawn.setdefault("bars", t) is None or path)
    monkeypatch.setattr(gf, "probe_figure", lambda c, path: drawn.setdefault("probe", c) is None or path)
    report(sweep, b, evaluate=False, copy_tables=res, echo=lambda s: None)
    assert drawn["bars"].set_index("point").walls.to_dict() == {first.id: 0.25, second.id: 0.75}
    assert drawn["probe"].groupby("point").probe.max().to_dict() == {first.id: 0.25, second.id: 0.75}
    kept = pd.read_csv(res / "generalization_probe.csv")
    assert sorted(zip(kept.point, kept.episode)) == sorted((p.id, e) for p in (first, second) for e in (4, 9))
    assert pd.read_csv(b / "generalization_probe.csv").point.unique().tolist() == [second.id]  # the folder's own
    drawn.clear()
    report(sweep, b, evaluate=False, echo=lambda s: None)  # no copy to results/: the folder's points only
    assert drawn["bars"].point.tolist() == [second.id] and drawn["probe"].point.unique().tolist() == [second.id]


def test_a_point_evaluated_with_the_same_attempts_is_not_evaluated_again(tmp_path):
    from fedjax_nav.evaluation.suite import kept_suite

    d = tmp_path / "eval" / "heldout"
    assert kept_suite(tmp_path, "heldout", 1) is None
    d.mkdir(parents=True)
    (d / "suite.json").write_text(json.dumps({"attempts_requested": 1, "attempts_per_agent": 5}))  # SNDDPG: 1 net
    assert kept_suite(tmp_path, "heldout", 1) is not None and kept_suite(tmp_path, "heldout", 2) is None
    (d / "suite.json").write_text(json.dumps({"attempts_per_agent": 1}))  # written before attempts_requested was kept
    assert kept_suite(tmp_path, "heldout", 1) is not None


def test_probe_legend_names_what_tells_points_apart():
    from fedjax_nav.analysis.generalization_figures import distinct_parts

    a = "method=snddpg, env.room_families=('cylinders', 'boxes'), ppo.gamma=0.99, env.reward_collision=-10.0"
    b = "method=snddpg, env.room_families=('cylinders', 'boxes'), ppo.gamma=0.999, env.reward_collision=-10.0"
    c = "method=snddpg, env.room_families=('mixture',), ppo.gamma=0.999, env.reward_collision=-10.0"
    assert distinct_parts([a, b]) == {a: "ppo.gamma=0.99", b: "ppo.gamma=0.999"}
    # a tuple's commas stay inside its part
    want = {b: "env.room_families=('cylinders', 'boxes')", c: "env.room_families=('mixture',)"}
    assert distinct_parts([b, c]) == want
    assert distinct_parts([a]) == {a: a} and distinct_parts([a, a]) == {a: a}


def test_probe_curves_are_named_the_same_in_every_methods_panel():
    """An 18-point sweep (3 learners x 2 fleets x 3 methods) named its curves by whole labels,
    method and room tuple included: 18 legend entries. A curve is named by its fleet and what else
    tells points apart, the method being its panel: 6 names, each in every panel, every budget of a
    curve under one name (the longest is drawn)."""
    from fedjax_nav.analysis.generalization_figures import curve_names

    het = "heterogeneous (cylinders, boxes, walls, mixture, mixture)"
    fams = {het: "('cylinders', 'boxes', 'walls', 'mixture', 'mixture')", "procedural (mixture)": "('mixture',)"}
    rows = [
        {"point": f"{cfg}{m}{rooms[:3]}{ep}", "method": m, "rooms": rooms, "budget": ep}
        | {"label": f"config={cfg}, env.room_families={fams[rooms]}, method={m}, run.episodes={ep}"}
        for cfg in ("td3", "ppo-gru", "ddpg")
        for rooms in fams
        for m in ("flddpg", "iddpg", "snddpg")
        for ep in (30, 300)
    ]
    c = pd.DataFrame(rows)
    names = curve_names(c)
    assert sorted(set(names)) == sorted(
        f"{f}, config={cfg}" for f in ("heterogeneous", "procedural") for cfg in ("td3", "ppo-gru", "ddpg")
    )
    assert (c.assign(n=names).groupby("n").method.nunique() == 3).all()
    one = c[c.label.str.startswith("config=td3")]  # nothing but the fleet tells points apart
    assert set(curve_names(one)) == {"heterogeneous", "procedural"}
    two = one.assign(rooms=one.rooms.str.replace("procedural (mixture)", "procedural (walls)"), point=one.point + "w")
    two = pd.concat([one[one.rooms == "procedural (mixture)"], two[two.rooms == "procedural (walls)"]])
    assert set(curve_names(two)) == {"procedural (mixture)", "procedural (walls)"}  # two fleets share the word


def test_figures_give_up_to_twenty_points_a_colour_each():
    """The bars and probe curves took matplotlib's 10-colour cycle: a sweep of 24 points drew
    pairs of points in one colour."""
    from fedjax_nav.analysis.plots import distinct_colors

    for n in (1, 10, 11, 18, 20):
        assert len(set(distinct_colors(n))) == n, n


def test_bars_of_several_learners_get_a_panel_each_with_one_legend(tmp_path, monkeypatch):
    """23 points of four learners drew 23 bars per family with a 23-line legend of whole labels: the
    bars now stand one panel per learner (what tells points apart besides method and fleet), each
    named by method and fleet, one legend entry per name across the panels."""
    import matplotlib.figure

    het = "heterogeneous (cylinders, boxes, walls, mixture, mixture)"
    fams = {het: "('cylinders', 'boxes', 'walls', 'mixture', 'mixture')", "procedural (mixture)": "('mixture',)"}
    rows = [
        {"point": f"{cfg}{m}{rooms[:3]}", "method": m, "rooms": rooms, "episodes": 30, "arena": 0.5}
        | {"arena_seed_std": 0.1, "label": f"config={cfg}, env.room_families={fams[rooms]}, method={m}"}
        | {f: 0.8 for f in FAMILIES}
        for cfg in ("td3", "ppo")
        for rooms in fams
        for m in ("flddpg", "iddpg")
    ]
    seen = {}
    real = matplotlib.figure.Figure.legend
    monkeypatch.setattr(
        matplotlib.figure.Figure,
        "legend",
        lambda fig, h, labels, **kw: (
            seen.update(panels=[a.get_title(loc="left") for a in fig.axes], names=list(labels))
            or real(fig, h, labels, **kw)
        ),
    )
    assert gf.figure(pd.DataFrame(rows), FAMILIES, tmp_path / "bars.png", {"family": 0.95}, 30).stat().st_size > 0
    assert seen["panels"] == ["config=td3", "config=ppo"]
    want = [f"{m}, {f}" for f in ("heterogeneous", "procedural") for m in ("FLDDPG", "IDDPG")]
    assert seen["names"] == want
    # a sweep of levers (one point each): one panel, what tells a point apart in its bar's name
    gf.figure(pd.DataFrame(rows[3:5]), FAMILIES, tmp_path / "levers.png", {"family": 0.95}, 30)
    assert seen["panels"] == [""] and seen["names"] == [
        "IDDPG, procedural, config=td3",
        "FLDDPG, heterogeneous, config=ppo",
    ]


def test_a_report_on_a_second_suite_writes_beside_the_first(sweep, tmp_path):
    """The heldout report's tables are kept when the same points are reported on dense-heldout:
    the second suite's files carry its name; the probe ran in training, so its curves are one file
    named after the sweep, whichever suite is reported."""
    import shutil

    from fedjax_nav.experiments.generalization import report_name

    p = _point(sweep, "flddpg-procedural")
    _write(tmp_path / "points" / p.id, [0.7, 0.7], [1.0, 0.9], {f: [0.9, 0.8] for f in FAMILIES})
    _probe_metrics(tmp_path / "points" / p.id, 0.5)
    dense = tmp_path / "points" / p.id / "eval" / "dense-heldout"
    shutil.copytree(tmp_path / "points" / p.id / "eval" / "heldout", dense)
    fam = pd.read_csv(dense / "suite_families.csv")
    fam = fam.assign(family=fam.family.replace({"walls": "maze"}), success=0.1)
    fam.to_csv(dense / "suite_families.csv", index=False)
    report(sweep, tmp_path, evaluate=False, copy_tables=tmp_path / "res", echo=lambda s: None)
    report(sweep, tmp_path, suite="dense-heldout", evaluate=False, copy_tables=tmp_path / "res", echo=lambda s: None)
    assert report_name("generalization", "dense-heldout") == "generalization_dense-heldout"
    held = pd.read_csv(tmp_path / "res" / "generalization.csv")
    assert "walls" in held and held.walls[0] == pytest.approx(0.85)
    d = pd.read_csv(tmp_path / "res" / "generalization_dense-heldout.csv")
    assert "maze" in d and "walls" not in d and d.maze[0] == pytest.approx(0.1)
    assert (tmp_path / "generalization_dense-heldout.md").exists()
    assert (tmp_path / "res" / "generalization_dense-heldout_goal.csv").exists()
    assert sorted(f.name for f in (tmp_path / "res").glob("*probe*")) == ["generalization_probe.csv"]


def test_per_net_rows_name_the_rooms_each_network_trained_on(sweep, tmp_path):
    """A heterogeneous fleet's robot i trained on family i; a central learner's one network on all
    of them: <name>_per_net.csv gives each network's success per held-out family and overall."""
    fed, central = _point(sweep, "flddpg-hetero"), _point(sweep, "snddpg-hetero")
    fams = {f: [0.5, 0.5] for f in FAMILIES}
    for p in (fed, central):
        _write(tmp_path / "points" / p.id, [1.0, 1.0], [0.5, 0.5], fams)
    # network i succeeds on walls in i of its 4 episodes there, everywhere else always
    nets = [(central, [0]), (fed, range(5))]
    for p, ids in nets:
        eps = [
            {"family": f, "seed": seed, "net": i, "success": int(f != "walls" or 2 * seed + k < i)}
            for i in ids
            for f in FAMILIES
            for seed in range(2)
            for k in range(2)
        ]
        pd.DataFrame(eps).to_csv(tmp_path / "points" / p.id / "eval" / "heldout" / "suite_episodes.csv", index=False)
    report(sweep, tmp_path, evaluate=False, copy_tables=tmp_path / "res", echo=lambda s: None)
    t = pd.read_csv(tmp_path / "res" / "generalization_per_net.csv")
    f = t[t.method == "flddpg"].set_index("net")
    assert f.trained_on.tolist() == ["cylinders", "boxes", "walls", "mixture", "mixture"]
    assert f.walls.tolist() == pytest.approx([0.0, 0.25, 0.5, 0.75, 1.0])
    assert f.cylinders.tolist() == pytest.approx([1.0] * 5)
    assert f["all"].tolist() == pytest.approx([0.75, 0.8125, 0.875, 0.9375, 1.0])
    c = t[t.method == "snddpg"]
    assert len(c) == 1 and c.trained_on.iloc[0] == "cylinders+boxes+walls+mixture" and c.walls.iloc[0] == 0.0


def _reported_twice_over(sweep, tmp_path, first, second):
    """Folder a holds both points, folder b only `second`; a is reported into res/ (the copy the
    tests then alter and report b over). Returns (a, b, res)."""
    fams = {f: [0.5, 0.6] for f in FAMILIES}
    a, b = tmp_path / "a", tmp_path / "b"
    for folder, p in ((a, first), (a, second), (b, second)):
        _write(folder / "points" / p.id, [0.4, 0.5], [0.2, 0.3], fams)
    res = tmp_path / "res"
    report(sweep, a, evaluate=False, copy_tables=res, echo=lambda s: None)
    return a, b, res


def test_copied_tables_keep_the_points_trained_elsewhere_in_the_sweeps_order(sweep, tmp_path):
    """results/ holds every point reported so far: a report from a folder that lacks some points
    (trained on another machine) keeps their rows in the copy; rows of points no longer in the
    sweep are dropped, and both are said."""
    first, second = _point(sweep, "flddpg-thesis"), _point(sweep, "flddpg-procedural")
    _, b, res = _reported_twice_over(sweep, tmp_path, first, second)
    stale = pd.read_csv(res / "generalization.csv")
    pd.concat([stale, stale.iloc[:1].assign(point="0123456789ab")]).to_csv(res / "generalization.csv", index=False)
    said = []
    report(sweep, b, evaluate=False, copy_tables=res, echo=said.append)
    assert pd.read_csv(b / "generalization.csv").point.tolist() == [second.id]  # the folder's own table
    assert pd.read_csv(res / "generalization.csv").point.tolist() == [first.id, second.id]  # grid order
    per_seed = pd.read_csv(res / "generalization_per_seed.csv")
    assert sorted(zip(per_seed.point, per_seed.seed)) == sorted((p.id, s) for p in (first, second) for s in (0, 1))
    assert pd.read_csv(res / "generalization_goal.csv").point.tolist() == [second.id]  # thesis rooms: no goal
    assert any("kept 1 row(s)" in s and "dropped 1" in s for s in said), said


def test_the_copied_goal_table_checks_every_kept_point_and_an_unmatchable_copy_is_said(sweep, tmp_path):
    """The goal table in results/ is the goal check of the merged main table, so a kept point keeps
    its goal row even where the old goal copy cannot be matched to points (written before its
    `point` column); a table that cannot be matched is replaced, and said."""
    ind, fed = _point(sweep, "iddpg-procedural"), _point(sweep, "flddpg-procedural")
    _, b, res = _reported_twice_over(sweep, tmp_path, ind, fed)
    goal = pd.read_csv(res / "generalization_goal.csv")
    goal.drop(columns="point").to_csv(res / "generalization_goal.csv", index=False)  # an older copy
    per_seed = pd.read_csv(res / "generalization_per_seed.csv")
    per_seed.drop(columns="point").to_csv(res / "generalization_per_seed.csv", index=False)
    said = []
    report(sweep, b, evaluate=False, copy_tables=res, echo=said.append)
    assert pd.read_csv(res / "generalization_goal.csv").point.tolist() == [ind.id, fed.id]
    assert pd.read_csv(res / "generalization_per_seed.csv").point.unique().tolist() == [fed.id]
    assert any("generalization_per_seed.csv: replaced" in s and "point" in s for s in said), said


def test_a_report_from_a_folder_without_points_keeps_results_and_rederives_the_goal(sweep, tmp_path):
    """A report on an empty (or wrong) folder never wipes results/: every table keeps its rows, and
    the goal table is derived again from the main table (how the goal tables of points trained on
    lost machines are brought up to the current goal check)."""
    fams = {f: [0.5, 0.6] for f in FAMILIES}
    ind, fed = _point(sweep, "iddpg-procedural"), _point(sweep, "flddpg-procedural")
    a = tmp_path / "a"
    for p in (ind, fed):
        _write(a / "points" / p.id, [0.4, 0.5], [0.2, 0.3], fams)
    res = tmp_path / "res"
    report(sweep, a, evaluate=False, copy_tables=res, echo=lambda s: None)
    before = {f.name: f.read_text() for f in res.iterdir()}
    goal = pd.read_csv(res / "generalization_goal.csv")
    goal.drop(columns=["point", "worst10"]).to_csv(res / "generalization_goal.csv", index=False)  # an older copy
    with pytest.raises(RunDirError, match="no_such: no such sweep folder"):
        report(sweep, tmp_path / "no_such", evaluate=False, copy_tables=res, echo=lambda s: None)
    (tmp_path / "empty").mkdir()
    report(sweep, tmp_path / "empty", evaluate=False, copy_tables=res, echo=lambda s: None)
    after = {f.name: f.read_text() for f in res.iterdir()}
    assert after == before


def _seed_rows(point, method, label, matrix, episodes=300):
    """per_seed rows of one point: matrix[seed][family] over FAMILIES."""
    base = {"point": point, "label": label, "method": method, "learner": "ppo", "rooms": "r", "episodes": episodes}
    return [base | {"seed": s} | dict(zip(FAMILIES, row)) for s, row in enumerate(matrix)]


def test_iqm_and_probability_of_improvement_match_an_independent_computation():
    """rliable's IQM is scipy's 25 % trimmed mean of the flat seeds x families matrix (an outlying seed
    moves it less than the mean); the probability of improvement is, per family, the share of seed
    pairs where the first point is above (ties half), averaged over families; only points that differ
    in nothing but the method are compared."""
    pytest.importorskip("rliable")
    from scipy.stats import trim_mean

    rng = np.random.default_rng(0)
    fl = rng.uniform(0.6, 1.0, (4, 4))
    fl[0] = 0.0  # one failed seed
    ind = rng.uniform(0.5, 0.9, (4, 4))
    ind[1, 2] = fl[2, 2]  # a tie
    other = rng.uniform(0.0, 1.0, (4, 4))
    ps = pd.DataFrame(
        _seed_rows("a", "flddpg", "env.x=1, method=flddpg, run.episodes=300", fl)
        + _seed_rows("b", "iddpg", "env.x=1, method=iddpg, run.episodes=300", ind)
        + _seed_rows("c", "iddpg", "env.x=1, method=iddpg, run.episodes=30", other, episodes=30)
    )
    r = gz.robust(ps, FAMILIES).set_index("point")
    assert r.loc["a", "iqm"] == pytest.approx(trim_mean(fl.ravel(), 0.25))
    assert r.loc["a", "iqm"] == pytest.approx(np.sort(fl.ravel())[4:12].mean())  # the middle 8 of 16
    assert r.loc["a", "mean"] == pytest.approx(fl.mean()) and r.loc["a", "iqm"] > r.loc["a", "mean"]

    def prob(x, y):
        return np.mean([np.mean([(a > b) + 0.5 * (a == b) for a in x[:, f] for b in y[:, f]]) for f in range(4)])

    assert r.loc["a", "p_over_iddpg"] == pytest.approx(prob(fl, ind))
    assert r.loc["b", "p_over_flddpg"] == pytest.approx(prob(ind, fl))
    assert r.loc["a", "p_over_iddpg"] + r.loc["b", "p_over_flddpg"] == pytest.approx(1.0)
    assert np.isnan(r.loc["c", "p_over_flddpg"])  # 30 episodes: no FLDDPG point with its other settings
    assert np.isnan(r.loc["a", "p_over_flddpg"])  # never against its own method
    shown = gz.robust_readable(r.reset_index())
    assert "P(> IDDPG)" in shown.columns and shown.loc[0, "P(> FLDDPG)"] == "-"


def test_the_report_writes_the_iqm_table_beside_the_others(sweep, tmp_path):
    pytest.importorskip("rliable")
    fl, ind = _point(sweep, "flddpg-procedural"), _point(sweep, "iddpg-procedural")
    _write(tmp_path / "points" / fl.id, [0.7, 0.7], [1.0, 0.9], {f: [0.9, 0.8] for f in FAMILIES})
    _write(tmp_path / "points" / ind.id, [0.7, 0.7], [1.0, 0.9], {f: [0.6, 0.5] for f in FAMILIES})
    report(sweep, tmp_path, evaluate=False, copy_tables=tmp_path / "res", echo=lambda s: None)
    r = pd.read_csv(tmp_path / "generalization_iqm.csv").set_index("method")
    assert r.loc["flddpg", "p_over_iddpg"] == 1.0 and r.loc["iddpg", "p_over_flddpg"] == 0.0
    assert r.loc["flddpg", "iqm"] == pytest.approx(0.85)
    assert (tmp_path / "res" / "generalization_iqm.csv").exists()
    assert "## IQM and probability of improvement" in (tmp_path / "generalization.md").read_text()


def test_without_rliable_the_report_says_which_extra_to_install_and_writes_the_rest(sweep, tmp_path, monkeypatch):
    import re
    import sys
    from pathlib import Path

    import tomllib

    monkeypatch.setitem(sys.modules, "rliable", None)  # `import rliable` raises ImportError
    fl = _point(sweep, "flddpg-procedural")
    _write(tmp_path / "points" / fl.id, [0.7, 0.7], [1.0, 0.9], {f: [0.9, 0.8] for f in FAMILIES})
    lines = []
    report(sweep, tmp_path, evaluate=False, echo=lines.append)
    assert (tmp_path / "generalization.csv").exists() and not (tmp_path / "generalization_iqm.csv").exists()
    said = [s for s in lines if "rliable" in s]
    extra = re.search(r"fedjax_nav\[(\w+)\]", said[0]).group(1)
    pyproject = tomllib.loads((Path(__file__).resolve().parents[1] / "pyproject.toml").read_text())
    assert any(r.startswith("rliable") for r in pyproject["project"]["optional-dependencies"][extra])


def test_the_committed_iqm_table_and_the_guides_numbers_derive_from_the_committed_per_seed_table():
    """results/generalization_1e8_iqm.csv is `robust` of results/generalization_1e8_per_seed.csv, and
    the federated question's table in docs/generalization.md shows its 9.8e7 rows' IQM and
    probabilities as they are (a new report or a changed statistic cannot leave the docs behind)."""
    pytest.importorskip("rliable")
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    r = gz.robust(pd.read_csv(root / "results" / "generalization_1e8_per_seed.csv"), FAMILIES)
    pd.testing.assert_frame_equal(r, pd.read_csv(root / "results" / "generalization_1e8_iqm.csv"), check_dtype=False)
    guide = (root / "docs" / "generalization.md").read_text()
    order = ("flddpg", "iddpg", "snddpg")
    for _, p in r[r.episodes == 300].iterrows():
        cells = [f"{p['iqm']:.3f}"] + ["-" if m == p.method else f"{p[f'p_over_{m}']:.3f}" for m in order]
        assert f"| {p['mean']:.3f} [" in guide and "| " + " | ".join(cells) + " |" in guide, p.point
