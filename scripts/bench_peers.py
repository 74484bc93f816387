"""Side-by-side benchmarks against the peers a user would pick instead, in ONE run on one machine.

    pip install torch==2.13.0          # CPU wheel first (a plain `torch` pulls a multi-GB CUDA build)
    pip install -e ".[bench]"          # gymnasium, stable-baselines3, jaxmarl
    python scripts/bench_peers.py [--quick] [--record docs/benchmarks.md]

(a) env stepping, 24 beams, one agent per env, random actions, one jitted lax.scan:
    JaxMARL's JaxNav (`step`, which always computes a full reset too, and `step_env`, which
    skips it) against fedjax_nav's NavEnv (`fedjax_nav.experiments.bench.bench_env`, the thesis's rooms),
    at batch 1 and 4096 -> agent-steps/s and ratios.
(b) training on the same task (room train-0, one robot, 64x3 actor and critic, batch 512, one
    gradient step every 5 env steps, buffer 10k, gamma 0.9, lr 1e-3, hard target copies):
    Stable-Baselines3 DDPG (PyTorch, CPU) through the gymnasium wrapper
    (`fedjax_nav.env.gym_env.NavGymEnv`), timed over a fixed number of steps after warm-up and
    `learning_starts`, against fedjax_nav's trainer (IDDPG with one robot on train-0: one
    1024-step episode after compilation) and the thesis-scale 5-robot FLDDPG episode
    (`fedjax_nav.experiments.bench.bench_train`) -> agent-steps/s, agent-updates/s and ratios.

Everything is measured in this one process, so the ratios hold even when the shared machine's
load drifts between runs (the load average is printed before and after).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

from fedjax_nav.experiments import bench  # noqa: E402

WORLD = "train-0"


def load() -> str:
    return " / ".join(f"{x:.2f}" for x in os.getloadavg())


# ----------------------------------------------------------------------------- (a) JaxNav


def bench_jaxnav(batch: int, steps: int, which: str, repeat: int = 2) -> float:
    """agent-steps/s of JaxNav (1 agent, 24 beams, range 3.5 m) over a jitted scan of `steps`."""
    from jaxmarl.environments.jaxnav import JaxNav

    env = JaxNav(num_agents=1, lidar_num_beams=24, lidar_max_range=3.5)
    agent = env.agents[0]
    step_fn = env.step if which == "step" else env.step_env
    lo, hi = jnp.array([0.0, -env.max_w]), jnp.array([env.max_v, env.max_w])

    def rollout(key, state):
        def body(carry, k):
            state, acc = carry
            k_act, k_step = jax.random.split(k)
            a = jax.random.uniform(k_act, (2,), minval=lo, maxval=hi)
            obs, state, rew, dones, info = step_fn(k_step, state, {agent: a})
            return (state, acc + jnp.sum(obs[agent]) + rew[agent]), None  # consume obs

        (state, acc), _ = jax.lax.scan(body, (state, jnp.float32(0.0)), jax.random.split(key, steps))
        return acc

    keys = jax.random.split(jax.random.key(0), batch)
    _, states = jax.jit(jax.vmap(env.reset))(keys)
    # strip weak types from the reset state: else the scan's carry types differ and it recompiles
    states = jax.tree.map(lambda x: jnp.asarray(x, x.dtype) if isinstance(x, jax.Array) else x, states)
    f = jax.jit(jax.vmap(rollout))
    t = bench._time(f, keys, states, repeat=repeat)
    return batch * steps / t


# ----------------------------------------------------------------------------- (b) SB3 DDPG


def bench_sb3(steps: int, warm: int = 1000, learning_starts: int = 512) -> dict:
    import torch
    from stable_baselines3 import DDPG

    from fedjax_nav import methods
    from fedjax_nav.env.gym_env import NavGymEnv

    env = NavGymEnv(WORLD, episode_length=1024, random_starts=methods.get("iddpg").random_starts)
    # the gym wrapper alone, random actions from Python: the floor under any Python-stepped learner
    env.reset(seed=0)
    for _ in range(50):
        env.step(env.action_space.sample())
    n = 2000
    t0 = time.perf_counter()
    for _ in range(n):
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        if term or trunc:
            env.reset()
    gym_sps = n / (time.perf_counter() - t0)

    model = DDPG(
        "MlpPolicy",
        env,
        learning_rate=1e-3,
        buffer_size=10_000,
        learning_starts=learning_starts,
        batch_size=512,
        tau=1.0,
        gamma=0.9,
        train_freq=5,
        gradient_steps=1,
        policy_kwargs=dict(net_arch=dict(pi=[64, 64, 64], qf=[64, 64, 64])),
        device="cpu",
        seed=0,
        verbose=0,
    )
    model.learn(total_timesteps=learning_starts + warm)  # warm-up: buffer filled, updates running
    u0 = model._n_updates
    t0 = time.perf_counter()
    model.learn(total_timesteps=steps, reset_num_timesteps=False)
    dt = time.perf_counter() - t0
    updates = model._n_updates - u0
    # profile: SB3's gradient steps alone (its train(), no env), and one policy call (predict)
    model.train(gradient_steps=10, batch_size=512)
    t0 = time.perf_counter()
    model.train(gradient_steps=N_UPDATES, batch_size=512)
    train_s = (time.perf_counter() - t0) / N_UPDATES
    obs, _ = env.reset(seed=0)
    t0 = time.perf_counter()
    for _ in range(1000):
        model.predict(obs, deterministic=True)
    predict_s = (time.perf_counter() - t0) / 1000
    return {
        "agent_steps_per_s": steps / dt,
        "agent_updates_per_s": updates / dt,
        "updates": updates,
        "steps": steps,
        "seconds": dt,
        "gym_env_steps_per_s": gym_sps,
        "torch_threads": torch.get_num_threads(),
        "update_s": train_s,
        "predict_s": predict_s,
    }


N_UPDATES = 205  # gradient steps in one 1024-step episode at T_train = 5


def bench_jax_updates() -> float:
    """Seconds per DDPG update of fedjax_nav alone (1 agent, 64x3, batch 512, sampled from a full
    10k buffer), N_UPDATES in one jitted lax.scan: the floor under one robot's training step."""
    from fedjax_nav.agents import buffer as rb
    from fedjax_nav.agents import ddpg

    nets = ddpg.make_nets(64, 3, "relu")
    agent = ddpg.init_agent(nets, jax.random.key(0), 28)
    n = 10_000
    k = jax.random.split(jax.random.key(1), 3)
    rows = rb.Transition(
        jax.random.uniform(k[0], (n, 28)),
        jax.random.uniform(k[1], (n, 2)),
        jax.random.normal(k[2], (n,)),
        jax.random.uniform(k[0], (n, 28)),
        jnp.zeros(n),
    )
    buf = rb.add(rb.init(n, 28), rows, jnp.int32(0), jnp.int32(n))

    def many(agent, buf, key):
        def body(a, kk):
            a, _ = ddpg.update(nets, a, rb.sample(buf, kk, 512, jnp.int32(n), jnp.int32(n)), 0.9, 1e-3)
            return a, None

        return jax.lax.scan(body, agent, jax.random.split(key, N_UPDATES))[0]

    return bench._time(jax.jit(many), agent, buf, jax.random.key(2)) / N_UPDATES


def bench_fedjax_train(method: str, worlds_: list[str] | None) -> dict:
    over = [f"method={method}", "offpolicy.buffer_size=10000"]
    if worlds_:
        over.append("env.worlds=[" + ",".join(worlds_) + "]")
    return bench.bench_train(seeds=(1,), episodes=1, overrides=over)[0]


# ----------------------------------------------------------------------------- main


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="tiny sizes (a smoke test, numbers meaningless)")
    ap.add_argument("--sb3-steps", type=int, default=5000, help="SB3 steps timed after warm-up")
    ap.add_argument("--record", help="append the table to this markdown file (docs/benchmarks.md)")
    args = ap.parse_args(argv)
    q = args.quick
    load_before = load()
    t_start = time.perf_counter()

    # (a) env stepping
    batches = (1, 64) if q else (1, 4096)
    ours = {
        r["batch"]: r["agent_steps_per_s"]
        for r in bench.bench_env(batches=batches, steps=20 if q else 200)
        if r["devices"] == 1
    }
    env_rows = []
    for b in batches:
        big = b >= 1024
        js = bench_jaxnav(b, steps=5 if q else (20 if big else 200), which="step")
        jse = bench_jaxnav(b, steps=5 if q else (50 if big else 200), which="step_env")
        env_rows.append((b, ours[b], js, jse))
        print(
            f"env batch {b}: fedjax_nav {ours[b]:,.0f}, JaxNav step {js:,.0f}, step_env {jse:,.0f} agent-steps/s",
            flush=True,
        )

    # (b) training
    sb3 = bench_sb3(steps=200 if q else args.sb3_steps, warm=100 if q else 1000)
    print(
        f"SB3 DDPG: {sb3['agent_steps_per_s']:,.0f} agent-steps/s, {sb3['agent_updates_per_s']:,.1f} updates/s",
        flush=True,
    )
    one = bench_fedjax_train("iddpg", [WORLD])
    print(f"fedjax_nav IDDPG 1 robot: {one['agent_steps_per_s']:,.0f} agent-steps/s", flush=True)
    five = bench_fedjax_train("flddpg", None)
    print(f"fedjax_nav FLDDPG 5 robots: {five['agent_steps_per_s']:,.0f} agent-steps/s", flush=True)
    jax_update_s = bench_jax_updates()
    load_after = load()

    lines = []
    for b, o, js, jse in env_rows:
        lines.append(f"| env, batch {b} | fedjax_nav NavEnv (thesis rooms) | {o:,.0f} agent-steps/s | |")
        lines.append(
            f"| env, batch {b} | JaxNav `step` (with its reset) | {js:,.0f} agent-steps/s | **{o / js:,.1f}x** |"
        )
        lines.append(
            f"| env, batch {b} | JaxNav `step_env` (no reset) | {jse:,.0f} agent-steps/s | **{o / jse:,.1f}x** |"
        )
    lines.append(
        f"| gym wrapper alone | NavGymEnv, random actions from Python | {sb3['gym_env_steps_per_s']:,.0f} steps/s | |"
    )
    lines.append(
        f"| train, 1 robot | SB3 DDPG via NavGymEnv ({sb3['steps']} steps after warm-up, torch threads "
        f"{sb3['torch_threads']}) | {sb3['agent_steps_per_s']:,.0f} agent-steps/s, "
        f"{sb3['agent_updates_per_s']:,.1f} agent-updates/s | 1x |"
    )
    for label, r in (("fedjax_nav IDDPG, 1 robot, train-0", one), ("fedjax_nav FLDDPG, 5 robots (thesis)", five)):
        lines.append(
            f"| train, {r['robots']} robot(s) | {label}: one 1024-step episode after compile "
            f"({r['compile_s_incl_first_chunk']:.1f} s) | {r['agent_steps_per_s']:,.0f} agent-steps/s, "
            f"{r['agent_updates_per_s']:,.1f} agent-updates/s | "
            f"**{r['agent_steps_per_s'] / sb3['agent_steps_per_s']:,.1f}x** steps, "
            f"{r['agent_updates_per_s'] / sb3['agent_updates_per_s']:,.1f}x updates |"
        )
    table = "| what | setting | result | ratio (fedjax_nav / peer) |\n|---|---|---|---|\n" + "\n".join(lines)

    # Where the time goes, per 5 env steps + 1 gradient step (one T_train cycle of one robot)
    sb3_cycle = 5 / sb3["agent_steps_per_s"]
    sb3_env, sb3_pred, sb3_upd = 5 / sb3["gym_env_steps_per_s"], 5 * sb3["predict_s"], sb3["update_s"]
    ours_cycle = 5 / one["agent_steps_per_s"]
    ms = lambda x: f"{1e3 * x:.2f} ms"  # noqa: E731
    pct = lambda x, tot: f"{100 * x / tot:.0f}%"  # noqa: E731
    prof = [
        f"| SB3 DDPG | whole cycle (measured above) | {ms(sb3_cycle)} | 100% |",
        f"| SB3 DDPG | 1 gradient step alone (`model.train`, torch) | {ms(sb3_upd)} | {pct(sb3_upd, sb3_cycle)} |",
        f"| SB3 DDPG | 5 env steps through NavGymEnv (jitted NavEnv + host copies) | {ms(sb3_env)} | "
        f"{pct(sb3_env, sb3_cycle)} |",
        f"| SB3 DDPG | 5 policy calls (`model.predict`) | {ms(sb3_pred)} | {pct(sb3_pred, sb3_cycle)} |",
        f"| SB3 DDPG | the rest (SB3's Python loop: buffer, callbacks, logging) | "
        f"{ms(sb3_cycle - sb3_upd - sb3_env - sb3_pred)} | "
        f"{pct(sb3_cycle - sb3_upd - sb3_env - sb3_pred, sb3_cycle)} |",
        f"| fedjax_nav IDDPG, 1 robot | whole cycle (measured above) | {ms(ours_cycle)} | 100% |",
        f"| fedjax_nav IDDPG, 1 robot | 1 gradient step alone (sample + update, jitted scan) | {ms(jax_update_s)} | "
        f"{pct(jax_update_s, ours_cycle)} |",
        f"| fedjax_nav IDDPG, 1 robot | the rest (5 x act + env step + buffer add, in the scan) | "
        f"{ms(ours_cycle - jax_update_s)} | {pct(ours_cycle - jax_update_s, ours_cycle)} |",
        f"| ratio | gradient step alone, torch (SB3) / JAX | **{sb3_upd / jax_update_s:.1f}x** | |",
        f"| ratio | SB3's whole cycle / fedjax_nav's gradient step alone (the most the 1-robot ratio reaches "
        f"without a faster update) | "
        f"**{sb3_cycle / jax_update_s:.1f}x** | |",
    ]
    prof_table = (
        "| who | part of one T_train cycle (5 env steps + 1 gradient step) | time | share |\n"
        "|---|---|---|---|\n" + "\n".join(prof)
    )
    table += "\n\nWhere the time goes (same run):\n\n" + prof_table
    print(table)
    print(f"load average before {load_before}, after {load_after}; {time.perf_counter() - t_start:.0f} s")

    if args.record:
        from importlib.metadata import version

        import gymnasium
        import jaxmarl
        import stable_baselines3
        import torch

        versions = (
            f"jaxmarl {version('jaxmarl')}, stable-baselines3 {stable_baselines3.__version__}, "
            f"torch {torch.__version__}, gymnasium {gymnasium.__version__}"
        )
        del jaxmarl
        cmd = " ".join(["python", *sys.argv])
        with open(args.record, "a") as f:
            f.write(
                f"\n### {time.strftime('%Y-%m-%d %H:%M', time.gmtime())} — peers\n\n"
                f"Command: `{cmd}`\n\nMachine: {bench.machine()}; {versions}. Load average (1/5/15 min) "
                f"before {load_before}, after {load_after} (a shared machine: the ratios come from one run).\n\n"
                "Same task for the training rows: room train-0, one robot, 64x3 actor and critic, batch 512, one "
                "gradient step every 5 env steps, buffer 10k, gamma 0.9, lr 1e-3, hard target copies (SB3: tau=1); "
                "SB3 learning_starts=512, no action noise; fedjax_nav's first episode (compiled, with its own 512-row "
                "warm-up) is not timed. JaxNav: 1 agent, 24 beams, max range 3.5 m, random actions, batch 4096 over "
                "20 (`step`) / 50 (`step_env`) steps, batch 1 over 200.\n\n"
                f"{table}\n"
            )
        print(f"appended to {args.record}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
