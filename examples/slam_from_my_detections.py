"""ROSHAN on your own detections: build a problem, solve it, solve many, call the solver yourself.

A user has intrinsics, odometry poses and a detector's tracked boxes. Here they are made up: three
cars beside a straight 12-frame drive, their boxes from the geometry core plus 2 px noise, the
poses with 2 cm / 0.3 deg of noise. Then:

1. ``slam.make_problem`` + ``slam.initialize`` + ``slam.solve_batch``: one map;
2. the Levenberg-Marquardt inside ``solve_batch`` called directly, through ``optx.least_squares``
   with ``slam.roshan_solver`` (the structured LM is an optimistix solver), here continuing from
   ``solve_batch``'s answer: the same cost function, polished a little further (the direct call
   runs up to ``max_steps`` iterations of its own). (``solve_batch`` adds what a
   bare LM call lacks: the rescue of objects the single-view start strands, and objects the
   data cannot fix held out of the joint solve.)
3. ``slam.solve_many``: a batch of maps in one program (one after another on a CPU, where each
   map gets exactly its own answer; side by side on an accelerator).

Run: ``python examples/slam_from_my_detections.py`` (about a minute on a 2-core CPU: three
programs compile).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from jaxsem import metrics, quadrics as q, slam

K = np.array([[525.0, 0.0, 320.0], [0.0, 525.0, 240.0], [0.0, 0.0, 1.0]])
TRUE_CENTERS = np.array([[4.0, 12.0, 0.75], [-4.0, 18.0, 0.75], [4.5, 25.0, 0.75]])
TRUE_RADII = np.array([[2.3, 0.9, 0.7], [2.5, 0.95, 0.75], [2.4, 0.9, 0.72]])


def my_detections(seed: int, frames: int = 12):
    """What a user's pipeline gives: odometry poses and tracked boxes (made up here)."""
    rng = np.random.default_rng(seed)
    yaw = np.array([1.5, 1.6, 1.55])  # cars parked along the road
    R = np.stack([np.asarray(q.so3_exp(np.array([0.0, 0.0, a]))) for a in yaw])
    eyes = [np.array([0.0, 1.5 * k, 1.5]) for k in range(frames)]
    truth_poses = np.stack([np.asarray(q.look_at(e, e + np.array([0.0, 10.0, -0.75]))) for e in eyes])
    boxes, box_pose, box_object = [], [], []
    for t in range(frames):
        b, ok = q.project_bbox(R, TRUE_CENTERS, TRUE_RADII, K, truth_poses[t])
        b, ok = np.asarray(b), np.asarray(ok)
        inside = ok & (b[:, 0] < 640) & (b[:, 2] > 0) & (b[:, 1] < 480) & (b[:, 3] > 0)
        for j in np.flatnonzero(inside):
            boxes.append(np.clip(b[j] + rng.normal(0, 2.0, 4), [0, 0, 0, 0], [640, 480, 640, 480]))
            box_pose.append(t)
            box_object.append(j)
    noisy = truth_poses.copy()
    for t in range(frames):  # odometry noise: 2 cm, 0.3 deg
        dR = np.asarray(q.so3_exp(rng.normal(0, np.deg2rad(0.3), 3)))
        noisy[t, :3, :3] = dR @ noisy[t, :3, :3]
        noisy[t, :3, 3] += rng.normal(0, 0.02, 3)
    problem = slam.make_problem(
        K,
        (640, 480),
        noisy,
        np.array(boxes),
        np.array(box_pose),
        np.array(box_object),
        ["car"] * 3,
        capacity=(frames, 3 * frames, 3),  # fixed sizes: every map shares one compiled program
    )
    return problem, R


def main() -> dict:
    config = slam.SolverConfig(max_steps=300)  # trials over all phases, rescue included
    problem, R_true = my_detections(0)
    # The small steps around the solves are jitted too: run op by op, the initialisation and the
    # cost each compile a hundred or more tiny programs (seconds each time).
    initialize = jax.jit(slam.initialize)
    total_cost = jax.jit(slam.total_cost)
    init = initialize(problem, config)

    # 1. One map.
    est, info = slam.solve_batch(problem, init, config)
    print(slam.result_message(info.result), f"after {int(info.accepted)} iterations")
    err = jax.jit(metrics.ellipsoid_errors)(est.rotation, est.center, est.radii, R_true, TRUE_CENTERS, TRUE_RADII)

    # 2. The same problem through optimistix, with ROSHAN's solver.
    pose_free = problem.pose_mask.astype(problem.pose_prior.dtype)
    sol = optx.least_squares(
        lambda e, args: slam.residual_blocks(args[0], e, args[1]),
        slam.roshan_solver(config),
        est,
        args=(problem, config, pose_free, problem.object_mask),
        throw=False,
        max_steps=config.max_steps,
    )
    optx_cost = float(total_cost(problem, sol.value, config))

    # 3. Three maps in one program.
    maps = [my_detections(s)[0] for s in (1, 2, 3)]
    problems = slam.stack_problems(maps)
    inits = jax.jit(jax.vmap(slam.initialize, in_axes=(0, None)))(problems, config)
    ests, infos = slam.solve_many(problems, inits, config)
    many_pos = [float(jnp.mean(jnp.linalg.norm(ests.center[k] - TRUE_CENTERS, axis=-1))) for k in range(3)]
    solo = slam.solve_batch(maps[1], jax.tree_util.tree_map(lambda x: x[1], inits), config)[0]

    out = {
        "success": bool(info.success),
        "position_m": float(np.mean(np.asarray(err["position"]))),
        "cost": float(info.cost),
        "optx_cost": optx_cost,
        "optx_steps": int(sol.stats["num_steps"]),
        "many_equals_solo_m": float(jnp.max(jnp.abs(ests.center[1] - solo.center))),
        "many_success": [bool(s) for s in np.asarray(infos.success)],
        "many_position_m": many_pos,
    }
    print(out)
    return out


if __name__ == "__main__":
    main()
