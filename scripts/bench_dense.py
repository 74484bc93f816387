"""Dense rooms: compile time, throughput and peak memory of one env step's geometry.

One "step" per pose = one lidar cast (24 beams, 3.5 m) + one `nearest_distance`, as
`NavEnv.step` does, jitted and vmapped over a batch of poses (4096 by default). Rooms:

- thesis: the thesis's five training rooms, stacked (48 segments + 12 circles after padding:
  the unrolled path);
- dense:  five 12 x 12 m rooms, each with 150 random cylinders and 50 random boxes (4 segments
  each) inside the 4 walls: 204 segments + 150 circles = 354 rows (the chunked path);
- cyl1000: one 20 x 20 m room with 1,000 random cylinders (4 segments + 1,000 circles).

Two layouts of the same batch:
- shared:   vmap over rooms of vmap over poses, the room's arrays shared by its poses
            (in_axes=None), e.g. evaluation, or seeds sharing their robots' rooms;
- per-pose: every pose carries its own copy of its room's arrays (in_axes=0), the layout of
            `fedjax-nav bench env` and of a per-robot vmap.

Programs: the default (`method="auto"`: unrolled for the thesis rooms, chunked above 80 rows) and,
in the rooms above 80 rows, `method="culled"` (fedjax_nav/env/cull.py) beside it in the same run.

Throughput is timed in one process with the variants alternated, `--repeats` times, median
reported (the machine is shared). Compile time and peak memory come from one fresh subprocess per
variant (no compilation cache): its peak RSS while compiling and running once (VmHWM, reset just
before compiling), and how much that is above its RSS before compiling.

    python scripts/bench_dense.py                      # the table of docs/dense_rooms.md (+ culled rows)
    python scripts/bench_dense.py --old                # + the unrolled program on dense rooms
    python scripts/bench_dense.py --sweep              # unrolled vs chunked by row count
    python scripts/bench_dense.py --record docs/dense_rooms.md

The procedural families' env step (forest, warehouse, maze, cave against a sparse family):
scripts/bench_dense_families.py, which reuses this script's geometry, timing and report helpers.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import time

os.environ.setdefault("JAX_PLATFORMS", "cpu")

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

jax.config.update("jax_enable_compilation_cache", False)

from fedjax_nav import worlds  # noqa: E402
from fedjax_nav.env import geometry  # noqa: E402

NUM_BEAMS, MAX_RANGE = 24, 3.5
ROOMS = ("thesis", "dense", "cyl1000")
LAYOUTS = ("shared", "per-pose")


# ----------------------------------------------------------------------------- rooms


def random_room(seed: int, size: float, cylinders: int, boxes: int, radius=(0.05, 0.2), box_size=(0.2, 0.6)):
    """A room through `worlds.from_dict` (validated like a user's file): random cylinders and
    boxes anywhere inside the walls (they may overlap each other), one start, one goal."""
    rng = np.random.default_rng(seed)
    half = size / 2
    circ = np.c_[rng.uniform(-half + 0.3, half - 0.3, (cylinders, 2)), rng.uniform(*radius, cylinders)]
    bxs = np.c_[
        rng.uniform(-half + 0.5, half - 0.5, (boxes, 2)),
        rng.uniform(*box_size, (boxes, 2)),
        rng.uniform(0, np.pi, boxes),
    ]
    segs = np.concatenate(
        [worlds.wall_segments([size, size]).reshape(-1, 4)] + [worlds.box_segments(*b).reshape(-1, 4) for b in bxs]
    )

    def clearance(p):
        d_seg = worlds.point_segment_distance_np(p, segs).min()
        d_circ = (np.hypot(*(p - circ[:, :2]).T) - circ[:, 2]).min() if cylinders else np.inf
        inside_box = any(_in_box(p, b) for b in bxs)
        return -1.0 if inside_box else min(d_seg, d_circ)

    points = []
    while len(points) < 2:
        p = rng.uniform(-half + 0.5, half - 0.5, 2)
        if clearance(p) > worlds.CLEARANCE + 0.05:
            points.append(p)
    spec = {
        "size": [size, size],
        "circles": circ.tolist(),
        "boxes": bxs.tolist(),
        "starts": [[*points[0], 0.0]],
        "goals": [list(points[1])],
    }
    world, _ = worlds.from_dict(spec, f"<random room {seed}>")
    return world


def _in_box(p, box):
    cx, cy, sx, sy, yaw = box
    c, s = np.cos(yaw), np.sin(yaw)
    dx, dy = p[0] - cx, p[1] - cy
    return abs(c * dx + s * dy) <= sx / 2 and abs(-s * dx + c * dy) <= sy / 2


def build_rooms(name: str):
    """Stacked rooms (leading room axis) and their half-size for drawing poses."""
    if name == "thesis":
        return worlds.load_many(worlds.THESIS_TRAIN)
    if name == "dense":
        return worlds.stack([random_room(seed, 12.0, 150, 50) for seed in range(5)])
    if name == "cyl1000":
        return worlds.stack([random_room(0, 20.0, 1000, 0, radius=(0.05, 0.15))])
    raise ValueError(name)


def rows_of(stacked) -> tuple[int, int]:
    return int(stacked.segments.shape[1]), int(stacked.circles.shape[1])


# ----------------------------------------------------------------------------- the timed program


def step_geometry(segments, pose, circles, method="auto"):
    """One env step's geometry for one pose: the cast and the clearance."""
    ranges = geometry.lidar(segments, pose, NUM_BEAMS, MAX_RANGE, circles, method=method)
    return ranges, geometry.nearest_distance(segments, pose[:2], circles, method=method)


def make_case(room: str, layout: str, batch: int, method: str = "auto", stacked=None):
    """(jitted fn, args) for `batch` random poses spread over the room's stack."""
    stacked = stacked if stacked is not None else build_rooms(room)
    n_rooms = stacked.segments.shape[0]
    per_room = -(-batch // n_rooms)
    rng = np.random.default_rng(1)
    half = np.asarray(stacked.size, np.float64)[:, None, :] / 2  # [R, 1, 2]
    xy = rng.uniform(-1.0, 1.0, (n_rooms, per_room, 2)) * (half - 0.3)
    poses = np.concatenate([xy, rng.uniform(-np.pi, np.pi, (n_rooms, per_room, 1))], -1).astype(np.float32)
    fn = lambda s, p, c: step_geometry(s, p, c, method)  # noqa: E731
    if layout == "shared":
        f = jax.jit(jax.vmap(jax.vmap(fn, (None, 0, None))))
        args = (stacked.segments, jnp.asarray(poses), stacked.circles)
    else:
        idx = np.repeat(np.arange(n_rooms), per_room)
        f = jax.jit(jax.vmap(fn))
        args = (stacked.segments[idx], jnp.asarray(poses.reshape(-1, 3)), stacked.circles[idx])
    return f, args


def compile_seconds(f, args) -> float:
    t0 = time.perf_counter()
    f.lower(*args).compile()
    return time.perf_counter() - t0


def maxrss_mb() -> float:
    """Peak resident memory of this process so far (VmHWM; ru_maxrss where /proc is missing)."""
    return _proc_status_mb(os.getpid(), "VmHWM") or resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def rss_mb() -> float:
    return _proc_status_mb(os.getpid(), "VmRSS")


def reset_peak_rss() -> None:
    """Make the peak RSS (VmHWM) restart from the current RSS (Linux >= 4.0)."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
    except OSError:
        pass


# ----------------------------------------------------------------------------- child: compile + memory


def _variant(room: str, layout: str, method: str) -> dict:
    return {"room": room, "layout": layout, "method": method}


def child(room: str, layout: str, batch: int, method: str) -> dict:
    f, args = make_case(room, layout, batch, method)
    jax.block_until_ready(args)
    before = rss_mb()
    reset_peak_rss()
    t0 = time.perf_counter()
    compiled = f.lower(*args).compile()
    c = time.perf_counter() - t0
    t0 = time.perf_counter()
    jax.block_until_ready(compiled(*args))
    first = time.perf_counter() - t0
    return {
        **_variant(room, layout, method),
        "compile_s": c,
        "first_call_s": first,
        "rss_before_mb": before,
        "rss_peak_mb": maxrss_mb(),
    }


def run_child(room: str, layout: str, batch: int, method: str, timeout: float, rss_cap_mb: float = 1e9) -> dict:
    """Run `child` in a fresh interpreter. Killed after `timeout` s or above `rss_cap_mb` of
    resident memory (the machine is shared), reporting how far it got (peak RSS, VmHWM)."""
    cmd = [sys.executable, __file__, "--child", room, layout, method, "--batch", str(batch)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    t0, hwm = time.perf_counter(), 0.0
    while proc.poll() is None:
        hwm = max(hwm, _vm_hwm_mb(proc.pid))
        elapsed = time.perf_counter() - t0
        if elapsed > timeout or hwm > rss_cap_mb:
            proc.kill()
            proc.wait()
            return {
                **_variant(room, layout, method),
                "killed_after_s": elapsed,
                "killed_for": "time" if elapsed > timeout else "memory",
                "rss_peak_mb": hwm,
            }
        time.sleep(0.1)
    out, err = proc.communicate()
    if proc.returncode != 0:
        raise RuntimeError(f"child {room} {layout} {method} failed:\n{err[-2000:]}")
    return json.loads(out.strip().splitlines()[-1])


def _vm_hwm_mb(pid: int) -> float:
    return _proc_status_mb(pid, "VmHWM")


def _proc_status_mb(pid: int, field: str) -> float:
    try:
        with open(f"/proc/{pid}/status") as fh:
            for line in fh:
                if line.startswith(field + ":"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return 0.0


# ----------------------------------------------------------------------------- throughput, alternated


def throughput(cases: dict, repeats: int) -> tuple[dict, dict]:
    """cases: key -> (f, args), all compiled first; then `repeats` rounds over all keys.
    Returns the median wall time and the median CPU time (all threads of this process) of one
    call per key. On a shared machine the CPU time moves less with other jobs' load than the
    wall time does, so it is the steadier basis for comparing two programs."""
    for f, args in cases.values():
        jax.block_until_ready(f(*args))
    wall, cpu = {k: [] for k in cases}, {k: [] for k in cases}
    for _ in range(repeats):
        for k, (f, args) in cases.items():
            t0, c0 = time.perf_counter(), time.process_time()
            jax.block_until_ready(f(*args))
            wall[k].append(time.perf_counter() - t0)
            cpu[k].append(time.process_time() - c0)
    return ({k: statistics.median(v) for k, v in wall.items()}, {k: statistics.median(v) for k, v in cpu.items()})


# ----------------------------------------------------------------------------- the threshold sweep


def sweep(batch: int, repeats: int, counts=(32, 48, 64, 80, 96, 128, 192)) -> list[str]:
    """Unrolled vs chunked by row count: 12 x 12 m rooms of boxes and cylinders, 4 rows of boxes
    for every 3 cylinders (like the dense rooms), per-pose layout."""
    lines = [
        "| rows (M + C) | compile s: unrolled | chunked | steps/s: unrolled | chunked "
        "| steps per CPU-s: unrolled | chunked |",
        "|---|---|---|---|---|---|---|",
    ]
    for n in counts:
        n_boxes = max(0, round((n - 4) * 4 / 7 / 4))
        n_cyl = max(0, n - 4 - 4 * n_boxes)
        stacked = worlds.stack([random_room(7, 12.0, n_cyl, n_boxes)])
        cases, comp = {}, {}
        for method in ("unrolled", "chunked"):
            f, args = make_case("", "per-pose", batch, method, stacked=stacked)
            comp[method] = compile_seconds(f, args)
            cases[method] = (f, args)
        t, cpu = throughput(cases, repeats)
        m, c = rows_of(stacked)
        lines.append(
            f"| {m + c} ({m} + {c}) | {comp['unrolled']:.2f} | {comp['chunked']:.2f} | "
            f"{batch / t['unrolled']:,.0f} | {batch / t['chunked']:,.0f} | "
            f"{batch / cpu['unrolled']:,.0f} | {batch / cpu['chunked']:,.0f} |"
        )
        print(lines[-1], flush=True)
    return lines


# ----------------------------------------------------------------------------- main


def machine() -> str:
    try:
        lines = subprocess.run(["lscpu"], capture_output=True, text=True).stdout.splitlines()
        model = next((ln.split(":", 1)[1].strip() for ln in lines if ln.startswith("Model name")), platform.processor())
    except OSError:
        model = platform.processor()
    return (
        f"{model}, {os.cpu_count()} cores (shared), load average {os.getloadavg()[0]:.2f}; "
        f"jax {jax.__version__}, python {platform.python_version()}"
    )


def report_head(script: str, argv=None) -> list[str]:
    """The first lines of a benchmark's report: the command line (argv: this process's by default)
    and the machine."""
    cmd = " ".join(argv if argv is not None else sys.argv[1:])
    return [f"Command: `python scripts/{script} {cmd}`".rstrip(), "", f"Machine: {machine()}", ""]


def report_end(out: list[str], script: str, record: str | None) -> None:
    """The load average after the run closes the report `out`; printed, and appended to the
    markdown file `record` (if given) under a dated heading naming `script`."""
    out.append(f"\nLoad average after: {os.getloadavg()[0]:.2f}")
    text = "\n".join(out)
    print(text)
    if record:
        with open(record, "a") as fh:
            fh.write(f"\n### {time.strftime('%Y-%m-%d %H:%M')} — `scripts/{script}`\n\n{text}\n")


def methods_of(stacked, no_culled: bool) -> list[str]:
    """The programs timed in a room: the default (auto), and the culled one where auto chunks."""
    m, c = rows_of(stacked)
    return ["auto"] + ([] if no_culled or m + c <= geometry.UNROLL_MAX_ROWS else ["culled"])


def table_row(variant, stacked, batch: int, t: dict, cpu: dict, mem: dict) -> str:
    """One row of the main table; ratios against the thesis rooms' default program, same layout."""
    r, lay, meth = variant
    m, c = rows_of(stacked)
    path = meth if meth != "auto" else ("unrolled" if m + c <= geometry.UNROLL_MAX_ROWS else "chunked")
    ref = ("thesis", lay, "auto")
    rel = f"{t[ref] / t[variant]:.2f}x" if ref in t else ""
    rel_cpu = f"{cpu[ref] / cpu[variant]:.2f}x" if ref in cpu else ""
    mm = mem.get(variant)
    if mm is None:
        comp, rss = "", ""
    elif "killed_for" in mm:
        comp, rss = f"killed ({mm['killed_for']})", f"{mm['rss_peak_mb']:.0f}"
    else:
        comp = f"{mm['compile_s']:.2f}"
        rss = f"{mm['rss_peak_mb']:.0f} (+{mm['rss_peak_mb'] - mm['rss_before_mb']:.0f})"
    return (
        f"| {r} | {m + c} ({m} + {c}) | {path} | {lay} | {comp} | {batch / t[variant]:,.0f} | {rel} | "
        f"{batch / cpu[variant]:,.0f} | {rel_cpu} | {rss} |"
    )


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--batch", type=int, default=4096)
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--rooms", default=",".join(ROOMS))
    ap.add_argument("--layouts", default=",".join(LAYOUTS))
    ap.add_argument("--no-memory", action="store_true", help="skip the compile/memory subprocesses")
    ap.add_argument("--no-culled", action="store_true", help="skip the culled program's rows")
    ap.add_argument(
        "--old",
        action="store_true",
        help="also compile the unrolled program on the dense and 1,000-cylinder rooms (subprocesses)",
    )
    ap.add_argument("--old-timeout", type=float, default=300.0, help="s; kill an unrolled compile after this")
    ap.add_argument("--old-rss-cap", type=float, default=4000.0, help="MB; kill an unrolled compile above this")
    ap.add_argument("--sweep", action="store_true", help="unrolled vs chunked by row count (threshold)")
    ap.add_argument("--record", metavar="FILE", help="append the tables to FILE (markdown)")
    ap.add_argument("--child", nargs=3, metavar=("ROOM", "LAYOUT", "METHOD"), help=argparse.SUPPRESS)
    a = ap.parse_args(argv)

    if a.child:
        room, layout, method = a.child
        print(json.dumps(child(room, layout, a.batch, method)))
        return

    rooms, layouts = a.rooms.split(","), a.layouts.split(",")
    out = report_head("bench_dense.py", argv)

    stacks = {r: build_rooms(r) for r in rooms}
    variants = [(r, lay, meth) for r in rooms for meth in methods_of(stacks[r], a.no_culled) for lay in layouts]
    cases = {v: make_case(v[0], v[1], a.batch, v[2], stacked=stacks[v[0]]) for v in variants}
    t, cpu = throughput(cases, a.repeats)
    mem = {} if a.no_memory else {v: run_child(*v[:2], a.batch, v[2], timeout=600.0) for v in variants}
    out += [
        f"Batch {a.batch} poses; one step = one {NUM_BEAMS}-beam cast + one nearest_distance per pose; "
        f"median of {a.repeats} alternated repeats (wall time, and CPU time of all threads); vs thesis: "
        "same layout. Compile and peak RSS: one fresh process per row (peak RSS while compiling and running "
        'once; in brackets: above the RSS before compiling). Path culled: `method="culled"` '
        '(docs/dense_rooms.md, "Culling per tile"), bitwise the chunked loop.',
        "",
        "| room | rows (M + C) | path | layout | compile s | steps/s | vs thesis | steps per CPU-s | vs thesis "
        "| peak RSS MB (+ over before) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    out += [table_row(v, stacks[v[0]], a.batch, t, cpu, mem) for v in variants]
    if a.old:
        out += [
            "",
            "The unrolled program (the code before the chunked path) on the same rooms, per-pose layout:",
            "",
            "| room | rows | compile s | peak RSS MB (+ over before) |",
            "|---|---|---|---|",
        ]
        for r in [r for r in rooms if r != "thesis"]:
            mm = run_child(r, "per-pose", a.batch, "unrolled", timeout=a.old_timeout, rss_cap_mb=a.old_rss_cap)
            m, c = rows_of(stacks[r])
            if "killed_for" in mm:
                out.append(
                    f"| {r} | {m + c} | not compiled: killed after {mm['killed_after_s']:.0f} s "
                    f"({mm['killed_for']} limit) | {mm['rss_peak_mb']:.0f} when killed |"
                )
            else:
                out.append(
                    f"| {r} | {m + c} | {mm['compile_s']:.2f} | {mm['rss_peak_mb']:.0f} "
                    f"(+{mm['rss_peak_mb'] - mm['rss_before_mb']:.0f}) |"
                )
            print(out[-1], flush=True)
    if a.sweep:
        out += ["", f"Threshold sweep (per-pose layout, batch {a.batch}, median of {a.repeats}):", ""]
        out += sweep(a.batch, a.repeats)
    report_end(out, "bench_dense.py", a.record)


if __name__ == "__main__":
    main()
