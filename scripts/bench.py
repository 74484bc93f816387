"""Benchmarks: same as `fedjax-nav bench`. Example: python scripts/bench.py all --record docs/benchmarks.md"""

import sys

from fedjax_nav.cli import main

if __name__ == "__main__":
    sys.exit(main(["bench", *sys.argv[1:]]))
