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
"""

from __future__ import annotations

from pathlib import Path

import mkdocs_gen_files
from mkdocs.structure.files import InclusionLevel

PACKAGE = "fedjax_nav"
ROOT = Path(__file__).resolve().parent.parent

nav = mkdocs_gen_files.Nav()

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
    with mkdocs_gen_files.open(Path("reference", doc), "w") as fd:
        fd.write(f"# `{'.'.join(parts)}`\n\n::: {'.'.join(parts)}\n")
    mkdocs_gen_files.set_edit_path(Path("reference", doc), path.relative_to(ROOT))

SUMMARY = "reference/SUMMARY.md"
with mkdocs_gen_files.open(SUMMARY, "w") as fd:
    fd.write(f"* [{PACKAGE}]({PACKAGE}/index.md)\n")
    fd.writelines(nav.build_literate_nav())
# literate-nav still reads an excluded file; mkdocs builds no page from it
mkdocs_gen_files.FilesEditor.current().files.get_file_from_path(SUMMARY).inclusion = InclusionLevel.EXCLUDED
