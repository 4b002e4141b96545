"""Scaling of batch work over devices with jaxsem.parallel (issue 13 part 5).

Each device count D runs in its own process (on a CPU host, D devices are forced with
``XLA_FLAGS=--xla_force_host_platform_device_count=D``; on a GPU host pass ``--devices`` up to the
GPU count). Per D, three batch jobs run through ``parallel.sharded_vmap`` and, as the baseline in
the same process, plain ``jax.jit(jax.vmap(...))`` on one device:

- ``lsd_eval``: LSD per-sample NLL over a batch of crops (batch evaluation);
- ``lsd_grad``: gradient of the batch's summed NLL w.r.t. the parameters (a training step's work);
- ``objmap``: object-map updates of many robots (jaxsem.mapping, 8 frames);
- ``slam`` (``--slam``): ROSHAN batch solve over simulated maps (compiles for minutes on 2 cores);
- ``volumon_step`` (``--train``): one VoluMon training step (tiny preset, batch made on the
  device), ``make_train_step(..., mesh)`` with the state replicated against the one-device step.

Timings are medians of repeats after a warm-up call, with ``block_until_ready``. Each process
also checks that the sharded result equals the single-device one. On a 2-core CPU, forced
devices share the two cores (and XLA's CPU backend already threads one device), so the numbers
here measure the overhead of the sharded path rather than a speedup; the speedup needs real
devices (GPUs, or hosts). Writes benchmarks/results/scaling.{json,md}.

    python benchmarks/scaling.py                        # D = 1, 2, 4 forced CPU devices
    python benchmarks/scaling.py --devices 1 2 --batch 64 --slam --train
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import subprocess
import sys
import time
from typing import Any

from jaxsem.volumon._train import init_state  # layers: white-box

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import _harness

RESULTS = pathlib.Path(__file__).resolve().parent / "results"


def child(args) -> dict:
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    from jaxsem import mapping, parallel
    from jaxsem.models import LSDConfig, init_lsd, lsd_nll

    mesh = parallel.data_mesh()
    out = {
        "devices": jax.device_count(),
        "platform": jax.devices()[0].platform,
        "jobs": {},
    }

    def maxdiff(a, b):
        la, lb = jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)
        return max(float(jnp.max(jnp.abs(jnp.asarray(x, float) - jnp.asarray(y, float)))) for x, y in zip(la, lb))

    def record(name, vfn, sfn, inputs, batch):
        t_single = _harness.median_time(vfn, *inputs, repeats=args.repeats)
        t_sharded = _harness.median_time(sfn, *inputs, repeats=args.repeats)
        diff = maxdiff(sfn(*inputs), vfn(*inputs))
        out["jobs"][name] = {
            "batch": batch,
            "single_s": t_single,
            "sharded_s": t_sharded,
            "max_diff": diff,
        }
        print(
            f"D={out['devices']} {name}: single {1e3 * t_single:.1f} ms, sharded "
            f"{1e3 * t_sharded:.1f} ms, max diff {diff:.2e}",
            flush=True,
        )

    B = args.batch
    rng = np.random.default_rng(0)
    k = args.crop
    cfg = LSDConfig(map_size=k, features=(8, 16, 32), context_features=16)
    model, params = init_lsd(jax.random.PRNGKey(0), cfg, jnp.float32)
    occ = jnp.asarray(rng.integers(-1, 2, (B, k, k)), jnp.int8)
    sem = jnp.asarray(rng.choice([0, 2, 3, 4], (B, k, k), p=[0.9, 0.04, 0.03, 0.03]), jnp.int8)
    ctx = jnp.asarray(rng.normal(size=(B, 4)), jnp.float32)
    mask = jnp.asarray(rng.random((B, k, k)) < 0.02)

    def nll(p, o, s, c, m):
        out: Any = model.apply({"params": p}, o[None], s[None], c[None])  # LSDOutput
        return lsd_nll(out.log_prob, m[None])

    axes = (None, 0, 0, 0, 0)
    v_nll = jax.jit(jax.vmap(nll, in_axes=axes))
    s_nll = parallel.sharded_vmap(nll, mesh, in_axes=axes)
    record("lsd_eval", v_nll, s_nll, (params, occ, sem, ctx, mask), B)
    v_grad = jax.jit(jax.grad(lambda p, *a: jnp.sum(jax.vmap(nll, in_axes=axes)(p, *a))))
    s_grad = jax.jit(jax.grad(lambda p, *a: jnp.sum(s_nll(p, *a))))
    record("lsd_grad", v_grad, s_grad, (params, occ, sem, ctx, mask), B)

    R, M, F = B, 4, 8
    centers = jnp.asarray(rng.normal(size=(F, R, M, 3)) * 4)

    def run_maps(c):  # c: (F, M, 3) one robot's frames
        state = mapping.init(32)

        def step(s, cf):
            det = mapping.Ellipsoids(
                jnp.broadcast_to(jnp.eye(3), (M, 3, 3)),
                cf,
                jnp.full((M, 3), 0.4),
                jnp.full((M,), 2, jnp.int32),
                jnp.ones((M,), bool),
            )
            return mapping.update(s, det, gate=1.0), None

        return jax.lax.scan(step, state, c)[0].center

    cm = jnp.swapaxes(centers, 0, 1)  # (R, F, M, 3)
    record(
        "objmap",
        jax.jit(jax.vmap(run_maps)),
        parallel.sharded_vmap(run_maps, mesh),
        (cm,),
        R,
    )

    if args.train:
        from jaxsem import volumon

        vcfg = volumon.get_config("both", "tiny").replace(data="device", batch_size=B, augment=True)
        state, vmodel, tx = init_state(vcfg)
        step1 = volumon.make_train_step(vmodel, tx, vcfg)
        step_d = volumon.make_train_step(vmodel, tx, vcfg, mesh)
        state_d = jax.device_put(state, parallel.replicated(mesh))
        # inputs are closed over: the one-device step takes the state on one device, the sharded
        # one the replicated state (the parameters after one step are compared)
        record("volumon_step", lambda: step1(state)[0]["params"], lambda: step_d(state_d)[0]["params"], (), B)

    if args.slam:
        from jaxsem import slam
        from jaxsem.slam import sim

        scfg = sim.quadricslam_config("orbit", num_frames=20, num_objects=5, min_objects=5)
        maps = sim.simulate_batch(0, B, scfg)
        problems = jax.vmap(lambda m: sim.to_problem(m, scfg))(maps)
        inits = jax.vmap(sim.initial_estimate)(maps)
        sc = sim.solver_config("roshan", scfg, max_steps=10)

        def solve(p, i):
            return slam.solve_batch(p, i, sc)[0].center

        record(
            "slam",
            jax.jit(jax.vmap(solve)),
            lambda p, i: slam.solve_maps(p, i, sc, mesh)[0].center,
            (problems, inits),
            B,
        )
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "scaling").splitlines()[0])
    p.add_argument("--devices", type=int, nargs="+", default=[1, 2, 4])
    p.add_argument("--batch", type=int, default=32)
    p.add_argument("--crop", type=int, default=64, help="LSD crop side (cells)")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--slam", action="store_true")
    p.add_argument("--train", action="store_true", help="add a VoluMon training-step row")
    p.add_argument("--cpu", action="store_true", help="force CPU devices (default on CPU hosts)")
    p.add_argument("--out", default=str(RESULTS))
    p.add_argument("--name", default="scaling")
    p.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child:
        print("RESULT " + json.dumps(child(args)), flush=True)
        return 0
    runs = []
    t0 = time.perf_counter()
    for d in args.devices:
        env = dict(os.environ)
        flags = env.get("XLA_FLAGS", "")
        env["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={d}".strip()
        if args.cpu:
            env["JAX_PLATFORMS"] = "cpu"
        cmd = (
            [
                sys.executable,
                __file__,
                "--child",
                "--batch",
                str(args.batch),
                "--crop",
                str(args.crop),
                "--repeats",
                str(args.repeats),
            ]
            + (["--slam"] if args.slam else [])
            + (["--train"] if args.train else [])
        )
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
        sys.stdout.write("".join(ln + "\n" for ln in proc.stdout.splitlines() if not ln.startswith("RESULT ")))
        lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
        if proc.returncode or not lines:
            print(proc.stderr[-3000:], file=sys.stderr)
            return 1
        runs.append(json.loads(lines[-1][len("RESULT ") :]))
    total = time.perf_counter() - t0
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    head = ["job", "batch"] + [f"D={r['devices']}: sharded / vmap (ms)" for r in runs] + ["max |sharded - vmap|"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name in runs[0]["jobs"]:
        cells = [name, str(runs[0]["jobs"][name]["batch"])]
        for r in runs:
            j = r["jobs"][name]
            cells.append(
                f"{1e3 * j['sharded_s']:.1f} / {1e3 * j['single_s']:.1f} (x{j['single_s'] / j['sharded_s']:.2f})"
            )
        cells.append(f"{max(r['jobs'][name]['max_diff'] for r in runs):.1e}")
        lines.append("| " + " | ".join(cells) + " |")
    table = "\n".join(lines)
    print(table)
    cmd = "python benchmarks/scaling.py " + " ".join(sys.argv[1:] if argv is None else argv)
    date = _harness.utc_now()
    machine = f"{platform.machine()} host, {_harness.nproc()} cores, platform {runs[0]['platform']} (shared, noisy)"
    record = {"command": cmd, "date": date, "machine": machine, "args": vars(args), "runs": runs, "seconds": total}
    md = [
        *_harness.header(f"## Scaling over devices (`{args.name}`, jaxsem.parallel)", cmd, date, machine),
        (
            "Each D is a separate process with D devices; `sharded` is `parallel.sharded_vmap` "
            "(shard_map over a data-axis Mesh, batch padded to a multiple of D), `vmap` is "
            "`jit(vmap)` on one device in the same process (x: vmap time / sharded time); "
            f"medians of {args.repeats} repeats after warm-up. Load average during the run: "
            f"{load}."
        ),
        "",
        table,
        "",
        (
            "On a CPU host the forced devices share the same cores, so these figures show the "
            "sharded path's overhead and its exactness, not a speedup; a speedup needs devices "
            "with their own compute (GPUs, TPU cores, hosts)."
        ),
        "",
    ]
    out = _harness.write_results(args.out, args.name, record, md)
    print(f"wrote {out / (args.name + '.json')} and .md in {total / 60:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
