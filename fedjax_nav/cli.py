"""`fedjax-nav`: the command line. Each command parses its flags and dispatches to a module.

Heavy imports (jax, brax, matplotlib) happen inside the commands so that `--help` is instant.
Input errors (bad config, world file, checkpoint) end with one line and exit code 2.
"""
from __future__ import annotations

import argparse
import sys


class UserError(Exception):
    """An input error the user can fix; printed as one line, exit code 2."""


def _render(args: argparse.Namespace) -> int:
    from fedjax_nav.env.render import render_worlds

    paths = render_worlds(args.worlds or None, out_dir=args.out, steps=args.steps, seed=args.seed)
    for p in paths:
        print(f"wrote {p}")
    return 0


def _bench(args: argparse.Namespace) -> int:
    from fedjax_nav.bench import main as bench_main

    return bench_main(args)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="fedjax-nav", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("render", help="draw playgrounds with a short random-policy trajectory")
    p.add_argument("worlds", nargs="*", help="world names or files (default: every shipped world)")
    p.add_argument("--out", default="runs/render", help="output folder for the PNGs")
    p.add_argument("--steps", type=int, default=300, help="random-policy steps to draw")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=_render)

    p = sub.add_parser("bench", help="measure throughput (env, train, sweep, all)")
    p.add_argument("what", nargs="?", default="env", choices=["env", "train", "sweep", "all"])
    p.add_argument("--quick", action="store_true", help="small sizes, for a smoke test")
    p.add_argument("--record", default=None, help="append the results to this markdown file")
    p.set_defaults(func=_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    from fedjax_nav.worlds import WorldError

    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (UserError, WorldError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
