"""The robustness report (docs/robustness.md): the table reads each point's summary.json and
eval.json, the verdict applies the issue's acceptance rules, the figures are drawn. Points are
written by hand (no training): the report only reads files."""

import json

import numpy as np
import pandas as pd
import pytest

from fedjax_nav.analysis import robustness as rb
from fedjax_nav.config.sweepfile import load_sweep
from fedjax_nav.configs import SWEEP_DIR
from fedjax_nav.experiments.robustness import report


def _summary(honest, all_=None, bytes_=51274000.0):
    all_ = honest if all_ is None else all_
    return {
        "seeds": len(honest),
        "episodes_done": 125,
        "success_last": float(np.mean(all_)),
        "success_last_std": float(np.std(all_)),
        "success_last_per_seed": list(all_),
        "success_last_honest": float(np.mean(honest)),
        "success_last_honest_std": float(np.std(honest)),
        "success_last_honest_per_seed": list(honest),
        "fed_bytes_sent": bytes_,
        "fed_skipped_rounds": 0.0,
        "diverged_seeds": [],
    }


def _eval_json(honest_per_seed, all_per_seed):
    def block(per):
        return {
            "overall": {"success_rate": float(np.mean(per)), "success_seed_std": float(np.std(per))},
            "success_per_seed": {str(i): v for i, v in enumerate(per)},
        }

    return {"all_agents": block(all_per_seed), "honest_agents": block(honest_per_seed)}


@pytest.fixture(scope="module")
def sweep():
    return load_sweep(SWEEP_DIR / "robustness.yaml")


def _point(sweep, **values):
    for p in sweep.points:
        if all(p.values.get(k) == v for k, v in values.items()) and len(p.values) == len(values):
            return p
    raise KeyError(values)


def test_the_table_reads_each_points_summary_and_evaluation(sweep, tmp_path):
    clean = _point(sweep, **{"fed.aggregator": "method"})
    noisy = _point(sweep, **{"fed.aggregator": "median", "fed.attack": "noise", "fed.byzantine": 1})
    for p, s in ((clean, _summary([0.9, 0.8])), (noisy, _summary([0.85, 0.75], [0.7, 0.6]))):
        (tmp_path / "points" / p.id).mkdir(parents=True)
        (tmp_path / "points" / p.id / "summary.json").write_text(json.dumps(s))
    # the clean run's robots but the last: robot 4 never succeeds, robots 0-3 in 3 of 4 episodes
    # of seed 0 and in every episode of seed 1 (last 25 of 30 episodes)
    rows = [
        (e, seed, r, int(r < 4 and (seed == 1 or e % 4 != 0))) for e in range(30) for seed in range(2) for r in range(5)
    ]
    pd.DataFrame(rows, columns=["episode", "seed", "robot", "reached_goal"]).to_csv(
        tmp_path / "points" / clean.id / "metrics.csv", index=False
    )
    ev = tmp_path / "points" / noisy.id / "eval" / "eval"
    ev.mkdir(parents=True)
    (ev / "eval.json").write_text(json.dumps(_eval_json([0.5, 0.7], [0.4, 0.6])))
    out = report(sweep, tmp_path, evaluate=False, copy_tables=tmp_path / "res", echo=lambda s: None)
    t = pd.read_csv(tmp_path / "robustness.csv")
    assert list(t.setting) == ["median, noise x1", "FedAvg, clean"]  # grid order of the file
    r = t.set_index("setting")
    assert r.loc["median, noise x1", "success_honest"] == pytest.approx(0.8)
    assert r.loc["median, noise x1", "success_all"] == pytest.approx(0.65)
    assert r.loc["median, noise x1", "eval_honest"] == pytest.approx(0.6)
    assert r.loc["median, noise x1", "eval_all"] == pytest.approx(0.5)
    assert np.isnan(r.loc["FedAvg, clean", "eval_honest"])  # not evaluated
    last = [e for e in range(5, 30)]
    want = (np.mean([e % 4 != 0 for e in last]) + 1.0) / 2
    assert r.loc["FedAvg, clean", "success_but_last"] == pytest.approx(want)
    assert np.isnan(r.loc["median, noise x1", "success_but_last"])
    m = rb.matrix(t, "success_honest", 1)
    assert list(m.columns) == ["clean", "noise"] and list(m.index) == ["FedAvg", "median"]
    assert m.loc["median", "noise"] == "0.800 ± 0.050" and m.loc["FedAvg", "clean"] == "0.850 ± 0.050"
    assert m.loc["median", "clean"] == "" and m.loc["FedAvg", "noise"] == ""  # not run
    assert rb.matrix(t, "eval_honest", 1).loc["FedAvg", "clean"] == "n/a"  # run, not evaluated
    ps = pd.read_csv(tmp_path / "robustness_per_seed.csv")
    assert ps[ps.setting == "median, noise x1"].eval_honest.tolist() == [0.5, 0.7]
    assert [p.name for p in out["figures"]] == ["robustness_learning.png", "robustness_eval.png"]
    assert all(p.stat().st_size > 1000 for p in out["figures"])
    assert sorted(p.name for p in (tmp_path / "res").iterdir()) == sorted(
        ["robustness.csv", "robustness_per_seed.csv", "robustness_verdict.csv"]
    )


def _row(setting_, aggregator, attack, byz, participation, robots, honest):
    return dict(
        setting=setting_,
        method="flddpg",
        aggregator=aggregator,
        attack=attack,
        byzantine=byz,
        participation=participation,
        robots=robots,
        success_honest=honest,
        success_honest_std=0.05,
        success_but_last=honest - 0.05 if not byz else np.nan,
    )


def test_the_verdict_applies_the_issues_rules():
    t = pd.DataFrame(
        [
            _row("clean", "method", "clean", 0, 1.0, 5, 0.90),
            _row("dropout", "method", "clean", 0, 0.7, 5, 0.80),  # 0.889 of clean: fails 10%
            _row("fleet", "method", "clean", 0, 1.0, 4, 0.82),
            _row("a", "method", "noise", 1, 1.0, 5, 0.00),
            _row("b", "median", "noise", 1, 1.0, 5, 0.85),  # within 10% and above the fleet: passes
            _row("c", "krum", "noise", 1, 1.0, 5, 0.50),
            _row("d", "method", "scale", 1, 1.0, 5, 0.10),
            _row("e", "median", "scale", 1, 1.0, 5, 0.815),  # within 10% (0.81) but below the fleet
            _row("f", "median", "zeros", 2, 1.0, 5, 0.9),  # 2 Byzantine: not an acceptance cell
        ]
    )
    v = rb.verdict(t).set_index("check")
    assert list(v.index) == ["30% absent every round", "1 of 5 Byzantine, noise", "1 of 5 Byzantine, scale"]
    assert not v.loc["30% absent every round", "passes"]
    assert v.loc["1 of 5 Byzantine, noise", "passes"] and v.loc["1 of 5 Byzantine, noise", "best"] == "median"
    assert v.loc["1 of 5 Byzantine, noise", "fedavg"] == 0.0
    assert v.loc["1 of 5 Byzantine, noise", "aggregators_run"] == 2
    assert v.loc["1 of 5 Byzantine, noise", "clean_same_robots"] == pytest.approx(0.85)
    assert not v.loc["1 of 5 Byzantine, scale", "passes"]


def test_settings_are_named_from_the_config(sweep):
    names = {rb.setting(p.cfg) for p in sweep.points}
    assert {"FedAvg, clean", "FedAvg, clean, 30% absent", "FedAvg, clean, 4 robots", "IDDPG"} <= names
    assert "geometric median, sign_flip x2" in names
    assert len(names) == len(sweep.points)  # every point of the file has a distinct name
