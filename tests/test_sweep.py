"""Sweeps: the files of configs/sweeps/, grouping by static structure, one compilation per group,
each grid point equal to the same config trained alone, resume after a kill, the CLI.

One tiny FLDDPG sweep (tau x buffer size, 2 seeds, 2 episodes of 16 steps, its 5 robots in the
smallest room) is trained once per module and read by most tests; the others train the same
group again (the persistent compilation cache of conftest.py makes that cheap).
"""

import json
from pathlib import Path

import jax
import numpy as np
import pandas as pd
import pytest
import yaml

from fedjax_nav import cli, config, rundir
from fedjax_nav.config import sweepfile as sf
from fedjax_nav.experiments.sweeps import run_sweep
from fedjax_nav.training import sweep as sw
from fedjax_nav.training.run import train

ROOT = Path(__file__).resolve().parents[1]
SWEEPS = sorted((ROOT / "configs" / "sweeps").glob("*.yaml"))
TINY_SET = [
    "env.episode_length=16",
    "run.chunk_episodes=1",
    "offpolicy.batch_size=8",
    "offpolicy.hidden=16",
    "run.checkpoint_every=0",
    "run.episodes=2",
    "fed.period=1",
    # the 5 robots in the smallest shipped room: the env's lidar and collision tests are unrolled
    # over the obstacles, so tracing and compiling grow with them (60 in the thesis rooms padded to one shape)
    "env.worlds=[train-0,train-0,train-0,train-0,train-0]",
]


def write_sweep(folder: Path, name: str = "tiny", **extra) -> Path:
    spec = {
        "name": name,
        "base": str(ROOT / "configs" / "thesis" / "flddpg.yaml"),
        "seeds": 2,
        "set": TINY_SET,
        "grid": {"fed.tau": [0.0, 0.5, 1.0], "offpolicy.buffer_size": [16, 48]},
    }
    spec.update(extra)
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    return path


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sweep")
    sweep = sf.load_sweep(write_sweep(folder))
    out = folder / "out"
    summ, stats = run_sweep(sweep, out, progress=False, echo=lambda s: None)
    return {"folder": folder, "sweep": sweep, "out": out, "summary": summ, "stats": stats}


# ----------------------------------------------------------------------------- the files


@pytest.mark.parametrize("path", SWEEPS, ids=[p.stem for p in SWEEPS])
def test_every_shipped_sweep_loads(path):
    s = sf.load_sweep(path)
    assert s.points and s.seeds >= 1 and s.description
    ids = [p.id for p in s.points]
    assert len(set(ids)) == len(ids), "two grid points resolve to the same config"
    labels = [p.label for p in s.points]
    assert len(set(labels)) == len(labels), "two grid points share a label (tables and curves group by it)"
    spec, _ = sf._extended(path, yaml.safe_load(path.read_text()))  # a base it `extends` from another sweep
    for p in s.points:
        base = yaml.safe_load((path.parent / str(p.values.get("base", spec.get("base")))).read_text())
        # the base config's budget (the thesis's 125 unless it says otherwise) unless swept
        episodes = p.values.get("run.episodes", base.get("run", {}).get("episodes", 125))
        assert p.cfg.run.seeds == s.seeds and p.cfg.run.episodes == episodes and p.cfg.env.episode_length == 1024
        for k, v in p.values.items():
            if k != "base":  # a section's field ("ddpg.tau") or a top-level one ("method")
                assert config.get(p.cfg, k) == (tuple(v) if isinstance(v, list) else v), k


def test_a_grid_over_the_method_writes_its_tables(tmp_path):
    """A grid over the top-level `method` (generalization_scale's) gives the tidy table one `method`
    column holding each point's method (its tables failed with a duplicate column)."""
    from fedjax_nav.analysis.sweeps import point_metrics

    sweep = sf.load_sweep(write_sweep(tmp_path, grid={"method": ["iddpg", "flddpg"], "fed.tau": [0.5, 1.0]}))
    points = tmp_path / "points"
    for p in sweep.points:
        (points / p.id).mkdir(parents=True)
        pd.DataFrame({"episode": [0, 1], "seed": 0, "robot": 0, "success": [0, 1]}).to_csv(
            points / p.id / rundir.METRICS, index=False
        )
    t = point_metrics(sweep, points)
    assert list(t.columns[:4]) == ["point", "label", "method", "fed.tau"] and not t.columns.duplicated().any()
    by_point = t.groupby("point")[["method", "fed.tau"]].first()
    assert {(by_point.loc[p.id, "method"], by_point.loc[p.id, "fed.tau"]) for p in sweep.points} == {
        (m, tau) for m in ("iddpg", "flddpg") for tau in (0.5, 1.0)
    }


def test_shipped_sweeps_cover_the_thesis_experiments():
    names = {p.stem for p in SWEEPS}
    assert {
        "gamma",
        "rho",
        "buffer_iddpg",
        "buffer_seddpg",
        "buffer_snddpg",
        "buffer_flddpg",
        "fed_period_steps",
        "fed_period_episodes",
        "tau",
        "methods",
        "pw_beta",
        "rw_beta",
        "improvements",
    } <= names
    tau = sf.load_sweep(ROOT / "configs" / "sweeps" / "tau.yaml")
    assert [p.cfg.fed.tau for p in tau.points] == [0.0, 0.5, 1.0] and tau.seeds == 8
    steps = sf.load_sweep(ROOT / "configs" / "sweeps" / "fed_period_steps.yaml")
    assert {p.cfg.fed.period_unit for p in steps.points} == {"steps"}


def test_traced_fields_share_a_group_and_static_ones_split():
    gamma = sf.load_sweep(ROOT / "configs" / "sweeps" / "gamma.yaml")
    assert len({sw.group_key(p.cfg) for p in gamma.points}) == 4  # one per method; gamma is traced
    buf = sf.load_sweep(ROOT / "configs" / "sweeps" / "buffer_flddpg.yaml")
    assert len({sw.group_key(p.cfg) for p in buf.points}) == 1  # capacity traced up to the allocation
    ep = sf.load_sweep(ROOT / "configs" / "sweeps" / "fed_period_episodes.yaml")
    st = sf.load_sweep(ROOT / "configs" / "sweeps" / "fed_period_steps.yaml")
    assert sw.group_key(ep.points[0].cfg) != sw.group_key(st.points[0].cfg)  # period_unit is static


def test_plan_allocates_the_largest_buffer_and_packs_to_the_budget():
    buf = sf.load_sweep(ROOT / "configs" / "sweeps" / "buffer_flddpg.yaml", overrides=["env.episode_length=16"])
    jobs = sw.merge_jobs(buf.points)
    (g,) = sw.plan(jobs, budget=2**40)
    assert g.trainer.cfg.buffer_rows == 70000 and len(g.batches) == 1 and g.batch_rows == 20
    per_row, once = sw.point_bytes(g.trainer)
    (g2,) = sw.plan(jobs, budget=9 * per_row + once)  # 9 rows fit: points of 4 seeds pack 2 per batch
    assert [len(b) for b in g2.batches] == [2, 2, 1] and g2.batch_rows == 8
    with pytest.raises(sf.SweepError, match="memory budget"):
        sw.plan(jobs, budget=per_row)


def test_shared_configs_are_trained_once_with_the_most_seeds():
    a = sf.load_sweep(ROOT / "configs" / "sweeps" / "tau.yaml")  # 8 seeds, tau 0.5 = the thesis FLDDPG
    b = sf.load_sweep(ROOT / "configs" / "sweeps" / "buffer_flddpg.yaml")  # 4 seeds, 10 000 = the same
    jobs = sw.merge_jobs(a.points + b.points)
    assert len(jobs) == 3 + 5 - 1
    shared = [j for j in jobs if j.id == a.points[1].id]
    assert len(shared) == 1 and shared[0].cfg.run.seeds == 8 and a.points[1].id == b.points[1].id


@pytest.mark.parametrize(
    "spec, match",
    [
        ({"grid": {"fed.tau": [0.5]}, "bogus": 1}, "unknown key"),
        ({"grid": {"fed.tau": []}}, "grid.fed.tau must be a non-empty list"),
        ({"grid": {"fed.tau": [1.5]}}, "fed.tau"),
        ({"grid": {"fed.nope": [1]}}, "nope"),
        ({"base": "missing.yaml", "grid": {"fed.tau": [0.5]}}, "missing.yaml"),
        ({"grid": {"fed.tau": [0.5]}, "thesis": {"by": "offpolicy.gamma"}}, "thesis.by"),
        ({"grid": {"fed.tau": [0.5]}, "goal": {"walls": 0.9}}, "goal.walls is not a goal"),
        ({"grid": {"fed.tau": [0.5]}, "goal": {"arena": 1.5}}, "goal.arena must be a success rate"),
        ({"grid": {"fed.tau": [0.5]}, "goal": [0.9]}, "goal must be a mapping"),
    ],
)
def test_bad_sweep_files_name_the_key(tmp_path, spec, match):
    full = {"base": str(ROOT / "configs" / "thesis" / "flddpg.yaml"), **spec}
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(full))
    with pytest.raises(sf.SweepError, match=match):
        sf.load_sweep(path)


def test_a_sweep_that_extends_another_is_its_recipe_with_its_own_grid(tmp_path):
    (tmp_path / "sub").mkdir()
    (tmp_path / "base.yaml").write_text((ROOT / "configs" / "thesis" / "flddpg.yaml").read_text())
    write_sweep(tmp_path, name="recipe", base="base.yaml", set=[*TINY_SET, "fed.tau=0.25"])
    child = tmp_path / "sub" / "child.yaml"  # the parent's `base: base.yaml` is beside the parent, not the child
    child.write_text(
        yaml.safe_dump(
            {"name": "child", "extends": "../recipe.yaml", "set": ["fed.tau=1.0"], "grid": {"fed.period": [1, 2]}}
        )
    )
    s = sf.load_sweep(child)
    written_out = sf.load_sweep(
        write_sweep(tmp_path, name="flat", set=[*TINY_SET, "fed.tau=0.25", "fed.tau=1.0"], grid={"fed.period": [1, 2]})
    )
    assert s.seeds == 2 and s.keys == ("fed.period",)
    assert [p.id for p in s.points] == [p.id for p in written_out.points]
    assert all(p.cfg.fed.tau == 1.0 for p in s.points)  # its own set after the inherited one
    # a shipped sweep's name works too, and a chain that loops is one error naming the key
    assert sf.load_sweep(
        write_sweep(tmp_path, name="named", extends="planning_shared_budget", grid={"run.episodes": [2]})
    )
    (tmp_path / "a.yaml").write_text(yaml.safe_dump({"extends": "b.yaml", "grid": {"fed.tau": [0.5]}}))
    (tmp_path / "b.yaml").write_text(yaml.safe_dump({"extends": "a.yaml", "grid": {"fed.tau": [0.5]}}))
    with pytest.raises(sf.SweepError, match="extends: more than"):
        sf.load_sweep(tmp_path / "a.yaml")
    (tmp_path / "c.yaml").write_text(yaml.safe_dump({"extends": "nowhere.yaml", "grid": {"fed.tau": [0.5]}}))
    with pytest.raises(sf.SweepError, match="c.yaml: extends: no sweep file 'nowhere.yaml'"):
        sf.load_sweep(tmp_path / "c.yaml")


def test_parse_bytes():
    assert sw.parse_bytes("4G") == 4 * 2**30 and sw.parse_bytes("512M") == 512 * 2**20
    assert sw.parse_bytes("1.5GB") == int(1.5 * 2**30) and sw.parse_bytes(1000) == 1000
    with pytest.raises(sf.SweepError, match="memory budget"):
        sw.parse_bytes("lots")


# ----------------------------------------------------------------------------- running


def test_a_grid_of_traced_values_compiles_once(tiny):
    (g,) = tiny["stats"]["groups"]
    assert g["traces"] == 1 and g["jobs"] == 6 and g["batches"] == 1 and g["batch_rows"] == 12


def test_tables_hold_every_point_seed_episode_and_robot(tiny):
    out, sweep = tiny["out"], tiny["sweep"]
    res = pd.read_csv(out / "results.csv")
    assert len(res) == 6 * 2 * 2 * 5  # points x seeds x episodes x robots
    assert {
        "point",
        "label",
        "fed.tau",
        "offpolicy.buffer_size",
        "seed",
        "episode",
        "robot",
        "reward",
        "reached_goal",
    } <= set(res.columns)
    summ = pd.read_csv(out / "summary.csv")
    assert list(summ["point"]) == [p.id for p in sweep.points] and (summ["seeds"] == 2).all()
    assert np.isfinite(summ[["success_last", "reward_last"]].to_numpy()).all()
    for p in sweep.points:  # each point is a run directory `fedjax-nav evaluate` can read
        d = out / "points" / p.id
        assert {"config.yaml", "metrics.csv", "summary.json", "params.npz"} <= {f.name for f in d.iterdir()}
    assert (out / "learning_curves.png").stat().st_size > 0
    assert not (out / "batches").exists()


def _run_metrics(folder: Path) -> pd.DataFrame:
    return pd.read_csv(folder / "metrics.csv")


def test_each_grid_point_equals_the_config_trained_alone(tiny, tmp_path):
    """The point (tau 1, buffer 16) of the 12-row batch (buffers allocated at 48 rows) against
    `train` with its own config: same numbers to float32 round-off, same discrete outcomes."""
    p = tiny["sweep"].points[4]
    assert p.values == {"fed.tau": 1.0, "offpolicy.buffer_size": 16}
    train(p.cfg, tmp_path / "alone", progress=False)
    a, b = _run_metrics(tmp_path / "alone"), _run_metrics(tiny["out"] / "points" / p.id)
    assert list(a.columns) == list(b.columns) and len(a) == len(b)
    for k in ("goals", "reached_goal", "collisions", "fed_events", "seed", "episode", "robot"):
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    for k in ("reward", "critic_loss", "actor_loss", "q", "epsilon"):
        np.testing.assert_allclose(a[k], b[k], rtol=1e-5, atol=1e-6, err_msg=k)
    with np.load(tmp_path / "alone" / "params.npz") as za, np.load(tiny["out"] / "points" / p.id / "params.npz") as zb:
        assert set(za.files) == set(zb.files)
        for k in za.files:
            np.testing.assert_allclose(za[k], zb[k], rtol=1e-5, atol=1e-6, err_msg=k)


def test_a_finished_sweep_trains_nothing_again(tiny):
    sweep, out = tiny["sweep"], tiny["out"]
    stamps = {p.id: (out / "points" / p.id / "summary.json").stat().st_mtime_ns for p in sweep.points}
    _, stats = run_sweep(sweep, out, progress=False, echo=lambda s: None)
    assert stats["skipped"] == 6 and stats["groups"] == []
    assert stamps == {p.id: (out / "points" / p.id / "summary.json").stat().st_mtime_ns for p in sweep.points}


def test_a_killed_sweep_resumes_without_recomputing_finished_points(tiny, tmp_path, monkeypatch):
    """Batch 1 finishes; batch 2 dies after its first episode (checkpointed). The rerun trains only
    batch 2, from the checkpoint, and every number equals the uninterrupted sweep's."""
    sweep = sf.load_sweep(write_sweep(tiny["folder"], "tiny-kill", set=TINY_SET + ["run.checkpoint_every=1"]))
    assert [p.id for p in sweep.points] == [p.id for p in tiny["sweep"].points]
    per_row, once = sw.point_bytes(sw.plan(sw.merge_jobs(sweep.points), 2**40)[0].trainer)
    budget = 6 * per_row + once  # 3 points of 2 seeds per batch: 2 batches
    out = tmp_path / "killed"

    calls = []
    real_post_init = sw.Compiled.__post_init__

    def dying(self):
        real_post_init(self)
        fn = self.fn

        def wrapped(*a):
            calls.append(1)
            if len(calls) == 4:  # batch 1: calls 1-2; batch 2 dies in its 2nd episode
                raise KeyboardInterrupt
            return fn(*a)

        self.fn = wrapped

    monkeypatch.setattr(sw.Compiled, "__post_init__", dying)
    with pytest.raises(KeyboardInterrupt):
        run_sweep(sweep, out, budget=budget, progress=False, echo=lambda s: None)
    monkeypatch.setattr(sw.Compiled, "__post_init__", real_post_init)
    done = [p for p in sweep.points if (out / "points" / p.id / "summary.json").exists()]
    assert len(done) == 3 and any((out / "batches").iterdir())
    stamps = {p.id: (out / "points" / p.id / "summary.json").stat().st_mtime_ns for p in done}

    _, stats = run_sweep(sweep, out, budget=budget, progress=False, echo=lambda s: None)
    assert stats["skipped"] == 3 and stats["groups"][0]["jobs"] == 3
    assert stats["groups"][0]["traces"] == 1, "a resumed batch traced its chunk again"
    assert stamps == {p.id: (out / "points" / p.id / "summary.json").stat().st_mtime_ns for p in done}
    resumed = [
        json.loads((out / "points" / p.id / "summary.json").read_text())["resumed_from_episode"]
        for p in sweep.points
        if p not in done
    ]
    assert resumed == [1, 1, 1]
    for p in sweep.points:
        a, b = _run_metrics(out / "points" / p.id), _run_metrics(tiny["out"] / "points" / p.id)
        for k in ("goals", "collisions", "fed_events"):
            np.testing.assert_array_equal(a[k], b[k], err_msg=f"{p.label} {k}")
        for k in ("reward", "critic_loss", "q"):
            np.testing.assert_allclose(a[k], b[k], rtol=1e-5, atol=1e-6, err_msg=f"{p.label} {k}")


def test_cli_sweep_prints_the_summary_and_resumes(tiny, capsys):
    out = tiny["out"]
    path = tiny["folder"] / "tiny.yaml"
    assert cli.main(["sweep", str(path), "--out", str(out), "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "fed.tau=0.5, offpolicy.buffer_size=48" in text and "all points were done" in text
    assert cli.main(["sweep", str(tiny["folder"] / "nope.yaml"), "--quiet"]) == 2
    assert "nope.yaml" in capsys.readouterr().err


def test_stack_hparams_keeps_equal_fields_scalar():
    from fedjax_nav.config import load_config
    from fedjax_nav.training.hparams import hparams_from_config, stack_hparams

    a = hparams_from_config(load_config(ROOT / "configs" / "thesis" / "flddpg.yaml"))
    b = a.replace_flat({"fed.tau": jax.numpy.float32(1.0)})
    hp = stack_hparams([a, b, b])
    assert hp.fed.tau.shape == (3,) and hp.offpolicy.gamma.shape == () and hp.offpolicy.train_every.shape == ()


def test_rows_pad_to_a_multiple_of_the_devices():
    tau = sf.load_sweep(ROOT / "configs" / "sweeps" / "tau.yaml", overrides=["env.episode_length=16"], seeds=1)
    (g,) = sw.plan(sw.merge_jobs(tau.points), budget=2**40, devices=2)
    assert g.batch_rows == 4 and g.batched == {"fed.tau"}  # 3 points x 1 seed, padded to 4 rows
    seeds, hp, spans = sw.batch_rows(g.batches[0], g.batch_rows, g.batched)
    assert list(seeds) == [0, 0, 0, 0] and hp.fed.tau.shape == (4,) and hp.offpolicy.gamma.shape == ()
    assert [(lo, n) for _, lo, n in spans] == [(0, 1), (1, 1), (2, 1)]


def test_a_sweep_spread_over_two_devices_matches_one(tiny, tmp_path):
    """The tiny sweep again with its 12 rows over 2 forced CPU devices (the CLI's default on this
    2-core machine), in a subprocess: same outcomes, numbers within float32 round-off."""
    import os
    import subprocess
    import sys

    script = (
        "import json, sys\nfrom fedjax_nav.experiments.sweeps import run_sweep\n"
        "from fedjax_nav.config.sweepfile import load_sweep\n"
        "s = load_sweep(sys.argv[1])\n"
        "_, st = run_sweep(s, sys.argv[2], progress=False, echo=lambda x: None)\n"
        "print(json.dumps(st))\n"
    )
    env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2", "JAX_PLATFORMS": "cpu"}
    out = tmp_path / "two"
    r = subprocess.run(
        [sys.executable, "-c", script, str(tiny["folder"] / "tiny.yaml"), str(out)],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    stats = json.loads(r.stdout.strip().splitlines()[-1])
    assert stats["devices"] == 2 and stats["groups"][0]["traces"] == 1 and stats["groups"][0]["batch_rows"] == 12
    for p in tiny["sweep"].points:
        a, b = _run_metrics(out / "points" / p.id), _run_metrics(tiny["out"] / "points" / p.id)
        for k in ("goals", "collisions", "fed_events"):
            np.testing.assert_array_equal(a[k], b[k], err_msg=f"{p.label} {k}")
        for k in ("reward", "critic_loss", "q"):
            np.testing.assert_allclose(a[k], b[k], rtol=1e-5, atol=1e-6, err_msg=f"{p.label} {k}")


# ----------------------------------------------------------------------------- traced really means traced


def test_a_sweep_over_env_constants_compiles_once(tmp_path):
    """env.* fields marked traced are HParams, not constants of the program: one group, one trace
    for a grid over two of them, and each value reaches the env: two points that differ only in
    v_max differ in reward, two that differ only in collision_distance in collisions (one sweep
    for both fields: one compilation)."""
    grid = {"env.v_max": [0.15, 0.25], "env.collision_distance": [0.25, 2.0]}  # 0.25: the preset's, the default
    sweep = sf.load_sweep(write_sweep(tmp_path, "env", grid=grid, seeds=1))
    assert len(sweep.points) == 4 and len(sw.plan(sw.merge_jobs(sweep.points), budget=2**40)) == 1
    _, stats = run_sweep(sweep, tmp_path / "out", progress=False, echo=lambda s: None)
    assert [g["traces"] for g in stats["groups"]] == [1]
    frames = {
        (p.values["env.v_max"], p.values["env.collision_distance"]): pd.read_csv(
            tmp_path / "out" / "points" / p.id / "metrics.csv"
        )
        for p in sweep.points
    }
    assert not np.allclose(frames[0.15, 0.25]["reward"], frames[0.25, 0.25]["reward"])
    assert not np.allclose(frames[0.25, 0.25]["collisions"], frames[0.25, 2.0]["collisions"])


def test_every_traced_field_is_an_input_the_program_uses():
    """For each field declared traced: it is an HParams leaf, it is excluded from the static group
    key, and the jitted chunk's program reads it (an HParams leaf the program ignored, e.g. because
    the trainer closed over the config's value instead, would be dead in the jaxpr)."""
    from fedjax_nav.config import load_config, traced_fields
    from fedjax_nav.training.hparams import hparams_from_config
    from fedjax_nav.training.trainer import Trainer

    cfg = load_config(ROOT / "configs" / "thesis" / "pwddpg.yaml", TINY_SET + ["run.episodes=1"])
    hp = hparams_from_config(cfg)
    assert set(hp.to_flat()) == set(traced_fields()) and len(hp.to_flat()) >= 19
    assert not set(json.loads(sw.group_key(cfg))) & set(traced_fields())

    def unused_by(cfg):
        tr = Trainer(cfg)

        def init_and_train(h):  # epsilon_start only acts at init
            states = jax.vmap(lambda k: tr.init(k, h))(jax.random.split(jax.random.key(0), 1))
            return tr.chunk(states, h, jax.numpy.int32(0), 1)

        closed = jax.make_jaxpr(init_and_train)(hp)
        names = list(hp.to_flat())  # the struct flattens in the sections' and fields' order
        hp_vars = closed.jaxpr.invars
        used = {v for eqn in closed.jaxpr.eqns for v in eqn.invars if hasattr(v, "aval") and not hasattr(v, "val")}
        return {n for n, v in zip(names, hp_vars) if v not in used}

    # PWDDPG with an episode period: fed.period, tau and beta all act; the robust aggregators'
    # options and the attack's scale act when they are selected: every field must be read by one
    unused = unused_by(cfg)
    robust = {"fed.trim": "trimmed_mean", "fed.krum_f": "krum", "fed.krum_m": "krum", "fed.max_norm": "norm_bounded"}
    for agg in sorted(set(robust.values())):
        extra = [f"fed.aggregator={agg}", "fed.byzantine=1", "fed.attack=scale"]
        unused &= unused_by(
            load_config(ROOT / "configs" / "thesis" / "flddpg.yaml", TINY_SET + ["run.episodes=1"] + extra)
        )
    # the robot model's fields act when a model other than the ideal one is selected
    unused &= unused_by(
        load_config(
            ROOT / "configs" / "thesis" / "flddpg.yaml", TINY_SET + ["run.episodes=1", "robot.model=turtlebot3_burger"]
        )
    )
    # env.room_every acts in a run on procedural rooms, the learnability fields with room_sampling: learnability
    unused &= unused_by(
        load_config(
            ROOT / "configs" / "thesis" / "flddpg.yaml",
            TINY_SET
            + [
                "run.episodes=1",
                "env.rooms=procedural",
                "env.room_families=[cylinders]",
                "env.room_sampling=learnability",
            ],
        )
    )
    # each learner's own section acts when that learner trains (agents/learners.py)
    small_ppo = ["ppo.rollout=8", "ppo.minibatches=1", "ppo.epochs=1", "ppo.hidden=16"]
    for learner in ("td3", "sac", "ppo"):
        unused &= unused_by(
            load_config(
                ROOT / "configs" / "thesis" / "flddpg.yaml",
                TINY_SET + ["run.episodes=1", f"learner={learner}"] + (small_ppo if learner == "ppo" else []),
            )
        )
    assert not unused, f"traced fields the program never reads: {sorted(unused)}"


def test_a_grid_over_episodes_trains_its_longest_run_and_saves_the_shorter_from_its_start(tmp_path):
    """run.episodes [2, 4], seeds 2 and 1 (points) : one job of 4 episodes and 2 seeds, the
    2-episode point written from its first 2 episodes, equal to that config trained alone."""
    path = write_sweep(tmp_path, "budgets", grid={"run.episodes": [2, 4]})
    sweep = sf.load_sweep(path)
    jobs = sw.fold_prefixes(sw.merge_jobs(sweep.points))
    (job,) = jobs
    assert job.cfg.run.episodes == 4 and [p.cfg.run.episodes for p in job.prefixes] == [2]
    out = tmp_path / "out"
    summ, stats = run_sweep(sweep, out, progress=False, echo=lambda s: None)
    assert stats["prefixes"] == 1 and len(stats["groups"]) == 1 and stats["groups"][0]["traces"] == 1
    short, long = sweep.points
    s = json.loads((out / "points" / short.id / "summary.json").read_text())
    assert s["episodes_done"] == 2 and s["seeds"] == 2 and s["prefix_of"] == long.id
    train(short.cfg, tmp_path / "alone", progress=False)
    a, b = _run_metrics(tmp_path / "alone"), _run_metrics(out / "points" / short.id)
    assert list(a.columns) == list(b.columns) and len(a) == len(b)
    for k in ("goals", "reached_goal", "collisions", "fed_events", "seed", "episode", "robot"):
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    for k in ("reward", "critic_loss", "actor_loss", "q", "epsilon"):
        np.testing.assert_allclose(a[k], b[k], rtol=1e-5, atol=1e-6, err_msg=k)
    with np.load(tmp_path / "alone" / "params.npz") as za, np.load(out / "points" / short.id / "params.npz") as zb:
        for k in za.files:
            np.testing.assert_allclose(za[k], zb[k], rtol=1e-5, atol=1e-6, err_msg=k)
    long_df = _run_metrics(out / "points" / long.id)
    assert long_df["episode"].max() == 3
    np.testing.assert_array_equal(long_df[long_df.episode < 2]["reward"], b["reward"])
    # a rerun trains nothing; a budget that is not a multiple of the chunk stays its own job
    assert run_sweep(sweep, out, progress=False, echo=lambda s: None)[1]["groups"] == []
    from dataclasses import replace

    def budget(cfg, episodes):
        return replace(cfg, run=replace(cfg.run, chunk_episodes=2, episodes=episodes))

    assert len(sw.fold_prefixes([sw.Job(budget(short.cfg, 3), "a"), sw.Job(budget(long.cfg, 4), "b")])) == 2
    assert len(sw.fold_prefixes([sw.Job(budget(short.cfg, 2), "a"), sw.Job(budget(long.cfg, 4), "b")])) == 1


def test_two_sweeps_sharing_a_folder_keep_their_own_tables(tiny, tmp_path):
    """A second sweep trained into the first one's folder (shared points) writes its tables under
    tables/<name>/ and leaves the first sweep's results.csv, summary.csv and sweep.yaml as they were."""
    out = tiny["out"]
    before = {f: (out / f).read_bytes() for f in ("results.csv", "summary.csv", "sweep.yaml")}
    subset = {"fed.tau": [0.5], "offpolicy.buffer_size": [16]}  # one point of the tiny sweep
    other = sf.load_sweep(write_sweep(tiny["folder"], "tiny-subset", grid=subset))
    msgs = []
    summ, stats = run_sweep(other, out, progress=False, echo=msgs.append)
    assert stats["groups"] == [] and stats["tables"] == str(out / "tables" / "tiny-subset")  # shared point: no training
    assert before == {f: (out / f).read_bytes() for f in before}
    assert len(pd.read_csv(out / "tables" / "tiny-subset" / "summary.csv")) == 1 and len(summ) == 1
    assert any("tables of sweep 'tiny'" in m for m in msgs)


def test_only_selects_points_by_their_values(tmp_path):
    """`sweep --only KEY=VALUE`: values of one key are alternatives, keys must all hold; values are
    read as --set reads them; a bad key, a bad value or no match is one error naming it."""
    sweep = sf.load_sweep(write_sweep(tmp_path))
    pick = sf.select(sweep, ["fed.tau=0.5"])
    assert [p.cfg.offpolicy.buffer_size for p in pick] == [16, 48] and {p.cfg.fed.tau for p in pick} == {0.5}
    pick = sf.select(sweep, ["fed.tau=0.5", "fed.tau=1", "offpolicy.buffer_size=48"])
    assert [(p.cfg.fed.tau, p.cfg.offpolicy.buffer_size) for p in pick] == [(0.5, 48), (1.0, 48)]
    assert sf.select(sweep) == sweep.points
    for only, match in [
        (["fed.tau=0.25"], "matches none of the 6 points of tiny"),
        (["fed.nope=1"], "nope"),
        (["fed.tau=abc"], "fed.tau"),
        (["fed.tau"], "key=value"),
    ]:
        with pytest.raises(sf.SweepError, match=match):
            sf.select(sweep, only)


def test_cli_sweep_only_trains_the_selected_points_and_tables_the_rest(tiny, tmp_path, capsys):
    """The selected point trains alone, to the numbers of the whole sweep; the others stay
    untrained and the tables are written for what is done."""
    out = tmp_path / "only"
    path = tiny["folder"] / "tiny.yaml"
    argv = [
        "sweep",
        str(path),
        "--out",
        str(out),
        "--quiet",
        "--only",
        "fed.tau=0.5",
        "--only",
        "offpolicy.buffer_size=16",
    ]
    assert cli.main(argv) == 0
    (p,) = [p for p in tiny["sweep"].points if p.cfg.fed.tau == 0.5 and p.cfg.offpolicy.buffer_size == 16]
    assert sorted(d.name for d in (out / "points").iterdir()) == [p.id]
    a, b = _run_metrics(out / "points" / p.id), _run_metrics(tiny["out"] / "points" / p.id)
    np.testing.assert_array_equal(a["goals"], b["goals"])
    np.testing.assert_allclose(a["reward"], b["reward"], rtol=1e-5, atol=1e-6)
    assert "fed.tau=0.5, offpolicy.buffer_size=16" in capsys.readouterr().out
    assert cli.main(["sweep", str(path), "--out", str(out), "--quiet", "--only", "fed.tau=7"]) == 2
    err = capsys.readouterr().err.strip()
    assert "fed.tau" in err and len(err.splitlines()) == 1
