"""scripts/bench_give_way.py (docs/shared_rooms.md, "Speed"): both programs run and are timed at a
tiny scale; bad --ks is one line."""

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("bench_give_way", ROOT / "scripts" / "bench_give_way.py")
bench_give_way = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench_give_way)


@pytest.mark.full  # two programs compiled for a benchmark script: 20 s
def test_both_steps_are_timed_with_the_rules_off_and_on(capsys):
    rows = bench_give_way.rows([2], rooms=2, steps=3, repeats=1)
    got = [(r["robots_per_room"], r["give_way"], r["give_way_door"]) for r in rows]
    assert got == [(2, 0.0, 0.0), (2, 0.05, 0.0), (2, 0.05, 1.6)]
    assert all(r["before_steps_per_s"] > 0 and r["now_steps_per_s"] > 0 and r["cost"] > 0 for r in rows)
    assert bench_give_way.main(["--ks", "four"]) == 2
    assert "--ks 'four'" in capsys.readouterr().err
