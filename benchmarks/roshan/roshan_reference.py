"""ROSHAN's differentiable solve: ``solve_batch(..., method="optimistix")`` against the dense
optimistix Levenberg-Marquardt it replaced, and against the default structured solve.

(a) Forward solves of ``slam.toy_map`` maps (float32, the library default): compile time, time
    per map (median of the first run after compiling and ``--repeats`` more), final cost and result, for
    - ``dense``: ``optx.LevenbergMarquardt`` on the tangent delta (the former
      ``method="optimistix"``, reproduced here as the baseline: one JVP per unknown, dense QR);
    - ``optimistix``: ``SchurLevenbergMarquardt`` on the tangent delta (implicit adjoint);
    - ``schur``: the default ``solve_batch`` (rescue phase, then the structured LM).
(b) A gradient through the solution (the radii error of a few-view map w.r.t. the class prior
    mean, as ``tests/slam/test_slam_gradients.py``): compile and run time of ``value_and_grad``,
    dense against the new path.

Run: ``python benchmarks/roshan/roshan_reference.py`` (``--help`` for sizes).
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from jaxsem import factors as F, slam
from jaxsem.slam._cost import Delta, retract  # layers: white-box
from jaxsem.slam._toy import few_views  # layers: white-box


def _dense_solve(problem, init, config):
    """The former ``method="optimistix"``: optimistix's dense LM on the tangent delta."""

    def fn(delta, args):
        p, anchor, cfg = args
        return slam.residual_blocks(p, retract(anchor, delta), cfg)

    T, J, dtype = init.camera_T_world.shape[0], init.center.shape[0], init.center.dtype
    zero = Delta(jnp.zeros((T, 6), dtype), *(jnp.zeros((J, 3), dtype) for _ in range(3)))

    solver = optx.LevenbergMarquardt(rtol=config.rtol, atol=config.atol)  # pyright: ignore[reportArgumentType]
    sol = optx.least_squares(fn, solver, zero, args=(problem, init, config), max_steps=config.max_steps, throw=False)
    est = retract(init, sol.value)
    return est, slam.total_cost(problem, est, config), sol.result == optx.RESULTS.successful


def _new_solve(method):
    def solve(problem, init, config):
        est, info = slam.solve_batch(problem, init, config, method=method)
        return est, info.cost, info.success

    return solve


def _time(fn, args, repeats):
    t = time.perf_counter()
    compiled = jax.jit(fn).lower(*args).compile()
    compile_s = time.perf_counter() - t
    t = time.perf_counter()
    out = jax.block_until_ready(compiled(*args))
    ts = [time.perf_counter() - t]
    for _ in range(repeats):
        t = time.perf_counter()
        out = jax.block_until_ready(compiled(*args))
        ts.append(time.perf_counter() - t)
    return compile_s, float(np.median(ts)), out


def _few_views(dtype):
    problem, r = few_views()
    return problem, jnp.asarray(r, dtype)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--maps", type=int, default=2)
    ap.add_argument("--seed", type=int, default=900)
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--objects", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=0, help="timed runs after the first")
    ap.add_argument("--skip-dense", action="store_true", help="skip the dense baseline (slow)")
    args = ap.parse_args()

    cfg = slam.SolverConfig()
    solvers = {"optimistix": _new_solve("optimistix"), "schur": _new_solve("schur")}
    if not args.skip_dense:
        solvers = {"dense": _dense_solve, **solvers}
    maps = [slam.toy_map(args.seed + k, num_frames=args.frames, num_objects=args.objects)[0] for k in range(args.maps)]
    print(f"(a) {args.maps} toy maps (seed {args.seed}..), {args.frames} frames, {args.objects} objects, float32")
    print("| solver | map | compile (s) | s per map | cost | successful |")
    print("|---|---|---|---|---|---|")
    for name, fn in solvers.items():
        for k, problem in enumerate(maps):
            init = slam.initialize(problem, cfg)
            compile_s, run_s, (_, cost, ok) = _time(fn, (problem, init, cfg), args.repeats)
            print(
                f"| {name} | {args.seed + k} | {compile_s:.1f} | {run_s:.3f} | {float(cost):.2f} | {bool(ok)} |",
                flush=True,
            )

    problem, r_true = _few_views(jnp.float32)
    mean0, sigma = F.shape_prior_table()
    car = F.class_index("car")

    def objective(solve):
        def f(car_mean):
            cfg = slam.SolverConfig(shape_prior_mean=mean0.at[car].set(car_mean), shape_prior_sigma=sigma)
            est, _, _ = solve(problem, slam.initialize(problem, cfg), cfg)
            return jnp.sum(jnp.square(est.radii[0] - r_true))

        return jax.value_and_grad(f)

    print("\n(b) value_and_grad through the solve (few-view map, w.r.t. the car prior mean)")
    print("| solver | compile (s) | run (s) | value | gradient |")
    print("|---|---|---|---|---|")
    for name in [n for n in ("dense", "optimistix") if n in solvers]:
        compile_s, run_s, (val, grad) = _time(objective(solvers[name]), (mean0[car],), args.repeats)
        print(
            f"| {name} | {compile_s:.1f} | {run_s:.3f} | {float(val):.4g} | {np.round(np.asarray(grad), 4)} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
