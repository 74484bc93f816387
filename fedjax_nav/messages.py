"""How a value or a message appears in a one-line error: the helpers every reader of user input
(configs, sweep files, world files, `--set` values) and every command's "error: " line share.
Standard library only, so that `import fedjax_nav.config` stays free of jax."""

from __future__ import annotations

import re
from typing import Any

# Shown values are cut to this many characters (an error line must stay one readable line).
SHOW_CHARS = 80


def shorten(text: str, limit: int = SHOW_CHARS) -> str:
    """`text`, or its first `limit` characters and how long it was."""
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text):,} chars)"


def one_line(message: Any, limit: int = SHOW_CHARS) -> str:
    """An error message as one line, each word longer than 120 characters (a path or a value of
    thousands) cut by `shorten`: what every command prints after "error: "."""
    text = " ".join(str(message).splitlines())
    return re.sub(r"\S{121,}", lambda m: shorten(m.group(), limit), text)


def show(value: Any, limit: int = SHOW_CHARS) -> str:
    """repr(value) for an error message, cut to `limit` characters (`shorten`)."""
    try:
        text = repr(value)
    except ValueError:  # an int of more than 4300 digits has no repr
        text = f"<an integer of about {int(value.bit_length() * 0.30103) + 1:,} digits>"
    except RecursionError:
        text = f"<a {type(value).__name__} nested too deeply to show>"
    return shorten(text, limit)
