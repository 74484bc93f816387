"""The package as a researcher installs it: a wheel built from the repository, installed into a
fresh virtual environment outside the repository, used from an empty directory: `configs`,
`train` (tiny), `reproduce --scale ci --only tau` and `evaluate` find everything they need in
the installed package, never in the checkout.

The wheel is built the way pip builds any sdist (an isolated build environment with the
pyproject's setuptools); the fresh venv gets the wheel itself without dependencies, and the
dependencies (jax, flax, ...) come from the test's own environment through a path entry, so no
second copy of jax is installed. Only directory entries are added (not the test venv's .pth files), so the
checkout's editable install cannot leak in: the test checks where `fedjax_nav` is imported from.
"""

import os
import subprocess
import sys
import sysconfig
import venv
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TINY = [
    "--set",
    "env.episode_length=16",
    "--set",
    "run.episodes=2",
    "--set",
    "run.chunk_episodes=1",
    "--set",
    "offpolicy.batch_size=8",
    "--set",
    "offpolicy.hidden=16",
    "--set",
    "offpolicy.buffer_size=64",
    "--set",
    "fed.period=1",
    "--set",
    "run.checkpoint_every=0",
    "--set",  # a shipped room still (found in the installed package), the smallest: compiles fastest
    "env.worlds=[train-0,train-0,train-0,train-0,train-0]",
]


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    base = tmp_path_factory.mktemp("wheel")
    dist = base / "dist"
    r = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(dist), str(ROOT)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    (wheel,) = dist.glob("fedjax_nav-*.whl")
    env_dir = base / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    py = env_dir / "bin" / "python"
    site = Path(
        subprocess.run(
            [str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    )
    # the wheel, unpacked as pip would (no pip in the fresh venv; the test env's pip targets it)
    r = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(site), str(wheel)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    deps = sysconfig.get_paths()["purelib"]  # jax, flax, ... of the test environment
    (site / "zz_test_deps.pth").write_text(deps + "\n")
    bin_dir = env_dir / "bin"
    (bin_dir / "fedjax-nav").write_text(f"#!{py}\nimport sys\nfrom fedjax_nav.cli import main\nsys.exit(main())\n")
    (bin_dir / "fedjax-nav").chmod(0o755)
    work = base / "empty"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env.update(PATH=f"{bin_dir}{os.pathsep}{env.get('PATH', '')}", JAX_PLATFORMS="cpu", MPLBACKEND="Agg")
    return {"py": py, "bin": bin_dir, "work": work, "env": env, "site": site}


def run(installed, *args, timeout=900):
    return subprocess.run(
        [str(installed["bin"] / "fedjax-nav"), *map(str, args)],
        cwd=installed["work"],
        env=installed["env"],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_the_installed_package_is_the_wheel_not_the_checkout(installed):
    r = subprocess.run(
        [
            str(installed["py"]),
            "-c",
            "import fedjax_nav, fedjax_nav.configs as c; print(fedjax_nav.__file__); print(c.CONFIG_DIR)",
        ],
        cwd=installed["work"],
        env=installed["env"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    for line in r.stdout.split():
        assert str(installed["site"]) in line and str(ROOT) not in line


def test_the_wheel_ships_the_type_marker(installed):
    """PEP 561: without `py.typed` in the installed package, mypy reads every fedjax_nav name as Any."""
    assert (installed["site"] / "fedjax_nav" / "py.typed").is_file()


def test_configs_train_reproduce_and_evaluate_from_an_empty_directory(installed):
    r = run(installed, "configs")
    assert r.returncode == 0 and "thesis/flddpg" in r.stdout and "tau" in r.stdout, r.stderr[-2000:]
    assert "learners/ppo" in r.stdout  # the learners' presets, which 20 sweeps take as their base
    r = run(installed, "train", "--config", "thesis/flddpg", "--out", "run", "--quiet", *TINY)
    assert r.returncode == 0, r.stderr[-3000:]
    assert (installed["work"] / "run" / "params.npz").exists()
    r = run(installed, "evaluate", "run", "--attempts", "1", "--max-steps", "32")
    assert r.returncode == 0, r.stderr[-3000:]
    assert (installed["work"] / "run" / "eval" / "eval" / "eval.json").exists()
    r = run(installed, "reproduce", "--scale", "ci", "--only", "tau", "--out", "rep", "--quiet", "--devices", "1")
    assert r.returncode == 0, r.stderr[-3000:]
    assert (installed["work"] / "rep" / "report.md").exists()
