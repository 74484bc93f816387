"""The run directory has one owner, `fedjax_nav.rundir`: no other source spells the names of its
files and folders (or a sweep folder's), and `train --resume` refuses a changed config in one
function, `training.preflight.refuse_config_change`, before it loads anything and against the checkpoint."""

import ast
from dataclasses import replace
from pathlib import Path

import pytest

from fedjax_nav import cli, rundir
from fedjax_nav.config import Config, ConfigError, save_config, to_dict
from fedjax_nav.training import preflight

PKG = Path(__file__).resolve().parents[1] / "fedjax_nav"
NAMES = {v for k, v in vars(rundir).items() if k.isupper() and isinstance(v, str)}  # metrics.csv, points, ...
FILES = {n for n in NAMES if "." in n}  # the file names (config.yaml, ..., .lock)
# "eval" names the eval/ folder and also the thesis's evaluation world (a world, not a path).
WORLDS = {"eval"}
# Names still spelled by modules that route them through rundir next (their owners edit them):
# an entry that no longer matches fails too, so it is removed when its module is routed.
PENDING = {
    "evaluation/suite.py": {"suite.json", "suite_families.csv", "suite_episodes.csv"},
}


def _text(node) -> str | None:
    return node.value if isinstance(node, ast.Constant) and isinstance(node.value, str) else None


def spelled(source: str) -> set[str]:
    """The rundir names a source spells: a string that is a file name, or a path ending in one
    ("eval/eval.json", f"{run}/metrics.csv"); a path joined with any name (`out / "points"`); a
    module constant bound to any name (`DIR = "tensorboard"`). Prose (a string with spaces) is not
    a path."""
    tree = ast.parse(source)
    found = set()
    for node in ast.walk(tree):
        text = _text(node)
        if text is not None and not any(c.isspace() for c in text) and text.rsplit("/", 1)[-1] in FILES:
            found.add(text.rsplit("/", 1)[-1])
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.Div) and _text(node.right) in NAMES:
            found.add(_text(node.right))
    for node in tree.body:
        if isinstance(node, (ast.Assign, ast.AnnAssign)) and _text(node.value) in NAMES - WORLDS:
            found.add(_text(node.value))
    return found


def test_the_scan_finds_every_way_of_spelling_a_name():
    src = (
        'A = "tensorboard"\nB = "eval"\n'
        'def f(run, out):\n    x = run / "checkpoints"\n    y = f"{run}/metrics.csv"\n'
        '    z = "eval/eval.json"\n    w = out / "points" / "abc"\n    print("wrote metrics.csv, summary.json")\n'
    )
    assert spelled(src) == {"tensorboard", "checkpoints", "metrics.csv", "eval.json", "points"}


def test_no_source_but_rundir_spells_a_run_directory_name():
    bad, stale = [], []
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(PKG).as_posix()
        if rel == "rundir.py" or "__pycache__" in path.parts:
            continue
        found, pending = spelled(path.read_text()), PENDING.get(rel, set())
        bad += [f"{rel}: {name!r}" for name in sorted(found - pending)]
        stale += [f"{rel}: {name!r}" for name in sorted(pending - found)]
    assert not bad, "use fedjax_nav.rundir's names and functions instead:\n" + "\n".join(bad)
    assert not stale, "routed through rundir now: remove from PENDING:\n" + "\n".join(stale)


# ----------------------------------------------------------------------------- the resume refusal


def test_the_refusal_permits_only_the_changeable_fields_and_only_when_asked():
    changed = ["run.episodes", "offpolicy.gamma"]
    preflight.refuse_config_change(["run.episodes", "run.tensorboard"], True, "RUN/config.yaml", "x")
    preflight.refuse_config_change([], False, "RUN/config.yaml", "x")
    with pytest.raises(ConfigError) as without:
        preflight.refuse_config_change(changed, False, "RUN/config.yaml", "the saved one")
    head = str(without.value).split("; resuming")[0]
    assert head == "RUN/config.yaml: differs from the saved one in run.episodes, offpolicy.gamma", head
    assert "--allow-config-change" in str(without.value)
    with pytest.raises(ConfigError) as allowed:
        preflight.refuse_config_change(changed, True, "RUN/config.yaml", "the saved one")
    assert str(allowed.value).split("; resuming")[0].endswith(" in offpolicy.gamma"), str(allowed.value)


class _Checkpoints:
    """What `check_resumable` reads of a `Checkpointer`: the latest step and its saved config."""

    def __init__(self, folder: Path, saved: Config, step: int = 4):
        self.dir, self.saved, self.step = folder / rundir.CHECKPOINTS, saved, step

    def latest(self):
        return self.step

    def saved_config(self, step):
        return to_dict(self.saved)


@pytest.fixture
def calls(monkeypatch):
    """Every call of the refusal (then the real one runs)."""
    seen, real = [], preflight.refuse_config_change

    def spy(changed, allow, path, against):
        seen.append((sorted(changed), allow, str(path)))
        return real(changed, allow, path, against)

    monkeypatch.setattr(preflight, "refuse_config_change", spy)
    return seen


def test_both_resume_checks_refuse_through_the_one_function(calls, tmp_path, capfd):
    saved = Config()
    save_config(saved, tmp_path / rundir.CONFIG)
    # before loading anything: the saved config.yaml against the command line's
    rc = cli.main(["train", "--resume", str(tmp_path), "--quiet", "--set", "offpolicy.gamma=0.5"])
    err = [ln for ln in capfd.readouterr().err.splitlines() if ln.strip()]
    assert rc == 2 and len(err) == 1, err
    # inside train(): the config to resume with against the checkpoint's
    asked = replace(saved, offpolicy=replace(saved.offpolicy, gamma=0.5))
    with pytest.raises(ConfigError) as inside:
        preflight.check_resumable(_Checkpoints(tmp_path, saved), asked, tmp_path, False)
    config = str(tmp_path / rundir.CONFIG)
    assert calls == [(["offpolicy.gamma"], False, config), (["offpolicy.gamma"], False, config)]
    # one sentence: the same fields and the same hint, only what was compared differs
    cli_line, train_line = err[0].removeprefix("error: "), str(inside.value)
    assert cli_line.split(" differs from ")[0] == train_line.split(" differs from ")[0] == config + ":"
    assert cli_line.split(" in offpolicy.gamma")[1] == train_line.split(" in offpolicy.gamma")[1], (
        cli_line,
        train_line,
    )
    assert str(tmp_path / rundir.CHECKPOINTS / "4") in train_line


def test_the_goal_share_is_goals_over_ended_attempts_for_a_frame_and_for_raw_counts():
    import numpy as np
    import pandas as pd

    df = pd.DataFrame({"episode": [0, 0, 1, 1], "goals": [3, 0, 1, 1], "collisions": [1, 0, 2, 0]})
    assert rundir.goal_share(df, last=1) == 2 / 4  # episode 1 only
    assert rundir.goal_share(df, last=2) == 5 / 8
    assert rundir.share_of_goals(np.array([[3, 0]]), np.array([[1, 0]])) == 0.75  # the bars' chunk arrays
    assert np.isnan(rundir.share_of_goals(np.zeros(3), np.zeros(3)))  # nothing ended
