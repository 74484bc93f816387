"""A griffe extension for the API reference (loaded by mkdocstrings; see mkdocs.yml).

The project documents a field with a comment on its line, as gymnax's `EnvParams` do:
`v_max: jax.Array = struct.field(...)  # m/s`. Griffe reads docstrings only, so these fields
would show bare or not at all; this extension gives every attribute without a docstring the
comment(s) written on its own lines as its docstring. Comment lines above a field (they describe
a group of fields) are left out.
"""

from __future__ import annotations

import io
import textwrap
import tokenize

import griffe

TOOL_COMMENTS = ("noqa", "type:", "fmt:", "pragma")  # comments for linters and formatters, not readers


def trailing_comment(lines: list[str]) -> str:
    """The text of the comments on a statement's own lines, joined by spaces ("" when none)."""
    source = textwrap.dedent("\n".join(lines)) + "\n"
    try:
        tokens = list(tokenize.generate_tokens(io.StringIO(source).readline))
    except (tokenize.TokenError, IndentationError, SyntaxError):  # not a whole statement: no comment taken
        return ""
    texts = (t.string.lstrip("#").strip() for t in tokens if t.type == tokenize.COMMENT)
    return " ".join(t for t in texts if t and not t.startswith(TOOL_COMMENTS))


class FieldComments(griffe.Extension):
    """Attribute docstrings from the comments on the attribute's lines."""

    def on_attribute_instance(self, *, attr: griffe.Attribute, **kwargs) -> None:
        if attr.docstring is not None or attr.lineno is None:
            return
        try:
            lines = attr.lines
        except (OSError, KeyError):  # no source available for this object
            return
        text = trailing_comment(lines)
        if text:
            attr.docstring = griffe.Docstring(text, lineno=attr.lineno, endlineno=attr.endlineno, parent=attr)
