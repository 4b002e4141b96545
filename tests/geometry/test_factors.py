"""ROSHAN factors: finite-difference Jacobians, zero residual at truth, border-edge masks,
degenerate geometry, robust losses, the class table and single-view initialisation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import factors as F, quadrics as Q
from jaxsem.slam._cost import first_order_object, first_order_pose, retract_object, retract_pose  # layers: white-box

K = jnp.array([[525.0, 0.0, 320.0], [0.0, 525.0, 240.0], [0.0, 0.0, 1.0]])
IMAGE = jnp.array([640.0, 480.0])


def _scene(seed=0):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=4)
    R = Q.quaternion_to_rotation(jnp.asarray(q / np.linalg.norm(q)))
    c = jnp.asarray(rng.normal(size=3) * 0.5)
    r = jnp.asarray(rng.uniform(0.5, 2.0, 3))
    eye = jnp.asarray([14.0, 3.0, 2.0]) + jnp.asarray(rng.normal(size=3))
    pose = Q.look_at(eye, c + jnp.asarray(rng.normal(size=3) * 0.3))
    return pose, R, c, r


def _fd_check(f, x, eps=1e-6, rtol=1e-5, atol=1e-6):
    """jacfwd of f at x against central finite differences (one vmapped compile)."""
    steps = eps * jnp.eye(x.shape[0])
    both = jax.jit(lambda x: (jax.jacfwd(f)(x), jax.vmap(f)(jnp.concatenate([x + steps, x - steps]))))
    jac, vals = both(x)
    n = x.shape[0]
    fd = ((vals[:n] - vals[n:]) / (2 * eps)).T
    np.testing.assert_allclose(jac, fd, rtol=rtol, atol=atol)
    return jac


def _pose_obj_fn(factor, pose, R, c, r):
    """A factor as a function of the 15 tangent coordinates (pose 6, rotation 3, centre 3,
    radii parameter 3) through the true exponential-map retraction."""

    def f(x):
        P = retract_pose(pose, x[:6])
        R2, c2, r2 = retract_object(R, c, r, x[6:15])
        return factor(P, R2, c2, r2)

    return f


@pytest.mark.slow
def test_box_residual_jacobian_matches_finite_differences():
    pose, R, c, r = _scene(0)
    box_true, valid = Q.project_bbox(R, c, r, K, pose)
    assert bool(valid)
    meas = box_true + jnp.array([3.0, -2.0, 4.0, 1.0])
    f = _pose_obj_fn(lambda P, R2, c2, r2: F.box_residual(P, R2, c2, r2, meas, K, IMAGE), pose, R, c, r)
    jac = _fd_check(f, jnp.zeros(15))
    assert np.abs(jac[:4]).max() > 1.0  # edges depend on every block

    # The first-order twins used by the structured solver give the same Jacobian at zero.
    def g(x):
        P = first_order_pose(pose, x[:6])
        R2, c2, r2 = first_order_object(R, c, r, x[6:15])
        return F.box_residual(P, R2, c2, r2, meas, K, IMAGE)

    np.testing.assert_allclose(jax.jit(jax.jacfwd(g))(jnp.zeros(15)), jac, rtol=1e-9, atol=1e-9)


@pytest.mark.slow
def test_texture_pose_shape_jacobians_match_finite_differences():
    pose, R, c, r = _scene(2)
    depth, _ = Q.texture_plane_depth(R, c, r, pose)
    f = _pose_obj_fn(lambda P, R2, c2, r2: F.texture_residual(P, R2, c2, r2, depth + 0.3, 0.2)[None], pose, R, c, r)
    _fd_check(f, jnp.zeros(15))
    prior = retract_pose(pose, jnp.array([0.1, -0.05, 0.02, 0.03, -0.02, 0.04]))
    fp = lambda x: F.pose_prior_residual(retract_pose(pose, x), prior, 0.02, 0.05)
    _fd_check(fp, jnp.full(6, 0.01))
    mean, sigma = jnp.array([2.4, 0.9, 0.7]), jnp.array([0.3, 0.1, 0.1])
    fs = lambda s: F.shape_prior_residual(F.radii_from_param(s), mean, sigma)
    _fd_check(fs, F.param_from_radii(r))


def test_zero_residual_at_truth():
    pose, R, c, r = _scene(3)
    box, _ = Q.project_bbox(R, c, r, K, pose)
    depth, _ = Q.texture_plane_depth(R, c, r, pose)
    np.testing.assert_allclose(F.box_residual(pose, R, c, r, box, K, IMAGE), 0.0, atol=1e-9)
    np.testing.assert_allclose(F.texture_residual(pose, R, c, r, depth), 0.0, atol=1e-12)
    np.testing.assert_allclose(F.pose_prior_residual(pose, pose, 0.01, 0.01), 0.0, atol=1e-9)
    mean = jnp.asarray(F.shape_prior("car").mean)
    np.testing.assert_allclose(F.shape_prior_residual(mean, mean, 0.1), 0.0)


def test_pose_prior_whitens_simulated_odometry_noise_far_from_the_origin():
    """Regression: the prior's error was taken in the world frame (``log(prior^-1 pose)``), so
    a 1 deg rotation of a camera 40 m from the origin showed up as a ~0.7 m translation residual
    (mean square ~100 instead of 1 per component at sigma = 5 cm)."""
    from jaxsem.slam import sim

    rng = np.random.default_rng(0)
    n = 4000
    eyes = jnp.asarray(rng.uniform(-40.0, 40.0, (n, 3)))
    targets = eyes + jnp.asarray(rng.normal(size=(n, 3)))
    truth = jax.vmap(Q.look_at)(eyes, targets)
    noisy = sim.perturb_poses(jax.random.PRNGKey(1), truth, 0.05, 1.0)
    res = F.pose_prior_residual(truth, noisy, jnp.deg2rad(1.0), 0.05)
    mean_square = np.mean(np.asarray(res) ** 2, axis=0)
    np.testing.assert_allclose(mean_square, 1.0, rtol=0.15)


@pytest.mark.slow  # about 5 s of compiling: the fast suite stays under 6 minutes
def test_border_edges_are_dropped_exactly():
    pose, R, c, r = _scene(4)
    box, _ = Q.project_bbox(R, c, r, K, pose)
    # Measured box touching the left border (u_min = 3 px) and the bottom (v_max = 475 px).
    meas = jnp.array([3.0, box[1] + 5.0, box[2] + 5.0, 475.0])
    res = F.box_residual(pose, R, c, r, meas, K, IMAGE, border_margin=10.0)
    mask = F.edge_mask(meas, IMAGE, 10.0)
    np.testing.assert_array_equal(np.asarray(mask), [False, True, True, False])
    assert res[0] == 0.0 and res[3] == 0.0
    assert abs(res[1]) > 1.0 and abs(res[2]) > 1.0
    # The dropped edges stay zero (and carry no gradient) whatever the ellipsoid does.
    g = jax.jacfwd(lambda cc: F.box_residual(pose, R, cc, r, meas, K, IMAGE))(c)
    np.testing.assert_array_equal(np.asarray(g[0]), 0.0)
    np.testing.assert_array_equal(np.asarray(g[3]), 0.0)
    # Exactly at the margin the edge is still dropped; just inside it is kept.
    m2 = F.edge_mask(jnp.array([10.0, 10.5, 629.5, 470.0]), IMAGE, 10.0)
    np.testing.assert_array_equal(np.asarray(m2), [False, True, True, False])


def test_an_occluder_cut_edge_costs_less_than_the_same_gap_outwards():
    """A measured box is the visible part: with ``outward_scale`` k, a measured edge short of the
    projection (cut inwards, as an occluder would) costs k^2 less than the same gap the other way;
    k = 1 is the default, symmetric factor; the residual is continuous at the truth with finite
    gradients there."""
    pose, R, c, r = _scene(1)
    box, valid = Q.project_bbox(R, c, r, K, pose)
    assert bool(valid)

    @jax.jit
    def edges(meas, k, cc):
        return F.box_residual(pose, R, cc, r, meas, K, IMAGE, outward_scale=k)[:4]

    gap = 6.0
    for i, inward in enumerate([1.0, 1.0, -1.0, -1.0]):  # the direction that shrinks the box
        step = jnp.zeros(4).at[i].set(gap * inward)
        for k in (1.0, 3.0):
            cut = edges(box + step, k, c)  # the measured edge moved into the box
            grown = edges(box - step, k, c)  # ... and out of it
            np.testing.assert_allclose(float(jnp.sum(cut**2)) * k**2, float(jnp.sum(grown**2)), rtol=1e-3)
            assert float(jnp.sum(grown**2)) > 1.0
    np.testing.assert_allclose(
        edges(box + 2.0, 1.0, c), F.box_residual(pose, R, c, r, box + 2.0, K, IMAGE)[:4], rtol=0, atol=0
    )
    for tiny in (1e-9, -1e-9):
        assert float(jnp.max(jnp.abs(edges(box + tiny, 4.0, c)))) < 1e-8
    g = jax.jacfwd(lambda cc: edges(box, 4.0, cc))(c)
    assert bool(jnp.all(jnp.isfinite(g))) and float(jnp.max(jnp.abs(g))) > 1.0


@pytest.mark.slow
@pytest.mark.parametrize("case", ["inside", "behind", "straddling"])
def test_degenerate_geometry_is_finite_and_points_back_to_validity(case):
    pose = Q.look_at(jnp.array([0.0, 0.0, 1.5]), jnp.array([10.0, 0.0, 1.5]))
    R = jnp.eye(3)
    r = jnp.array([2.4, 0.9, 0.7])
    c = {
        "inside": jnp.array([0.5, 0.2, 1.3]),
        "behind": jnp.array([-8.0, 1.0, 1.5]),
        "straddling": jnp.array([0.3, 4.0, 1.5]),
    }[case]
    meas = jnp.array([300.0, 200.0, 360.0, 260.0])
    _, valid = Q.project_bbox(R, c, r, K, pose)
    assert not bool(valid)
    cost = lambda cc, rr: 0.5 * jnp.sum(jnp.square(F.box_residual(pose, R, cc, rr, meas, K, IMAGE)))
    val = cost(c, r)
    gc, gr = jax.grad(cost, argnums=(0, 1))(c, r)
    assert np.isfinite(val) and np.all(np.isfinite(gc)) and np.all(np.isfinite(gr))
    assert np.linalg.norm(gc) > 1e-3  # never a flat constant
    forward = pose[2, :3]  # camera z axis in the world
    assert float(jnp.dot(-gc, forward)) > 0  # descent moves the ellipsoid in front of the camera
    # A descent step raises the near-side depth (towards valid geometry) and lowers the cost.
    near = lambda cc, rr: Q.texture_plane_depth(R, cc, rr, pose)[0]
    step = 1e-3 / jnp.linalg.norm(gc)
    assert near(c - step * gc, r - step * gr) > near(c, r)
    assert cost(c - step * gc, r - step * gr) < val
    # The invalid side costs more than the valid neighbourhood of the same measurement.
    c_ok = c.at[0].set(12.0)
    assert cost(c_ok, r) < val


def test_robust_losses_reweight_and_stay_finite():
    r = jnp.linspace(-10, 10, 41)
    k = 2.0
    hub = F.robust_residual(r, "huber", k)
    rho_h = jnp.where(jnp.abs(r) <= k, r**2, 2 * k * jnp.abs(r) - k**2)
    np.testing.assert_allclose(hub**2, rho_h, rtol=1e-12)
    cau = F.robust_residual(r, "cauchy", k)
    np.testing.assert_allclose(cau**2, k**2 * jnp.log1p(r**2 / k**2), rtol=1e-10, atol=1e-14)
    assert np.all(np.sign(cau) == np.sign(r))
    for loss in ("l2", "huber", "cauchy"):
        g = jax.grad(lambda x: F.robust_residual(x, loss, k))(0.0)
        np.testing.assert_allclose(g, 1.0)
    with pytest.raises(ValueError, match="huber"):
        F.robust_residual(r, "tukey")


def test_class_table_and_lookup():
    car = F.shape_prior("car")
    np.testing.assert_allclose(2 * np.array(car.mean), [4.88, 1.84, 1.45])
    assert int(np.argmax(car.sigma)) == 0  # largest uncertainty on the length
    np.testing.assert_allclose(2 * np.array(F.shape_prior("cracker_box").mean), [0.164036, 0.213437, 0.0718])
    can = 2 * np.array(F.shape_prior("soup_can").mean)
    assert abs(can[0] - 0.0677) < 1e-9 and abs(can[2] - 0.1018) < 1e-9  # cylinder axis along z
    for name in ("person", "door", "chair", "ball"):
        assert name in F.CLASS_NAMES
    with pytest.raises(ValueError, match="known classes.*car"):
        F.class_index("truck")
    mean, sigma = F.shape_prior_table()
    assert mean.shape == (len(F.CLASS_NAMES), 3) and bool(jnp.all(sigma > 0))


def test_radii_parameterisation_is_positive_and_invertible():
    r = jnp.array([1e-3, 0.035, 0.9, 2.44, 30.0])
    np.testing.assert_allclose(F.radii_from_param(F.param_from_radii(r)), r, rtol=1e-10)
    s = jnp.array([-50.0, -5.0, 0.0, 700.0])
    out = F.radii_from_param(s)
    assert bool(jnp.all(out > 0)) and bool(jnp.all(jnp.isfinite(out)))


def test_single_view_init_on_ray_and_matches_texture_plane():
    pose, R, c, r = _scene(5)
    box, _ = Q.project_bbox(R, c, r, K, pose)
    depth, _ = Q.texture_plane_depth(R, c, r, pose)
    mean = jnp.asarray(F.shape_prior("car").mean)
    R0, c0, r0 = F.single_view_init(pose, box, K, mean, texture_depth=depth, texture_mask=True)
    np.testing.assert_allclose(R0, jnp.eye(3))
    np.testing.assert_allclose(r0, mean)
    # Centre projects onto the box centre, and the predicted texture plane equals the measured one.
    p = K @ (pose[:3, :3] @ c0 + pose[:3, 3])
    np.testing.assert_allclose(p[:2] / p[2], [(box[0] + box[2]) / 2, (box[1] + box[3]) / 2], atol=1e-8)
    np.testing.assert_allclose(Q.texture_plane_depth(R0, c0, r0, pose)[0], depth, atol=1e-9)
    # Without a texture plane and with the depth from the box size switched off: the default
    # depth along the optical axis.
    _, c1, _ = F.single_view_init(
        pose, box, K, mean, texture_depth=depth, texture_mask=False, default_depth=7.0, depth_from_box=False
    )
    np.testing.assert_allclose(Q.camera_depth(c1, pose), 7.0, atol=1e-9)
