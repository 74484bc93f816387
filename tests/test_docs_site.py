"""The documentation site as built (mkdocs.yml, docs/gen_ref_pages.py): every API reference page
is reachable from the navigation, the literate-nav file is not a page of its own, and fields
documented by a comment on their line (flax.struct dataclasses) are listed with that comment.

Needs the `docs` extra (CI installs it); skipped without mkdocs. One build, about 5 s.
"""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings_handlers.python")
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "DISABLE_MKDOCS_2_WARNING": "true"}
    r = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    return out


def test_every_reference_page_is_in_the_navigation(site):
    pages = {p.parent.relative_to(site).as_posix() + "/" for p in (site / "reference").rglob("index.html")}
    nav = set(re.findall(r'href="(reference/[^"#]*)"', (site / "index.html").read_text()))
    assert "reference/fedjax_nav/" in pages and "reference/fedjax_nav/env/nav/" in pages
    assert pages - nav == set(), "reference pages reachable only by search"


def test_the_nav_file_is_not_a_page(site):
    assert not (site / "reference" / "SUMMARY").exists()


def test_dataclass_fields_are_listed_with_their_comments(site):
    # EnvParams is documented where it is defined (env/params.py); env.nav re-exports it
    html = (site / "reference" / "fedjax_nav" / "env" / "params" / "index.html").read_text()
    for field in ("world", "v_max", "goal_radius", "lidar_offset"):
        assert f'id="fedjax_nav.env.params.EnvParams.{field}"' in html, field
    v_max = html[html.index('id="fedjax_nav.env.params.EnvParams.v_max"') :]
    v_max = re.sub(r"<[^>]+>", " ", v_max[: v_max.index('id="fedjax_nav.env.params.EnvParams.omega_max"')])
    assert "m/s" in v_max  # the field's comment (`v_max: ... # m/s`) is its description


def test_the_reference_overview_lists_every_module_with_its_docstrings_first_sentence(site):
    """reference/index.md (docs/gen_ref_pages.py) heads the API reference: a row per module page,
    its purpose read from the module's docstring, so that a changed docstring changes the row."""
    html = (site / "reference" / "index.html").read_text()
    text = re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", html))
    pages = {p.parent.relative_to(site / "reference").as_posix() for p in (site / "reference").rglob("index.html")}
    linked = set(re.findall(r'href="(fedjax_nav(?:/[^"#]*)?)/"', html))
    assert linked == pages - {"."}, "every module page is a row of the overview"
    # the first sentence, not the first line: this one wraps in the source
    assert "The navigation task for one robot: pure reset / step over flax.struct state and params." in text
    assert "PPO (Schulman et al. 2017) for one agent as pure functions" in text  # 'et al.' ends no sentence
    nav = (site / "index.html").read_text()
    assert 'href="reference/"' in nav  # the overview is the section's own page
