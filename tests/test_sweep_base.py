"""A sweep file's `base:` names its config as `fedjax-nav train --config` does (`config.io.locate`):
a shipped name works from any sweep file, a file beside the sweep file wins, a bad name is one
SweepError line naming the sweep file and the name (fedjax_nav/config/sweepfile.py's docstring)."""

from pathlib import Path

import pytest
import yaml

from fedjax_nav.config import load_config, save_config
from fedjax_nav.config import sweepfile as sf

ROOT = Path(__file__).resolve().parents[1]


def sweep_file(folder: Path, **spec) -> Path:
    path = folder / "mine.yaml"
    path.write_text(yaml.safe_dump({"name": "mine", **spec}, sort_keys=False))
    return path


def test_a_shipped_name_as_base_loads_as_with_config(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # nothing named thesis/ here: the shipped preset is found by name
    s = sf.load_sweep(sweep_file(tmp_path, base="thesis/flddpg", grid={"fed.tau": [0.0, 1.0]}))
    want = [load_config("thesis/flddpg", [f"fed.tau={t}", "run.seeds=1"]) for t in (0.0, 1.0)]
    assert [p.cfg for p in s.points] == want
    by_path = sf.load_sweep(
        sweep_file(tmp_path, base=str(ROOT / "configs/thesis/flddpg.yaml"), grid={"fed.tau": [0.0, 1.0]})
    )
    assert [p.id for p in s.points] == [p.id for p in by_path.points]


def test_a_grid_over_shipped_names_labels_each_by_its_method(tmp_path):
    s = sf.load_sweep(sweep_file(tmp_path, grid={"base": ["thesis/iddpg", "thesis/flddpg.yaml"]}))
    assert [p.label for p in s.points] == ["method=iddpg", "method=flddpg"]
    assert [p.cfg.method for p in s.points] == ["iddpg", "flddpg"]


def test_a_file_beside_the_sweep_file_wins_over_the_shipped_name(tmp_path):
    (tmp_path / "thesis").mkdir()
    mine = load_config("thesis/flddpg", ["offpolicy.gamma=0.5"])
    save_config(mine, tmp_path / "thesis" / "flddpg.yaml")
    (p,) = sf.load_sweep(sweep_file(tmp_path, base="thesis/flddpg.yaml")).points
    assert p.cfg.offpolicy.gamma == 0.5


@pytest.mark.parametrize("base", ["thesis/nope", "../nowhere/flddpg.yaml"])
def test_a_bad_base_is_one_line_naming_the_file_and_the_name(tmp_path, base):
    path = sweep_file(tmp_path, base=base)
    with pytest.raises(sf.SweepError) as e:
        sf.load_sweep(path)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{path}: base: {base}: no such config file")
    assert "thesis/flddpg" in msg  # the shipped names it could have been
