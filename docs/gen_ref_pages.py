"""Write the API reference at build time (run by mkdocs-gen-files; see mkdocs.yml).

One page per public module of `fedjax_nav/` holding `::: module` (mkdocstrings renders it by
static analysis with griffe: nothing is imported), plus `reference/SUMMARY.md` for
mkdocs-literate-nav. Private modules (`_name.py`, `_pkg/`) and `__main__` are skipped. A module
moved or renamed needs no docs edit; a broken cross-reference in a docstring still fails
`mkdocs build --strict`.

The nav under "API reference" is the package's page first, then its subpackages and modules as
siblings (not all nested under one `fedjax_nav` entry: Material's `navigation.indexes` takes a
section's first index page as the section's own link and would hide everything under it).
SUMMARY.md only feeds the nav: it is excluded from the site, so no `reference/SUMMARY/` page.

`reference/index.md` heads the section: every module with what it is for, the first sentence of
its docstring (read with `ast`, nothing imported), so the overview changes with the docstrings and
cannot drift from them.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import mkdocs_gen_files
from mkdocs.structure.files import InclusionLevel

PACKAGE = "fedjax_nav"
ROOT = Path(__file__).resolve().parent.parent

nav = mkdocs_gen_files.Nav()
modules: list[tuple[str, str, str]] = []  # (dotted name, page under reference/, purpose)


def purpose(path: Path, longest: int = 260) -> str:
    """The first sentence of the module's docstring ('-' without one), on one line (a full stop inside
    'e.g.', 'et al.', 'Fig.', a file name or a number does not end it); a sentence longer than `longest`
    characters up to its first ': ' or '; ', where it names what the module is for."""
    doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
    para = " ".join(doc.strip().split("\n\n", 1)[0].split())
    m = re.match(r"(.*?(?<!e\.g)(?<!i\.e)(?<!et al)(?<!Fig)(?<!Eq)(?<!vs)\.)(?=\s|$)", para)
    text = m.group(1) if m else para
    if len(text) > longest:
        head = re.split(r"[:;] ", text, maxsplit=1)[0]
        text = head if len(head) >= 20 else text
    return text.rstrip(":;, ").replace("|", "\\|") or "-"


for path in sorted((ROOT / PACKAGE).rglob("*.py")):
    module = path.relative_to(ROOT).with_suffix("")
    parts = module.parts
    if "__pycache__" in parts:
        continue
    # only real packages: every folder on the way holds an __init__.py
    if not all((ROOT.joinpath(*parts[:i]) / "__init__.py").is_file() for i in range(1, len(parts))):
        continue
    if parts[-1] == "__init__":
        parts = parts[:-1]
        doc = Path(*parts, "index.md")
    elif parts[-1] == "__main__":
        continue
    else:
        doc = Path(*parts).with_suffix(".md")
    if any(p.startswith("_") for p in parts):
        continue
    if len(parts) > 1:  # the package's own page heads the section (below)
        nav[parts[1:]] = doc.as_posix()
    modules.append((".".join(parts), doc.as_posix(), purpose(path)))
    with mkdocs_gen_files.open(Path("reference", doc), "w") as fd:
        fd.write(f"# `{'.'.join(parts)}`\n\n::: {'.'.join(parts)}\n")
    mkdocs_gen_files.set_edit_path(Path("reference", doc), path.relative_to(ROOT))

with mkdocs_gen_files.open("reference/index.md", "w") as fd:
    fd.write("# API reference\n\n")
    fd.write("Every public module of `fedjax_nav` and what it is for (the first sentence of its docstring); ")
    fd.write("each page holds the module's classes, functions and fields, generated from the docstrings. ")
    fd.write("How the modules depend on each other: [Architecture](../architecture.md).\n\n")
    fd.write("| module | what it is for |\n|---|---|\n")
    fd.writelines(f"| [`{name}`]({page}) | {text} |\n" for name, page, text in modules)
mkdocs_gen_files.set_edit_path("reference/index.md", Path(__file__).relative_to(ROOT))

SUMMARY = "reference/SUMMARY.md"
with mkdocs_gen_files.open(SUMMARY, "w") as fd:
    fd.write("* [Overview](index.md)\n")
    fd.write(f"* [{PACKAGE}]({PACKAGE}/index.md)\n")
    fd.writelines(nav.build_literate_nav())
# literate-nav still reads an excluded file; mkdocs builds no page from it
mkdocs_gen_files.FilesEditor.current().files.get_file_from_path(SUMMARY).inclusion = InclusionLevel.EXCLUDED
