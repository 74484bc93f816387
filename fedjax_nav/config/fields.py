"""How a config field is declared (`_f`: its default, range or choices, whether it is traced, its
doc, kept in the dataclass field's metadata) and the error a bad value raises. The sections of
`schema.py` and `env_schema.py` declare their fields with it; validate, traced and the docs read
the metadata back.
"""

from __future__ import annotations

from dataclasses import field


class ConfigError(ValueError):
    """A config value is invalid; the message names the file, the key and what is allowed."""


def _f(default, lo=None, hi=None, choices=None, traced=False, doc=""):
    meta = {"lo": lo, "hi": hi, "choices": choices, "traced": traced, "doc": doc}
    if isinstance(default, (list, tuple)):
        return field(default_factory=lambda: tuple(default), metadata=meta)
    return field(default=default, metadata=meta)
