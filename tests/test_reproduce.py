"""`fedjax-nav reproduce --scale ci`: every experiment of chapter 4 at a reduced scale, into a
report folder with every figure and table; a second invocation trains nothing; the analysis
notebook runs headless on the report, and on a fresh clone (no runs, nothing set: the tables
committed under results/).

The reduced programme (54 distinct configs x 2 seeds, 9 compiled groups, 8 evaluations) is run
once per module: about 2 minutes on a 2-core CPU, most of it compilation (which is why the ci
scale puts every robot in the smallest room and evaluates in a small 4-goal room).
"""

import json
import shutil
from pathlib import Path

import pandas as pd
import pytest

from fedjax_nav import cli, methods
from fedjax_nav.experiments import reproduce as rp
from fedjax_nav.federated.comm import communication

ROOT = Path(__file__).resolve().parents[1]
FIGURES = [
    "fig11_snddpg_buffer.png",
    "fig12_fed_period_learning.png",
    "fig13_fed_period_success.png",
    "fig14_tau.png",
    "fig15_methods_reward.png",
    "fig16_methods_success.png",
    "fig17_eval_best_agents.png",
    "fig18_eval_methods.png",
    "fig19_improvements_learning.png",
    "fig20_eval_improvements.png",
]
TABLES = [
    "table2_hyperparameters.csv",
    "table2_hyperparameters.md",
    "table3_communication.csv",
    "table3_communication.md",
    "eval_summary.csv",
    "report.md",
    "reproduce.json",
]


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    out = tmp_path_factory.mktemp("reproduce") / "ci"
    info = rp.reproduce("ci", out, progress=False, echo=lambda s: None)
    return out, info


def test_every_figure_and_table_is_written(report):
    out, info = report
    for name in FIGURES + TABLES:
        assert (out / name).exists() and (out / name).stat().st_size > 0, name
    assert sorted(info["figures"]) == FIGURES
    for name in rp.EXPERIMENTS:
        d = out / "experiments" / name
        assert {"results.csv", "summary.csv", "by_setting.csv", "sweep.yaml"} <= {f.name for f in d.iterdir()}, name


def test_one_compilation_per_group_and_shared_configs_trained_once(report):
    _, info = report
    groups = info["train"]["groups"]
    assert len(groups) == 9 and all(g["traces"] == 1 for g in groups)
    assert info["distinct_runs"] == 54 and info["seed_runs"] == 108  # 13 experiments ask for 62 settings


def test_report_puts_the_thesis_numbers_beside_the_measured(report):
    out, _ = report
    md = (out / "report.md").read_text()
    for name in rp.EXPERIMENTS:
        assert f"### {name}:" in md
    for thesis_number in ("0.49", "1.35", "0.79", "0.1078", "0.3797", "13248000"):
        assert thesis_number in md, thesis_number
    assert "Reduced scale" in md
    gamma = pd.read_csv(out / "experiments" / "gamma" / "by_setting.csv")
    assert list(gamma["setting"]) == [0.8, 0.9, 0.999] and list(gamma["runs"]) == [8, 8, 8]  # 4 methods x 2 seeds
    assert list(gamma["thesis_success"]) == [0.40, 0.49, 0.43]
    buf = pd.read_csv(out / "experiments" / "buffer_flddpg" / "by_setting.csv")
    assert list(buf["setting"]) == [100, 200, 600, 1000, 1400]  # x 0.02 at ci scale, as run


def test_table3_counts_match_eq25_at_the_run_scale(report):
    out, info = report
    t3 = pd.read_csv(out / "table3_communication.csv").set_index("method")
    assert list(t3.index) == ["iddpg", "seddpg", "snddpg", "flddpg"]
    for m in t3.index:
        expect = communication(methods.get(m), 10, 64, 5, 32, "episodes", 2)["n_comm"]
        assert t3.loc[m, "n_comm (Eq. 25)"] == pytest.approx(expect)
    assert t3.loc["flddpg", "aggregation events counted"] == 5  # E_update = 2 over 10 episodes
    assert t3.loc["flddpg", "bytes per federated round"] > 0 and t3.loc["iddpg", "bytes per federated round"] == 0


def test_every_evaluated_method_has_a_row(report):
    out, info = report
    ev = pd.read_csv(out / "eval_summary.csv")
    # the ci scale evaluates in its small room, written beside the report and kept per point
    assert info["eval_world"] == "ci-arena" and (out / "ci-arena.json").exists()
    assert all((out / "points" / p / "eval" / "ci-arena" / "eval.json").exists() for p in ev["point"])
    assert list(ev["label"]) == ["iddpg", "seddpg", "snddpg", "flddpg", "pwddpg", "rwddpg", "gsddpg", "flsddpg"]
    assert (ev["episodes"] == 40).all()  # 2 seeds x 5 agents x 4 goals x 1 attempt (SNDDPG: 2 x 1 x 4 x 5)
    assert ev["success"].between(0, 1).all()


def test_running_again_trains_and_evaluates_nothing(report, capsys):
    out, _ = report
    assert cli.main(["reproduce", "--scale", "ci", "--out", str(out), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "54 point(s), 54 already done; 0 to train" in text and "evaluated" not in text
    info = json.loads((out / "reproduce.json").read_text())
    assert len(info["history"]) == 2 and info["history"][1]["trained_points"] == 0


def test_unknown_experiment_is_an_input_error(capsys):
    assert cli.main(["reproduce", "--only", "gamma,nope", "--quiet"]) == 2
    assert "nope" in capsys.readouterr().err


def _run_notebook(path: Path):
    """Execute the analysis notebook at `path`, its kernel in the notebook's folder; returns
    everything it printed or displayed as text."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    nb = nbformat.read(path, as_version=4)
    assert all(not c.get("outputs") for c in nb.cells if c.cell_type == "code"), "commit the notebook without outputs"
    nbclient.NotebookClient(
        nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}}
    ).execute()
    outputs = [o for c in nb.cells for o in c.get("outputs", [])]
    return "".join(o.get("text", "") + o.get("data", {}).get("text/plain", "") for o in outputs)


def test_the_analysis_notebook_runs_on_a_fresh_clone(tmp_path, monkeypatch):
    # a clone's files the notebook may read (notebooks/, results/), and no runs/ folder
    clone = tmp_path / "clone"
    shutil.copytree(ROOT / "results", clone / "results")
    (clone / "notebooks").mkdir()
    shutil.copy(ROOT / "notebooks" / "analysis.ipynb", clone / "notebooks")
    monkeypatch.delenv("FEDJAX_NAV_RESULTS", raising=False)  # the kernel inherits this environment
    monkeypatch.chdir(clone)
    printed = _run_notebook(clone / "notebooks" / "analysis.ipynb")
    assert f"committed {clone / 'results'}" in printed  # neither runs nor the variable: the committed tables
    assert "redrew 13 experiment tables" in printed  # every experiment file of chapter 4
    assert "fed_period_steps" in printed and "thesis_success" in printed  # the per-setting table
    assert "flsddpg" in printed and "n_comm (Eq. 25)" in printed  # evaluation and Table 3


def test_the_analysis_notebook_runs_on_the_report(report, monkeypatch):
    out, _ = report
    monkeypatch.setenv("FEDJAX_NAV_RESULTS", str(out))  # a user's own report
    printed = _run_notebook(ROOT / "notebooks" / "analysis.ipynb")
    assert f"report {out}" in printed and "fig20_eval_improvements.png" in printed
    assert "redrew 13 experiment tables" in printed  # results/: every experiment file of chapter 4
