"""Write tests/full_tier.txt, the tests that the README's test command leaves to the full tier
(`pytest -m full`), from a cold run's junit report (docs/benchmarks.md, "The test suite: two
tiers"): every test that took at least THRESHOLD seconds, and every test of the files that start
other processes or devices (WHOLE_FILES).

    HOME=$(mktemp -d) CI=true pytest -q -m "full or not full" --junitxml=cold.xml
    python scripts/test_tiers.py cold.xml > tests/full_tier.txt
"""

from __future__ import annotations

import sys
import xml.etree.ElementTree as ET

THRESHOLD = 10.0  # s of one test, cold, on the 2-core reference VM (docs/benchmarks.md)
# Files whose every test goes: 4 forced devices, two processes, a wheel built and installed, the
# whole `reproduce --scale ci` programme in one module fixture.
WHOLE_FILES = ("test_sharding.py", "test_distributed.py", "test_wheel.py", "test_reproduce.py")


def full_tier(junit: str, threshold: float = THRESHOLD) -> list[str]:
    """'file.py::test_name[params]' of the tests in the full tier, sorted."""
    out = set()
    for case in ET.parse(junit).getroot().iter("testcase"):
        file = case.get("classname").split(".")[-1] + ".py"
        node = f"{file}::{case.get('name')}"
        if file in WHOLE_FILES or float(case.get("time")) >= threshold:
            out.add(node)
    return sorted(out)


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print("usage: python scripts/test_tiers.py JUNIT.xml > tests/full_tier.txt", file=sys.stderr)
        return 2
    print(f"# The full tier: tests of at least {THRESHOLD:g} s cold, and every test of {', '.join(WHOLE_FILES)}.")
    print("# Written by scripts/test_tiers.py from a cold run's junit report (docs/benchmarks.md).")
    for node in full_tier(argv[0]):
        print(node)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
