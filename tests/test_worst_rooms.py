"""The worst rooms of a held-out suite evaluation, drawn (fedjax_nav.evaluation.worst_rooms): the
rooms of lowest success in suite_episodes.csv (ties by room index), their episodes replayed with
the evaluation's protocol and keys (the same episodes, outcome for outcome), the figure written by
`evaluate --suite` beside the evaluation, a missing evaluation one line naming the command, and
the generalization report's copy. One tiny trained run whose actor is then set by hand to drive
at the goal (successes in open rooms, collisions in cluttered ones: rooms differ)."""

import contextlib
import io
import json
import shutil

import numpy as np
import pandas as pd
import pytest

from fedjax_nav import cli, rundir
from fedjax_nav.config import load_config
from fedjax_nav.evaluation import EvalError
from fedjax_nav.evaluation.worst_rooms import rank_rooms, replay, worst_rooms

TINY = [
    "method=iddpg",
    "env.episode_length=8",
    "run.episodes=1",
    "run.chunk_episodes=1",
    "run.checkpoint_every=0",
    "offpolicy.batch_size=4",  # an update at step 5 of the run's 8 (offpolicy.train_every = 5)
    "offpolicy.buffer_size=64",
    "offpolicy.hidden=8",
    "offpolicy.depth=1",
    "env.worlds=[train-0,train-0]",  # the smallest shipped room: compile time grows with obstacles
]
T = 200  # the evaluation's time-out: long enough to reach a goal
PNG = b"\x89PNG\r\n\x1a\n"


def _steer(run):
    """Replace the trained actors (which barely move) by hand-set ones driving at the goal: omega =
    tanh(3 bearing), v = sigmoid(2) for robot 0 and sigmoid(0.5) for robot 1 (obs[25]: the bearing)."""
    f = run / rundir.PARAMS
    with np.load(f) as z:
        p = {k: z[k] for k in z.files}
    S, N, D, H = p["actor/params/Dense_0/kernel"].shape
    zeros = lambda *s: np.zeros((S, N, *s), np.float32)  # noqa: E731
    k0, b0, kv, kw = zeros(D, H), zeros(H), zeros(H, 1), zeros(H, 1)
    k0[..., 25, 0], k0[..., 25, 1], b0[..., 2] = 1.0, -1.0, 1.0  # relu(bearing), relu(-bearing), 1
    kv[..., 2, 0] = np.asarray([2.0, 0.5], np.float32)[:N]
    kw[..., 0, 0], kw[..., 1, 0] = 3.0, -3.0
    heads = {"Dense_0": (k0, b0), "v_head": (kv, zeros(1)), "omega_head": (kw, zeros(1))}
    for name, (kernel, bias) in heads.items():
        p[f"actor/params/{name}/kernel"], p[f"actor/params/{name}/bias"] = kernel, bias
    np.savez(f, **p)


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory):
    """The run, evaluated on the probe suite (16 rooms, 2 goals) with 2 attempts by the CLI, which
    draws the worst rooms too; its output."""
    from fedjax_nav.training.run import train

    run = tmp_path_factory.mktemp("worst") / "run"
    train(load_config(None, TINY), run, progress=False)
    _steer(run)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = cli.main(["evaluate", str(run), "--suite", "probe", "--attempts", "2", "--max-steps", str(T)])
    assert rc == 0, out.getvalue()
    return run, out.getvalue()


def test_rooms_rank_by_success_lowest_first_ties_by_room_index():
    ep = pd.DataFrame(
        {
            "room": [3, 3, 0, 0, 2, 2, 1, 1, 4, 4],
            "family": ["b", "b", "a", "a", "b", "b", "a", "a", "c", "c"],
            "room_seed": [13, 13, 10, 10, 12, 12, 11, 11, 14, 14],
            "success": [0, 1, 1, 1, 0, 0, 0, 1, 0, 0],
            "collision": [1, 0, 0, 0, 1, 0, 0, 0, 0, 0],
            "timeout": [0, 0, 0, 0, 0, 1, 1, 0, 1, 1],
        }
    )
    r = rank_rooms(ep)
    assert r.room.tolist() == [2, 4, 1, 3, 0]  # 0.0 (rooms 2, 4), 0.5 (rooms 1, 3), 1.0
    assert r.family.tolist() == ["b", "c", "a", "b", "a"] and r.room_seed.tolist() == [12, 14, 11, 13, 10]
    assert r.success.tolist() == [0.0, 0.0, 0.5, 0.5, 1.0] and r.episodes.tolist() == [2] * 5
    assert r.collision.tolist() == [0.5, 0.0, 0.0, 0.5, 0.0] and r.timeout.tolist() == [0.5, 1.0, 0.5, 0.0, 0.0]


def test_evaluate_suite_draws_the_worst_rooms_beside_the_evaluation(evaluated):
    run, said = evaluated
    fig = rundir.eval_dir(run, "probe") / rundir.SUITE_WORST_ROOMS_FIGURE
    assert f"wrote {fig}" in said.splitlines()
    assert fig.read_bytes()[:8] == PNG and fig.stat().st_size > 10_000


def test_the_replay_is_the_kept_evaluation_of_the_lowest_rooms(evaluated):
    run, _ = evaluated
    folder = rundir.eval_dir(run, "probe")
    ep = pd.read_csv(folder / rundir.SUITE_EPISODES)
    per_room = ep.groupby("room")["success"].mean()
    assert 0 < ep.success.mean() < 1 and ep.collision.any() and per_room.nunique() > 2  # rooms differ

    # every room (the evaluation's own shapes: its compiled program), every attempt: worst first
    w = replay(run, "probe", rooms=99, attempts=5)
    ranked = sorted(per_room.index, key=lambda r: (per_room[r], r))
    assert w.rooms.room.tolist() == ranked
    np.testing.assert_allclose(w.rooms.success, per_room[ranked])
    n, A, G, K = w.success.shape
    assert (n, A, K) == (16, 2, 2) and w.poses.shape[-2:] == (T + 1, 3)  # at most the evaluation's attempts
    agent = {(int(s), int(k)): a for a, (s, k) in enumerate(zip(w.agent_seed, w.agent_net))}
    assert len(ep) == A * K * int(w.num_goals.sum())  # every kept episode, once
    for r in ep.itertuples():
        i, a = ranked.index(r.room), agent[(r.seed, r.net)]
        got = (w.success, w.collision, w.timeout, w.steps)
        assert [int(x[i, a, r.goal, r.attempt]) for x in got] == [r.success, r.collision, r.timeout, r.steps], r

    # the figure's default (its program compiled by the CLI): the 6 lowest rooms, their first attempt
    one = replay(run, "probe", rooms=6, attempts=1)
    assert one.rooms.room.tolist() == ranked[:6]
    assert per_room[ranked[:6]].max() <= per_room.drop(ranked[:6]).min()
    for f in ("success", "collision", "timeout", "steps", "poses"):
        np.testing.assert_array_equal(getattr(one, f), getattr(w, f)[:6, :, :, :1], err_msg=f)


def test_a_missing_evaluation_is_one_line_naming_the_command(evaluated):
    run, _ = evaluated
    with pytest.raises(EvalError) as e:
        worst_rooms(run, "heldout")
    msg = str(e.value)
    assert "\n" not in msg and f"fedjax-nav evaluate {run} --suite heldout" in msg
    assert str(rundir.eval_dir(run, "heldout")) in msg


def test_no_figures_writes_none_and_out_keeps_the_figure_beside_the_evaluation(evaluated, tmp_path):
    run, _ = evaluated
    for flags, drawn in ((["--no-figures"], False), ([], True)):
        out = tmp_path / ("none" if flags else "drawn")
        argv = ["evaluate", str(run), "--suite", "probe", "--attempts", "2", "--max-steps", str(T), "--out", str(out)]
        with contextlib.redirect_stdout(io.StringIO()):
            assert cli.main(argv + flags) == 0
        assert (out / rundir.SUITE_EPISODES).exists()
        assert (out / rundir.SUITE_WORST_ROOMS_FIGURE).exists() == drawn


def test_the_generalization_report_copies_each_points_worst_rooms(tmp_path):
    from fedjax_nav.config.sweepfile import load_sweep
    from fedjax_nav.experiments.generalization import report

    sweep = load_sweep("generalization")
    p = sweep.points[0]
    point = rundir.points_dir(tmp_path) / p.id
    folder = rundir.eval_dir(point, "heldout")
    folder.mkdir(parents=True)
    s = {"seeds": 1, "episodes_done": 1, "success_last": 0.5, "success_last_std": 0.0, "success_last_per_seed": [0.5]}
    (point / rundir.SUMMARY).write_text(json.dumps(s))
    shutil.copyfile(__file__, folder / rundir.SUITE_WORST_ROOMS_FIGURE)  # any file: the report copies it
    out = report(sweep, tmp_path, evaluate=False, copy_figures=tmp_path / "img", echo=lambda s: None)
    slug = p.label.replace("=", "_").replace(", ", "_")
    assert (tmp_path / "img" / f"generalization_worst_rooms_{slug}.png") in out["copied"]


def test_a_suite_evaluated_under_another_robot_is_kept_apart_and_replayed_under_it(evaluated):
    """`evaluate --suite probe --robot pooled_360` once ran the run's own robot and wrote over its
    evaluation: now it drives the model (the protocol's static settings), keeps it in
    eval/probe-robot-pooled_360/ with the model in suite.json, and its worst rooms replay under it."""
    from fedjax_nav.evaluation.runs import load_run
    from fedjax_nav.evaluation.suite import suite_protocol, under_robot
    from fedjax_nav.worlds import load

    run, _ = evaluated
    own = json.loads((run / "eval" / "probe" / "suite.json").read_text())
    out = io.StringIO()
    args = ["evaluate", str(run), "--suite", "probe", "--attempts", "2", "--max-steps", str(T), "--robot", "pooled_360"]
    with contextlib.redirect_stdout(out):
        assert cli.main(args) == 0, out.getvalue()
    folder = run / "eval" / "probe-robot-pooled_360"
    kept = json.loads((folder / "suite.json").read_text())
    assert kept["robot"]["model"] == "pooled_360" and kept["robot"]["scan_samples"] == 360
    assert own["robot"]["model"] == "ideal" and json.loads((run / "eval" / "probe" / "suite.json").read_text()) == own
    assert (folder / "worst_rooms.png").read_bytes()[:8] == PNG
    pooled = under_robot(load_run(run), kept["robot"])
    protocol = suite_protocol(pooled, load("train-0"), 1, 0.01, 0.01, 0, T)
    assert protocol.settings["robot"] and protocol.settings["scan_samples"] == 360
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()) as err:
        shared = ["evaluate", str(run), "--suite", "probe", "--robots-per-room", "2", "--robot", "pooled_360"]
        assert cli.main(shared) == 2
    assert "--robot" in err.getvalue()
