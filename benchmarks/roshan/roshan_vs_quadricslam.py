"""jaxsem ROSHAN solvers vs gtsam_quadrics (QuadricSLAM 0.3.0) LM on the same problem instances.

Setting (``jaxsem.slam.sim.quadricslam_config``): 10 cars, 60 frames, 640x480, f = 525, Orbit and
Forward paths, 3 px box noise, pose priors 5 cm / 1 deg, texture depth 0.1 m + 1 %. Two
initialisations: "plain" (QuadricSLAM's: each ellipsoid 10 m along its first detection's
bearing, identity rotation, radii 1 m) and "single-view" (ROSHAN's section 4.3.5 init: texture
depth + class-mean radii, ``jaxsem.slam.initialize``). Per block (path x init) jaxsem runs first,
then the peer as a subprocess on the same problem file (interleaved, one run). Errors from
``jaxsem.metrics`` (via ``jaxsem.slam.sim.map_errors``); a map "collapses" when its mean object
position error exceeds 2 m; "prior dev" is the largest whitened pose-prior residual norm over
the map's cameras (6 dof; 3 sigma per axis = 7.3).

Systems: "QS factors" = ``slam.baseline_config(baseline_shape_weight=0.0)`` (QuadricSLAM's
factor set: pose priors + boxes); "ROSHAN" = ``slam.SolverConfig()`` noise-matched. Both with
the default GTSAM-like stopping (rtol = atol = 1e-5).

Run: ``python benchmarks/roshan/roshan_vs_quadricslam.py --maps 4 --peer-python PEER/bin/python`` (a venv with gtsam-quadrics).
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

import jax

from jaxsem.slam._batch import solve_schur  # layers: white-box
from jaxsem.slam._problem import bucket_capacity, compact_boxes  # layers: white-box
from jaxsem.slam._results import result_code  # layers: white-box

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402  (after enabling x64)
import numpy as np  # noqa: E402

from jaxsem import factors as F, slam  # noqa: E402
from jaxsem.slam import sim  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import _jaxls_anchor as jaxls_anchor  # noqa: E402
import _peer_client  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
BENCH = HERE.parent  # benchmarks/: the shared results folder and _harness
sys.path.insert(0, str(BENCH))
import _harness  # noqa: E402

NOTES = """How to read it: ms/map (loop) is the median over maps of one jitted solve each (after a
warm-up); ms/map (vmap) is one vmapped solve of all maps divided by their number; steps are the
median accepted / trial LM steps over all phases of a solve (the peer's and jaxls' are their
iterations); errors are medians over maps of each map's mean over its objects (``jaxsem.metrics``
via ``jaxsem.slam.sim.map_errors``; the peer's radii scored as |r|); "final cost" is
``jaxsem.slam.total_cost`` under QuadricSLAM's factor set (border edges masked, so every
system's estimate is scored by the same yardstick); codes count maps per ``jaxsem.slam.RESULTS``
code. "jaxls LM (QS factors)" is brentyi/jaxls with its defaults (LM, conjugate gradients on its
automatic Schur reduction, relative cost tolerance 1e-5, 100 iterations) minimising exactly the
QS-factor cost of the row "jaxsem QS factors" (``benchmarks/roshan/_jaxls_anchor.py``, costs built from
``jaxsem.slam.box_rows`` / ``pose_rows``); it recompiles for every map (its problem analysis is
static), so its compile column is the first map's. The verdict is in ``benchmarks/RESULTS.md``.
"""


# One compilation per system for every block (same padded shapes on both paths).
_VMAP = jax.jit(jax.vmap(solve_schur, in_axes=(0, 0, None)))


def _time(fn, repeats):
    """Median seconds of ``repeats`` calls of ``fn()`` (no warm-up: the callers warm up)."""
    return _harness.median_time(fn, repeats=repeats, warmup=False)


def _prior_dev(est_poses, problems, cfg):
    n = cfg.noise
    w = F.pose_prior_residual(est_poses, problems.pose_prior, n.pose_rotation_sigma, n.pose_translation_sigma)
    return np.asarray(jnp.max(jnp.linalg.norm(w, axis=-1), axis=-1))


def _summary(name, est, maps, problems, cfg, ms, extra):
    e = sim.map_errors(est, maps)
    pos = np.asarray(e["position"])
    row = {
        "system": name,
        "ms_per_map": ms,
        "position_m": float(np.median(pos)),
        "shape_m": float(np.median(np.asarray(e["shape"]))),
        "orientation_deg": float(np.median(np.asarray(e["orientation"]))),
        "collapses": int((pos > 2.0).sum()),
        "maps": int(pos.shape[0]),
        "prior_dev_max": float(np.max(_prior_dev(est.camera_T_world, problems, cfg))),
    }
    row.update(extra)
    return row


def run_block(path, init_name, args, peer_python):
    scfg = sim.quadricslam_config(path)
    maps = sim.simulate_batch(args.seed, args.maps, scfg)
    problems = sim.to_problem(maps, scfg)
    # sim.to_problem keeps a slot per (frame, object), dropped detections included (600 slots;
    # Forward maps have about 200 real boxes): move the real boxes first and trim the padding
    # to the power-of-two bucket of the largest map (never above the original size), as a user
    # building problems with slam.make_problem + slam.bucket_capacity would.
    most = int(np.max(np.asarray(problems.box_mask.sum(-1))))
    slots = min(int(problems.box.shape[-2]), bucket_capacity(1, most, 1)[1])
    problems = compact_boxes(problems, slots)
    roshan = sim.solver_config("roshan", scfg, max_steps=args.max_steps)
    qs = sim.solver_config("baseline", scfg, max_steps=args.max_steps, baseline_shape_weight=0.0)
    if init_name == "plain":
        inits = sim.initial_estimate(maps)
    else:
        inits = jax.vmap(lambda p: slam.initialize(p, roshan))(problems)
    take = lambda tree, k: jax.tree_util.tree_map(lambda x: x[k], tree)
    rows = []
    for name, cfg in (("jaxsem QS factors", qs), ("jaxsem ROSHAN", roshan)):
        one = lambda p, i, cfg=cfg: solve_schur(p, i, cfg)  # jitted; compiled once per system
        vm = lambda p, i, cfg=cfg: _VMAP(p, i, cfg)
        t = time.perf_counter()
        jax.block_until_ready(one(take(problems, 0), take(inits, 0)))
        compile_s = time.perf_counter() - t
        singles = [(take(problems, k), take(inits, k)) for k in range(args.maps)]
        per_map = [_time(lambda p=p, i=i, one=one: one(p, i), args.repeats) for p, i in singles]
        if cfg is qs:
            qs_per_map = [1e3 * t for t in per_map]
        jax.block_until_ready(vm(problems, inits))
        t_vmap = _time(lambda vm=vm: vm(problems, inits), args.repeats) / args.maps
        est, info = vm(problems, inits)
        codes = np.bincount(np.asarray(result_code(info.result)), minlength=5).tolist()
        rows.append(
            _summary(
                name,
                est,
                maps,
                problems,
                qs,
                1e3 * float(np.median(per_map)),
                {
                    "vmap_ms_per_map": 1e3 * t_vmap,
                    "compile_s": compile_s,
                    "accepted_steps": float(np.median(np.asarray(info.accepted))),
                    "trial_steps": float(np.median(np.asarray(info.steps))),
                    "final_cost_qs": float(
                        np.median(np.asarray(jax.vmap(lambda p, e: slam.total_cost(p, e, qs))(problems, est)))
                    ),
                    "codes_ok_max_nonfinite_damping_ill": codes,
                    "unfixable_per_map": float(np.mean(np.asarray(info.unfixable.sum(-1)))),
                    "rescued_per_map": float(np.mean(np.asarray(info.rescued.sum(-1)))),
                },
            )
        )
    if args.jaxls_maps and jaxls_anchor.available():
        m = min(args.jaxls_maps, args.maps)
        sub = lambda tree: jax.tree_util.tree_map(lambda x: x[:m], tree)
        est, ms, iters, compile_s = jaxls_anchor.solve_maps(sub(problems), sub(inits), qs, args.repeats)
        sub_maps = sub(maps)
        rows.append(
            _summary(
                "jaxls LM (QS factors)",
                est,
                sub_maps,
                sub(problems),
                qs,
                float(np.median(ms)),
                {
                    "vmap_ms_per_map": None,
                    "compile_s": compile_s,
                    "accepted_steps": float(np.median(iters)),
                    "trial_steps": None,
                    "final_cost_qs": float(
                        np.median(np.asarray(jax.vmap(lambda p, e: slam.total_cost(p, e, qs))(sub(problems), est)))
                    ),
                    "jaxsem_qs_ms_same_maps": float(np.median(qs_per_map[:m])),
                },
            )
        )
    if peer_python:
        a = lambda x: np.asarray(x, np.float64)
        out = _peer_client.solve(
            peer_python,
            K=a(problems.K[0]),
            pose_prior=a(problems.pose_prior),
            pose_mask=np.asarray(problems.pose_mask),
            init_pose=a(inits.camera_T_world),
            init_rotation=a(inits.rotation),
            init_center=a(inits.center),
            init_radii=a(inits.radii),
            object_mask=np.asarray(problems.object_mask),
            box=a(problems.box),
            box_pose=np.asarray(problems.box_pose),
            box_object=np.asarray(problems.box_object),
            box_mask=np.asarray(problems.box_mask),
            rot_sigma=float(qs.noise.pose_rotation_sigma),
            trans_sigma=float(qs.noise.pose_translation_sigma),
            box_sigma=float(qs.noise.box_sigma),
        )
        est = slam.SlamEstimate(
            jnp.asarray(out["poses"]),
            jnp.asarray(out["rotation"]),
            jnp.asarray(out["center"]),
            jnp.asarray(out["radii"]),
        )
        rows.append(
            _summary(
                "gtsam_quadrics LM",
                est,
                maps,
                problems,
                qs,
                1e3 * float(np.median(out["time"])),
                {
                    "vmap_ms_per_map": None,
                    "compile_s": 0.0,
                    "accepted_steps": float(np.median(out["iterations"])),
                    "trial_steps": None,
                    "final_cost_qs": float(
                        np.median(np.asarray(jax.vmap(lambda p, e: slam.total_cost(p, e, qs))(problems, est)))
                    ),
                    "peer_own_error": float(np.median(out["error"])),
                },
            )
        )
    for r in rows:
        r.update(path=path, init=init_name, box_slots=slots)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--maps", type=int, default=4)
    ap.add_argument("--seed", type=int, default=1000, help="report seeds (tuning used 100)")
    ap.add_argument("--max-steps", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=2)
    _peer_client.add_peer_flag(ap)
    ap.add_argument(
        "--jaxls-maps",
        type=int,
        default=5,
        help="maps per block solved by jaxls (the JAX anchor, if installed; it compiles once per map; 0 to skip)",
    )
    ap.add_argument("--paths", default="orbit,forward")
    ap.add_argument("--inits", default="plain,single-view")
    ap.add_argument("--rewrite-md", action="store_true", help="only rewrite the markdown from OUT/NAME.json")
    _harness.output_arguments(ap, "roshan_vs_quadricslam")
    args = ap.parse_args(argv)
    res = pathlib.Path(args.out)
    if args.rewrite_md:
        saved = res / f"{args.name}.json"
        if not saved.is_file():
            ap.error(f"--rewrite-md: no {saved} (see --out, --name)")
        write_md(json.loads(saved.read_text()), res, args.name)
        return
    _peer_client.check_peer_flag(args.peer_python, sys.exit)
    peer = args.peer_python
    rows = []
    for path in args.paths.split(","):
        for init in args.inits.split(","):
            rows += run_block(path, init, args, peer)
            print(json.dumps(rows[-4:], default=float), flush=True)
    out = {
        "command": "python benchmarks/roshan/roshan_vs_quadricslam.py "
        + " ".join(sys.argv[1:] if argv is None else argv),
        "date": subprocess.run(["date", "-u"], capture_output=True, text=True).stdout.strip(),
        "machine": f"{platform.machine()} 2-core CPU, shared (load average {os.getloadavg()[0]:.0f} at the end)",
        "rows": rows,
    }
    res.mkdir(parents=True, exist_ok=True)
    tmp = res / f"{args.name}.json.tmp"
    tmp.write_text(json.dumps(out, indent=2, default=float))
    tmp.replace(res / f"{args.name}.json")
    write_md(out, res, args.name)


def write_md(out, res: pathlib.Path, name: str):
    """The markdown table of a run's JSON (``--rewrite-md`` redoes it from the saved JSON)."""
    rows = out["rows"]
    lines = [
        "| path | init | box slots | system | ms/map (loop) | ms/map (vmap) | accepted / trial steps | pos m | shape m | orient deg | collapses | prior dev max | final cost (QS factors) | codes [ok,max,nonfinite,damping,ill] | unfixable/map |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    f = lambda x, p=1: "-" if x is None else f"{x:.{p}f}"
    for r in rows:
        lines.append(
            f"| {r['path']} | {r['init']} | {r.get('box_slots', 600)} | {r['system']} | {f(r['ms_per_map'])} | {f(r['vmap_ms_per_map'])} | "
            f"{f(r['accepted_steps'], 0)} / {f(r['trial_steps'], 0)} | {r['position_m']:.3f} | {r['shape_m']:.3f} | "
            f"{r['orientation_deg']:.1f} | {r['collapses']} of {r['maps']} | {r['prior_dev_max']:.1f} | "
            f"{r['final_cost_qs']:.0f} | {r.get('codes_ok_max_nonfinite_damping_ill', '-')} | {f(r.get('unfixable_per_map'))} |"
        )
    table = "\n".join(lines)
    print(table)
    md_notes = NOTES
    md = (
        f"## ROSHAN solvers vs gtsam_quadrics (QuadricSLAM) on the same instances\n\nCommand: `{out['command']}`  \n"
        f"Date: {out['date']}  \nMachine: {out['machine']}\n\n{table}\n\n{md_notes}\n"
    )
    tmp = res / f"{name}.md.tmp"
    tmp.write_text(md)
    tmp.replace(res / f"{name}.md")


if __name__ == "__main__":
    main()
