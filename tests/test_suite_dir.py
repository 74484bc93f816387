"""`fedjax-nav evaluate RUN --suite DIR|GLOB` (fedjax_nav/evaluation/suite.py): a folder or glob of
the user's own world files evaluated as one suite in one compiled program, each file a family
named by its stem, the tables of a named suite (the tail included) in RUN/eval/<folder name>/; an
empty folder or glob is one line and exit 2; `--suite NAME` is unchanged.

The run is written by hand (no training): one agent whose actor is a constant, full speed straight
ahead (every weight zero, the speed head's bias large), so each room's outcome is known: a goal
straight ahead is reached, a wall ahead is hit, a far goal times out."""

import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
import yaml

from fedjax_nav import rundir
from fedjax_nav.cli import main
from fedjax_nav.config import from_dict, save_config
from fedjax_nav.evaluation import EvalError, suite, suite_files

STEPS = 60  # the time-out: 60 x 0.1 s x 0.25 m/s = 1.5 m of driving
ROOMS = {  # start 0 faces +x; the constant actor drives straight on
    "far.yml": {"size": [5, 2], "starts": [[-2, 0, 0]], "goals": [[2, 0]]},  # 3.5 m to the disk: time-out
    "open.yaml": {"size": [3, 2], "starts": [[-1, 0, 0]], "goals": [[0.5, 0]]},  # 1.0 m to the disk: success
    "wall.json": {"size": [3, 3], "segments": [[0, -1.5, 0, 0.5]], "starts": [[-1, 0, 0]], "goals": [[1, 0]]},
}


def constant_run(folder):
    """A run directory (config.yaml, params.npz) of one IDDPG agent driving at full speed, omega 0."""
    from fedjax_nav.agents import ddpg

    cfg = from_dict(
        {
            "method": "iddpg",
            "env": {"worlds": ["train-0"], "episode_length": STEPS},
            "offpolicy": {"hidden": 8, "depth": 1},
            "run": {"seeds": 1},
        }
    )
    folder.mkdir(parents=True)
    save_config(cfg, folder / rundir.CONFIG)
    nets = ddpg.make_nets(8, 1, "relu")
    actor = jax.tree.map(jnp.zeros_like, nets.actor.init(jax.random.key(0), jnp.zeros(28)))
    actor["params"]["v_head"]["bias"] = jnp.full((1,), 12.0)  # sigmoid(12) = v_max to 6e-6
    rundir.write_params(folder, {"actor": jax.tree.map(lambda x: np.asarray(x)[None, None], actor)})
    return folder


def write_rooms(folder):
    folder.mkdir(parents=True)
    for name, spec in ROOMS.items():
        text = json.dumps(spec) if name.endswith(".json") else yaml.safe_dump(spec)
        (folder / name).write_text(text)
    (folder / "notes.txt").write_text("not a world file")  # ignored: not *.json / *.yaml / *.yml
    return folder


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory):
    """The CLI on the folder, once: (run dir, the folder, exit code, suite dir)."""
    root = tmp_path_factory.mktemp("suitedir")
    run, maps = constant_run(root / "run"), write_rooms(root / "maps")
    argv = ["evaluate", str(run), "--suite", str(maps), "--attempts", "1", "--max-steps", str(STEPS)]
    rc = main([*argv, "--range-noise", "0", "--action-noise", "0"])
    return run, maps, rc, rundir.eval_dir(run, "maps")


def test_a_folder_of_worlds_is_one_suite_with_a_family_per_file(evaluated):
    run, maps, rc, out = evaluated
    assert rc == 0
    fams = pd.read_csv(out / suite.FAMILIES_CSV).set_index("family")
    assert list(fams.index) == ["far", "open", "wall", "all"]  # file order; notes.txt left out
    assert fams.rooms.tolist() == [1, 1, 1, 3]
    assert fams.success.tolist() == [0.0, 1.0, 0.0, pytest.approx(1 / 3)]
    assert fams.loc["wall", "collision"] == 1.0 and fams.loc["far", "timeout"] == 1.0
    assert fams.loc["open", ["collision", "timeout"]].tolist() == [0.0, 0.0]
    s = json.loads((out / suite.SUITE_JSON).read_text())
    assert s["rooms"] == 3 and s["suite"] == str(maps)
    assert [p.split("/")[-1] for p in s["suites"]] == sorted(ROOMS)
    ep = pd.read_csv(out / suite.EPISODES_CSV)
    assert len(ep) == 3 and (ep.room_seed == -1).all()


def test_the_tail_of_a_file_suite(evaluated):
    """worst 10 % of 3 rooms = the worst room; the path ratio of the one success is driven / 1.0 m,
    the overshoot of the last step (v_max dt = 2.5 cm) at most; shortest paths by room."""
    out = evaluated[3]
    fams = pd.read_csv(out / suite.FAMILIES_CSV).set_index("family")
    assert fams.loc["all", "worst10"] == 0.0 and fams.loc["all", "worst10_rooms"] == 1
    assert fams.loc["all", "worst10_ci_low"] <= 0.0 <= fams.loc["all", "worst10_ci_high"]
    assert fams.loc["open", "worst10"] == 1.0
    assert 1.0 <= fams.loc["open", "path_ratio_median"] <= 1.0 + 0.026
    assert fams.loc["all", "path_ratio_median"] == fams.loc["open", "path_ratio_median"]
    assert fams.loc["all", "path_ratio_episodes"] == 1 and np.isnan(fams.loc["wall", "path_ratio_median"])
    ep = pd.read_csv(out / suite.EPISODES_CSV).set_index("family")
    assert ep.loc["open", "shortest_path"] == pytest.approx(1.0, abs=1e-6)
    assert ep.loc["far", "shortest_path"] == pytest.approx(3.5, abs=1e-6)
    # round the wall's end (0, 0.5) inflated by 0.25: tangents 2 x 1.0897, arc 0.25 x 1.379, less D_g 0.5
    assert 2.0240 <= ep.loc["wall", "shortest_path"] <= 2.0240 + 0.05
    assert np.isnan(ep.loc["wall", "path_ratio"]) and ep.loc["wall", "collision"] == 1


@pytest.mark.parametrize("kind", ["empty folder", "glob"])
def test_no_world_file_is_one_line_and_exit_2(evaluated, tmp_path, capsys, kind):
    run = evaluated[0]
    target = tmp_path / "nothing"
    target.mkdir()
    (target / "readme.md").write_text("no worlds here")
    arg = str(target) if kind == "empty folder" else str(target / "*.yaml")
    assert main(["evaluate", str(run), "--suite", arg]) == 2
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1 and arg in lines[0] and "no world file" in lines[0], lines


def test_a_bad_world_file_is_named(evaluated, tmp_path, capsys):
    run = evaluated[0]
    (tmp_path / "bad.yaml").write_text("size: [2, 2]\nstarts: [[5, 5, 0]]\ngoals: [[0, 0]]\n")
    assert main(["evaluate", str(run), "--suite", str(tmp_path)]) == 2
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "bad.yaml" in lines[0] and "starts[0]" in lines[0], lines


def test_globs_files_and_folders_select_and_name(evaluated, tmp_path, monkeypatch):
    maps = evaluated[1]
    assert [f.name for f in suite.world_files(str(maps / "*.y*ml"))] == ["far.yml", "open.yaml"]
    assert [f.name for f in suite.world_files(str(maps / "wall.json"))] == ["wall.json"]
    for arg in (str(maps), str(maps) + "/", str(maps / "*.yaml"), str(maps / "wall.json")):
        assert suite.is_file_suite(arg) and suite.suite_folder(arg) == "maps"
    world, fams, seeds, files = suite_files.file_suite(str(maps))
    assert world.goals.shape[0] == 3 and list(fams) == ["far", "open", "wall"]
    assert world.segments.shape[1] == max(4 + len(r.get("segments", [])) for r in ROOMS.values())  # padded
    # two files with one stem: the file names tell the families apart
    (tmp_path / "a.json").write_text(json.dumps(ROOMS["open.yaml"]))
    (tmp_path / "a.yaml").write_text(yaml.safe_dump(ROOMS["open.yaml"]))
    assert list(suite_files.file_suite(str(tmp_path))[1]) == ["a.json", "a.yaml"]
    # a suite name wins over a folder of the same name in the working folder
    monkeypatch.chdir(tmp_path)
    (tmp_path / "probe").mkdir()
    assert not suite.is_file_suite("probe") and suite.suite_folder("probe") == "probe"
    assert not suite.is_file_suite("heldout") and suite.suite_folder("heldout") == "heldout"


# ----------------------------------------------------------------------------- entries that cannot be read


def _unreadable(folder, kind):
    """An entry named like a world file that is not one: its path."""
    if kind == "symlink loop":
        (folder / "loop.json").symlink_to(folder / "loop.json")
        return folder / "loop.json", "is a symlink loop"
    if kind == "dangling link":
        (folder / "gone.yaml").symlink_to(folder / "missing.yaml")
        return folder / "gone.yaml", "is a symbolic link to a missing file"
    if kind == "FIFO":
        os.mkfifo(folder / "pipe.yml")  # never opened: stat says what it is
        return folder / "pipe.yml", "is a FIFO, not a regular file"
    (folder / "sub.json").mkdir()
    return folder / "sub.json", "is a directory"


KINDS = ["symlink loop", "dangling link", "FIFO", "folder"]


@pytest.mark.parametrize("kind", KINDS)
def test_an_entry_that_cannot_be_read_refuses_the_suite_naming_it(tmp_path, kind):
    """Before: it was left out, and the suite reported one room fewer, exit 0."""
    maps = write_rooms(tmp_path / "maps")
    bad, words = _unreadable(maps, kind)
    alone = [] if kind == "folder" else [str(bad)]  # a folder named alone is a suite folder of its own
    for arg in [str(maps), str(maps / f"*{bad.suffix}"), *alone]:
        for load in (suite.world_files, suite_files.file_suite):
            with pytest.raises(EvalError) as e:
                load(arg)
            msg = str(e.value)
            assert msg.startswith(f"{bad}: {words}") and "\n" not in msg, msg
    bad.unlink() if not bad.is_dir() or bad.is_symlink() else bad.rmdir()
    assert [f.name for f in suite.world_files(str(maps))] == sorted(ROOMS)  # the rest is a suite again


def test_the_cli_refuses_a_suite_folder_with_a_symlink_loop_in_one_line_exit_2(tmp_path, capsys):
    """Refused before any run is loaded or any program compiled (`evaluate_suite_runs` checks the suite first)."""
    run, maps = constant_run(tmp_path / "run"), write_rooms(tmp_path / "maps")
    bad, words = _unreadable(maps, "symlink loop")
    assert main(["evaluate", str(run), "--suite", str(maps)]) == 2
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1 and str(bad) in lines[0] and words in lines[0], lines
    assert not rundir.eval_dir(run, "maps").exists()


def test_evaluate_set_drives_the_runs_agents_under_a_changed_value_into_out(evaluated, tmp_path, capsys):
    """`fedjax-nav evaluate RUN --suite DIR --set KEY=VALUE --out DIR`: the far room, a time-out at
    the run's speed, is reached at 4x it; written into --out only, the run's own eval/ untouched;
    a static key, several runs or no --out are one line and exit 2."""
    run, maps, rc, kept = evaluated
    assert rc == 0
    before = sorted(p.name for p in (run / "eval").iterdir())
    argv = ["evaluate", str(run), "--suite", str(maps), "--attempts", "1", "--max-steps", str(STEPS)]
    out = tmp_path / "fast"
    assert main([*argv, "--set", "env.v_max=1.0", "--out", str(out)]) == 0
    fast = pd.read_csv(out / rundir.SUITE_EPISODES)
    own = pd.read_csv(kept / rundir.SUITE_EPISODES)
    assert own.loc[own.family == "far", "timeout"].all() and fast.loc[fast.family == "far", "success"].all()
    assert sorted(p.name for p in (run / "eval").iterdir()) == before and (out / "worst_rooms.png").exists()
    assert f"({run})" in capsys.readouterr().out  # the run named by its folder
    for bad, says in (
        (["--set", "env.num_beams=12", "--out", str(tmp_path / "b")], "env.num_beams: not a traced value"),
        (["--set", "env.v_max=1.0"], "--set: evaluates one run into --out"),
    ):
        assert main([*argv, *bad]) == 2
        err = capsys.readouterr().err
        assert says in err and len(err.strip().splitlines()) == 1, err
    world = tmp_path / "world"  # one world, one robot per room, and K robots per room
    assert (
        main(["evaluate", str(run), "--world", str(maps / "open.yaml"), "--set", "env.v_max=1.0", "--out", str(world)])
        == 0
    )
    assert (world / "eval.json").exists()
    shared = tmp_path / "shared"
    argv = ["evaluate", str(run), "--suite", str(maps), "--robots-per-room", "2", "--set", "env.v_max=1.0"]
    assert main([*argv, "--max-steps", str(STEPS), "--out", str(shared)]) == 0
    assert (shared / rundir.SHARED_JSON).exists() and (shared / rundir.SHARED_FIGURE).exists()
