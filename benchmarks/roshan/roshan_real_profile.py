"""Where a ROSHAN solve on a real LM-O stretch spends its time (issue 27: seconds per stretch
against gtsam_quadrics' 147 ms).

On one tuning stretch (``roshan_real.py``'s setting: drifting odometry, rendered visible boxes,
user class priors), times in one run: the block linearisation, one damped Schur step with the
odometry's block-tridiagonal pose part (and the previous block Thomas elimination alone, which solved
each pivot with ``jnp.linalg.solve`` and the k right-hand sides, as the baseline), the same
step without odometry, and the whole baseline and ROSHAN solves. Tuning split only.

    python benchmarks/roshan/roshan_real_profile.py --scene DATA/lmo/test/000002 [--stretch 0]
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import jax
import jax.numpy as jnp

from jaxsem.slam._batch import damped_schur_step, solve_schur  # layers: white-box
from jaxsem.slam._cost import linearize  # layers: white-box

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))
import _harness
import roshan_real

from jaxsem import slam
from jaxsem.volumon import data as vdata


def _tridiagonal_solve_before(D, C, B):
    """The block Thomas elimination as it was: ``jnp.linalg.solve`` of each pivot with all k
    right-hand sides (the baseline of this benchmark)."""
    C_prev = jnp.concatenate([jnp.zeros_like(C[:1]), C[:-1]])

    def forward(carry, x):
        G_prev, Y_prev = carry
        D_t, C_t, Cp_t, B_t = x
        CpT = jnp.swapaxes(Cp_t, -1, -2)
        sol = jnp.linalg.solve(D_t - CpT @ G_prev, jnp.concatenate([C_t, B_t - CpT @ Y_prev], -1))
        G, Y = sol[:, : C_t.shape[-1]], sol[:, C_t.shape[-1] :]
        return (G, Y), (G, Y)

    _, (G, Y) = jax.lax.scan(forward, (jnp.zeros_like(D[0]), jnp.zeros_like(B[0])), (D, C, C_prev, B))

    def backward(X_next, x):
        X = x[1] - x[0] @ X_next
        return X, X

    return jax.lax.scan(backward, jnp.zeros_like(B[0]), (G, Y), reverse=True)[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=pathlib.Path, required=True)
    ap.add_argument("--stretch", type=int, default=0)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    scene = vdata.load_bop_split(args.scene, "tune")
    st = slam.find_stretches(scene)[args.stretch]
    table, _ = slam.user_class_table(vdata.bop_class_extents(scene), seed=27)
    seq, odo = slam.stretch_sequence(st, table, setting="clean", seed=args.stretch)
    cfgs = roshan_real.configs(seq)
    seq_t, _ = roshan_real.front_end(seq)
    problem = roshan_real.problem_of(seq_t, odo, table)
    init = jax.jit(slam.initialize)(problem, cfgs["roshan"])
    free = jnp.ones(init.camera_T_world.shape[0], init.center.dtype)
    n = jax.jit(linearize)(problem, init, cfgs["roshan"], free)
    print(f"machine: {_harness.machine()}; poses {n.Hpp.shape[0]} (padded), objects {n.Hoo.shape[0]} (padded)")
    rows = {}
    rows["linearize (ms)"] = _harness.median_time(
        jax.jit(linearize), problem, init, cfgs["roshan"], free, repeats=args.repeats
    )
    step = jax.jit(damped_schur_step)
    rows["Schur step, odometry (ms)"] = _harness.median_time(
        step, n, 1e-3, free, problem.object_mask, repeats=args.repeats
    )
    no_odo = n._replace(Hpp_next=None)
    rows["Schur step, no odometry (ms)"] = _harness.median_time(
        step, no_odo, 1e-3, free, problem.object_mask, repeats=args.repeats
    )
    # The previous elimination alone, on this step's system (pivots (T, 6, 6), right-hand sides
    # Hpo's J * 9 columns and the gradient): what each damped step with odometry paid before.
    T, J = n.Hpo.shape[0], n.Hpo.shape[1]
    rhs = jnp.concatenate([jnp.moveaxis(n.Hpo, 1, 2).reshape(T, 6, J * 9), n.gp[:, :, None]], -1)
    damped = n.Hpp + 1e-3 * jnp.eye(6, dtype=n.Hpp.dtype)
    rows["previous tridiagonal elimination alone (ms)"] = _harness.median_time(
        jax.jit(_tridiagonal_solve_before), damped, n.Hpp_next, rhs, repeats=args.repeats
    )
    solve = jax.jit(solve_schur)
    for name in ("baseline", "roshan"):
        cfg = cfgs[name]
        i0 = jax.jit(slam.initialize)(problem, cfg)
        compiled = solve.lower(problem, i0, cfg).compile()
        seconds, (_, info) = _harness.timed(compiled, problem, i0, cfg, repeats=args.repeats)
        rows[f"{name} solve (ms)"] = seconds
        rows[f"{name} steps"] = int(info.steps)
    for k, v in rows.items():
        print(f"| {k} | {v * 1e3:.1f} |" if k.endswith("(ms)") else f"| {k} | {v} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
