"""Issue 27, item 3: odometry (between) factors between consecutive poses.

The factor against finite differences and against its defining properties (zero for the measured
motion, invariant to where the world origin is, the pose prior when the first pose is the
origin); the block-tridiagonal Schur step against dense linear algebra; and end to end: drifting
odometry plus boxes recovers the poses better than the odometry alone."""

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from jaxsem import factors as F, quadrics as Q, slam
from jaxsem.slam._batch import damped_schur_step, solve_schur  # layers: white-box
from jaxsem.slam._cost import Delta, linearize, retract  # layers: white-box
from jaxsem.slam._schur import schur_normal  # layers: white-box
from jaxsem.slam._solver_config import NoiseModel  # layers: white-box


def _pose(rng, scale=3.0):
    q = rng.normal(size=4)
    R = np.asarray(Q.quaternion_to_rotation(jnp.asarray(q / np.linalg.norm(q))))
    return np.asarray(Q.rigid_transform(R, rng.normal(size=3) * scale))


def _perturb(T, xi):
    return T @ np.asarray(jaxlie.SE3.exp(jnp.asarray(xi)).as_matrix())


def test_between_factor_properties():
    rng = np.random.default_rng(0)
    a, b, world = _pose(rng), _pose(rng), _pose(rng)
    measured = np.asarray(Q.relative_pose(a, b))
    np.testing.assert_allclose(F.between_residual(a, b, measured, 0.01, 0.02), 0.0, atol=1e-9)
    # Moving the world origin (the same transform applied to both poses) changes nothing.
    noisy = _perturb(measured, rng.normal(size=6) * 0.05)
    r = F.between_residual(a, b, noisy, 0.01, 0.02)
    np.testing.assert_allclose(F.between_residual(a @ world, b @ world, noisy, 0.01, 0.02), r, atol=1e-9)
    # With the first pose at the origin it is the pose prior on the second.
    prior = np.asarray(Q.invert_pose(noisy))
    np.testing.assert_allclose(
        F.between_residual(np.eye(4), b, noisy, 0.01, 0.02), F.pose_prior_residual(b, prior, 0.01, 0.02), atol=1e-9
    )
    # Batched over leading axes.
    batch = F.between_residual(np.stack([a, a]), np.stack([b, b]), np.stack([noisy, measured]), 0.01, 0.02)
    assert batch.shape == (2, 6)
    np.testing.assert_allclose(batch[0], r, atol=1e-12)


def test_between_factor_against_finite_differences():
    rng = np.random.default_rng(1)
    a, b = _pose(rng), _pose(rng)
    measured = _perturb(np.asarray(Q.relative_pose(a, b)), rng.normal(size=6) * 0.1)
    aj, bj, mj = (jnp.asarray(x) for x in (a, b, measured))

    def f(x):  # right perturbations of both poses, as the solvers retract
        ta = aj @ jaxlie.SE3.exp(x[:6]).as_matrix()
        tb = bj @ jaxlie.SE3.exp(x[6:]).as_matrix()
        return F.between_residual(ta, tb, mj, 0.02, 0.05)

    x0 = jnp.asarray(rng.normal(size=12) * 0.01)
    eps = 1e-6
    steps = eps * jnp.eye(12)

    @jax.jit
    def both(x):
        vals = jax.vmap(f)(jnp.concatenate([x + steps, x - steps]))
        return jax.jacfwd(f)(x), ((vals[:12] - vals[12:]) / (2 * eps)).T

    fwd, fd = both(x0)
    np.testing.assert_allclose(fwd, fd, rtol=1e-5, atol=1e-6)


def _drifting_problem(seed=0, num_frames=10, bias=(0.01, 0.0, 0.02, 0.0, 0.004, 0.0)):
    """A toy orbit map whose poses come from odometry with a constant per-step bias (the random
    walk's drift) plus noise: ``(problem, truth, dead_reckoned)``; pose 0 is the truth."""
    base, truth = slam.toy_map(seed, num_objects=4, num_frames=num_frames, path="orbit", pose_noise=(0.0, 0.0))
    rng = np.random.default_rng(seed)
    true = np.asarray(truth.camera_T_world)
    steps = []
    for t in range(num_frames - 1):
        rel = np.asarray(Q.relative_pose(true[t], true[t + 1]))
        xi = np.asarray(bias) + rng.normal(size=6) * np.array([0.002, 0.002, 0.002, 0.0005, 0.0005, 0.0005])
        steps.append(_perturb(rel, xi))
    dead = [true[0]]
    for s in steps:
        dead.append(np.asarray(Q.invert_pose(s)) @ dead[-1])
    dead = np.stack(dead)
    M = int(base.box_mask.sum())
    tex = np.where(np.asarray(base.texture_mask), np.asarray(base.texture_depth), np.nan)[:M]
    problem = slam.make_problem(
        base.K,
        base.image_size,
        dead,
        np.asarray(base.box)[:M],
        np.asarray(base.box_pose)[:M],
        np.asarray(base.box_object)[:M],
        np.asarray(base.object_class),
        tex,
        odometry=np.stack(steps),
    )
    return problem, true, dead


# The two end-to-end solves share one program (some 25 s of compiles): the config and the free
# poses are its arguments, and both problems carry explicit pose-prior weights (one pytree).
SOLVE = jax.jit(lambda p, free, cfg: solve_schur(p, None, cfg, pose_free=free))


def _with_prior_weights(problem, w):
    return eqx.tree_at(lambda p: p.pose_prior_weight, problem, jnp.asarray(w, jnp.float64), is_leaf=lambda x: x is None)


def _cfg(**kw):
    noise = NoiseModel(
        pose_rotation_sigma=1.0,  # the priors are the dead-reckoned poses: nearly no weight
        pose_translation_sigma=10.0,
        odometry_rotation_sigma=0.005,
        odometry_translation_sigma=0.02,
        box_sigma=2.0,
        texture_sigma=0.1,
    )
    return slam.SolverConfig(noise=noise, **kw)


@pytest.mark.slow
def test_tridiagonal_schur_step_equals_dense_normal_equations():
    problem, _, _ = _drifting_problem(num_frames=5)
    cfg = _cfg()
    init = slam.initialize(problem, cfg)
    T, J = problem.num_poses, problem.num_objects
    assert len(slam.residual_blocks(problem, init, cfg)) == 4

    def flat(x):
        o = x[T * 6 :].reshape(J, 9)
        d = Delta(x[: T * 6].reshape(T, 6), o[:, :3], o[:, 3:6], o[:, 6:])
        return jnp.concatenate([b.reshape(-1) for b in slam.residual_blocks(problem, retract(init, d), cfg)])

    lam = 1e-2
    free = problem.pose_mask.astype(jnp.float64).at[0].set(0.0)  # pose 0 held

    @jax.jit
    def both(x0):
        Jd = jax.jacfwd(flat)(x0)
        keep = jnp.concatenate([jnp.repeat(free, 6), jnp.ones(J * 9)])
        Jd = Jd * keep[None, :]
        r = flat(x0)
        H = Jd.T @ Jd
        Hd = H + lam * (jnp.diag(jnp.diag(H)) + 1e-9 * jnp.eye(x0.shape[0]))
        Hd = jnp.where((keep[:, None] * keep[None, :]) > 0, Hd, jnp.eye(x0.shape[0]))
        dense = jnp.linalg.solve(Hd, -Jd.T @ r) * keep
        n = linearize(problem, init, cfg, free)
        dp, do = damped_schur_step(n, lam, free, problem.object_mask)
        return dense, jnp.concatenate([dp.reshape(-1), do.reshape(-1)]), 0.5 * jnp.sum(r * r), n.cost

    dense, schur, cost, ncost = both(jnp.zeros(T * 6 + J * 9))
    assert np.abs(dense[6 : T * 6]).max() > 1e-4  # the poses do move
    np.testing.assert_allclose(schur, dense, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(ncost, cost, rtol=1e-10)


@pytest.mark.slow
def test_drifting_odometry_and_boxes_beat_odometry_alone():
    problem, true, dead = _drifting_problem()
    problem = _with_prior_weights(problem, np.ones((problem.num_poses, 2)))  # None's meaning
    cfg = _cfg(max_steps=50)
    free = np.ones(problem.num_poses, bool)
    free[0] = False  # the first pose anchors the map (it is the truth)
    est, info = SOLVE(problem, free, cfg)
    assert bool(jnp.isfinite(info.cost)) and not bool(info.unfixable.any())

    def position_error(poses):
        centres = np.asarray(Q.invert_pose(poses))[:, :3, 3]
        return np.linalg.norm(centres - np.asarray(Q.invert_pose(true))[:, :3, 3], axis=-1)

    alone, solved = position_error(dead), position_error(np.asarray(est.camera_T_world))
    print(
        f"camera position error (m), odometry alone: mean {alone.mean():.3f} last {alone[-1]:.3f}; "
        f"odometry + boxes: mean {solved.mean():.3f} last {solved[-1]:.3f}; {slam.result_message(info.result)}"
    )
    assert alone[-1] > 0.1, alone  # the drift is real
    assert solved.mean() < 0.5 * alone.mean(), (solved, alone)
    assert solved[-1] < 0.5 * alone[-1], (solved, alone)


def _generic_and_roshan_normal(problem, est, cfg):
    """The Schur normal equations two ways: schur_normal's generic linearisation of
    ``residual_blocks`` and ROSHAN's own ``linearize``; with the total cost."""
    free = problem.pose_mask.astype(jnp.float64)
    solver = slam.roshan_solver(cfg)
    args = (problem, cfg, free, problem.object_mask)

    @jax.jit
    def both(est):
        fn = lambda e, a: slam.residual_blocks(a[0], e, a[1])
        generic = schur_normal(fn, est, args, solver.structure(args), solver.retract, 6, 9)
        return generic, linearize(problem, est, cfg, free), slam.total_cost(problem, est, cfg)

    return both(est)


@pytest.mark.slow
def test_generic_linearisation_with_odometry_equals_roshans():
    # schur_normal's pose_pair block (2 dp + dl coloured columns) against ROSHAN's linearize
    # (per-factor jacfwd) on a map with odometry: the differentiable path (solve_batch
    # method="optimistix") linearises this way.
    problem, _, _ = _drifting_problem(num_frames=5)
    cfg = _cfg()
    est = slam.initialize(problem, cfg)
    generic, roshan, _ = _generic_and_roshan_normal(problem, est, cfg)
    assert generic.Hpp_next is not None and roshan.Hpp_next is not None
    for a, b in zip(generic, roshan):
        np.testing.assert_allclose(a, b, rtol=1e-7, atol=1e-7 * float(jnp.max(jnp.abs(b))))


def _same_boxes(problem, *args, **kw):
    """``slam.make_problem`` of ``problem``'s camera, pose priors and boxes, the rest from the arguments."""
    return slam.make_problem(
        problem.K,
        problem.image_size,
        problem.pose_prior,
        problem.box,
        problem.box_pose,
        problem.box_object,
        problem.object_class,
        *args,
        **kw,
    )


@pytest.mark.slow  # two solver programs compile (12-18 s on the 2-core CPU)
def test_pose_prior_weight_scales_each_poses_prior_and_zero_drops_it():
    problem, _, _ = _drifting_problem(num_frames=4)
    T = problem.num_poses
    w = np.array([[3.0, 2.0], [0.0, 0.0], [0.5, 0.0], [1.0, 1.0]])
    weighted = _same_boxes(
        problem,
        np.where(np.asarray(problem.texture_mask), np.asarray(problem.texture_depth), np.nan),
        odometry=np.asarray(problem.odometry)[: T - 1],
        pose_prior_weight=w,
    )
    cfg = _cfg()
    # jitted: op by op the initialisation, the residuals and the cost compiled hundreds of programs
    est = jax.jit(slam.initialize)(problem, cfg)
    residual_blocks, total_cost = jax.jit(slam.residual_blocks), jax.jit(slam.total_cost)
    # poses off their priors, so every prior row is non-zero
    est = slam.SlamEstimate(
        jnp.asarray(
            np.stack([_perturb(np.asarray(p), np.full(6, 0.01 * (k + 1))) for k, p in enumerate(est.camera_T_world)])
        ),
        est.rotation,
        est.center,
        est.radii,
    )
    plain = np.asarray(residual_blocks(problem, est, cfg)[1])
    rows = np.asarray(residual_blocks(weighted, est, cfg)[1])
    assert np.all(np.abs(plain) > 0)
    np.testing.assert_allclose(rows, plain * np.repeat(w, 3, axis=1), rtol=1e-12)
    # the structured solvers' linearisation sees the same weighted cost
    free = weighted.pose_mask.astype(jnp.float64)
    n = jax.jit(linearize)(weighted, est, cfg, free)
    np.testing.assert_allclose(n.cost, total_cost(weighted, est, cfg), rtol=1e-10)
    assert float(total_cost(weighted, est, cfg)) != pytest.approx(float(total_cost(problem, est, cfg)))
    for bad in (np.ones(T + 1), -np.ones(T), np.full(T, np.nan)):
        with pytest.raises(ValueError, match="pose_prior_weight"):
            _same_boxes(problem, pose_prior_weight=bad)


@pytest.mark.slow
def test_a_prior_on_the_first_pose_only_follows_the_boxes_not_the_drift():
    # Priors at 2 cm / 1 deg on every dead-reckoned pose pin the map to the drift; a prior on the
    # first pose alone, with the same odometry and boxes, lets the boxes pull the poses back.
    problem, true, dead = _drifting_problem()
    noise = NoiseModel(
        pose_rotation_sigma=np.radians(1.0),
        pose_translation_sigma=0.02,
        odometry_rotation_sigma=0.005,
        odometry_translation_sigma=0.02,
        box_sigma=2.0,
        texture_sigma=0.1,
    )
    cfg = slam.SolverConfig(noise=noise, max_steps=50)
    T = problem.num_poses
    first = np.zeros((T, 2))
    first[0] = 20.0
    # every pose's prior as an explicit weight of 1 (what None means): both problems one pytree
    # structure, so the solver compiles once for the two (and for the drifting test's solve)
    every, only_first = _with_prior_weights(problem, np.ones((T, 2))), _with_prior_weights(problem, first)
    solve = lambda p: SOLVE(p, np.asarray(p.pose_mask), cfg)  # every pose free

    def position_error(poses):
        centres = np.asarray(Q.invert_pose(poses))[:, :3, 3]
        return np.linalg.norm(centres - np.asarray(Q.invert_pose(true))[:, :3, 3], axis=-1).mean()

    pinned = position_error(np.asarray(solve(every)[0].camera_T_world))
    freed = position_error(np.asarray(solve(only_first)[0].camera_T_world))
    assert SOLVE._cache_size() == 1  # one program for the two problems (and the drifting test's)
    print(f"mean camera position error: priors on every pose {pinned:.3f} m, first pose only {freed:.3f} m")
    assert freed < 0.5 * pinned, (freed, pinned)


def test_upright_factor_against_finite_differences_and_its_symmetries():
    rng = np.random.default_rng(5)
    up = np.array([0.0, 0.0, 1.0])
    q = rng.normal(size=4)
    R = np.asarray(Q.quaternion_to_rotation(jnp.asarray(q / np.linalg.norm(q))))
    yaw = np.asarray(jaxlie.SO3.from_z_radians(0.7).as_matrix())
    flip = np.diag([1.0, -1.0, -1.0])
    sigma = 0.1
    # upright whatever the heading, and upside down too (the ellipsoid does not change)
    np.testing.assert_allclose(F.upright_residual(yaw, up, sigma), 0.0, atol=1e-12)
    np.testing.assert_allclose(F.upright_residual(yaw @ flip, up, sigma), 0.0, atol=1e-12)
    # a tilt of a few degrees about the x axis reads sin(tilt) / sigma on one row
    tilt = np.asarray(jaxlie.SO3.from_x_radians(0.05).as_matrix())
    np.testing.assert_allclose(
        np.abs(F.upright_residual(yaw @ tilt, up, sigma)), [0.0, np.sin(0.05) / sigma], atol=1e-12
    )
    # turning about the up axis changes nothing; the axis picks the standing axis
    r = F.upright_residual(R, up, sigma)
    np.testing.assert_allclose(F.upright_residual(yaw @ R, up, sigma), r, atol=1e-12)
    assert F.upright_residual(R, up, sigma, axis=0).shape == (2,)
    with pytest.raises(ValueError, match="axis"):
        F.upright_residual(R, up, sigma, axis=3)
    Rj = jnp.asarray(R)
    f = lambda w: F.upright_residual(Rj @ jaxlie.SO3.exp(w).as_matrix(), jnp.asarray(up), sigma)
    w0 = jnp.asarray(rng.normal(size=3) * 0.1)
    eps = 1e-6
    fd = np.stack([(f(w0 + eps * e) - f(w0 - eps * e)) / (2 * eps) for e in jnp.eye(3)], axis=1)
    np.testing.assert_allclose(jax.jacfwd(f)(w0), fd, rtol=1e-5, atol=1e-7)


@pytest.mark.slow
def test_upright_prior_linearisation_equals_the_generic_one():
    problem, _, _ = _drifting_problem(num_frames=5)
    cfg = _cfg(use_upright=True)
    est = slam.initialize(problem, cfg)
    # tilt every object so the prior is active
    tilt = jnp.asarray(jaxlie.SO3.from_x_radians(0.3).as_matrix())
    est = slam.SlamEstimate(est.camera_T_world, est.rotation @ tilt, est.center, est.radii)
    assert slam.residual_blocks(problem, est, cfg)[2].shape[-1] == 5
    generic, roshan, cost = _generic_and_roshan_normal(problem, est, cfg)
    np.testing.assert_allclose(roshan.cost, cost, rtol=1e-10)
    for a, b in zip(generic, roshan):
        np.testing.assert_allclose(a, b, rtol=1e-7, atol=1e-7 * float(jnp.max(jnp.abs(b))))


@pytest.mark.slow
def test_support_prior_linearisation_equals_the_generic_one():
    problem, _, _ = _drifting_problem(num_frames=5)
    cfg = _cfg(use_upright=True, use_support=True, support_height=-0.5, support_sigma=0.05)
    est = slam.initialize(problem, cfg)
    tilt = jnp.asarray(jaxlie.SO3.from_x_radians(0.3).as_matrix())
    est = slam.SlamEstimate(est.camera_T_world, est.rotation @ tilt, est.center, est.radii)
    shapes = slam.residual_blocks(problem, est, cfg)[2]
    assert shapes.shape[-1] == 6 and float(jnp.max(jnp.abs(shapes[:, 5]))) > 1.0  # the prior is active
    generic, roshan, cost = _generic_and_roshan_normal(problem, est, cfg)
    np.testing.assert_allclose(roshan.cost, cost, rtol=1e-10)
    for a, b in zip(generic, roshan):
        np.testing.assert_allclose(a, b, rtol=1e-7, atol=1e-7 * float(jnp.max(jnp.abs(b))))
