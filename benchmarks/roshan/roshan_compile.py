"""How long a user waits for ROSHAN's first answer on the real LM-O desk, in a fresh process:
with an empty persistent compilation cache (cold) and again with the cache the first process
filled (warm), for the batch solve (``jaxsem.slam.solve_batch``), the online smoother's first
update (``jaxsem.slam.run_sequence``, the benchmark's setting) and ``jaxsem.slam.solve_many``
(four copies of the stretch, odometry noise reseeded).

The problem is the first tuning stretch as ``roshan_real.py`` builds it (ROSHAN's config, texture
planes from its front end), padded to ``bucket_capacities`` over the tuning split's stretches.
``first_s`` is the first call (tracing, compiling or loading from the cache, and one solve);
``again_s`` the median of three later calls; ``compile_s`` their difference. Each process uses
``JAXSEM_CACHE_DIR`` set to one fresh folder (``import jaxsem`` turns the library's cache on).

    python benchmarks/roshan/roshan_compile.py --scene DATA/lmo/test/000002 --json OUT
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

import jax
import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
import _harness
import roshan_real

from jaxsem import slam
from jaxsem.slam._bop_slam import pose_prior_weights  # layers: white-box
from jaxsem.volumon import data as vdata

SYSTEMS = ("batch", "online", "solve_many")


def _first_and_again(fn) -> dict[str, float]:
    t0 = time.perf_counter()
    jax.block_until_ready(fn())
    first = time.perf_counter() - t0
    again = _harness.median_time(fn, repeats=3, warmup=False)
    return {"first_s": first, "again_s": again, "compile_s": max(first - again, 0.0)}


def child(scene_dir: pathlib.Path) -> dict:
    """One fresh process's first and later call times (the problem's construction not timed)."""
    scene = vdata.load_bop_split(scene_dir, "tune")
    stretches = slam.find_stretches(scene)
    table, _ = slam.user_class_table(vdata.bop_class_extents(scene), seed=27)
    made = [slam.stretch_sequence(st, table, seed=n) for n, st in enumerate(stretches)]
    caps = slam.bucket_capacities([roshan_real.stretch_size(s) for s, _ in made])
    seq, odo = made[0]
    cfg = roshan_real.configs(seq)["roshan"]
    seq_t, _ = roshan_real.front_end(seq)
    poses = np.stack([f.camera_T_world for f in seq.frames])
    noise = dict(seq.noise or {})
    weight = pose_prior_weights(
        poses,
        "first",
        prior_translation=noise["pose_translation_sigma"],
        prior_rotation_deg=noise["pose_rotation_sigma_deg"],
    )
    problem = roshan_real.problem_of(seq_t, odo, table, weight, caps[0])
    init = slam.initialize(problem, cfg)
    out: dict[str, object] = {"capacity": list(caps[0])}
    out["batch"] = _first_and_again(lambda: slam.solve_batch(problem, init, cfg))
    args = roshan_real.parse_args(["--scene", str(scene_dir), "--split", "tune", "--json", os.devnull])
    res = roshan_real.run_online(seq_t, cfg, weight, args)["result"]
    frames = np.asarray(res.frame_seconds, np.float64)
    out["online"] = {
        "first_s": float(frames[0]),
        "again_s": float(np.median(frames[1:])),
        "compile_s": float(max(frames[0] - np.median(frames[1:]), 0.0)),
    }
    many = slam.stack_problems([problem] * 4)
    inits = slam.stack_problems([init] * 4)
    out["solve_many"] = _first_and_again(lambda: slam.solve_many(many, inits, cfg))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=pathlib.Path, required=True)
    ap.add_argument("--json", type=pathlib.Path, required=True)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print("RESULT " + json.dumps(child(args.scene)), flush=True)
        return 0
    rows = {}
    with tempfile.TemporaryDirectory(prefix="jaxsem_compile_") as cache:
        env = {**os.environ, "JAXSEM_CACHE_DIR": cache}
        env.pop("JAXSEM_NO_COMPILATION_CACHE", None)
        for run in ("cold", "warm"):
            t0 = time.perf_counter()
            cmd = [sys.executable, __file__, "--scene", str(args.scene), "--json", os.devnull, "--child"]
            text = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True).stdout
            rows[run] = json.loads(next(x for x in text.splitlines() if x.startswith("RESULT "))[7:])
            rows[run]["process_s"] = time.perf_counter() - t0
            print(run, json.dumps(rows[run]), flush=True)
    record = {
        "command": "python " + " ".join(sys.argv),
        "date": _harness.utc_now(),
        "machine": _harness.machine(),
        **rows,
    }
    args.json.write_text(json.dumps(record, indent=1))
    for s in SYSTEMS:
        print(f"| {s} | " + " | ".join(f"{rows[r][s]['first_s']:.2f} s" for r in ("cold", "warm")) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
