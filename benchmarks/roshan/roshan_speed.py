"""ROSHAN solver speed: batch (vmap vs a loop of jitted solves vs GTSAM) and online latency.

(a) Batch: N simulated Forward maps (``jaxsem.slam.sim.quadricslam_config("forward")``: 10 cars,
    60 frames) solved with the structured (Schur) LM, ``jax.vmap`` over maps vs a Python loop of
    jitted per-map solves, and GTSAM LM on the first few maps with the same factors (pose priors +
    box factors, QuadricSLAM's factor set: a Python ``CustomFactor`` box factor with numeric
    Jacobians). Final cost is evaluated with ``jaxsem.slam.total_cost`` for every system.
(b) Online: per-frame latency of ``online_update`` on a Forward sequence (default 300 frames,
    20 objects), median and 95th percentile, the first (compiling) call reported apart.

Run: ``python benchmarks/roshan/roshan_speed.py`` (``--help`` for sizes and seeds).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import sys
import time

import jax

from jaxsem.slam._batch import damped_schur_step, solve_schur  # layers: white-box
from jaxsem.slam._cost import linearize, retract_object, retract_pose  # layers: white-box
from jaxsem.slam._problem import bucket_capacity, compact_boxes  # layers: white-box
from jaxsem.slam._toy import frames_from_problem  # layers: white-box

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from jaxsem import factors as F, slam  # noqa: E402
from jaxsem.slam import sim  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
BENCH = HERE.parent  # benchmarks/: the shared results folder and _harness
sys.path.insert(0, str(BENCH))
import _harness  # noqa: E402


def _median_time(fn, repeats):
    """Median seconds of ``repeats`` calls of ``fn()`` (no warm-up: the callers warm up)."""
    return _harness.median_time(fn, repeats=repeats, warmup=False)


# ---------------------------------------------------------------------------------------------
# GTSAM peer (numpy box model, numeric Jacobians).


def _np_box(pose, rotvec, center, radii, K):
    th = np.linalg.norm(rotvec)
    k = rotvec / th if th > 1e-12 else np.zeros(3)
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    R = np.eye(3) + np.sin(th) * Kx + (1 - np.cos(th)) * Kx @ Kx
    Z = np.eye(4)
    Z[:3, :3], Z[:3, 3] = R, center
    Qs = Z @ np.diag([*(radii**2), -1.0]) @ Z.T
    P = K @ pose[:3]
    Cs = P @ Qs @ P.T
    near = (pose[:3, :3] @ center + pose[:3, 3])[2] - np.linalg.norm(radii * (pose[:3, :3] @ R)[2])
    du = Cs[0, 2] ** 2 - Cs[0, 0] * Cs[2, 2]
    dv = Cs[1, 2] ** 2 - Cs[1, 1] * Cs[2, 2]
    if near <= 0 or du < 0 or dv < 0:
        return None
    u = (Cs[0, 2] + np.array([1, -1]) * np.sqrt(du)) / Cs[2, 2]
    v = (Cs[1, 2] + np.array([1, -1]) * np.sqrt(dv)) / Cs[2, 2]
    return np.array([u.min(), v.min(), u.max(), v.max()])


def gtsam_solve(problem, init, cfg, max_iterations=20):
    """Pose priors + box factors (edge masks as ours; constant 1000 px when degenerate, as
    QuadricSLAM does) with GTSAM's LM. Ellipsoids are Vector9 ``[rotvec, center, softplus^-1 r]``."""
    import gtsam

    K = np.asarray(problem.K)
    W, H = np.asarray(problem.image_size)
    n = cfg.noise
    sig = float(n.box_sigma)
    margin = float(cfg.border_margin)
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    X = lambda t: gtsam.symbol("x", t)
    L = lambda j: gtsam.symbol("l", j)
    prior_noise = gtsam.noiseModel.Diagonal.Sigmas(
        np.array([n.pose_rotation_sigma] * 3 + [n.pose_translation_sigma] * 3, float)
    )
    pm = np.asarray(problem.pose_mask)
    for t in np.flatnonzero(pm):
        graph.add(gtsam.PriorFactorPose3(X(t), gtsam.Pose3(np.asarray(problem.pose_prior[t])), prior_noise))
        values.insert(X(t), gtsam.Pose3(np.asarray(init.camera_T_world[t])))
    om = np.asarray(problem.object_mask)
    for j in np.flatnonzero(om):
        rv = (
            gtsam.Rot3(np.asarray(init.rotation[j])).ravel()
            if False
            else gtsam.Rot3.Logmap(gtsam.Rot3(np.asarray(init.rotation[j])))
        )
        s = np.asarray(F.param_from_radii(init.radii[j]))
        values.insert(L(j), np.concatenate([rv, np.asarray(init.center[j]), s]))
    unit = gtsam.noiseModel.Unit.Create(4)

    def make(meas, mask):
        def err(this, vals, H_list):
            key_p, key_l = this.keys()
            pose = vals.atPose3(key_p)
            vec = vals.atVector(key_l)

            def f(pose_m, v):
                b = _np_box(pose_m, v[:3], v[3:6], np.logaddexp(0, v[6:9]), K)
                if b is None:
                    return np.full(4, 1000.0 / sig) * mask
                return (b - meas) / sig * mask

            e0 = f(pose.matrix(), vec)
            if H_list is not None:
                h = 1e-6
                Jp = np.zeros((4, 6))
                for i in range(6):
                    d = np.zeros(6)
                    d[i] = h
                    Jp[:, i] = (f(pose.retract(d).matrix(), vec) - f(pose.retract(-d).matrix(), vec)) / (2 * h)
                Jl = np.zeros((4, 9))
                for i in range(9):
                    d = np.zeros(9)
                    d[i] = h
                    Jl[:, i] = (f(pose.matrix(), vec + d) - f(pose.matrix(), vec - d)) / (2 * h)
                H_list[0] = Jp
                H_list[1] = Jl
            return e0

        return err

    box = np.asarray(problem.box)
    bm = np.asarray(problem.box_mask)
    for m in np.flatnonzero(bm):
        b = box[m]
        mask = np.array([b[0] > margin, b[1] > margin, b[2] < W - margin, b[3] < H - margin], float)
        graph.add(gtsam.CustomFactor(unit, [X(int(problem.box_pose[m])), L(int(problem.box_object[m]))], make(b, mask)))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    t0 = time.perf_counter()
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    elapsed = time.perf_counter() - t0
    poses = np.array(init.camera_T_world)
    for t in np.flatnonzero(pm):
        poses[t] = result.atPose3(X(t)).matrix()
    R, c, r = np.array(init.rotation), np.array(init.center), np.array(init.radii)
    for j in np.flatnonzero(om):
        v = result.atVector(L(j))
        R[j] = gtsam.Rot3.Expmap(v[:3]).matrix()
        c[j] = v[3:6]
        r[j] = np.logaddexp(0, v[6:9])
    est = slam.SlamEstimate(jnp.asarray(poses), jnp.asarray(R), jnp.asarray(c), jnp.asarray(r))
    return est, elapsed


# ---------------------------------------------------------------------------------------------


def batch_benchmark(args):
    sim_cfg = sim.quadricslam_config("forward")
    maps = sim.simulate_batch(args.seed, args.maps, sim_cfg)
    problems = sim.to_problem(maps, sim_cfg)
    # Real boxes first, padding trimmed to the batch's power-of-two bucket (600 -> 256 slots).
    most = int(np.max(np.asarray(problems.box_mask.sum(-1))))
    slots = min(int(problems.box.shape[-2]), bucket_capacity(1, most, 1)[1])
    problems = compact_boxes(problems, slots)
    inits = sim.initial_estimate(maps)
    # QuadricSLAM's factor set (pose priors + box factors) so that GTSAM solves the same cost.
    cfg = sim.solver_config("baseline", sim_cfg, max_steps=args.max_steps, baseline_shape_weight=0.0)
    solve = lambda p, i: solve_schur(p, i, cfg)
    vm = jax.jit(jax.vmap(solve))
    one = jax.jit(solve)
    t = time.perf_counter()
    jax.block_until_ready(vm(problems, inits))
    compile_vmap = time.perf_counter() - t
    take = lambda tree, k: jax.tree_util.tree_map(lambda x: x[k], tree)
    t = time.perf_counter()
    jax.block_until_ready(one(take(problems, 0), take(inits, 0)))
    compile_one = time.perf_counter() - t
    many = jax.jit(lambda p, i: slam.solve_many(p, i, cfg, strategy="map"))
    t = time.perf_counter()
    jax.block_until_ready(many(problems, inits))
    compile_many = time.perf_counter() - t
    singles = [(take(problems, k), take(inits, k)) for k in range(args.maps)]
    # Interleaved: vmap, loop, solve_many in turn, medians of each.
    t_vmap, t_loop, t_many = [], [], []
    for _ in range(args.repeats):
        t_vmap.append(_median_time(lambda: vm(problems, inits), 1))
        t_loop.append(_median_time(lambda: [one(p, i) for p, i in singles], 1))
        t_many.append(_median_time(lambda: many(problems, inits), 1))
    t_vmap, t_loop, t_many = (float(np.median(v)) for v in (t_vmap, t_loop, t_many))
    est_m, info_m = many(problems, inits)
    est_v, info_v = vm(problems, inits)
    cost_jax = np.asarray(info_v.cost)
    # Each member's vmapped answer against its solo solve (rounding of batched arithmetic only;
    # a member's carry is frozen once it stops).
    dev, same_steps, dev_many = [], 0, []
    for k, (p, i) in enumerate(singles):
        e, inf = one(p, i)
        dev.append(float(jnp.max(jnp.abs(e.center - est_v.center[k]))))
        dev_many.append(float(jnp.max(jnp.abs(e.center - est_m.center[k]))))
        same_steps += int(int(inf.steps) == int(info_v.steps[k]))
    steps = np.asarray(info_v.steps)
    rows = {
        "jaxsem vmap (Schur LM)": dict(
            ms_per_map=1e3 * t_vmap / args.maps, median_final_cost=float(np.median(cost_jax)), compile_s=compile_vmap
        ),
        "jaxsem loop of jitted solves": dict(
            ms_per_map=1e3 * t_loop / args.maps, median_final_cost=float(np.median(cost_jax)), compile_s=compile_one
        ),
        "jaxsem solve_many (strategy 'map', the CPU default)": dict(
            ms_per_map=1e3 * t_many / args.maps,
            median_final_cost=float(np.median(np.asarray(info_m.cost))),
            compile_s=compile_many,
        ),
    }
    rows["_vmap_vs_loop"] = dict(
        loop_over_vmap=t_loop / t_vmap,
        box_slots=slots,
        median_trial_steps=float(np.median(steps)),
        max_trial_steps=int(steps.max()),
        max_center_dev_m=float(np.max(dev)),
        median_center_dev_m=float(np.median(dev)),
        members_same_steps=same_steps,
        many_over_loop=t_many / t_loop,
        many_max_center_dev_m=float(np.max(dev_many)),
    )
    rows["_components"] = component_times(problems, inits, cfg, args)
    if not args.skip_gtsam:
        g_costs, g_times, j_costs = [], [], []
        for k in range(min(args.gtsam_maps, args.maps)):
            p, i = singles[k]
            est, el = gtsam_solve(p, i, cfg)
            g_times.append(el)
            g_costs.append(float(slam.total_cost(p, est, cfg)))
            j_costs.append(float(cost_jax[k]))
        rows["GTSAM LM (Python CustomFactor)"] = dict(
            ms_per_map=1e3 * float(np.median(g_times)),
            median_final_cost=float(np.median(g_costs)),
            compile_s=0.0,
            maps=len(g_costs),
            jaxsem_median_cost_same_maps=float(np.median(j_costs)),
        )
    return rows


def component_times(problems, inits, cfg, args):
    """Why vmap does not beat the loop: the pieces of one LM iteration timed on one map and per
    map vmapped over all of them (ms), and a fixed number of identical iterations (no control
    flow that could diverge between members), single vs vmapped."""
    n = args.maps
    take = lambda tree, k: jax.tree_util.tree_map(lambda x: x[k], tree)
    p0, e0 = take(problems, 0), take(inits, 0)
    free = lambda p: p.pose_mask.astype(p.pose_prior.dtype)
    lin = lambda p, e: linearize(p, e, cfg, free(p))
    step = lambda p, nrm: damped_schur_step(nrm, jnp.asarray(1e-3, nrm.Hpp.dtype), free(p), p.object_mask)
    cost = lambda p, e: slam.total_cost(p, e, cfg)

    def fixed(p, e):
        def body(_, est):
            nrm = lin(p, est)
            dp, do = step(p, nrm)
            R, c, r = retract_object(est.rotation, est.center, est.radii, 1e-3 * do)
            est = slam.SlamEstimate(retract_pose(est.camera_T_world, 1e-3 * dp), R, c, r)
            return jax.tree_util.tree_map(lambda x: x + 0 * cost(p, est), est)

        return jax.lax.fori_loop(0, args.fixed_iterations, body, e)

    out = {}
    n0, nv = jax.jit(lin)(p0, e0), jax.jit(jax.vmap(lin))(problems, inits)
    for name, f, a1, av in (
        ("linearize", lin, (p0, e0), (problems, inits)),
        ("damped Schur step", step, (p0, n0), (problems, nv)),
        ("cost", cost, (p0, e0), (problems, inits)),
        (f"{args.fixed_iterations} fixed iterations", fixed, (p0, e0), (problems, inits)),
    ):
        one, many = jax.jit(f), jax.jit(jax.vmap(f))
        reps = 3 if "fixed" in name else 20
        out[name] = dict(
            single_ms=1e3 * _median_time(lambda: one(*a1), reps),
            vmap_ms_per_map=1e3 * _median_time(lambda: many(*av), max(reps // 4, 2)) / n,
        )
    return out


def online_benchmark(args):
    problem, truth = slam.toy_map(
        args.seed, num_objects=args.online_objects, num_frames=args.online_frames, path="forward"
    )
    D = int(max(np.bincount(np.asarray(problem.box_pose)[np.asarray(problem.box_mask)]).max(), 1))
    frames = frames_from_problem(problem, max_detections=D)
    cap = slam.Capacity(
        max_poses=args.window, max_objects=args.online_objects, max_boxes=args.window * D, max_detections=D
    )
    cfg = slam.SolverConfig()
    state = slam.online_init(
        cfg, cap, problem.K, problem.image_size, optimize_every=args.optimize_every, iterations=args.iterations
    )
    lat = []
    t = time.perf_counter()
    state = slam.online_update(state, frames[0])
    jax.block_until_ready(state)
    first = time.perf_counter() - t
    compiled = []  # XLA compilations after the first frame (online_update runs one shared program)

    def listen(event, duration, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            compiled.append(duration)

    jax.monitoring.register_event_duration_secs_listener(listen)
    try:
        for f in frames[1:]:
            t = time.perf_counter()
            state = slam.online_update(state, f)
            jax.block_until_ready(state)
            lat.append(time.perf_counter() - t)
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    lat = np.array(lat) * 1e3
    est = slam.online_estimate(state)
    err = np.linalg.norm(np.asarray(est.center - truth.center), axis=-1)
    return dict(
        frames=len(frames),
        objects=args.online_objects,
        max_detections=D,
        window=args.window,
        optimize_every=args.optimize_every,
        iterations=args.iterations,
        median_ms=float(np.median(lat)),
        p95_ms=float(np.percentile(lat, 95)),
        max_ms=float(lat.max()),
        first_call_s=first,
        median_position_error_m=float(np.median(err)),
        recompiles=len(compiled),
    )


def cli_benchmark(args):
    """(c) ``python infer/roshan.py`` end to end on a 60-frame Forward map, run as a user runs
    it: ``args.cli_runs`` separate processes in a row with the persistent compilation cache on
    (the first may fill it; the rest are warm). Wall time from each run's summary.json."""
    import os
    import sys
    import tempfile

    root = BENCH.parent
    env = {**os.environ, "PYTHONPATH": str(root) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        seq = pathlib.Path(tmp) / "seq"
        base = [sys.executable, str(root / "infer" / "roshan.py"), "--quiet", "--out", str(pathlib.Path(tmp) / "out")]
        subprocess.run(
            base + ["--simulate", "forward", "--seed", str(args.seed), "--write-sequence", str(seq)]
            + ["--run-dir", str(pathlib.Path(tmp) / "run_sim")],
            check=True, env=env, capture_output=True,
        )  # fmt: skip
        for k in range(args.cli_runs):
            run_dir = pathlib.Path(tmp) / f"run{k}"
            out = subprocess.run(
                base + ["--sequence", str(seq), "--run-dir", str(run_dir)],
                check=True, env=env, capture_output=True, text=True,
            )  # fmt: skip
            summary = json.loads((run_dir / "summary.json").read_text())
            solved = next(line for line in out.stdout.splitlines() if line.startswith("solved in"))
            rows.append(dict(wall_s=float(summary["wall_seconds"]), solved=solved))
    load = os.getloadavg()
    return dict(runs=rows, load_average=[round(x, 1) for x in load])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--maps", type=int, default=50, help="number of Forward maps (batch part)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-steps", type=int, default=20, help="LM iterations per batch solve")
    ap.add_argument("--repeats", type=int, default=3, help="timed repeats (median)")
    ap.add_argument("--fixed-iterations", type=int, default=20, help="iterations of the lockstep-free component test")
    ap.add_argument("--gtsam-maps", type=int, default=3, help="maps solved by the GTSAM peer")
    ap.add_argument("--skip-gtsam", action="store_true")
    ap.add_argument("--online-frames", type=int, default=300)
    ap.add_argument("--online-objects", type=int, default=20)
    ap.add_argument("--window", type=int, default=60, help="pose slots of the online smoother")
    ap.add_argument("--optimize-every", type=int, default=5)
    ap.add_argument("--iterations", type=int, default=2, help="LM steps per online optimisation")
    ap.add_argument("--skip-batch", action="store_true")
    ap.add_argument(
        "--cli-runs",
        type=int,
        default=0,
        help="(c) run infer/roshan.py this many times on a 60-frame map (writes results/roshan_cli.md)",
    )
    ap.add_argument("--skip-online", action="store_true")
    args = ap.parse_args(argv)

    out = {
        "command": "python benchmarks/roshan/roshan_speed.py " + " ".join(argv or __import__("sys").argv[1:]),
        "date": subprocess.run(["date", "-u"], capture_output=True, text=True).stdout.strip(),
        "machine": "2-core CPU (shared, noisy)",
    }
    lines = []
    if args.cli_runs:
        c = cli_benchmark(args)
        walls = [r["wall_s"] for r in c["runs"]]
        warm = walls[1:] if len(walls) > 1 else walls
        met = "met" if np.median(warm) < 5 else "NOT met"
        md = [
            "### Online: `python infer/roshan.py` end to end (issue 12, part 5)",
            "",
            f"Command: `{out['command']}`  ",
            f"Date: {out['date']}  ",
            f"Machine: {out['machine']}; load average at the end {c['load_average']}",
            "",
            "A simulated 60-frame Forward map (seed "
            f"{args.seed}) saved as a sequence directory, then `infer/roshan.py --sequence ... --quiet` run "
            f"{args.cli_runs} times in a row, each a new process with the persistent compilation cache on "
            "(the first run may fill it). Wall time from each run's `summary.json` (imports, solve, figures "
            "and map file included).",
            "",
            "| run | wall (s) | solver line |",
            "|---|---|---|",
            *[f"| {k + 1} | {r['wall_s']:.2f} | {r['solved']} |" for k, r in enumerate(c["runs"])],
            "",
            f"Warm runs (2nd on): median {np.median(warm):.2f} s (target under 5 s: {met}).",
            "",
        ]
        out["cli"] = c
        (BENCH / "results" / "roshan_cli.json").write_text(json.dumps(c, indent=2))
        (BENCH / "results" / "roshan_cli.md").write_text("\n".join(md))
        print("\n".join(md))
        if args.skip_batch and args.skip_online:
            return
    if not args.skip_batch:
        rows = batch_benchmark(args)
        out["batch"] = rows
        base = rows["jaxsem vmap (Schur LM)"]["ms_per_map"]
        lines += [
            f"### Batch: {args.maps} Forward maps (QuadricSLAM setting: 10 cars, 60 frames)",
            "",
            "| system | ms / map | ratio to vmap | median final cost | compile (s) |",
            "|---|---|---|---|---|",
        ]
        vl = rows["_vmap_vs_loop"]
        for name, r in rows.items():
            if name.startswith("_"):
                continue
            extra = (
                f" ({r['maps']} maps; jaxsem on the same maps: {r['jaxsem_median_cost_same_maps']:.1f})"
                if "maps" in r
                else ""
            )
            lines.append(
                f"| {name} | {r['ms_per_map']:.1f} | {r['ms_per_map'] / base:.2f} | "
                f"{r['median_final_cost']:.1f}{extra} | {r['compile_s']:.1f} |"
            )
        lines += [
            "",
            f"Loop time / vmap time: {vl['loop_over_vmap']:.2f} (target >= 2). Box slots {vl['box_slots']} "
            f"(real boxes first). Trial steps median {vl['median_trial_steps']:.0f}, max {vl['max_trial_steps']} "
            f"(the vmapped loop runs until its slowest member stops). Vmapped vs solo answer per member: "
            f"centre deviation median {vl['median_center_dev_m']:.1e} m, max {vl['max_center_dev_m']:.1e} m; "
            f"{vl['members_same_steps']} of {args.maps} members took the same number of steps. "
            f"`solve_many` (lax.map) time / loop time {vl['many_over_loop']:.2f} (target <= 1 on a CPU); its "
            f"answer against the solo solves: max centre deviation {vl['many_max_center_dev_m']:.1e} m.",
            "",
            "Pieces of one LM iteration (ms; vmapped: per map, over all the maps):",
            "",
            "| piece | one map | vmapped, per map | single / vmapped |",
            "|---|---|---|---|",
        ]
        for name, r in rows["_components"].items():
            lines.append(
                f"| {name} | {r['single_ms']:.3f} | {r['vmap_ms_per_map']:.3f} | "
                f"{r['single_ms'] / r['vmap_ms_per_map']:.2f} |"
            )
        lines.append("")
    if not args.skip_online:
        o = online_benchmark(args)
        out["online"] = o
        lines += [
            f"### Online: {o['frames']}-frame Forward sequence, {o['objects']} objects "
            f"(window {o['window']} poses, optimise every {o['optimize_every']} frames, "
            f"{o['iterations']} LM steps)",
            "",
            "| median ms/frame | p95 ms/frame | max ms | first call (compile) s | recompiles | median position error (m) |",
            "|---|---|---|---|---|---|",
            f"| {o['median_ms']:.2f} | {o['p95_ms']:.2f} | {o['max_ms']:.1f} | {o['first_call_s']:.1f} | "
            f"{o['recompiles']} | {o['median_position_error_m']:.2f} |",
            "",
        ]
    table = "\n".join(lines)
    print(table)
    res = BENCH / "results"
    res.mkdir(exist_ok=True)
    # A run without the batch part writes beside the full run's files instead of over them.
    stem = "roshan_speed" if "batch" in out else "roshan_speed_online"
    _write_atomic(res / f"{stem}.json", json.dumps(out, indent=2))
    behind = []
    if "online" in out:
        o = out["online"]
        met = "met" if o["median_ms"] < 5 and o["p95_ms"] < 33 else "NOT met"
        behind.append(
            f"Online target (median under 5 ms, p95 under 33 ms per frame): {met} (median "
            f"{o['median_ms']:.2f} ms, p95 {o['p95_ms']:.1f} ms; the p95 is set by the optimisation frames)."
        )
    if "batch" in out:
        vl = out["batch"]["_vmap_vs_loop"]
        comp = out["batch"]["_components"]
        ratio = lambda name: comp[name]["single_ms"] / comp[name]["vmap_ms_per_map"]
        fixed = next(k for k in comp if k.endswith("fixed iterations"))
        met = "met" if vl["loop_over_vmap"] >= 2 else "NOT met"
        behind.append(
            f"vmap over maps vs the loop of jitted solves: loop time / vmap time {vl['loop_over_vmap']:.2f} "
            f"(target >= 2: {met}). Why, measured in this run: batching 50 maps makes one LM iteration's "
            f"pieces only {ratio('linearize'):.2f}x (linearisation), {ratio('damped Schur step'):.2f}x (damped "
            f"Schur step) and {ratio('cost'):.2f}x (cost) cheaper per map, and {fixed} with no control flow "
            f"that could diverge between members run {ratio(fixed):.2f}x faster per map vmapped than one by "
            "one. On this 2-core CPU a single map's iteration is already compute-bound (elementwise loops "
            "over its boxes, a (9J x 6T)(6T x 9J) product and a Cholesky of the reduced system), so there is "
            "no per-call overhead for a batch to amortise; that ratio is the ceiling of what vmap can gain. "
            "On top, under vmap every phase runs until its slowest member stops and every inner damping loop "
            "until its slowest member accepts (XLA selects, it does not skip, the finished members' work), so "
            "the batch pays for more linearisations and trials than its median member: hence the measured "
            "ratio below 1. The vmapped answers are not a leak between members: a member's answer does not "
            "depend on the other members; these maps use QuadricSLAM's factor set from the plain "
            "initialisation with a 20-step cap, where the reduced systems are nearly singular early, so "
            "rounding differences between the batched and the unbatched compiled code grow to the deviations "
            "reported above."
        )
    behind = " ".join(behind)
    md = (
        f"## ROSHAN solver speed\n\nCommand: `{out['command']}`  \nDate: {out['date']}  \n"
        f"Machine: {out['machine']}\n\n{table}\n{behind}\n"
    )
    _write_atomic(res / f"{stem}.md", md)


def _write_atomic(path, text):
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)


if __name__ == "__main__":
    main()
