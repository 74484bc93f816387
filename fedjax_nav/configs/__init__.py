"""The shipped configs, as package data: presets (`thesis/<method>`, `paper/flddpg`) and the
experiment (sweep) files of thesis chapter 4 (`sweeps/<name>`).

Every command that takes a config or sweep file also takes a shipped name, so the package works
from any directory after `pip install`:

    resolve("thesis/flddpg")             -> .../fedjax_nav/configs/thesis/flddpg.yaml
    resolve("tau", kind="sweep")         -> .../fedjax_nav/configs/sweeps/tau.yaml
    resolve("my/own.yaml")               -> my/own.yaml (an existing path wins)
"""

from __future__ import annotations

from pathlib import Path

CONFIG_DIR = Path(__file__).resolve().parent
SWEEP_DIR = CONFIG_DIR / "sweeps"
KINDS = {"config": CONFIG_DIR, "sweep": SWEEP_DIR}


def names(kind: str = "config") -> list[str]:
    """Shipped names of one kind: "config" (presets) or "sweep" (experiment files)."""
    root = KINDS[kind]
    files = sorted(root.rglob("*.yaml"))
    if kind == "config":
        files = [f for f in files if SWEEP_DIR not in f.parents]
    return [f.relative_to(root).with_suffix("").as_posix() for f in files]


def resolve(name_or_path: str | Path, kind: str = "config") -> Path:
    """An existing path as it is; otherwise a shipped name of `kind` (with or without .yaml).
    Unknown names come back unchanged, so that the caller's "no such file" names what was asked."""
    p = Path(name_or_path)
    if p.exists():
        return p
    stem = p.as_posix().removesuffix(".yaml")
    for root in (KINDS[kind], CONFIG_DIR):
        cand = root / f"{stem}.yaml"
        if cand.is_file():
            return cand
    return p
