"""Write tests/full_tier.txt, the tests that the README's test command leaves to the full tier
(`pytest -m full`), from cold runs' junit reports (docs/benchmarks.md, "The test suite: two
tiers"): every test that took at least THRESHOLD seconds in any of them, and every test of the
files that start other processes or devices (WHOLE_FILES). Give the reports of the whole suite and
of the quick tier alone: a test that shared a compilation with a test moved out pays for it in the
second (it is moved out too).

    HOME=$(mktemp -d) CI=true pytest -q -m "full or not full" --junitxml=all.xml
    HOME=$(mktemp -d) CI=true pytest -q --junitxml=quick.xml
    python scripts/test_tiers.py all.xml quick.xml > tests/full_tier.txt
"""

from __future__ import annotations

import sys
import xml.etree.ElementTree as ET

THRESHOLD = 10.0  # s of one test, cold, on the 2-core reference VM (docs/benchmarks.md)
# Files whose every test goes: 4 forced devices, two processes, a wheel built and installed, the
# whole `reproduce --scale ci` programme in one module fixture.
WHOLE_FILES = ("test_sharding.py", "test_distributed.py", "test_wheel.py", "test_reproduce.py")


def full_tier(junits: list[str], threshold: float = THRESHOLD) -> list[str]:
    """'file.py::test_name[params]' of the tests in the full tier, sorted."""
    out = set()
    for junit in junits:
        for case in ET.parse(junit).getroot().iter("testcase"):
            file = case.get("classname").split(".")[-1] + ".py"
            node = f"{file}::{case.get('name')}"
            if file in WHOLE_FILES or float(case.get("time")) >= threshold:
                out.add(node)
    return sorted(out)


def main(argv: list[str]) -> int:
    if not argv:
        print("usage: python scripts/test_tiers.py JUNIT.xml [JUNIT.xml ...] > tests/full_tier.txt", file=sys.stderr)
        return 2
    print(f"# The full tier: tests of at least {THRESHOLD:g} s cold, and every test of {', '.join(WHOLE_FILES)}.")
    print("# Written by scripts/test_tiers.py from cold runs' junit reports (docs/benchmarks.md).")
    for node in full_tier(argv):
        print(node)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
