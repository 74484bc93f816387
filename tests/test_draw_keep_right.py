"""scripts/draw_keep_right.py (docs/shared_rooms.md, "Keeping right", "Giving way"): a
shared_report table's fleets split by the rule their labels end in, drawn; a table that is not
one is refused in one line."""

import importlib.util
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("draw_keep_right", ROOT / "scripts" / "draw_keep_right.py")
draw_keep_right = importlib.util.module_from_spec(spec)
spec.loader.exec_module(draw_keep_right)


def table() -> pd.DataFrame:
    rows = []
    fleets = ("central", 0.6), ("central, keeping right", 0.8), ("central, trained keeping right", 0.81)
    for label, s in fleets + (("central, keeping right and giving way", 0.9),):
        for k in (1, 2, 4, 8):
            for fam in ("mixture", "all"):
                rows.append(
                    dict(label=label, robots_per_room=k, family=fam, success=s / k**0.1, ci_seeds_low=s / k**0.1 - 0.01)
                    | dict(ci_seeds_high=s / k**0.1 + 0.01, robot_collision=0.05 * k)
                )
    return pd.DataFrame(rows)


def test_the_fleets_are_split_by_the_rule_and_drawn(tmp_path, capsys):
    parts = draw_keep_right.series(table())
    assert list(parts) == ["central"] and set(parts["central"]) == {"without", "with", "trained", "giving way"}
    assert parts["central"]["with"].robots_per_room.tolist() == [1, 2, 4, 8]  # the 'all' rows only
    csv = tmp_path / "t.csv"
    table().to_csv(csv, index=False)
    assert draw_keep_right.main([str(csv), "--out", str(tmp_path / "k.png")]) == 0
    assert (tmp_path / "k.png").stat().st_size > 10_000
    assert draw_keep_right.main([str(csv), "--out", str(tmp_path / "c.png"), "--fleet", "central"]) == 0
    assert draw_keep_right.main([str(csv), "--out", str(tmp_path / "d.png"), "--fleet", "centrall"]) == 2
    assert "'centrall'" in capsys.readouterr().err
    table().drop(columns="ci_seeds_low").to_csv(csv, index=False)
    assert draw_keep_right.main([str(csv), "--out", str(tmp_path / "b.png")]) == 2
    assert "ci_seeds_low" in capsys.readouterr().err
