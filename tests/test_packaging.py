"""The package as declared and as a user meets it first: `fedjax-nav --version`, the dependency
ranges of pyproject.toml (every one bounded above, the tested versions inside), the message of
`export --format onnx` without onnx (it names an extra that exists), and the learning curves of
a run too short to draw a line.
"""

import re
import sys
from importlib import metadata
from pathlib import Path

import pandas as pd
import pytest
from packaging.requirements import Requirement

import fedjax_nav
from fedjax_nav import cli
from fedjax_nav.analysis import plots

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def pyproject():
    tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
    return tomllib.loads((ROOT / "pyproject.toml").read_text())


def requirements(pyproject) -> dict[str, list[Requirement]]:
    """Every declared requirement: "" for the runtime ones, else the extra's name."""
    groups = {"": pyproject["project"]["dependencies"], **pyproject["project"]["optional-dependencies"]}
    return {name: [Requirement(r) for r in reqs] for name, reqs in groups.items()}


def test_every_preset_in_the_checkout_is_shipped_in_the_package(pyproject):
    # a sweep's `base: ../learners/ppo.yaml` from a wheel that lacked learners/ failed; read the
    # globs as setuptools does (relative to the package's folder)
    shipped = {
        p
        for pattern in pyproject["tool"]["setuptools"]["package-data"]["fedjax_nav.configs"]
        for p in (ROOT / "fedjax_nav" / "configs").glob(pattern)
    }
    presets = set((ROOT / "fedjax_nav" / "configs").rglob("*.yaml"))
    assert presets and presets <= shipped, sorted(str(p) for p in presets - shipped)


def test_version_prints_the_package_version(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out == f"fedjax-nav {fedjax_nav.__version__}\n"
    assert re.fullmatch(r"\d+\.\d+\.\d+", fedjax_nav.__version__)
    assert fedjax_nav.__version__ == metadata.version("fedjax_nav")  # the installed metadata agrees


def test_the_version_is_written_once(pyproject):
    assert "version" not in pyproject["project"] and "version" in pyproject["project"]["dynamic"]
    assert pyproject["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "fedjax_nav.__version__"}


def test_every_dependency_has_an_upper_bound(pyproject):
    unbounded = [
        f"{extra or 'runtime'}: {r}"
        for extra, reqs in requirements(pyproject).items()
        for r in reqs
        if not any(s.operator in ("<", "<=", "==", "~=") for s in r.specifier)
    ]
    assert not unbounded, unbounded


def test_the_installed_versions_are_inside_the_declared_ranges(pyproject):
    outside = []
    for extra, reqs in requirements(pyproject).items():
        for r in reqs:
            try:
                v = metadata.version(r.name)
            except metadata.PackageNotFoundError:  # an extra not installed here (e.g. bench's jaxmarl)
                assert extra, f"runtime dependency {r.name} is not installed"
                continue
            if not r.specifier.contains(v, prereleases=True):
                outside.append(f"{r} (installed {v})")
    assert not outside, outside


def test_export_onnx_without_onnx_names_the_extra_to_install(tmp_path, monkeypatch, capsys, pyproject):
    monkeypatch.setitem(sys.modules, "onnx", None)  # `import onnx` now raises ImportError
    rc = cli.main(["export", str(tmp_path / "run"), "--format", "onnx", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1
    assert 'pip install "fedjax_nav[onnx]"' in err
    extra = re.search(r"fedjax_nav\[(\w+)\]", err).group(1)
    assert "onnx" in [r.name for r in requirements(pyproject)[extra]]  # the extra named exists and brings onnx
    assert not (tmp_path / "out").exists()


def test_the_onnx_extra_brings_a_runtime_for_what_it_exports(pyproject):
    """`pip install "fedjax_nav[onnx]"` (and its earlier name `export`) can run an exported policy,
    not only write it: onnx and onnxruntime, with the bounds the dev extra tests."""
    reqs = requirements(pyproject)
    dev = {r.name: r.specifier for r in reqs["dev"]}
    for extra in ("onnx", "export"):
        got = {r.name: r.specifier for r in reqs[extra]}
        assert got == {name: dev[name] for name in ("onnx", "onnxruntime")}, extra


def test_the_changelog_has_an_unreleased_section_and_the_version(pyproject):
    text = (ROOT / "CHANGELOG.md").read_text()
    assert "keepachangelog.com" in text and "## [Unreleased]" in text
    assert f"## [{fedjax_nav.__version__}]" in text  # the version the package says it is


def _metrics(episodes: int, seeds: int = 2, robots: int = 3) -> pd.DataFrame:
    rows = [
        {"seed": s, "episode": e, "robot": r, "reached_goal": (s + r + e) % 2 == 0, "reward": 0.1 * (s + r)}
        for s in range(seeds)
        for e in range(episodes)
        for r in range(robots)
    ]
    return pd.DataFrame(rows, columns=["seed", "episode", "robot", "reached_goal", "reward"])


@pytest.fixture
def drawn(monkeypatch):
    """learning_curves' figures, kept instead of saved."""
    figures = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path: figures.append(fig) or Path(path))
    return figures


def test_a_one_episode_run_draws_its_points(drawn, tmp_path):
    plots.learning_curves(_metrics(episodes=1), tmp_path / "curves.png")
    (fig,) = drawn
    for ax in fig.axes:
        points = [
            line for line in ax.lines if len(line.get_xdata()) == 1 and line.get_marker() not in (None, "None", "")
        ]
        assert points, f"{ax.get_ylabel()}: one episode drawn as a line of one point (invisible)"
        assert list(points[0].get_xdata()) == [1]  # episodes are numbered from 1


def test_a_run_with_no_episode_says_why_its_axes_are_empty(drawn, tmp_path):
    plots.learning_curves(_metrics(episodes=0), tmp_path / "curves.png")
    (fig,) = drawn
    for ax in fig.axes:
        assert not ax.lines and any("nothing to draw" in t.get_text() for t in ax.texts)
