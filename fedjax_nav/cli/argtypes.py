"""What a command-line flag's value may be, and how a bad one is said (fedjax_nav.cli.parser
builds the commands' flags from these): argparse types that name the range they allow, and the
parser class whose errors are one line, exit 2."""

from __future__ import annotations

import argparse


def positive_int(text: str) -> int:
    """An argparse type: an integer >= 1 (device counts, attempts, steps)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {value}")
    return value


# A PRNG seed: jax takes any int64 (a larger one was an OverflowError traceback).
SEED_RANGE = (-(2**63), 2**63 - 1)
# `render --steps`: the random-policy trajectory is one jitted scan holding every step (1e8 steps
# asked for 3.2 GB at once; >= 2^31 overflowed the int32 step counter): 333x the default is plenty.
MAX_RENDER_STEPS = 100_000


def robots_per_room(text: str) -> tuple[int, ...]:
    """An argparse type: comma-separated integers >= 1 (`evaluate --robots-per-room`; the largest K
    allowed is evaluation.shared_rooms.MAX_ROBOTS, checked there)."""
    return tuple(positive_int(part.strip()) for part in text.split(","))


def bounded_int(lo: int, hi: int, what: str = "an integer"):
    """An argparse type: an integer in [lo, hi] (the error names the range)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what} in [{lo:,}, {hi:,}], got {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"expected {what} in [{lo:,}, {hi:,}], got {value}")
        return value

    parse.__name__ = "int"  # argparse names the type in its messages; scripts/attack.py reads it
    return parse


class OneLineParser(argparse.ArgumentParser):
    """argparse with one `error:` line (and the --help hint) instead of 3-10 lines of usage; exit 2.
    Subparsers inherit the class, so every command's flags behave alike.

    A text flag given an empty value (`--out ''`, `--resume "$UNSET"`) is refused: it never means
    the flag's default, which a flag left out gives (`train --resume ''` used to start a new run,
    `evaluate --out ''` wrote into the working folder, `reproduce --only ''` ran every experiment)."""

    def parse_known_args(self, args=None, namespace=None):
        ns, rest = super().parse_known_args(args, namespace)
        for a in self._actions:
            value = getattr(ns, a.dest, None)
            if a.option_strings and a.type in (None, str) and isinstance(value, str) and not value.strip():
                self.error(f"argument {'/'.join(a.option_strings)}: expected a value, got {value!r}")
        return ns, rest

    def error(self, message: str):
        from fedjax_nav.messages import one_line

        self.exit(2, f"error: {self.prog}: {one_line(message)} (see {self.prog} --help)\n")
