"""ROSHAN solvers: planted recovery, Schur step vs dense algebra, single-view ROSHAN vs baseline,
vmap == loop, online vs batch (1 % of the cost), no recompilation, bad input."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import quadrics as Q, slam, slam as C
from jaxsem.slam._batch import damped_schur_step, solve_schur  # layers: white-box
from jaxsem.slam._cost import Delta, linearize, retract  # layers: white-box
from jaxsem.slam._toy import frames_from_problem  # layers: white-box

K = np.array([[525.0, 0.0, 320.0], [0.0, 525.0, 240.0], [0.0, 0.0, 1.0]])
R_TRUE = np.asarray(Q.quaternion_to_rotation(jnp.array([0.9, 0.1, 0.2, 0.3]) / np.linalg.norm([0.9, 0.1, 0.2, 0.3])))
C_TRUE = np.array([0.5, -0.3, 0.8])
R_RADII = np.array([2.2, 0.9, 0.7])


# Shared jitted solvers and one padded size (T, M, J) = (10, 10, 1): tests that agree on them
# reuse one compilation.
CAP = (10, 10, 1)
# Tight stopping: these tests check exact recovery; QuadricSLAM's factor set (no shape term).
CFG_BASE = slam.baseline_config(baseline_shape_weight=0.0).tight(max_steps=60)
CFG_ROSHAN = slam.SolverConfig().tight(max_steps=60)
SOLVE_BASE = jax.jit(lambda p, i: solve_schur(p, i, CFG_BASE))
SOLVE_ROSHAN = jax.jit(lambda p, i: solve_schur(p, i, CFG_ROSHAN))


def _orbit(T=10):
    """Noise-free boxes of one ellipsoid from an orbit (independent of jaxsem.slam.sim)."""
    a = np.linspace(0, 2 * np.pi, T, endpoint=False)
    eyes = np.stack([12 * np.cos(a), 12 * np.sin(a), 1.5 + 2.0 * np.sin(2 * a)], -1)
    poses = np.asarray(Q.look_at(eyes, np.zeros(3)))
    box, valid = Q.project_bbox(R_TRUE, C_TRUE, R_RADII, K, poses)
    assert bool(np.all(valid))
    depth, _ = Q.texture_plane_depth(R_TRUE, C_TRUE, R_RADII, poses)
    problem = slam.make_problem(
        K,
        [640, 480],
        poses,
        np.asarray(box),
        np.arange(T),
        np.zeros(T, int),
        ["car"],
        texture_depth=np.asarray(depth),
        capacity=CAP,
    )
    return problem, poses


def _same_ellipsoid(est, j=0, atol=1e-4):
    q_est = Q.dual_quadric(est.rotation[j], est.center[j], est.radii[j])
    q_true = Q.dual_quadric(R_TRUE, C_TRUE, R_RADII)
    np.testing.assert_allclose(q_est, q_true, atol=atol)


@pytest.mark.slow
def test_planted_ellipsoid_recovered_from_noise_free_orbit():
    problem, poses = _orbit()
    init = slam.initialize(problem, CFG_BASE)
    est, info = SOLVE_BASE(problem, init)
    assert bool(info.success) and float(info.cost) < 1e-10
    np.testing.assert_allclose(est.center[0], C_TRUE, atol=1e-5)
    np.testing.assert_allclose(np.sort(np.asarray(est.radii[0])), np.sort(R_RADII), atol=1e-5)
    _same_ellipsoid(est)
    np.testing.assert_allclose(est.camera_T_world, poses, atol=1e-6)
    assert float(jnp.min(est.radii)) > 0


@pytest.mark.slow
def test_schur_step_equals_dense_normal_equations():
    problem, truth = slam.toy_map(3, num_objects=2, num_frames=5, path="forward")
    cfg = slam.SolverConfig()
    init = slam.initialize(problem, cfg)
    T, J = 5, 2

    def flat(x):
        o = x[T * 6 :].reshape(J, 9)
        d = Delta(x[: T * 6].reshape(T, 6), o[:, :3], o[:, 3:6], o[:, 6:])
        return jnp.concatenate([b.reshape(-1) for b in C.residual_blocks(problem, retract(init, d), cfg)])

    lam = 1e-2

    @jax.jit
    def both(x0):
        Jd = jax.jacfwd(flat)(x0)
        r = flat(x0)
        H = Jd.T @ Jd
        Hd = H + lam * (jnp.diag(jnp.diag(H)) + 1e-9 * jnp.eye(x0.shape[0]))
        dense = jnp.linalg.solve(Hd, -Jd.T @ r)
        free = problem.pose_mask.astype(x0.dtype)
        n = linearize(problem, init, cfg, free)
        dp, do = damped_schur_step(n, lam, free, problem.object_mask)
        return dense, jnp.concatenate([dp.reshape(-1), do.reshape(-1)])

    dense, schur = both(jnp.zeros(T * 6 + J * 9))
    assert np.abs(dense).max() > 1e-3
    np.testing.assert_allclose(schur, dense, rtol=1e-8, atol=1e-10)


@pytest.mark.slow
def test_roshan_recovers_depth_and_shape_from_one_view_where_baseline_cannot():
    # One camera, one car 20 m away; the initial guess sits at the fixed default 10 m depth.
    R = np.eye(3)
    c = np.array([20.0, 1.0, 0.725])
    r = np.array([2.44, 0.92, 0.725])  # the class mean (a Camry-sized car)
    pose = np.asarray(Q.look_at(np.array([0.0, 0.0, 1.5]), np.array([1.0, 0.0, 1.5])))
    box, _ = Q.project_bbox(R, c, r, K, pose)
    depth, _ = Q.texture_plane_depth(R, c, r, pose)
    problem = slam.make_problem(
        K,
        [640, 480],
        pose[None],
        np.asarray(box)[None],
        [0],
        [0],
        ["car"],
        texture_depth=[float(depth)],
        capacity=CAP,
    )
    results = {}
    for name, cfg, solve in [
        ("roshan", CFG_ROSHAN, SOLVE_ROSHAN),
        ("baseline", CFG_BASE, SOLVE_BASE),
    ]:
        # Start at the fixed 10 m depth (not from the box size, which the class-mean car fits exactly).
        est, _ = solve(problem, slam.initialize(problem, cfg.replace(depth_from_box=False)))
        results[name] = (
            np.linalg.norm(np.asarray(est.center[0]) - c),
            np.abs(np.asarray(est.radii[0]) - r).max(),
        )
    assert results["roshan"][0] < 0.2 and results["roshan"][1] < 0.1
    assert results["baseline"][0] > 5.0  # depth unobservable from one box
    assert results["roshan"][0] < 0.05 * results["baseline"][0]


@pytest.mark.slow
def test_online_matches_batch_and_never_recompiles(compiles):
    problem, truth = slam.toy_map(1, num_objects=3, num_frames=12, path="forward")
    cfg = slam.SolverConfig(max_steps=100)
    frames = frames_from_problem(problem, max_detections=4)
    cap = slam.Capacity(
        max_poses=12,
        max_objects=3,
        max_boxes=int(problem.box.shape[0]) + 2,
        max_detections=4,
    )
    state = slam.online_init(cfg, cap, problem.K, problem.image_size, optimize_every=3, iterations=2)
    state = slam.online_update(state, frames[0])  # compiles the online step
    with compiles() as c:
        for frame in frames[1:]:
            state = slam.online_update(state, frame)
    assert c.count == 0  # one program serves every frame
    state = slam.online_optimize(state, 100)
    online = slam.online_estimate(state)
    graph = state.problem
    assert int(graph.box_mask.sum()) == int(problem.box_mask.sum())
    c_online = float(jax.jit(slam.total_cost)(graph, online, cfg))  # op by op: hundreds of small compiles
    # The batch reference: a full solve of the same factors from the single-view initialisation.
    est, info = jax.jit(lambda p: solve_schur(p, slam.initialize(p, cfg), cfg))(graph)
    c_batch = float(info.cost)
    assert np.isfinite(c_online) and c_online <= 1.01 * c_batch
    # Both land near the truth.
    assert np.median(np.linalg.norm(np.asarray(online.center - truth.center), axis=-1)) < 1.0


def test_bad_input_is_rejected_or_masked():
    good = dict(
        K=K,
        image_size=[640, 480],
        pose_prior=np.eye(4)[None].repeat(2, 0),
        box=[[10.0, 20.0, 50.0, 60.0], [15.0, 25.0, 55.0, 65.0]],
        box_pose=[0, 1],
        box_object=[0, 0],
        object_class=["car"],
    )
    slam.make_problem(**good)
    with pytest.raises(ValueError, match="non-finite box"):
        slam.make_problem(**{**good, "box": [[np.nan, 20.0, 50.0, 60.0], [15.0, 25.0, 55.0, 65.0]]})
    with pytest.raises(ValueError, match="inverted"):
        slam.make_problem(**{**good, "box": [[50.0, 20.0, 10.0, 60.0], [15.0, 25.0, 55.0, 65.0]]})
    with pytest.raises(ValueError, match="known classes"):
        slam.make_problem(**{**good, "object_class": ["spaceship"]})
    with pytest.raises(ValueError, match="never posed"):
        slam.make_problem(**good, pose_mask=[True, False])
    with pytest.raises(ValueError, match="box_pose"):
        slam.make_problem(**{**good, "box_pose": [0, 5]})
    with pytest.raises(ValueError, match="image_size"):
        slam.make_problem(**{**good, "image_size": [640, 0]})
    with pytest.warns(UserWarning, match="dropped 1 NaN or inverted"):
        f = slam.make_frame(
            np.eye(4),
            [[1.0, 2.0, 3.0, 4.0], [np.nan, 0, 1, 1]],
            ["car", "car"],
            [0, 1],
            max_detections=4,
        )
    assert f.box_mask.tolist() == [True, False, False, False] and bool(jnp.all(jnp.isfinite(f.box)))
    with pytest.raises(ValueError, match="object_id"):
        slam.make_frame(np.eye(4), [[1.0, 2.0, 3.0, 4.0]], ["car"], [7], max_objects=4)


@pytest.mark.slow
def test_camera_inside_an_object_stays_finite_and_moves_out():
    # The initial ellipsoid swallows the camera of the second frame: the solve stays finite,
    # and the barrier pushes the object out (all projections valid at the end).
    problem, poses = _orbit()
    init = slam.initialize(problem, CFG_BASE)
    cam = -poses[1, :3, :3].T @ poses[1, :3, 3]
    init = slam.SlamEstimate(init.camera_T_world, init.rotation, jnp.asarray(cam)[None] + 0.3, init.radii)
    assert float(Q.algebraic_distance(cam[None], init.rotation[0], init.center[0], init.radii[0])[0]) < 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        est, info = SOLVE_BASE(problem, init)
    assert np.isfinite(float(info.cost)) and float(info.cost) < float(info.initial_cost)
    _, valid = Q.project_bbox(est.rotation[0], est.center[0], est.radii[0], K, poses)
    assert bool(np.all(valid))
