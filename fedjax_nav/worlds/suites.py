"""Room keys, the named held-out test suites, and procedural rooms as world files.

The disjointness rule (docs/generator.md): a room seed is an integer in [0, 2**32); seeds
>= TEST_SEED_BASE = 2**31 belong to the held-out suites, and training draws its rooms with
`train_room_key(i)`, which maps any counter into [0, 2**31).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from fedjax_nav.worlds.procedural import generate_batch, jitted_generator
from fedjax_nav.worlds.rooms import (
    BASE_FAMILIES,
    DENSE_FAMILIES,
    FAMILIES,
    INDOOR_FAMILIES,
    RoomSpec,
    make_spec,
    parse_overrides,
)
from fedjax_nav.worlds.world import World, WorldError, from_dict, map_spec, wall_segments

ROOM_ROOT = 0x5EED  # root of every room key
TEST_SEED_BASE = 2**31  # room seeds >= this are reserved for the held-out test suites
SUITE_STRIDE = 2**20  # each test suite owns a block of this many seeds


def room_key(seed) -> jax.Array:
    """The key of room seed `seed` (an integer in [0, 2**32), may be traced)."""
    return jax.random.fold_in(jax.random.key(ROOM_ROOT), jnp.asarray(seed, jnp.uint32))


def train_room_key(index) -> jax.Array:
    """A training room's key: any counter `index` (may be traced, e.g. episode * robots + robot)
    is mapped into the training half [0, 2**31) of the room seeds, disjoint from every suite."""
    return room_key(jnp.asarray(index, jnp.uint32) & jnp.uint32(TEST_SEED_BASE - 1))


def is_test_seed(seed) -> bool | np.ndarray:
    """Whether a room seed is reserved for the held-out test suites (seed >= 2**31)."""
    s = np.asarray(seed, np.int64)
    out = (s >= TEST_SEED_BASE) & (s < 2**32)
    return bool(out) if out.ndim == 0 else out


@dataclasses.dataclass(frozen=True)
class Suite:
    """A named held-out set: `rooms` rooms of `family` (default spec plus `overrides`), room
    seeds TEST_SEED_BASE + index * SUITE_STRIDE + 0 .. rooms-1."""

    family: str
    rooms: int
    index: int
    overrides: tuple = ()

    def spec(self) -> RoomSpec:
        return make_spec(self.family, **dict(self.overrides))

    def seeds(self) -> np.ndarray:
        return (TEST_SEED_BASE + self.index * SUITE_STRIDE + np.arange(self.rooms)).astype(np.uint32)


SUITES: dict[str, Suite] = {f"{fam}-50": Suite(fam, 50, i) for i, fam in enumerate(BASE_FAMILIES)}
# The generalisation test suites (docs/generalization.md): 50 rooms per family with 4 goals each,
# and the small probe of periodic evaluation during training (4 rooms per family, 2 goals).
# Each suite owns its own block of test seeds, so the probe never sees a test room.
SUITES.update(
    {f"{fam}-50x4": Suite(fam, 50, 4 + i, (("goals_min", 4), ("goals_max", 4))) for i, fam in enumerate(BASE_FAMILIES)}
)
SUITES.update(
    {f"{fam}-probe": Suite(fam, 4, 8 + i, (("goals_min", 2), ("goals_max", 2))) for i, fam in enumerate(BASE_FAMILIES)}
)
# The same three suites for each dense family, in blocks 12 and up (the base families' blocks, and
# so their rooms, are those they always had).
_D = len(DENSE_FAMILIES)
SUITES.update({f"{fam}-50": Suite(fam, 50, 12 + i) for i, fam in enumerate(DENSE_FAMILIES)})
SUITES.update(
    {
        f"{fam}-50x4": Suite(fam, 50, 12 + _D + i, (("goals_min", 4), ("goals_max", 4)))
        for i, fam in enumerate(DENSE_FAMILIES)
    }
)
SUITES.update(
    {
        f"{fam}-probe": Suite(fam, 4, 12 + 2 * _D + i, (("goals_min", 2), ("goals_max", 2)))
        for i, fam in enumerate(DENSE_FAMILIES)
    }
)
# The same three suites for each indoor family (office, corridors), in blocks 24 and up, after the
# dense families' (whose blocks and rooms stay those they had).
_I, _B = len(INDOOR_FAMILIES), 12 + 3 * _D
SUITES.update({f"{fam}-50": Suite(fam, 50, _B + i) for i, fam in enumerate(INDOOR_FAMILIES)})
SUITES.update(
    {
        f"{fam}-50x4": Suite(fam, 50, _B + _I + i, (("goals_min", 4), ("goals_max", 4)))
        for i, fam in enumerate(INDOOR_FAMILIES)
    }
)
SUITES.update(
    {
        f"{fam}-probe": Suite(fam, 4, _B + 2 * _I + i, (("goals_min", 2), ("goals_max", 2)))
        for i, fam in enumerate(INDOOR_FAMILIES)
    }
)
# Named groups of suites (one family each): `suite_rooms` accepts a suite or a group name.
SUITE_GROUPS: dict[str, tuple[str, ...]] = {
    "heldout": tuple(f"{fam}-50x4" for fam in BASE_FAMILIES),
    "families-50": tuple(f"{fam}-50" for fam in BASE_FAMILIES),
    "probe": tuple(f"{fam}-probe" for fam in BASE_FAMILIES),
    "dense-heldout": tuple(f"{fam}-50x4" for fam in DENSE_FAMILIES),
    "dense-50": tuple(f"{fam}-50" for fam in DENSE_FAMILIES),
    "dense-probe": tuple(f"{fam}-probe" for fam in DENSE_FAMILIES),
    "indoor-heldout": tuple(f"{fam}-50x4" for fam in INDOOR_FAMILIES),
    "indoor-50": tuple(f"{fam}-50" for fam in INDOOR_FAMILIES),
    "indoor-probe": tuple(f"{fam}-probe" for fam in INDOOR_FAMILIES),
}


def _suite_def(name: str) -> Suite:
    if name not in SUITES:
        raise WorldError(f"no test suite '{name}' (suites: {', '.join(SUITES)})")
    return SUITES[name]


def suite_seeds(name: str) -> np.ndarray:
    """The room seeds of a held-out suite (all `is_test_seed`)."""
    return _suite_def(name).seeds()


def suite_names(name: str) -> tuple[str, ...]:
    """The suites of a suite or group name (WorldError naming both lists for an unknown one)."""
    if name in SUITE_GROUPS:
        return SUITE_GROUPS[name]
    if name in SUITES:
        return (name,)
    raise WorldError(f"no test suite '{name}' (suites: {', '.join(SUITES)}; groups: {', '.join(SUITE_GROUPS)})")


def common_shape(specs, shapes=()) -> tuple[int, int, int, int]:
    """The (segments, circles, starts, goals) rows that fit every room of `specs` and every
    extra (segments, circles, starts, goals) in `shapes` (e.g. fixed worlds')."""
    from fedjax_nav.worlds.shapes import padded_shape

    return tuple(int(max(x)) for x in zip(*[padded_shape(s) for s in specs], *shapes))


def padded_spec(spec: RoomSpec, shape) -> RoomSpec:
    """`spec` padded to the rows `shape` (segments, circles, starts, goals)."""
    import dataclasses as _dc

    m, c, s, g = shape
    return _dc.replace(spec, max_segments=m, max_circles=c, max_starts=s, max_goals=g)


def suite_rooms(name: str) -> tuple[World, np.ndarray, np.ndarray]:
    """The rooms of a suite or group as one stacked World [rooms, ...] (padded to one shape),
    with each room's family (str[rooms]) and room seed (u32[rooms]), in the groups' order."""
    defs = [_suite_def(n) for n in suite_names(name)]
    shape = common_shape([d.spec() for d in defs])
    parts = [generate_batch(jax.vmap(room_key)(jnp.asarray(d.seeds())), padded_spec(d.spec(), shape)) for d in defs]
    world = jax.tree.map(lambda *x: jnp.concatenate(x), *parts)
    fams = np.concatenate([np.full(d.rooms, d.family) for d in defs])
    return world, fams, np.concatenate([d.seeds() for d in defs])


def suite(name: str) -> tuple[World, RoomSpec]:
    """The rooms of a held-out suite as a stacked World [rooms, ...], and their spec."""
    s = _suite_def(name)
    spec = s.spec()
    keys = jax.vmap(room_key)(jnp.asarray(s.seeds()))
    return generate_batch(keys, spec), spec


# ----------------------------------------------------------------------------- files


def _num(x) -> float:
    """The shortest decimal that reads back to the same float32."""
    return float(str(np.float32(x)))


def to_spec_dict(world: World, name: str | None = None, description: str | None = None) -> dict:
    """A world-file mapping (size, segments, circles, starts, goals) of one World: the outer walls
    (rows 0-3 when they match the size) and the padding rows are dropped, since `load` rebuilds
    the walls from the size. Box edges are written as segments. Floats are written as the
    shortest decimals that read back to the same float32, so `load` gives the same arrays."""
    if np.ndim(world.size) != 1:
        raise WorldError("to_spec_dict: one world at a time (this World has a leading playground axis)")
    size = np.asarray(world.size, np.float32)
    segs = np.asarray(world.segments, np.float32).reshape(-1, 4)
    if len(segs) >= 4 and np.array_equal(segs[:4], wall_segments(size).astype(np.float32)):
        segs = segs[4:]
    segs = segs[np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]) > 0]
    circles = np.asarray(world.circles, np.float32).reshape(-1, 3)
    circles = circles[circles[:, 2] > 0]
    out: dict[str, Any] = {}
    if name is not None:
        out["name"] = name
    if description is not None:
        out["description"] = description

    def rows(a):
        return [[_num(v) for v in r] for r in a]

    out.update(
        size=[_num(v) for v in size],
        segments=rows(segs),
        circles=rows(circles),
        starts=rows(np.asarray(world.starts, np.float32)[: int(world.num_starts)]),
        goals=rows(np.asarray(world.goals, np.float32)[: int(world.num_goals)]),
    )
    return out


def save_world(world: World, path: str | Path, name: str | None = None, description: str | None = None) -> Path:
    """Write one World as a world file (YAML for .yaml/.yml, JSON otherwise) that
    `worlds.load(path)` reads back to the same obstacles, starts and goals; returns the path.
    The mapping is validated with `worlds.from_dict` before it is written."""
    path = Path(path)
    spec = to_spec_dict(world, name=name if name is not None else path.stem, description=description)
    return write_spec(spec, path)


def write_spec(spec: dict, path: str | Path) -> Path:
    """Write a world file's mapping (YAML for .yaml/.yml, JSON otherwise, one row a line), after
    `worlds.from_dict` has validated it; returns the path."""
    path = Path(path)
    from_dict(spec, str(path))  # the file must load
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() in (".yaml", ".yml"):
        import yaml

        text = yaml.safe_dump(spec, sort_keys=False, default_flow_style=None, width=120)
    else:
        text = (
            "{\n"
            + ",\n".join(
                f"  {json.dumps(k)}: "
                + (
                    json.dumps(v)
                    if not (isinstance(v, list) and v and isinstance(v[0], list))
                    else "[\n    " + ",\n    ".join(json.dumps(r) for r in v) + "\n  ]"
                )
                for k, v in spec.items()
            )
            + "\n}\n"
        )
    path.write_text(text)
    return path


def _check_seed(seed) -> int:
    try:
        s = int(str(seed).strip()) if not isinstance(seed, (int, np.integer)) else int(seed)
    except ValueError:
        raise WorldError(f"--seed {seed!r}: must be an integer in [0, {2**32 - 1}]") from None
    if not 0 <= s < 2**32:
        raise WorldError(f"--seed {seed!r}: must be an integer in [0, {2**32 - 1}]")
    return s


def generate_to_file(family: str, seed: int, out: str | Path, **overrides) -> Path:
    """Draw the room of `family` and room seed `seed` (`room_key(seed)`; spec: the defaults plus
    `overrides`) and write it to `out` (JSON, or YAML for .yaml/.yml). Raises WorldError for a bad
    family, field, value or seed."""
    spec = make_spec(family, **overrides)
    seed = _check_seed(seed)
    world = jitted_generator(spec)(room_key(seed))
    changed = ", ".join(f"{k}={v}" for k, v in overrides.items())
    desc = f"procedural room: family={family}, seed={seed}" + (f", {changed}" if changed else "")
    if is_test_seed(seed):
        desc += " (a held-out test seed)"
    return save_world(world, out, description=desc)


# ----------------------------------------------------------------------------- command line


def import_map(map_yaml: str | Path, out: str | Path, **draw) -> Path:
    """Write the world of a ROS map_server map (`worlds.map_spec`; `draw`: starts, goals, seed,
    cell) to the world file `out` (JSON, or YAML for .yaml/.yml); returns the path."""
    return write_spec(map_spec(map_yaml, **draw), out)


def _import_cli(args: argparse.Namespace) -> Path:
    seed = None if args.seed is None else _check_seed(args.seed)
    return import_map(args.map, args.out, starts=args.starts, goals=args.goals, seed=seed, cell=args.cell)


def run_cli(args: argparse.Namespace) -> int:
    """Run ``worlds generate`` or ``worlds import``: 0 on success; 2 with one line on stderr for a
    bad input."""
    try:
        command = getattr(args, "worlds_command", "generate")
        if command not in ("generate", "import"):
            raise WorldError(f"unknown worlds command {command!r} (commands: generate, import)")
        if command == "import":
            return _report(_import_cli(args))
        if args.family not in FAMILIES:
            raise WorldError(f"--family {args.family!r}: not a family (families: {', '.join(FAMILIES)})")
        overrides = parse_overrides(args.set or [])
        path = generate_to_file(args.family, args.seed, args.out, **overrides)
    except WorldError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return _report(path)


def _report(path: Path) -> int:
    """Say what was written: the world's size and rows of each kind."""
    import yaml

    w = yaml.safe_load(path.read_text())  # JSON is YAML too; the file was just written by us
    rows = ", ".join(f"{len(w[k])} {k}" for k in ("boxes", "segments", "circles", "starts", "goals") if k in w)
    print(f"wrote {path}: {w['size'][0]:.2f} x {w['size'][1]:.2f} m, {rows}")
    return 0
