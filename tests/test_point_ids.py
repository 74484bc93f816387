"""The point ids of every shipped config and sweep point stay what they were.

A point's id (`fedjax_nav.config.sweepfile.point_id`) names its run directory, `points/<id>/`:
a sweep or `reproduce` that finds it there reuses the run instead of training it again. A change
of the config's layout (a field moved to another section, a section renamed) that changed an id
would orphan every finished run of that point. `tests/data/shipped_point_ids.json` holds the ids
recorded from the code before such a change: every shipped config (`configs/`), every point of
every shipped sweep, and every point of `reproduce --scale ci` (its overrides and buffer scale).

To record anew, when a change is meant to change ids (and say so in the commit):
`FEDJAX_NAV_RECORD_POINT_IDS=1 pytest -n 0 tests/test_point_ids.py`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from fedjax_nav.config import load_config
from fedjax_nav.config.sweepfile import load_sweep, point_id
from fedjax_nav.configs import names
from fedjax_nav.experiments.reproduce import SCALES, load_experiments

FILE = Path(__file__).resolve().parent / "data" / "shipped_point_ids.json"
RECORD = os.environ.get("FEDJAX_NAV_RECORD_POINT_IDS") == "1"


def shipped_ids() -> dict[str, str]:
    """{what: id} of every shipped config, every shipped sweep's points and the ci scale's points."""
    ids = {f"config {name}": point_id(load_config(name)) for name in names("config")}
    for name in names("sweep"):
        for i, p in enumerate(load_sweep(name).points):
            ids[f"sweep {name} [{i}] {p.label}"] = p.id
    for sweep in load_experiments(SCALES["ci"]):
        for i, p in enumerate(sweep.points):
            ids[f"ci {sweep.name} [{i}] {p.label}"] = p.id
    return ids


def test_shipped_point_ids_unchanged():
    ids = shipped_ids()
    if RECORD:
        FILE.write_text(json.dumps(ids, indent=1) + "\n")
    recorded = json.loads(FILE.read_text())
    changed = sorted(k for k in recorded.keys() & ids.keys() if recorded[k] != ids[k])
    assert not changed, f"{len(changed)} point ids changed, e.g. {changed[:3]}"
    assert ids.keys() == recorded.keys(), (
        f"points added {sorted(ids.keys() - recorded.keys())[:3]}, gone {sorted(recorded.keys() - ids.keys())[:3]}"
    )
