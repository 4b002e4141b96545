"""gtsam_quadrics (QuadricSLAM 0.3.0) LM on problem files written by roshan_vs_quadricslam.py.

Runs under a Python 3.10 venv with ``gtsam-quadrics`` and ``numpy<2`` (not jaxsem's
interpreter): ``python _quadricslam_peer.py IN.npz OUT.npz``. Factors: ``PriorFactorPose3`` on
``world_T_camera`` (sigmas [rot, trans], divided per pose by ``pose_prior_weight`` [trans, rot]
when the file holds it, no prior where both are 0), ``BetweenFactorPose3`` between consecutive poses when
the file holds ``odometry`` (``odometry[t]`` = pose t+1 in pose t's frame, sigmas
``odo_rot_sigma`` / ``odo_trans_sigma``) and ``BoundingBoxFactor`` (isotropic box sigma), the
peer's defaults otherwise (``LevenbergMarquardtParams()``: relative and absolute error decrease
1e-5, lambda 1e-5 x 10, 100 iterations). Times each map's ``optimize()`` alone.
"""

import sys
import time

import gtsam
import gtsam_quadrics as gq
import numpy as np


def solve(d, k):
    K = d["K"]
    cal = gtsam.Cal3_S2(K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2])
    sr, st, sb = float(d["rot_sigma"]), float(d["trans_sigma"]), float(d["box_sigma"])
    prior_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([sr] * 3 + [st] * 3))
    box_noise = gtsam.noiseModel.Isotropic.Sigma(4, sb)
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    X = lambda t: gtsam.symbol("x", t)
    Q = lambda j: gtsam.symbol("q", j)
    inv = lambda T: np.linalg.inv(T)
    weight = d["pose_prior_weight"][k] if "pose_prior_weight" in d else None
    for t in np.flatnonzero(d["pose_mask"][k]):
        wTc = gtsam.Pose3(inv(d["pose_prior"][k, t]))
        if weight is None:
            graph.add(gtsam.PriorFactorPose3(X(t), wTc, prior_noise))
        elif np.any(weight[t] > 0):
            # per-pose sigmas: the stated ones over [translation, rotation] weights, 0 = none
            w_t, w_r = (max(float(x), 1e-9) for x in weight[t])
            noise_t = gtsam.noiseModel.Diagonal.Sigmas(np.array([sr / w_r] * 3 + [st / w_t] * 3))
            graph.add(gtsam.PriorFactorPose3(X(t), wTc, noise_t))
        values.insert(X(t), gtsam.Pose3(inv(d["init_pose"][k, t])))
    if "odometry" in d:
        odo_noise = gtsam.noiseModel.Diagonal.Sigmas(
            np.array([float(d["odo_rot_sigma"])] * 3 + [float(d["odo_trans_sigma"])] * 3)
        )
        for t in np.flatnonzero(d["odometry_mask"][k]):
            graph.add(gtsam.BetweenFactorPose3(X(t), X(t + 1), gtsam.Pose3(d["odometry"][k, t]), odo_noise))
    for j in np.flatnonzero(d["object_mask"][k]):
        q = gq.ConstrainedDualQuadric(
            gtsam.Rot3(d["init_rotation"][k, j]),
            d["init_center"][k, j],
            d["init_radii"][k, j],
        )
        q.addToValues(values, Q(j))
    for m in np.flatnonzero(d["box_mask"][k]):
        b = d["box"][k, m]
        graph.add(
            gq.BoundingBoxFactor(
                gq.AlignedBox2(*b),
                cal,
                X(int(d["box_pose"][k, m])),
                Q(int(d["box_object"][k, m])),
                box_noise,
            )
        )
    params = gtsam.LevenbergMarquardtParams()
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    e0 = graph.error(values)
    t0 = time.perf_counter()
    res = opt.optimize()
    el = time.perf_counter() - t0
    poses = np.array(d["init_pose"][k])
    R, c, r = (
        np.array(d["init_rotation"][k]),
        np.array(d["init_center"][k]),
        np.array(d["init_radii"][k]),
    )
    for t in np.flatnonzero(d["pose_mask"][k]):
        poses[t] = inv(res.atPose3(X(t)).matrix())
    for j in np.flatnonzero(d["object_mask"][k]):
        q = gq.ConstrainedDualQuadric.getFromValues(res, Q(j))
        R[j] = q.pose().rotation().matrix()
        c[j] = q.centroid()
        r[j] = np.abs(q.radii())  # radii may go negative in the peer (only r^2 enters Q*)
    return {
        "time": el,
        "iterations": opt.iterations(),
        "error0": e0,
        "error": graph.error(res),
        "poses": poses,
        "rotation": R,
        "center": c,
        "radii": r,
    }


def main():
    d = dict(np.load(sys.argv[1]))
    out = [solve(d, k) for k in range(d["box"].shape[0])]
    np.savez(sys.argv[2], **{key: np.array([o[key] for o in out]) for key in out[0]})


if __name__ == "__main__":
    main()
