"""The evaluation protocol: scripted policies with known outcomes on tiny hand-built worlds, the
metrics' bookkeeping, determinism without noise, and `fedjax-nav evaluate` on a tiny trained run
(where its files go: one folder per world, `--out`, re-runs; docs/evaluation.md).

Every scripted test uses the same padded world shape, T and policy objects where it can, so the
evaluation program compiles a few times for the whole file.
"""

import json
import math
import os

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
import yaml  # noqa: E402

from fedjax_nav import rundir, worlds  # noqa: E402
from fedjax_nav.evaluation import (  # noqa: E402
    EVAL_FILES,
    EvalError,
    episodes_frame,
    evaluate_policy,
    load_run,
    summarize,
)

T = 100  # time-out of the scripted tests
V_MAX = 1.0  # m/s: 0.1 m per step, so the 6.5 m drive takes 66 steps
DT = 0.1
GOAL_RADIUS = 0.5
SHAPE = (8, 2, 2, 4)  # padded (segments, circles, starts, goals) of every hand-built world


def _world(start, goals, size=(10.0, 2.0)):
    w, _ = worlds.from_dict({"size": list(size), "starts": [start], "goals": goals}, "<test>")
    return worlds.pad(w, *SHAPE)


# start at x = -4 facing +x; G0 7 m straight ahead, G1 1 m ahead, G2 3 m ahead
CORRIDOR = _world([-4.0, 0.0, 0.0], [[3.0, 0.0], [-3.0, 0.0], [-1.0, 0.0]])
# facing the left wall (x = -5), 1 m away; the goals are behind the robot
FACING_WALL = _world([-4.0, 0.0, math.pi], [[3.0, 0.0], [-3.0, 0.0], [-1.0, 0.0]])
A, K = 4, 2  # agents and attempts of every scripted run (one compiled program serves them all)


def at_goal(obs):
    """Turn on the spot towards the goal, then drive straight at it at full speed."""
    bearing = obs[-3]
    omega = jnp.clip(bearing / (1.0 * DT), -1.0, 1.0)  # omega_max = 1 rad/s
    v = jnp.where(jnp.abs(bearing) < 1e-3, 1.0, 0.0)
    return jnp.stack([v, omega])


def scripted(p, obs):
    """A policy with per-agent parameters p = (speed, blind): drive at the goal with
    v = speed * v_max, or (blind = 1) straight ahead at that speed whatever the sensors say."""
    return jnp.where(p[1] > 0.5, jnp.stack([p[0], 0.0]), at_goal(obs) * jnp.stack([p[0], 1.0]))


def forward(obs):
    """Full speed ahead (an observation-only policy: no parameters)."""
    return jnp.array([1.0, 0.0])


def agents(*rows):
    rows = rows if len(rows) == A else rows * A
    return jnp.asarray(rows, jnp.float32)


DRIVE = agents((1.0, 0.0))
STILL = agents((0.0, 0.0))


def run(params=DRIVE, world=CORRIDOR, policy=scripted, **kw):
    kw.setdefault("range_noise", 0.0)
    kw.setdefault("action_noise", 0.0)
    return evaluate_policy(
        policy, world, params, attempts=K, max_steps=T, v_max=V_MAX, dt=DT, goal_radius=GOAL_RADIUS, **kw
    )


def test_straight_at_goal_succeeds_with_efficiency_one():
    r = run()
    assert r.shape == (A, 3, K)
    assert r.success.all() and not r.collision.any() and not r.timeout.any()
    straight = np.array([6.5, 0.5, 2.5])  # |goal - start| - goal radius
    np.testing.assert_allclose(r.straight_line, straight, atol=1e-6)
    np.testing.assert_allclose(r.start_goal_distance, straight + GOAL_RADIUS, atol=1e-6)
    step = V_MAX * DT
    # time = (distance - goal radius) / speed, up to the step that crosses into the radius
    expected_time = straight / V_MAX
    assert np.all(r.time_s >= expected_time[None, :, None] - 1e-6)
    assert np.all(r.time_s <= expected_time[None, :, None] + DT + 1e-6)
    # the path is the straight line plus at most one step of overshoot: efficiency ~ 1
    assert np.all(r.path_length <= straight[None, :, None] + step + 1e-4)
    assert np.all(r.efficiency <= 1.0 + 1e-6)
    assert np.all(r.efficiency >= straight[None, :, None] / (straight[None, :, None] + step) - 1e-4)
    np.testing.assert_allclose(r.efficiency[0, 0], 1.0, atol=step / 6.5 + 1e-4)
    # the trajectory: starts at the start, ends within the goal radius, frozen afterwards
    p = r.poses[0, 0, 0]
    assert p.shape == (T + 1, 3)
    np.testing.assert_allclose(p[0], [-4.0, 0.0, 0.0], atol=1e-6)
    n = int(r.steps[0, 0, 0])
    assert np.linalg.norm(p[n, :2] - r.goals[0]) < GOAL_RADIUS
    assert np.linalg.norm(p[n - 1, :2] - r.goals[0]) >= GOAL_RADIUS
    np.testing.assert_array_equal(p[n:], np.broadcast_to(p[n], p[n:].shape))
    # path length equals the polyline length of the recorded poses
    np.testing.assert_allclose(
        np.linalg.norm(np.diff(p[:, :2], axis=0), axis=1).sum(), r.path_length[0, 0, 0], rtol=1e-4
    )


def test_driving_into_a_wall_fails():
    r = run(None, FACING_WALL, forward, num_agents=A)
    assert r.shape == (A, 3, K)
    np.testing.assert_array_equal(r.poses, run(agents((1.0, 1.0)), FACING_WALL).poses)
    assert not r.success.any()
    assert r.collision.all() and not r.timeout.any()
    # the wall is 1 m ahead; a collision within D_c = 0.25 m: after 8 steps of 0.1 m
    assert np.all(r.steps == 8)
    assert np.all(np.isnan(r.efficiency))
    s = summarize(episodes_frame(r))["all_agents"]["overall"]
    assert s["success_rate"] == 0.0 and s["collisions"] == s["episodes"] == A * 3 * K
    assert s["time_mean"] is None and s["efficiency_mean"] is None


def test_time_outs_count_as_failures():
    r = run(STILL)
    assert r.timeout.all() and not r.success.any() and not r.collision.any()
    assert np.all(r.steps == T)
    np.testing.assert_allclose(r.time_s, T * DT)
    assert np.all(r.path_length == 0.0)
    s = summarize(episodes_frame(r))["all_agents"]["overall"]
    assert s["success_rate"] == 0.0 and s["timeouts"] == s["episodes"] == A * 3 * K


def test_per_goal_counts_add_up_and_best_agent_per_seed():
    # 4 agents: v = 1, 0.7, 0 (times out), 0.1 (reaches only G1, 0.5 m, within T)
    r = run(agents((1.0, 0.0), (0.7, 0.0), (0.0, 0.0), (0.1, 0.0)))
    assert r.shape == (4, 3, K)
    seeds = np.array([10, 10, 11, 11])
    df = episodes_frame(r, agent_seed=seeds, agent_net=np.array([0, 1, 0, 1]))
    assert len(df) == 4 * 3 * K
    assert (df["success"] + df["collision"] + df["timeout"]).eq(1).all()
    s = summarize(df)
    per_goal = s["all_agents"]["per_goal"]
    overall = s["all_agents"]["overall"]
    assert [g["goal"] for g in per_goal] == [0, 1, 2]
    for key in ("episodes", "successes", "collisions", "timeouts"):
        assert sum(g[key] for g in per_goal) == overall[key]
    assert all(g["episodes"] == 4 * K for g in per_goal)
    # agents 0, 1 succeed everywhere; agent 2 nowhere; agent 3 only at G1
    succ = r.success.all(axis=2)
    assert succ[0].all() and succ[1].all() and not r.success[2].any()
    assert list(r.success[3].any(axis=1)) == [False, True, False]
    assert overall["successes"] == int(r.success.sum())
    np.testing.assert_allclose(overall["success_rate"], r.success.mean())
    ok = df[df.success == 1]
    np.testing.assert_allclose(overall["time_mean"], ok.time_s.mean())
    np.testing.assert_allclose(overall["time_std"], ok.time_s.std(ddof=0))
    # slower agent: same path, longer time; time = straight / v within a step
    assert np.all(r.time_s[1, 0] >= 6.5 / 0.7 - 1e-4) and np.all(r.time_s[1, 0] <= 6.5 / 0.7 + DT + 1e-4)
    np.testing.assert_allclose(r.path_length[1], r.path_length[0], atol=V_MAX * DT + 1e-4)  # overshoot
    # best agent per seed: seed 10 -> agent 0 (same success as 1, faster); seed 11 -> agent 3
    best = s["best_agent_per_seed"]
    assert best["agents"] == [0, 3]
    assert "evaluation data" in best["note"]
    assert best["overall"]["episodes"] == 2 * 3 * K
    assert s["all_agents"]["success_per_seed"]["11"] == pytest.approx(r.success[2:].mean())
    assert [a["success_rate"] for a in s["per_agent"]] == pytest.approx(list(r.success.mean(axis=(1, 2))))


def test_zero_noise_is_deterministic_and_noise_makes_attempts_differ():
    a = run(seed=1)
    b = run(seed=2)
    for x, y in [(a.poses, b.poses), (a.steps, b.steps), (a.success, b.success), (a.path_length, b.path_length)]:
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(a.poses[:, :, 0], a.poses[:, :, 1])  # attempts identical too
    n1 = run(seed=1, range_noise=0.01, action_noise=0.05)
    n2 = run(seed=1, range_noise=0.01, action_noise=0.05)
    np.testing.assert_array_equal(n1.poses, n2.poses)  # same seed, same noise
    assert not np.array_equal(n1.poses[:, :, 0], n1.poses[:, :, 1])  # attempts differ
    assert n1.range_noise == 0.01 and n1.action_noise == 0.05


def test_one_compilation_for_every_setting_of_the_same_shapes():
    from fedjax_nav.evaluation import rollout

    run(seed=5)
    settings = dict(num_beams=24, max_range=3.5, collision_test="exact", episode_length=T, mode="eval", noise=True)
    program = rollout.eval_program(settings, scripted, 64)
    before = program._cache_size()
    run(STILL, FACING_WALL, seed=6, range_noise=0.3, action_noise=0.2)  # other world data, noise, params
    assert program._cache_size() == before == 1


def test_invalid_inputs(tmp_path):
    with pytest.raises(EvalError, match="attempts"):
        evaluate_policy(forward, CORRIDOR, attempts=0)
    with pytest.raises(EvalError, match="goals"):
        evaluate_policy(forward, CORRIDOR, goals=[5])
    with pytest.raises(EvalError, match="no such run directory"):
        load_run(tmp_path / "nope")
    (tmp_path / "half").mkdir()
    with pytest.raises(EvalError, match="params.npz"):
        (tmp_path / "half" / "config.yaml").write_text("method: iddpg\n")
        load_run(tmp_path / "half")


# ----------------------------------------------------------------------------- runs and the CLI


TINY_WORLD = {
    "size": [4.0, 4.0],
    "circles": [[0.0, 1.0, 0.2]],
    "starts": [[-1.0, -1.0, 0.0]],
    "goals": [[1.2, 1.2], [-1.2, 1.2]],
}


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """An IDDPG run trained for 1 episode of 16 steps on 2 copies of a tiny room, 2 seeds."""
    from fedjax_nav.config import from_dict
    from fedjax_nav.training.run import train

    root = tmp_path_factory.mktemp("evalrun")
    world_file = root / "tiny.yaml"
    world_file.write_text(yaml.safe_dump(TINY_WORLD))
    cfg = from_dict(
        {
            "method": "iddpg",
            "env": {"worlds": [str(world_file)] * 2, "episode_length": 16},
            "offpolicy": {"hidden": 16, "depth": 2, "buffer_size": 64, "batch_size": 8},
            "fed": {"period": 1},
            "run": {"episodes": 1, "seeds": 2, "chunk_episodes": 1, "checkpoint_every": 0},
        }
    )
    out = root / "iddpg"
    train(cfg, out, progress=False)
    return out, world_file


def _fake_snddpg(run_dir, dest):
    """A run directory shaped like SNDDPG's (one network per seed) from the IDDPG run."""
    dest.mkdir()
    cfg = yaml.safe_load((run_dir / "config.yaml").read_text())
    cfg["method"] = "snddpg"
    (dest / "config.yaml").write_text(yaml.safe_dump(cfg))
    with np.load(run_dir / "params.npz") as z:
        np.savez(dest / "params.npz", **{k: z[k][:, :1] for k in z.files})
    return dest


def test_load_run_shapes(tiny_run):
    run_dir, _ = tiny_run
    run = load_run(run_dir)
    assert run.num_agents == 4 and run.n_nets == 2 and run.num_robots == 2
    assert list(run.agent_seed) == [0, 0, 1, 1] and list(run.agent_net) == [0, 1, 0, 1]
    assert run.actor_params["params"]["Dense_0"]["kernel"].shape == (4, 28, 16)


def test_cli_evaluate_writes_results_and_figures(tiny_run, tmp_path, capsys):
    from fedjax_nav.cli import main

    run_dir, world_file = tiny_run
    sn = _fake_snddpg(run_dir, tmp_path / "snddpg")
    out = tmp_path / "cmp"
    rc = main(
        [
            "evaluate",
            str(run_dir),
            str(sn),
            "--world",
            str(world_file),
            "--attempts",
            "2",
            "--range-noise",
            "0.02",
            "--action-noise",
            "0.03",
            "--seed",
            "3",
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    printed = capsys.readouterr().out
    assert "noise" in printed and "0.02" in printed and "0.03" in printed
    assert "selected on evaluation data" in printed
    for d in (run_dir, sn):
        dest = rundir.eval_dir(d, world_file)
        assert dest == d / "eval" / "tiny"
        for name in EVAL_FILES:
            assert (dest / name).stat().st_size > 0, (dest, name)
        assert not (d / "eval.json").exists()  # nothing at the top level (the old layout)
    a = json.loads((rundir.eval_dir(run_dir, world_file) / "eval.json").read_text())
    b = json.loads((rundir.eval_dir(sn, world_file) / "eval.json").read_text())
    assert a["noise"]["range_noise"] == 0.02 and a["noise"]["action_noise"] == 0.03
    assert a["max_steps"] == 16 and a["eval_seed"] == 3
    # per-robot: 4 agents x 2 goals x 2 attempts; shared network: 2 agents x 2 goals x 4 attempts
    assert (a["agents"], a["attempts_per_agent"], a["episodes"]) == (4, 2, 16)
    assert (b["agents"], b["attempts_per_agent"], b["episodes"]) == (2, 4, 16)
    o = a["all_agents"]["overall"]
    assert sum(g["episodes"] for g in a["all_agents"]["per_goal"]) == o["episodes"] == 16
    assert o["successes"] + o["collisions"] + o["timeouts"] == 16
    import pandas as pd

    df = pd.read_csv(rundir.eval_dir(run_dir, world_file) / "eval_episodes.csv")
    assert len(df) == 16 and df["success"].sum() == o["successes"]
    for name in ("eval_comparison.csv", "eval_comparison.md", "eval_comparison.png"):
        assert (out / name).stat().st_size > 0
    cmp = pd.read_csv(out / "eval_comparison.csv")
    assert list(cmp["method"]) == ["iddpg", "snddpg"]


def test_cli_evaluate_bad_run_dir(tmp_path, capsys):
    from fedjax_nav.cli import main

    assert main(["evaluate", str(tmp_path / "missing")]) == 2
    assert "no such run directory" in capsys.readouterr().err


def _copy_run(run_dir, dest):
    """A fresh run directory holding the tiny run's config.yaml and params.npz (no evaluations)."""
    dest.mkdir()
    for name in ("config.yaml", "params.npz"):
        (dest / name).write_bytes((run_dir / name).read_bytes())
    return dest


OTHER_GOALS = [[1.2, -1.2], [-1.2, 1.2]]


def test_evaluations_are_kept_per_world(tiny_run, tmp_path, capsys):
    """The same run on two worlds: two folders with their own numbers; the second evaluation
    touches neither the first world's folder nor a legacy RUN/eval.json of the old layout."""
    import pandas as pd

    from fedjax_nav.cli import main

    run_dir, world_file = tiny_run
    run = _copy_run(run_dir, tmp_path / "run")
    legacy = run / "eval.json"
    legacy.write_text('{"legacy": true}')
    other = tmp_path / "other.yaml"  # same shapes as tiny.yaml (no new compilation), other goals
    other.write_text(yaml.safe_dump({**TINY_WORLD, "goals": OTHER_GOALS}))
    flags = ["--attempts", "1", "--no-figures"]
    assert main(["evaluate", str(run), "--world", str(world_file), *flags]) == 0
    first = run / "eval" / "tiny"
    kept = {n: (first / n).read_bytes() for n in ("eval.json", "eval_episodes.csv", "eval_trajectories.npz")}
    assert main(["evaluate", str(run), "--world", str(other), *flags]) == 0
    second = run / "eval" / "other"
    assert rundir.eval_dir(run, other) == second
    assert {n: (first / n).read_bytes() for n in kept} == kept
    assert legacy.read_text() == '{"legacy": true}'
    a, b = (json.loads((d / "eval.json").read_text()) for d in (first, second))
    assert (a["world"], b["world"]) == ("tiny", "other")
    assert a["world_source"] == str(world_file) and b["world_source"] == str(other)
    np.testing.assert_allclose(a["goals"], TINY_WORLD["goals"], atol=1e-6)
    np.testing.assert_allclose(b["goals"], OTHER_GOALS, atol=1e-6)
    for d, s in ((first, a), (second, b)):
        df = pd.read_csv(d / "eval_episodes.csv")
        assert len(df) == s["episodes"] == 4 * 2 * 1
        assert df["success"].sum() == s["all_agents"]["overall"]["successes"]
        np.testing.assert_allclose(sorted(set(df["goal_y"])), sorted({g[1] for g in s["goals"]}), atol=1e-6)
    assert "replacing" not in capsys.readouterr().out
    assert sorted(p.name for p in (run / "eval").iterdir()) == ["other", "tiny"]


def test_out_is_honoured_for_one_run(tiny_run, tmp_path, capsys):
    from fedjax_nav.cli import main

    run_dir, world_file = tiny_run
    run = _copy_run(run_dir, tmp_path / "run")
    out = tmp_path / "elsewhere"
    assert main(["evaluate", str(run), "--world", str(world_file), "--attempts", "1", "--out", str(out)]) == 0
    for name in EVAL_FILES:
        assert (out / name).stat().st_size > 0, name
    assert sorted(p.name for p in run.iterdir()) == ["config.yaml", "params.npz"]  # the run untouched
    assert json.loads((out / "eval.json").read_text())["episodes"] == 8
    assert f"{out / 'eval.json'}" in capsys.readouterr().out


def test_rerunning_an_evaluation_replaces_it_and_says_so(tiny_run, tmp_path, capsys):
    from fedjax_nav.cli import main

    run_dir, world_file = tiny_run
    run = _copy_run(run_dir, tmp_path / "run")
    dest = rundir.eval_dir(run, world_file)

    def evaluate(seed, *flags):
        assert (
            main(["evaluate", str(run), "--world", str(world_file), "--attempts", "1", "--seed", str(seed), *flags])
            == 0
        )
        return [line for line in capsys.readouterr().out.splitlines() if "replacing" in line]

    assert evaluate(2) == []
    assert (dest / "eval_bars.png").exists()
    assert evaluate(2, "--no-figures") == [
        f"replacing the earlier evaluation in {dest} (the same run, world and settings)"
    ]
    assert not (dest / "eval_bars.png").exists()  # no stale figure of the earlier evaluation is left
    assert evaluate(5, "--no-figures") == [f"replacing the earlier evaluation in {dest} (it differs: seed 2 -> 5)"]
    assert json.loads((dest / "eval.json").read_text())["eval_seed"] == 5
    assert sorted(p.name for p in (run / "eval").iterdir()) == ["tiny"]


def test_evaluation_imports_only_the_layers_below_it():
    """fedjax_nav.evaluation reads runs through fedjax_nav.rundir, never through training or analysis."""
    import ast
    from pathlib import Path

    import fedjax_nav.evaluation as pkg

    allowed = {
        "messages",
        "worlds",
        "env",
        "agents",
        "federated",
        "methods",
        "learner_table",
        "config",
        "rundir",
        "evaluation",
    }
    for path in sorted(Path(pkg.__file__).parent.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom) and node.level == 0
                else []
            )
            for name in names:
                parts = name.split(".")
                if parts[0] == "fedjax_nav" and len(parts) > 1:
                    assert parts[1] in allowed, f"{path.name} imports {name}"
                elif name == "fedjax_nav" and isinstance(node, ast.ImportFrom):
                    for a in node.names:
                        assert a.name in allowed, f"{path.name} imports fedjax_nav.{a.name}"
        assert len(path.read_text().splitlines()) < 400, path.name


def test_byzantine_robots_are_summarized_apart(tiny_run, tmp_path, capsys):
    """A run with fed.byzantine = 1: eval.json keeps every agent in `all_agents` and adds the
    honest agents (net 0 of each seed) and the Byzantine ones (net 1) apart; the table and the
    frame say which is which; the best agent per seed is an honest one."""
    from fedjax_nav.evaluation import evaluate_run
    from fedjax_nav.evaluation.report import summary_table

    run_dir, world_file = tiny_run
    dest = tmp_path / "byz"
    dest.mkdir()
    cfg = yaml.safe_load((run_dir / "config.yaml").read_text())
    cfg["method"] = "flddpg"
    cfg["fed"].update(byzantine=1, attack="noise")
    (dest / "config.yaml").write_text(yaml.safe_dump(cfg))
    (dest / "params.npz").write_bytes((run_dir / "params.npz").read_bytes())
    ev = evaluate_run(dest, world=world_file, attempts=2, max_steps=16)
    df, s = ev.frame, ev.summary
    assert (df["byzantine"] == (df["net"] == 1)).all()
    for key, rows in (("honest_agents", df[df.net == 0]), ("byzantine_agents", df[df.net == 1])):
        assert s[key]["overall"]["episodes"] == len(rows)
        assert s[key]["overall"]["success_rate"] == pytest.approx(rows["success"].mean())
    assert s["all_agents"]["overall"]["episodes"] == len(df)
    assert all(a in set(df[df.net == 0]["agent"]) for a in s["best_agent_per_seed"]["agents"])
    assert [a["byzantine"] for a in s["per_agent"]] == [False, True, False, True]
    table = summary_table(s)
    assert "honest agents" in table and "Byzantine" in table
    # the held-out suites mark them too: the honest agents' success per family
    from fedjax_nav.evaluation.suite import evaluate_suite

    suite = evaluate_suite(dest, "probe", attempts=1, max_steps=8)
    ep, fams = suite["episodes"], suite["families"]
    assert (ep["byzantine"] == (ep["net"] == 1)).all()
    want = ep[ep.net == 0].groupby("family")["success"].mean()
    for _, row in fams[fams.family != "all"].iterrows():
        assert row.success_honest == pytest.approx(want[row.family])
    # a run without Byzantine robots has no such blocks
    assert "honest_agents" not in evaluate_run(run_dir, world=world_file, attempts=1, max_steps=16).summary


def test_arena_and_suite_evaluations_drive_the_runs_robot_model(tiny_run, tmp_path, monkeypatch):
    """Both evaluations build the simulator from the run's config (config.envs): a run trained
    under the TurtleBot3 model is evaluated under it on the arena and on a held-out suite alike
    (the suite used to drive the ideal robot whatever the run's `robot:` said)."""
    from fedjax_nav.evaluation import evaluate_run, rollout, suite
    from fedjax_nav.robots import ROBOT_MODELS

    run_dir, world_file = tiny_run
    dest = tmp_path / "burger"
    dest.mkdir()
    cfg = yaml.safe_load((run_dir / "config.yaml").read_text())
    cfg["robot"] = {"model": "turtlebot3_burger"}
    (dest / "config.yaml").write_text(yaml.safe_dump(cfg))
    (dest / "params.npz").write_bytes((run_dir / "params.npz").read_bytes())
    seen, real = [], rollout.eval_program

    def spy(settings, policy, chunk):
        seen.append(dict(settings))
        return real(settings, policy, chunk)

    monkeypatch.setattr(suite, "eval_program", spy)
    monkeypatch.setattr(rollout, "eval_program", spy)
    burger = ROBOT_MODELS["turtlebot3_burger"]
    arena = evaluate_run(dest, world=world_file, attempts=1, max_steps=8)
    held = suite.evaluate_suite(dest, "probe", attempts=1, max_steps=8)
    assert len(seen) == 2
    for s in seen:
        assert s["robot"] and s["noise"] and s["mode"] == "eval" and s["episode_length"] == 8
        assert (s["substeps"], s["scan_samples"]) == (burger["substeps"], burger["scan_samples"])
    assert seen[0] == seen[1]
    assert arena.summary["noise"]["range_noise"] == held["summary"]["noise"]["range_noise"] == burger["range_noise"]


def test_robustness_report_evaluates_points_and_notes_a_diverged_one(tiny_run, tmp_path):
    """The robustness report evaluates every finished point on a world and reports, instead of
    failing on, a point whose actors hold NaN (a run diverged under attack)."""
    import shutil

    from fedjax_nav.config.sweepfile import load_sweep
    from fedjax_nav.experiments.robustness import evaluate_arena

    run_dir, _ = tiny_run
    spec = {"name": "r", "base": str(run_dir / "config.yaml"), "seeds": 2, "grid": {"offpolicy.lr": [0.001, 0.002]}}
    (tmp_path / "r.yaml").write_text(yaml.safe_dump(spec))
    sweep = load_sweep(tmp_path / "r.yaml")
    ok, bad = (tmp_path / "points" / p.id for p in sweep.points)
    for d in (ok, bad):
        shutil.copytree(run_dir, d, ignore=shutil.ignore_patterns("eval"))
    with np.load(bad / "params.npz") as z:
        np.savez(bad / "params.npz", **{k: np.full_like(z[k], np.nan) for k in z.files})
    said = []
    notes = evaluate_arena(sweep, tmp_path / "points", attempts=1, echo=said.append)
    assert list(notes) == [sweep.points[1].id] and "NaN" in notes[sweep.points[1].id]
    assert (ok / "eval" / "eval" / "eval.json").exists() and not (bad / "eval" / "eval" / "eval.json").exists()
    assert len(said) == 2
