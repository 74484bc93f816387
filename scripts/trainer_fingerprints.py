"""Fingerprints (sha256 of metrics, final networks and buffers) of tests/test_trainer.py's runs of
every thesis config, with the code this script is run from:

    PYTHONPATH=CHECKOUT python scripts/trainer_fingerprints.py CHECKOUT/tests OUT.json

OUT.json is one record ({"versions", "recorded_from", "cases"}) of tests/data/trainer_run_fingerprints.json,
which holds one per (jax versions, CPU kind): add it there, with the commit it was run from, to hold
later code on this kind of machine to it (tests/test_trainer.py; docs in tests/test_programme_fingerprint.py).
"""

import json
import sys

sys.path.insert(0, sys.argv[1])

import test_trainer as T  # noqa: E402
from test_programme_fingerprint import digest, versions  # noqa: E402

cases = {name: digest(T.run_thesis(name).metrics, T.run_thesis(name).states) for name in sorted(T.EXTRA)}
out = {"versions": versions(), "cases": cases}
json.dump(out, open(sys.argv[2], "w"), indent=1, sort_keys=True)
print(json.dumps(out, indent=1))
