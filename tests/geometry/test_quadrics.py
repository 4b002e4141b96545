"""Geometry core against independent computations of the same quantities.

The reference for boxes and texture depths is the surface itself: the ellipsoid is sampled
densely in its parametric angles, the extreme sample of each image coordinate is refined by a
zooming grid search on the surface, and the result compared with the closed forms (float64).
"""

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from jaxsem import quadrics as q
from jaxsem._geometry.bbox import _project_bbox  # layers: white-box (the custom-JVP path itself)

N_CASES = 200


def random_case(rng, n):
    """Random rotations, radii 0.1-3 m, ellipsoids 2-20 m in front of random cameras."""
    quat = rng.normal(size=(n, 4))
    R = np.asarray(q.quaternion_to_rotation(quat))
    radii = rng.uniform(0.1, 3.0, size=(n, 3))
    cam_quat = rng.normal(size=(n, 4))
    cam_R = np.asarray(q.quaternion_to_rotation(cam_quat))  # camera_R_world
    cam_t = rng.normal(scale=5.0, size=(n, 3))
    pose = np.tile(np.eye(4), (n, 1, 1))
    pose[:, :3, :3] = cam_R
    pose[:, :3, 3] = cam_t
    # Centre in the camera frame: depth 2-20 m plus the ellipsoid's size so that it is fully in
    # front; lateral offset keeps it roughly in view.
    depth = rng.uniform(2.0, 20.0, size=n) + radii.max(axis=1)
    lateral = rng.uniform(-0.4, 0.4, size=(n, 2)) * depth[:, None]
    center_cam = np.concatenate([lateral, depth[:, None]], axis=1)
    center = np.einsum("nji,nj->ni", cam_R, center_cam - cam_t)
    f = rng.uniform(300, 1200, size=n)
    K = np.tile(np.eye(3), (n, 1, 1))
    K[:, 0, 0] = f * rng.uniform(0.9, 1.1, size=n)
    K[:, 1, 1] = f
    K[:, 0, 2] = rng.uniform(200, 700, size=n)
    K[:, 1, 2] = rng.uniform(150, 500, size=n)
    K[:, 0, 1] = rng.uniform(-2, 2, size=n)  # a little skew, to exercise it
    return R, center, radii, K, pose


def _surface(R, c, r, theta, phi):
    """Surface points (n, ..., 3) at parametric angles theta (polar), phi (azimuth)."""
    s = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
    local = s * r[:, None, :]
    return np.einsum("nij,nkj->nki", R, local) + c[:, None, :]


def surface_extreme(R, c, r, value_fn, sign):
    """min over the surface of sign * value_fn(points) for each case, by dense search + zooming."""
    n = R.shape[0]
    th, ph = np.meshgrid(np.linspace(0, np.pi, 61), np.linspace(-np.pi, np.pi, 121), indexing="ij")
    th, ph = np.broadcast_to(th.ravel(), (n, th.size)), np.broadcast_to(ph.ravel(), (n, ph.size))
    vals = sign * value_fn(_surface(R, c, r, th, ph))
    best = np.argmin(vals, axis=1)
    bt, bp = th[np.arange(n), best], ph[np.arange(n), best]
    span_t, span_p = np.pi / 60, 2 * np.pi / 120
    g = np.linspace(-1, 1, 11)
    for _ in range(16):
        tt = bt[:, None] + span_t * np.repeat(g, 11)[None, :]
        pp = bp[:, None] + span_p * np.tile(g, 11)[None, :]
        vals = sign * value_fn(_surface(R, c, r, tt, pp))
        best = np.argmin(vals, axis=1)
        bt, bp = tt[np.arange(n), best], pp[np.arange(n), best]
        span_t, span_p = span_t / 3, span_p / 3
    return sign * vals[np.arange(n), best]


def to_camera(pose, pts):
    return np.einsum("nij,nkj->nki", pose[:, :3, :3], pts) + pose[:, None, :3, 3]


def pixel_uv(K, pose):
    def fn(pts):
        pc = to_camera(pose, pts)
        pix = np.einsum("nij,nkj->nki", K, pc)
        return pix[..., 0] / pix[..., 2], pix[..., 1] / pix[..., 2]

    return fn


@pytest.fixture(scope="module")
def cases():
    return random_case(np.random.default_rng(0), N_CASES)


def test_quadricslam_reference_box():
    K = np.array([[525.0, 0, 320], [0, 525, 240], [0, 0, 1]])
    pose = np.eye(4)
    pose[2, 3] = 5.0  # camera at world (0, 0, -5) looking along +z
    box, valid = q.project_bbox(np.eye(3), np.zeros(3), np.ones(3), K, pose)
    expected = [212.8348, 132.8348, 427.1652, 347.1652]
    np.testing.assert_allclose(box, expected, atol=1e-4)
    h = 525 / np.sqrt(24)
    np.testing.assert_allclose(box, [320 - h, 240 - h, 320 + h, 240 + h], atol=1e-9)
    assert bool(valid)
    conic = q.project_dual_conic(q.dual_quadric(np.eye(3), np.zeros(3), np.ones(3)), K, pose)
    box2, valid2 = q.conic_bbox(conic)
    np.testing.assert_allclose(box2, box, atol=1e-9)
    assert bool(valid2)


@pytest.mark.slow
def test_project_bbox_matches_surface_extremes(cases):
    R, c, r, K, pose = cases
    box, valid = q.project_bbox(R, c, r, K, pose)
    box = np.asarray(box)
    assert np.all(np.asarray(valid))
    uv = pixel_uv(K, pose)
    ref = np.stack(
        [
            surface_extreme(R, c, r, lambda p: uv(p)[0], +1),
            surface_extreme(R, c, r, lambda p: uv(p)[1], +1),
            surface_extreme(R, c, r, lambda p: uv(p)[0], -1),
            surface_extreme(R, c, r, lambda p: uv(p)[1], -1),
        ],
        axis=1,
    )
    np.testing.assert_allclose(box, ref, atol=1e-3, rtol=0)


def test_conic_route_equals_closed_form(cases):
    R, c, r, K, pose = cases
    box, valid = q.project_bbox(R, c, r, K, pose)
    conic = q.project_dual_conic(q.dual_quadric(R, c, r), K, pose)
    box2, valid2 = q.conic_bbox(conic)
    np.testing.assert_allclose(box2, box, atol=1e-6, rtol=1e-9)
    assert np.all(np.asarray(valid2))


def _composed_bbox(R, c, r, K, pose):
    """The readable reference: dual quadric -> dual conic -> eq. 4.10."""
    return q.conic_bbox(q.project_dual_conic(q.dual_quadric(R, c, r), K, pose))


def _cases_with_invalid(rng, n):
    """Random cases in front of the camera, plus cases with the camera inside the ellipsoid and
    cases straddling the principal plane (far from the boundaries of either mask)."""
    R, c, r, K, pose = random_case(rng, n)
    kind = np.arange(n) % 4  # 0, 1: in front; 2: camera inside; 3: straddling the image plane
    cam_R, cam_t = pose[:, :3, :3], pose[:, :3, 3]
    center_cam = np.einsum("nij,nj->ni", cam_R, c) + cam_t
    inside = rng.uniform(-0.3, 0.3, size=(n, 3)) * r.min(axis=1, keepdims=True)
    center_cam = np.where((kind == 2)[:, None], inside, center_cam)
    r_depth = np.sqrt(np.sum(np.square(np.einsum("nij,njk->nik", cam_R, R)[:, 2, :] * r), axis=1))
    straddle = center_cam * 0.0
    straddle[:, :2] = rng.uniform(-0.2, 0.2, size=(n, 2)) * r.min(axis=1, keepdims=True)
    straddle[:, 2] = rng.uniform(-0.5, 0.5, size=n) * r_depth
    center_cam = np.where((kind == 3)[:, None], straddle, center_cam)
    c = np.einsum("nji,nj->ni", cam_R, center_cam - cam_t)
    return (R, c, r, K, pose), kind


@pytest.mark.slow
def test_fused_path_agrees_with_composed_conic_path():
    rng = np.random.default_rng(21)
    (R, c, r, K, pose), kind = _cases_with_invalid(rng, 400)
    box, valid = q.project_bbox(R, c, r, K, pose)
    ref, ref_valid = _composed_bbox(R, c, r, K, pose)
    box, valid, ref, ref_valid = map(np.asarray, (box, valid, ref, ref_valid))
    assert np.array_equal(valid, ref_valid)
    assert np.array_equal(valid, kind < 2)
    np.testing.assert_allclose(box[valid], ref[valid], rtol=1e-9, atol=1e-9 * np.abs(ref[valid]).max())
    assert np.all(np.isfinite(box))
    # Behind the camera the dual conic is that of the mirror image in front, which conic_bbox
    # alone cannot tell apart: the fused path's depth test rejects it, and so does the composed
    # path (project_dual_conic reads the centre's depth off Q* and returns the zero conic).
    behind = (
        R[:20],
        -c[:20] + 2 * np.einsum("nji,nj->ni", pose[:20, :3, :3], -pose[:20, :3, 3]),
        r[:20],
        K[:20],
        pose[:20],
    )
    _, v_behind = q.project_bbox(*behind)
    _, ref_behind = _composed_bbox(*behind)
    assert not np.any(np.asarray(v_behind)) and not np.any(np.asarray(ref_behind))


_K_USED = np.zeros((3, 3), bool)
_K_USED[0, 0] = _K_USED[0, 1] = _K_USED[0, 2] = _K_USED[1, 1] = _K_USED[1, 2] = True


@pytest.mark.slow
def test_fused_path_gradients_match_composed_conic_path():
    rng = np.random.default_rng(22)
    R, c, r, K, pose = random_case(rng, 200)
    weights = rng.normal(size=(200, 4))
    loss = lambda fn: lambda *args: jnp.sum(fn(*args)[0] * weights)
    grads = jax.jit(jax.grad(loss(q.project_bbox), argnums=(0, 1, 2, 3, 4)))(R, c, r, K, pose)
    ref = jax.jit(jax.grad(loss(_composed_bbox), argnums=(0, 1, 2, 3, 4)))(R, c, r, K, pose)
    grads, ref = [np.asarray(g) for g in grads], [np.asarray(g) for g in ref]
    # K enters only through fx, s, cx, fy, cy (K is checked to have that form at the boundary);
    # the composed path also differentiates the structural zeros and ones.
    assert np.all(grads[3][:, ~_K_USED] == 0)
    grads[3], ref[3] = grads[3][:, _K_USED], ref[3][:, _K_USED]
    for name, g, g_ref in zip(["rotation", "center", "radii", "K", "camera_T_world"], grads, ref):
        np.testing.assert_allclose(g, g_ref, rtol=1e-7, atol=1e-10 * np.abs(g_ref).max(), err_msg=name)


@pytest.mark.slow
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_fused_path_custom_jvp_matches_plain_autodiff(dtype):
    """The hand-written JVP rule (and so its transpose, the gradient) against autodiff of the same
    forward formulas, on valid and invalid cases alike (invalid boxes have a defined gradient too)."""
    rng = np.random.default_rng(23)
    (R, c, r, K, pose), kind = _cases_with_invalid(rng, 400)
    r[::37] = 0.0  # zero radii: the square roots sit at zero
    c[1::41] = -c[1::41]  # some behind the camera
    args = [jnp.asarray(a, dtype) for a in (R, c, r, K, pose)]
    tangents = [jnp.asarray(rng.normal(size=np.shape(a)), dtype) for a in args]
    (box, valid), (dbox, _) = jax.jvp(_project_bbox, args, tangents)
    (box_p, valid_p), (dbox_p, _) = jax.jvp(q.project_bbox_reference, args, tangents)
    assert np.array_equal(valid, valid_p) and not np.all(valid) and np.any(valid)
    np.testing.assert_array_equal(box, box_p)
    tol = 1e-10 if dtype == np.float64 else 1e-4
    scale = np.abs(np.asarray(dbox_p, np.float64)) + 1e-3 * np.abs(np.asarray(dbox_p, np.float64)).max()
    assert np.all(np.abs(np.asarray(dbox, np.float64) - np.asarray(dbox_p, np.float64)) <= tol * scale)
    g = jnp.asarray(rng.normal(size=box.shape), dtype)
    vjp = jax.vjp(lambda *a: _project_bbox(*a)[0], *args)[1](g)
    vjp_p = jax.vjp(lambda *a: q.project_bbox_reference(*a)[0], *args)[1](g)
    for a, b in zip(vjp, vjp_p):
        a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
        assert np.all(np.isfinite(a))
        np.testing.assert_allclose(a, b, rtol=tol, atol=tol * np.abs(b).max())


def test_texture_plane_depth_matches_nearest_surface_point(cases):
    R, c, r, K, pose = cases
    depth, valid = q.texture_plane_depth(R, c, r, pose)
    ref = surface_extreme(R, c, r, lambda p: to_camera(pose, p)[..., 2], +1)
    assert np.all(np.asarray(valid))
    np.testing.assert_allclose(depth, ref, atol=1e-5, rtol=0)


def test_dual_and_primal_are_inverse(cases):
    R, c, r, _, _ = cases
    prod = np.asarray(q.dual_quadric(R, c, r)) @ np.asarray(q.primal_quadric(R, c, r))
    np.testing.assert_allclose(prod, np.broadcast_to(np.eye(4), prod.shape), atol=1e-9)


def test_algebraic_distance_sign_and_value(cases):
    R, c, r, _, _ = cases
    rng = np.random.default_rng(1)
    pts = c[:, None, :] + rng.normal(size=(N_CASES, 50, 3)) * r.max(axis=1)[:, None, None]
    d = np.asarray(q.algebraic_distance(pts, R, c, r))
    local = np.einsum("nji,nkj->nki", R, pts - c[:, None, :]) / r[:, None, :]
    inside = np.sum(local**2, -1) < 1
    assert np.array_equal(d < 0, inside)
    Q = np.asarray(q.primal_quadric(R, c, r))
    hom = np.concatenate([pts, np.ones(pts.shape[:-1] + (1,))], -1)
    np.testing.assert_allclose(d, np.einsum("nki,nij,nkj->nk", hom, Q, hom), atol=1e-8)


def test_surface_points_lie_on_surface(cases):
    R, c, r, _, _ = cases
    pts = q.surface_points(jax.random.PRNGKey(0), R, c, r, 64)
    assert pts.shape == (N_CASES, 64, 3)
    np.testing.assert_allclose(q.algebraic_distance(pts, R, c, r), 0.0, atol=1e-10)


def test_ground_extents_and_raster(cases):
    R, c, r, _, _ = cases
    bounds = np.asarray(q.ground_bounds(R, c, r))
    ref = np.stack(
        [
            surface_extreme(R, c, r, lambda p: p[..., 0], +1),
            surface_extreme(R, c, r, lambda p: p[..., 1], +1),
            surface_extreme(R, c, r, lambda p: p[..., 0], -1),
            surface_extreme(R, c, r, lambda p: p[..., 1], -1),
        ],
        axis=1,
    )
    np.testing.assert_allclose(bounds, ref, atol=1e-5)
    conic_box, valid = q.conic_bbox(q.ground_conic(R, c, r))
    assert np.all(np.asarray(valid))
    np.testing.assert_allclose(conic_box, bounds, atol=1e-8)


def test_rasterize_footprint_against_column_test():
    rng = np.random.default_rng(3)
    R = np.asarray(q.random_rotation(jax.random.PRNGKey(3), (4,)))
    c = np.column_stack([rng.uniform(1, 5, 4), rng.uniform(1, 4, 4), rng.uniform(0, 1, 4)])
    r = rng.uniform(0.2, 1.0, size=(4, 3))
    ids = np.array([1, 2, 3, 4])
    res, origin, shape = 0.1, np.array([0.0, 0.0]), (50, 60)
    grid = np.asarray(q.rasterize_footprint(R, c, r, ids, shape, origin, res))
    assert grid.shape == shape and grid.dtype == np.int32
    # Independent: a cell is covered when some point of its vertical column is inside.
    ys, xs = np.mgrid[0:50, 0:60]
    X = origin[0] + (xs + 0.5) * res
    Y = origin[1] + (ys + 0.5) * res
    expected = np.zeros(shape, int)
    margin_ok = np.ones(shape, bool)
    for k in range(4):
        zs = np.linspace(c[k, 2] - 1.2, c[k, 2] + 1.2, 1201)
        pts = np.stack(np.broadcast_arrays(X[..., None], Y[..., None], zs), -1) - c[k]
        local = (pts @ R[k]) / r[k]
        m = np.min(np.sum(local**2, -1), axis=-1)
        expected = np.where(m <= 1, np.maximum(expected, ids[k]), expected)
        margin_ok &= np.abs(m - 1) > 1e-2  # cells on the boundary are ambiguous at this sampling
    assert np.array_equal(grid[margin_ok], expected[margin_ok])
    assert (grid > 0).sum() > 100


# ---------------------------------------------------------------------------------------------
# Gradients.


def _box_of_params(params, K, pose):
    quat, center, log_r, cam_t = params[:4], params[4:7], params[7:10], params[10:13]
    R = q.quaternion_to_rotation(quat)
    pose = pose.at[:3, 3].add(cam_t)
    box, _ = q.project_bbox(R, center, jnp.exp(log_r), K, pose)
    depth, _ = q.texture_plane_depth(R, center, jnp.exp(log_r), pose)
    return jnp.concatenate([box, depth[None]])


@jax.jit
def _jacobians(params, K, pose):
    fn = lambda p: _box_of_params(p, K, pose)
    h = 1e-6
    steps = h * jnp.eye(params.size)
    fd = jax.vmap(lambda e: (fn(params + e) - fn(params - e)) / (2 * h), out_axes=1)(steps)
    return jax.jacfwd(fn)(params), jax.jacrev(fn)(params), fd


@pytest.mark.slow
def test_jacobians_three_ways(cases):
    R, c, r, K, pose = cases
    for i in range(20):
        quat = q.rotation_to_quaternion(R[i])
        params = jnp.concatenate([quat, c[i], jnp.log(r[i]), jnp.zeros(3)])
        jf, jr, fd = _jacobians(params, jnp.asarray(K[i]), jnp.asarray(pose[i]))
        np.testing.assert_allclose(jf, jr, rtol=1e-10, atol=1e-8)
        np.testing.assert_allclose(jf, fd, rtol=1e-5, atol=1e-6 * float(jnp.abs(jf).max()))


DEGENERATE = {
    "camera_at_centre": (np.zeros(3), np.array([1.0, 2.0, 0.5])),
    "camera_on_surface": (np.array([0.0, 0.0, 1.0]), np.array([1.0, 2.0, 1.0])),
    "behind_camera": (np.array([0.0, 0.0, -8.0]), np.array([1.0, 2.0, 0.5])),
    "straddling": (np.array([3.0, 0.0, 0.5]), np.array([1.0, 2.0, 1.5])),
    "radii_near_zero": (np.array([0.5, 0.3, 6.0]), np.array([1e-12, 1e-12, 1e-12])),
    "radii_zero": (np.array([0.5, 0.3, 6.0]), np.zeros(3)),
    "identical_radii": (np.array([0.5, 0.3, 6.0]), np.array([1.0, 1.0, 1.0])),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(DEGENERATE))
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_degenerate_inputs_finite_values_and_gradients(name, dtype):
    center, radii = DEGENERATE[name]
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]], dtype)
    pose = np.eye(4, dtype=dtype)

    @jax.jit
    def loss(center, radii, pose, K):
        box, valid = q.project_bbox(np.eye(3, dtype=dtype), center, radii, K, pose)
        depth, dvalid = q.texture_plane_depth(np.eye(3, dtype=dtype), center, radii, pose)
        conic = q.project_dual_conic(q.dual_quadric(np.eye(3, dtype=dtype), center, radii), K, pose)
        cbox, cvalid = q.conic_bbox(conic)
        alg = q.algebraic_distance(jnp.zeros((1, 3), dtype), np.eye(3, dtype=dtype), center, radii)
        return jnp.sum(box) + depth + 1e-3 * jnp.sum(cbox) + jnp.sum(alg) * 1e-6, (valid, dvalid, cvalid)

    args = (center.astype(dtype), radii.astype(dtype), pose, K)
    (value, (valid, dvalid, cvalid)), grads = jax.jit(jax.value_and_grad(loss, argnums=(0, 1, 2, 3), has_aux=True))(
        *args
    )
    assert np.isfinite(value)
    for g in grads:
        assert np.all(np.isfinite(g)), name
    if name in ("camera_at_centre", "camera_on_surface", "behind_camera", "straddling"):
        assert not bool(valid) and not bool(dvalid)
    if name in ("camera_at_centre", "camera_on_surface", "straddling"):
        assert not bool(cvalid)
    if name in ("identical_radii", "radii_near_zero"):
        assert bool(valid) and bool(dvalid)


def test_conic_bbox_of_degenerate_conics_is_finite():
    for C in [np.zeros((3, 3)), np.eye(3), -np.eye(3), np.diag([1.0, -1.0, -1.0])]:
        box, valid = q.conic_bbox(C)
        g = jax.grad(lambda C: jnp.sum(q.conic_bbox(C)[0]))(jnp.asarray(C))
        assert np.all(np.isfinite(box)) and np.all(np.isfinite(g))
        assert not bool(valid)


# ---------------------------------------------------------------------------------------------
# Shapes, dtypes, compilation.


@pytest.mark.slow
@pytest.mark.parametrize("batch", [(), (5,), (2, 3)])
def test_batch_shapes(batch):
    rng = np.random.default_rng(4)
    n = int(np.prod(batch)) if batch else 1
    R, c, r, K, pose = random_case(rng, n)
    R, c, r = R.reshape(batch + (3, 3)), c.reshape(batch + (3,)), r.reshape(batch + (3,))
    K, pose = K.reshape(batch + (3, 3)), pose.reshape(batch + (4, 4))
    assert q.dual_quadric(R, c, r).shape == batch + (4, 4)
    assert q.primal_quadric(R, c, r).shape == batch + (4, 4)
    conic = q.project_dual_conic(q.dual_quadric(R, c, r), K, pose)
    assert conic.shape == batch + (3, 3)
    box, valid = q.conic_bbox(conic)
    assert box.shape == batch + (4,) and valid.shape == batch
    box2, valid2 = q.project_bbox(R, c, r, K, pose)
    assert box2.shape == batch + (4,) and valid2.shape == batch
    depth, dv = q.texture_plane_depth(R, c, r, pose)
    assert depth.shape == batch and dv.shape == batch
    pts = q.surface_points(jax.random.PRNGKey(0), R, c, r, 7)
    assert pts.shape == batch + (7, 3)
    assert q.algebraic_distance(pts, R, c, r).shape == batch + (7,)
    assert q.ground_conic(R, c, r).shape == batch + (3, 3)
    # Batched results equal per-element results.
    flat = box2.reshape(-1, 4)
    for i in range(n):
        idx = np.unravel_index(i, batch) if batch else ()
        single, _ = q.project_bbox(R[idx], c[idx], r[idx], K[idx], pose[idx])
        np.testing.assert_allclose(flat[i], single, rtol=1e-12)


def test_one_camera_many_ellipsoids_broadcast(cases):
    R, c, r, K, pose = cases
    box, valid = q.project_bbox(R[:20], c[:20], r[:20], K[0], pose[0])
    assert box.shape == (20, 4) and valid.shape == (20,)
    for i in (0, 7, 19):
        single, _ = q.project_bbox(R[i], c[i], r[i], K[0], pose[0])
        np.testing.assert_allclose(box[i], single, rtol=1e-12)
    # vmap agrees with broadcasting.
    vbox, _ = jax.vmap(q.project_bbox, in_axes=(0, 0, 0, None, None))(R[:20], c[:20], r[:20], K[0], pose[0])
    np.testing.assert_allclose(vbox, box, rtol=1e-12)


def test_float32_close_to_float64(cases):
    R, c, r, K, pose = cases
    box64, _ = q.project_bbox(R, c, r, K, pose)
    args32 = [np.asarray(a, np.float32) for a in (R, c, r, K, pose)]
    box32, valid32 = q.project_bbox(*args32)
    assert box32.dtype == jnp.float32
    assert np.all(np.asarray(valid32))
    width = np.asarray(box64[:, 2] - box64[:, 0])
    err = np.abs(np.asarray(box32, np.float64) - np.asarray(box64))
    assert np.all(err < 1e-2 + 1e-4 * width[:, None]), err.max()


def test_jit_does_not_recompile_on_new_values(cases):
    R, c, r, K, pose = cases
    traces = []

    @jax.jit
    def f(R, c, r, K, pose):
        traces.append(1)
        return q.project_bbox(R, c, r, K, pose)

    f(R[:10], c[:10], r[:10], K[:10], pose[:10])[0].block_until_ready()
    f(R[10:20], c[10:20] + 0.1, r[10:20], K[10:20], pose[10:20])[0].block_until_ready()
    assert len(traces) == 1
    assert f._cache_size() == 1


def test_jaxlie_inputs_accepted(cases):
    R, c, r, K, pose = cases
    box, _ = q.project_bbox(jaxlie.SO3.from_matrix(R[0]), c[0], r[0], K[0], jaxlie.SE3.from_matrix(pose[0]))
    ref, _ = q.project_bbox(R[0], c[0], r[0], K[0], pose[0])
    np.testing.assert_allclose(box, ref, rtol=1e-9)


# ---------------------------------------------------------------------------------------------
# Bad input.


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(rotation=np.eye(4)), "rotation"),
        (dict(center=np.zeros(4)), "center"),
        (dict(radii=np.ones(2)), "radii"),
        (dict(K=np.eye(4)), "K"),
        (dict(K=np.array([[500.0, 0, 320], [0, np.nan, 240], [0, 0, 1]])), "K"),
        (dict(K=np.array([[500.0, 0, 320], [0, 500, 240], [0, 1, 1]])), "K"),
        (dict(camera_T_world=np.eye(3)), "camera_T_world"),
        (dict(camera_T_world=np.full((4, 4), np.inf)), "camera_T_world"),
        (dict(center=np.zeros((4, 3)), radii=np.ones((5, 3))), "center"),
    ],
)
def test_bad_input_is_refused_naming_argument(kwargs, name):
    args = dict(
        rotation=np.eye(3),
        center=np.array([0.0, 0, 5]),
        radii=np.ones(3),
        K=np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]),
        camera_T_world=np.eye(4),
    )
    args.update(kwargs)
    with pytest.raises(ValueError, match=name):
        q.project_bbox(**args)


def test_bad_input_other_functions():
    with pytest.raises(ValueError, match="points"):
        q.algebraic_distance(np.zeros(3), np.eye(3), np.zeros(3), np.ones(3))
    with pytest.raises(ValueError, match="dual_conic"):
        q.conic_bbox(np.eye(4))
    with pytest.raises(ValueError, match="grid_shape"):
        q.rasterize_footprint(np.eye(3), np.zeros(3), np.ones(3), 1, (0, 4), np.zeros(2), 0.1)
    with pytest.raises(ValueError, match="dual_quadric"):
        q.project_dual_conic(np.eye(3), np.eye(3), np.eye(4))


@pytest.mark.slow
def test_rotation_quaternion_round_trip():
    R = q.random_rotation(jax.random.PRNGKey(5), (500,))
    R = jnp.concatenate(
        [
            R,
            jnp.eye(3)[None],
            jnp.diag(jnp.array([1.0, -1, -1]))[None],
            jnp.diag(jnp.array([-1.0, 1, -1]))[None],
            jnp.diag(jnp.array([-1.0, -1, 1]))[None],
        ]
    )
    back = q.quaternion_to_rotation(q.rotation_to_quaternion(R))
    np.testing.assert_allclose(back, R, atol=1e-12)
    np.testing.assert_allclose(jnp.swapaxes(R, -1, -2) @ R, jnp.broadcast_to(jnp.eye(3), R.shape), atol=1e-12)
    g = jax.grad(lambda R: jnp.sum(q.rotation_to_quaternion(R)))(jnp.eye(3))
    assert np.all(np.isfinite(g))


def test_look_at_points_camera_at_target():
    eye = np.array([[3.0, -4.0, 1.5], [0.0, 0.0, 10.0]])
    target = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])  # the second looks straight down
    pose = np.asarray(q.look_at(eye, target))
    for k in range(2):
        R = pose[k, :3, :3]
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.isclose(np.linalg.det(R), 1.0)
        p = R @ target[k] + pose[k, :3, 3]
        np.testing.assert_allclose(p[:2], 0.0, atol=1e-9)
        assert p[2] > 0
    # Up (world z) appears as image-up (negative camera y) for the level camera.
    assert (pose[0, :3, :3] @ np.array([0, 0, 1.0]))[1] < 0


@pytest.mark.slow
def test_conic_outline_touches_the_box(cases):
    R, c, r, K, pose = cases
    conic = q.project_dual_conic(q.dual_quadric(R[:30], c[:30], r[:30]), K[:30], pose[:30])
    pts, valid = q.conic_outline(conic, 4000)
    box, _ = q.project_bbox(R[:30], c[:30], r[:30], K[:30], pose[:30])
    assert np.all(np.asarray(valid))
    extent = np.concatenate([pts.min(axis=-2), pts.max(axis=-2)], axis=-1)
    width = np.asarray(box[:, 2:] - box[:, :2]).max(-1, keepdims=True)
    # A 4000-gon misses the extreme by at most ~ (2 pi / 4000)^2 / 2 of the semi-axis.
    assert np.all(np.abs(extent - np.asarray(box)) <= 1e-5 * width + 1e-9)
    bad, bad_valid = q.conic_outline(np.eye(3), 8)
    assert not bool(bad_valid) and np.all(np.isfinite(bad))
