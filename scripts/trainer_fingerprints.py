"""Fingerprints (sha256 of metrics, final networks and buffers) of tests/test_trainer.py's runs of
every thesis config, with the code this script is run from:

    PYTHONPATH=CHECKOUT python scripts/trainer_fingerprints.py CHECKOUT/tests OUT.json

tests/data/trainer_run_fingerprints.json was written so from the code before the aggregators and the
env builder were refactored (commit 4330832); tests/test_trainer.py holds every later version to it.
"""

import json
import sys

sys.path.insert(0, sys.argv[1])

import test_trainer as T  # noqa: E402
from test_programme_fingerprint import digest  # noqa: E402

out = {name: digest(T.run_thesis(name).metrics, T.run_thesis(name).states) for name in sorted(T.EXTRA)}
json.dump(out, open(sys.argv[2], "w"), indent=1, sort_keys=True)
print(json.dumps(out, indent=1))
