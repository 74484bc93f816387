"""The README's Python snippet (section "From Python") runs as it stands: it is cut out of README.md
and executed in a fresh folder, so a renamed function or argument breaks this test, not a reader."""

import re
from pathlib import Path

import numpy as np

README = Path(__file__).resolve().parents[1] / "README.md"


def snippet() -> str:
    section = README.read_text().split("## From Python", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert len(blocks) == 1, "the README's 'From Python' section holds one python block"
    return blocks[0]


def test_the_readme_snippet_runs_and_writes_a_run_directory(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # its run directory (runs/readme) lands here
    scope: dict = {}
    exec(compile(snippet(), str(README), "exec"), scope)
    assert scope["rewards"].shape == (256,) and np.isfinite(np.asarray(scope["rewards"])).all()
    run = tmp_path / "runs" / "readme"
    for f in ("config.yaml", "metrics.csv", "summary.json", "params.npz"):
        assert (run / f).is_file(), f
    assert scope["summary"]["episodes_done"] == 5 and 0.0 <= scope["summary"]["success_last"] <= 1.0
    assert capsys.readouterr().out.strip()  # it prints the rewards' sum and the success
