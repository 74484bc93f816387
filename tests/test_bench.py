"""The benchmark functions run and report positive, consistent numbers (tiny sizes)."""

import pytest

from fedjax_nav.agents.ddpg import update_flops
from fedjax_nav.experiments import bench, bench_learners, bench_sweep


def test_env_bench_reports_throughput():
    rows = bench.bench_env(batches=(2,), steps=5)
    assert rows[0]["batch"] == 2 and rows[0]["agent_steps_per_s"] > 0
    assert "agent-steps/s" in bench.format_rows(rows)


def test_update_flops_matches_hand_count():
    # 64x3 networks, obs 28, action 2: actor fwd 2*(28*64 + 2*64*64 + 64*2), critic fwd
    # 2*(30*64 + 2*64*64 + 64*1); one update = 4 actor fwd + 6 critic fwd per row (see docstring).
    fa = 2 * (28 * 64 + 2 * 64 * 64 + 64 * 2)
    fc = 2 * (30 * 64 + 2 * 64 * 64 + 64 * 1)
    assert update_flops(28, 64, 3, 512) == 512 * (4 * fa + 6 * fc)
    assert 95e6 < update_flops(28, 64, 3, 512) < 110e6  # "about 98 MFLOP per agent" (docs/benchmarks.md)


def test_sweep_bench_times_one_by_one_and_batched():
    rows = bench_sweep.bench_sweep(
        points=2,
        episodes=1,
        overrides=(
            "env.episode_length=16",
            "offpolicy.batch_size=8",
            "offpolicy.hidden=16",
            "offpolicy.buffer_size=64",
            "env.worlds=[train-0,train-0,train-0,train-0,train-0]",  # the smallest room: compiles fastest
        ),
    )
    (r,) = rows
    assert r["points"] == 2 and r["one_by_one_s"] > 0 and r["sweep_s"] > 0
    assert abs(r["per_run_sweep_s"] * 2 - r["sweep_s"]) < 1e-9
    assert abs(r["per_run_one_by_one_s"] * 2 - r["one_by_one_s"]) < 1e-9
    # the reported speed-up is the ratio of the two measured times (per run), nothing else
    assert r["sweep_speedup"] == pytest.approx(r["one_by_one_s"] / r["sweep_s"], rel=1e-12)
    assert f"{r['sweep_speedup']:.2f}x" in bench.format_rows(rows)
    assert "one vmapped program" in bench.format_rows(rows)


def test_a_train_row_names_procedural_rooms():
    row = {"bench": "train", "method": "flddpg", "seeds": 1, "robots": 5, "agent_steps_per_s": 1000.0}
    row |= {"agent_updates_per_s": 10.0, "gflops": 1.0, "fraction_of_ceiling": 0.1, "episode_s": 5.0}
    row |= {"run_estimate_s": 625.0, "compile_s": 30.0}
    fixed = bench.format_rows([row | {"rooms": "fixed"}])
    proc = bench.format_rows([row | {"rooms": "procedural ['mixture']"}])
    assert "rooms" not in fixed and "procedural ['mixture'] rooms, new every episode" in proc


def test_a_learner_row_counts_every_environment_and_its_gradient_steps():
    # 2 robots in the smallest room (compile time grows with the rooms' obstacles)
    tiny = ("env.episode_length=8", "env.worlds=[train-0, train-0]", "ppo.hidden=8", "ppo.rollout=4")
    rows = bench_learners.bench_learners((*tiny, "env.envs_per_robot=3"), rows=(("ppo", ()),), env_batch=6, brax=False)
    train, env, env_procedural = rows
    assert train["learner"] == "ppo" and train["envs_per_robot"] == 3 and train["gflops"] > 0
    # agent-steps: 2 robots x 3 environments x 8 steps in one episode; PPO: 2 updates x 4 epochs x 4 minibatches
    assert train["agent_steps_per_s"] * train["episode_s"] == pytest.approx(2 * 3 * 8)
    assert train["agent_updates_per_s"] * train["episode_s"] == pytest.approx(2 * 2 * 4 * 4)
    text = bench.format_rows(rows)
    assert "train flddpg (ppo) | 1 seed(s) x 2 robots x 3 environments" in text and "gradient steps/s" in text
    assert "GFLOP/s" in text and env["batch"] == env_procedural["batch"] == 6
    assert env["rooms"] == "thesis rooms" and env_procedural["rooms"] == "procedural mixture rooms"


def test_each_row_of_braxs_algorithm_is_divided_by_the_last_brax_rate_of_the_same_run():
    rows = [
        {
            "bench": "train",
            "learner": "ppo",
            "method": "flddpg",
            "robots": 5,
            "envs_per_robot": 256,
            "rooms": "procedural ['mixture']",
            "agent_steps_per_s": 30.0,
            "vs_brax": "ppo",
        },
        {
            "bench": "train",
            "learner": "ppo",
            "method": "snddpg",
            "robots": 5,
            "envs_per_robot": 256,
            "rooms": "fixed",
            "agent_steps_per_s": 45.0,
            "vs_brax": "ppo",
        },
        {
            "bench": "train",
            "learner": "ppo-gru",
            "method": "flddpg",
            "robots": 5,
            "envs_per_robot": 256,
            "rooms": "fixed",
            "agent_steps_per_s": 9.0,
            "vs_brax": None,
        },
        {
            "bench": "train",
            "learner": "sac",
            "method": "iddpg",
            "robots": 1,
            "envs_per_robot": 64,
            "rooms": "fixed",
            "agent_steps_per_s": 20.0,
            "vs_brax": "sac",
        },
        {"bench": "brax_ppo", "agent_steps_per_s": 1.0},
        {"bench": "brax_ppo", "agent_steps_per_s": 60.0},
        {"bench": "brax_sac", "agent_steps_per_s": 25.0},
    ]
    ratios = bench_learners.brax_ratios(rows)
    # the GRU row is not brax's algorithm; SAC's row is divided by brax's SAC, not its PPO
    assert [r["value"] for r in ratios] == [0.5, 0.75, 0.8]
    text = bench.format_rows(ratios)
    assert "PPO snddpg (5 x 256 environments, thesis rooms) / brax's steady rate | 0.75x" in text
    assert "SAC iddpg (1 x 64 environments, thesis rooms) / brax's steady rate | 0.80x" in text
    assert "procedural rooms" in text.splitlines()[0]
