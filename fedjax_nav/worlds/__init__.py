"""Playgrounds as data: the `World` pytree and loading world files (`world`), the procedural rooms
(`rooms`, `procedural`, the families' modules), held-out suites and saved rooms (`suites`).

A world file (JSON or YAML, docs/worlds.md) has `size`, optional `boxes`, `segments`, `circles`,
and at least one of `starts` and `goals`; `load(name_or_path)` reads a shipped name or a file,
also a ROS map_server map's YAML (`rosmap`, `grid`: its occupied cells become boxes).
This module only re-exports: the package's own modules import from the module that defines a name.
"""

# Procedural rooms (docs/generator.md): specs in `rooms`, the JAX generator in `procedural`,
# keys, held-out suites and world files in `suites`.
from fedjax_nav.worlds.procedural import generate, generate_batch, generate_with_info  # noqa: E402, F401
from fedjax_nav.worlds.rooms import (  # noqa: E402, F401
    FAMILIES,
    RoomSpec,
    check_spec,
    make_spec,
)
from fedjax_nav.worlds.shapes import padded_shape  # noqa: E402, F401
from fedjax_nav.worlds.suites import (  # noqa: E402, F401
    SUITES,
    is_test_seed,
    room_key,
    save_world,
    suite,
    suite_rooms,
    suite_seeds,
    train_room_key,
)
from fedjax_nav.worlds.world import (  # noqa: F401
    CLEARANCE,
    MAX_COORD,
    MAX_FILE_BYTES,
    MAX_NODES,
    MAX_PRIMITIVES,
    PAPER_TRAIN,
    SHIPPED,
    THESIS_TRAIN,
    World,
    WorldError,
    box_segments,
    from_dict,
    load,
    load_many,
    load_with_meta,
    map_spec,
    pad,
    point_segment_distance_np,
    resolve,
    stack,
    wall_segments,
)
