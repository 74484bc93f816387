"""Rendering of worlds and random trajectories, and the `fedjax-nav render` command."""

from __future__ import annotations

import numpy as np
import pytest

from fedjax_nav import cli, worlds
from fedjax_nav.env import render

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
STEPS = 20  # one compiled rollout (all shipped worlds share the padded shapes) serves every test


def _is_png(path) -> bool:
    return path.is_file() and path.stat().st_size > 1000 and path.read_bytes()[:8] == PNG_MAGIC


def test_every_shipped_world_renders(tmp_path):
    paths = render.render_worlds(None, out_dir=tmp_path, steps=STEPS, seed=0)
    names = [p.stem for p in paths]
    assert names == [*worlds.SHIPPED, "overview"]
    for p in paths:
        assert _is_png(p), p


def test_random_rollout_shapes_and_episodes():
    world = worlds.load("train-0")
    poses, terminated = render.random_rollout(world, STEPS, seed=1)
    assert poses.shape == (STEPS, 3) and terminated.shape == (STEPS,)
    assert terminated.dtype == bool and np.all(np.isfinite(poses))
    # The robot moves at most v_max * dt = 2.5 cm per step from start 0.
    start = np.asarray(world.starts[0, :2])
    assert np.linalg.norm(poses[0, :2] - start) <= 0.025 + 1e-6
    paths, outcomes = render.split_episodes(world, poses, terminated)
    assert sum(len(p) - 1 for p in paths) == STEPS
    assert all(np.allclose(p[0], start) for p in paths)
    assert outcomes.count(None) <= 1


def test_split_episodes_outcomes():
    world = worlds.load("train-0")  # start 0 (2, 2.15), goal 0 (-2, -1.85)
    poses = np.array([[1.9, 2.15, 0], [-2.0, -1.8, 0], [1.9, 2.0, 0], [2.9, 2.9, 0], [1.8, 2.1, 0]])
    term = np.array([False, True, False, True, False])
    paths, outcomes = render.split_episodes(world, poses, term)
    assert outcomes == ["success", "collision", None]
    assert [len(p) for p in paths] == [3, 3, 2]


def test_draw_bare_world_and_trajectories(tmp_path):
    from matplotlib.figure import Figure

    fig = Figure()
    ax = fig.add_subplot()
    world = worlds.stack([worlds.load("train-1"), worlds.load("eval")])  # padded rows
    one = worlds.World(
        *[
            leaf[0]
            for leaf in (
                world.segments,
                world.circles,
                world.starts,
                world.num_starts,
                world.goals,
                world.num_goals,
                world.size,
            )
        ]
    )
    render.draw_world(ax, one, title="train-1 padded")
    assert len(ax.patches) >= 3  # the three boxes were found as closed quads
    xy = np.cumsum(np.full((2, 10, 2), 0.1), axis=1)
    render.draw_trajectories(ax, xy, mask=np.ones((2, 10), bool), colors=["k", "m"], outcomes=["success", "collision"])
    out = tmp_path / "bare.png"
    fig.savefig(out, dpi=50)
    assert _is_png(out)
    with pytest.raises(ValueError):
        render.draw_world(ax, world)  # a stacked World is not one world


def test_cli_render(tmp_path, capsys):
    out = tmp_path / "out"
    assert cli.main(["render", "train-0", "--out", str(out), "--steps", str(STEPS)]) == 0
    assert _is_png(out / "train-0.png")
    assert str(out / "train-0.png") in capsys.readouterr().out


def test_cli_render_bad_world(tmp_path, capsys):
    assert cli.main(["render", "no-such-world.json", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: no-such-world.json: no such world file")
    assert not list(tmp_path.iterdir())  # nothing written


def test_a_panel_of_any_room_shape_reads_at_a_glance():
    """A 5 x 16.6 m map was once drawn 98 x 563 px: each panel's shorter side is now >= 2.6 in,
    its longer side <= 11 in, at the room's own aspect."""
    for size in [(5.0, 16.6), (16.6, 5.0), (4.0, 4.0), (40.0, 2.0), (0.5, 30.0)]:
        w, h = render.panel_inches(size)
        assert min(w, h) >= 2.6 - 1e-9 or max(w, h) == pytest.approx(11.0)
        assert max(w, h) <= 11.0 + 1e-9
        assert w / h == pytest.approx(size[0] / size[1])
    assert render.panel_inches((5.0, 16.6))[0] >= 2.6


def test_a_tall_world_is_drawn_wide_enough(tmp_path):
    import json

    from matplotlib.image import imread

    tall = {
        "name": "tall",
        "size": [5.0, 16.6],
        "boxes": [[0.0, 2.0, 2.0, 0.3, 0.0]],
        "starts": [[0.0, -7.0, 1.57]],
        "goals": [[0.0, 7.0]],
    }
    (tmp_path / "tall.json").write_text(json.dumps(tall))
    png = render.render_worlds([str(tmp_path / "tall.json")], out_dir=tmp_path / "out", steps=0)[0]
    h, w = imread(png).shape[:2]
    assert w >= 250 and h / w < 16.6 / 5.0 + 0.5, (w, h)
