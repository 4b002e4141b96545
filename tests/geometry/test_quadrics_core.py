"""The geometry core's points/poses/corners API, conic outlines, and validation at the door.

References are independent of the code under test: OpenCV's ``projectPoints`` for the pinhole
model, eq. 4.10's closed-form box (:func:`conic_bbox`) for the outline, round trips through a
second function, and float64 for float32 gradients.
"""

import logging

import cv2
import hypothesis.extra.numpy as hnp
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from jaxsem import quadrics as q

K = np.array([[525.0, 0.0, 320.0], [0.0, 520.0, 240.0], [0.0, 0.0, 1.0]])

batch_shapes = hnp.array_shapes(min_dims=0, max_dims=3, min_side=1, max_side=3)
dtypes = st.sampled_from([np.float32, np.float64])


def _random_pose(rng, shape=()):
    R = np.asarray(q.random_rotation(jax.random.PRNGKey(int(rng.integers(1 << 30))), shape))
    T = np.zeros(shape + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = rng.normal(size=shape + (3,))
    T[..., 3, 3] = 1.0
    return T


def test_project_points_matches_opencv():
    rng = np.random.default_rng(0)
    T = _random_pose(rng)
    pts_cam = np.concatenate([rng.uniform(-2, 2, (50, 2)), rng.uniform(1, 8, (50, 1))], -1)
    world = (pts_cam - T[:3, 3]) @ T[:3, :3]  # world points that land in front of the camera
    uv, depth = q.project_points(world, K, T)
    rvec, _ = cv2.Rodrigues(T[:3, :3])
    ref, _ = cv2.projectPoints(world, rvec, T[:3, 3], K, None)
    np.testing.assert_allclose(uv, ref[:, 0, :], rtol=1e-10, atol=1e-8)
    np.testing.assert_allclose(depth, pts_cam[:, 2], rtol=1e-12)


@pytest.mark.slow
@settings(max_examples=8, deadline=None)
@given(shape=batch_shapes, dtype=dtypes, seed=st.integers(0, 2**31 - 1))
def test_back_project_inverts_project_points_over_batch_shapes(shape, dtype, seed):
    rng = np.random.default_rng(seed)
    T = _random_pose(rng, shape).astype(dtype)
    uv = rng.uniform(0, 640, shape + (2,)).astype(dtype)
    z = rng.uniform(0.5, 20, shape).astype(dtype)
    p = q.back_project(uv, z, K.astype(dtype), T)
    assert p.shape == shape + (3,) and p.dtype == dtype
    uv2, z2 = q.project_points(p, K.astype(dtype), T)
    tol = 2e-3 if dtype == np.float32 else 1e-8
    np.testing.assert_allclose(uv2, uv, atol=tol * 100)
    np.testing.assert_allclose(z2, z, rtol=tol)


@pytest.mark.slow
@settings(max_examples=8, deadline=None)
@given(shape=batch_shapes, seed=st.integers(0, 2**31 - 1))
def test_invert_pose_and_transform_points_round_trip(shape, seed):
    rng = np.random.default_rng(seed)
    T = _random_pose(rng, shape)
    p = rng.normal(size=shape + (3,))
    back = q.transform_points(q.invert_pose(T), q.transform_points(T, p))
    np.testing.assert_allclose(back, p, atol=1e-12)
    np.testing.assert_allclose(jnp.matmul(q.invert_pose(T), T), np.broadcast_to(np.eye(4), shape + (4, 4)), atol=1e-12)


def test_single_view_ellipsoid_puts_the_centre_on_the_box_ray():
    rng = np.random.default_rng(1)
    T = _random_pose(rng, (5,))
    box = np.array([[100.0, 80, 220, 200]] * 5)
    depth = rng.uniform(2, 12, 5)
    R, c, r = q.single_view_ellipsoid(box, K, T, depth, np.array([0.5, 0.4, 0.3]))
    uv, z = q.project_points(c, K, T)
    np.testing.assert_allclose(uv, np.broadcast_to([160.0, 140.0], (5, 2)), atol=1e-9)
    np.testing.assert_allclose(z, depth, rtol=1e-12)
    np.testing.assert_allclose(R, np.broadcast_to(np.eye(3), (5, 3, 3)))
    assert r.shape == (5, 3)


def test_stereo_pose_keeps_a_floating_baseline_dtype():
    # strict promotion: a float64 baseline used to come back float32 and failed to mix with the
    # float64 geometry in the dual loss (test_volumon_losses::test_dual_loss_on_rendered_data)
    for dtype in (np.float32, np.float64):
        T = q.stereo_right_T_left(np.array([0.1, 0.2], dtype))
        assert T.dtype == dtype and T.shape == (2, 4, 4)
        assert q.stereo_right_T_left(jnp.asarray(0.1, dtype)).dtype == dtype
        np.testing.assert_allclose(T[1], np.array([[1, 0, 0, -0.2], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype))
    assert q.stereo_right_T_left(0.1).dtype == jnp.float32  # Python numbers: float32, as before
    assert q.stereo_right_T_left(np.array(1)).dtype == jnp.float32
    assert q.stereo_right_T_left(np.float32(0.1), jnp.float64).dtype == jnp.float64


def test_cuboid_corners_follow_the_ndds_order():
    # FAT / NDDS: FrontTopRight, FrontTopLeft, FrontBottomLeft, FrontBottomRight, rear likewise; frame
    # x right, y down, z out of the front. Name each corner from its coordinates and compare.
    half = np.array([0.3, 0.2, 0.1])
    corners = np.asarray(q.cuboid_corners(np.eye(3), np.zeros(3), half))
    names = [
        ("Front" if p[2] > 0 else "Rear") + ("Top" if p[1] < 0 else "Bottom") + ("Right" if p[0] > 0 else "Left")
        for p in corners
    ]
    expected = [
        f + v + h
        for f in ("Front", "Rear")
        for v, h in (("Top", "Right"), ("Top", "Left"), ("Bottom", "Left"), ("Bottom", "Right"))
    ]
    assert names == expected
    np.testing.assert_allclose(np.abs(corners), np.broadcast_to(half, (8, 3)))
    # Oriented and moved: the corners are rigidly carried along (distances preserved).
    R = np.asarray(q.random_rotation(jax.random.PRNGKey(3)))
    moved = np.asarray(q.cuboid_corners(R, np.array([1.0, 2, 3]), half))
    d0 = np.linalg.norm(corners[:, None] - corners[None], axis=-1)
    d1 = np.linalg.norm(moved[:, None] - moved[None], axis=-1)
    np.testing.assert_allclose(d0, d1, atol=1e-12)
    np.testing.assert_allclose(moved.mean(0), [1.0, 2, 3], atol=1e-12)


def test_quaternion_conventions_are_named_and_consistent():
    R = np.asarray(q.random_rotation(jax.random.PRNGKey(4), (6,)))
    wxyz = q.rotation_to_quaternion_wxyz(R)
    xyzw = q.rotation_to_quaternion_xyzw(R)
    np.testing.assert_allclose(np.roll(np.asarray(wxyz), -1, -1), xyzw)
    np.testing.assert_allclose(q.quaternion_wxyz_to_rotation(wxyz), R, atol=1e-12)
    np.testing.assert_allclose(q.quaternion_xyzw_to_rotation(xyzw), R, atol=1e-12)
    # scipy's scalar-last convention as the outside reference
    from scipy.spatial.transform import Rotation

    np.testing.assert_allclose(q.quaternion_xyzw_to_rotation(Rotation.from_matrix(R).as_quat()), R, atol=1e-12)


def test_so3_exp_matches_rodrigues_of_opencv():
    omega = np.array([[0.0, 0.0, 0.0], [0.3, -0.2, 0.9], [1e-9, 0, 0]])
    ref = np.stack([cv2.Rodrigues(w)[0] for w in omega])
    np.testing.assert_allclose(q.so3_exp(omega), ref, atol=1e-12)
    g = jax.grad(lambda w: jnp.sum(q.so3_exp(w)))(jnp.zeros(3))
    assert bool(jnp.all(jnp.isfinite(g)))


# --------------------------------------------------------------------------------------------
# conic_outline: on the conic, finite float32 gradients, circles.


def _scene(key, n, dtype):
    k1, k2, k3 = jax.random.split(key, 3)
    R = q.random_rotation(k1, (n,), dtype=dtype)
    c = jnp.concatenate(
        [jax.random.uniform(k2, (n, 2), dtype, -1.5, 1.5), jax.random.uniform(k3, (n, 1), dtype, 4.0, 9.0)], -1
    )
    r = jax.random.uniform(jax.random.fold_in(key, 9), (n, 3), dtype, 0.2, 1.0)
    return R, c, r


@pytest.mark.slow
def test_conic_outline_extremes_match_the_closed_form_box():
    R, c, r = _scene(jax.random.PRNGKey(0), 50, jnp.float64)
    C = q.project_dual_conic(q.dual_quadric(R, c, r), K, np.eye(4))
    pts, valid = q.conic_outline(C, 4000)
    box, bvalid = q.conic_bbox(C)
    assert bool(jnp.all(valid == bvalid)) and bool(jnp.all(valid))
    extent = jnp.concatenate([pts.min(-2), pts.max(-2)], -1)
    np.testing.assert_allclose(extent, box, atol=0.05)  # 4000 points: sub-0.05 px sampling error


def test_conic_outline_gradients_finite_in_float32_and_match_float64():
    def loss(c, R, r):
        C = q.project_dual_conic(q.dual_quadric(R, c, r), K.astype(c.dtype), jnp.eye(4, dtype=c.dtype))
        pts, valid = q.conic_outline(C, 16)
        return jnp.sum(jnp.where(valid[..., None, None], pts, 0.0)) / 1000.0

    R, c, r = _scene(jax.random.PRNGKey(1), 10_000, jnp.float64)
    g64 = jax.jit(jax.grad(loss))(c, R, r)
    g32 = jax.jit(jax.grad(loss))(c.astype(jnp.float32), R.astype(jnp.float32), r.astype(jnp.float32))
    assert bool(jnp.all(jnp.isfinite(g32)))
    scale = jnp.max(jnp.abs(g64), axis=-1, keepdims=True)
    assert float(jnp.max(jnp.abs(g32.astype(jnp.float64) - g64) / scale)) < 2e-2


@pytest.mark.slow
def test_conic_outline_of_a_sphere_seen_head_on_has_a_radius_gradient():
    def mean_radius(rad, dtype):
        C = q.project_dual_conic(
            q.dual_quadric(jnp.eye(3, dtype=dtype), jnp.array([0.0, 0.0, 5.0], dtype), jnp.full(3, rad, dtype)),
            K.astype(dtype),
            jnp.eye(4, dtype=dtype),
        )
        pts, _ = q.conic_outline(C, 64)
        return jnp.mean(jnp.linalg.norm(pts - jnp.array([320.0, 240.0], dtype), axis=-1))

    for dtype in (jnp.float32, jnp.float64):
        r0 = jnp.asarray(0.5, dtype)
        g = jax.grad(mean_radius)(r0, dtype)
        eps = 1e-4
        fd = (mean_radius(0.5 + eps, jnp.float64) - mean_radius(0.5 - eps, jnp.float64)) / (2 * eps)
        assert bool(jnp.isfinite(g)) and abs(float(g) - float(fd)) / float(fd) < 1e-3


# --------------------------------------------------------------------------------------------
# Validation at the door: ValueError naming the argument, never a finite-looking wrong value.

R0 = np.eye(3)
C0 = np.array([0.0, 0.0, 5.0])
r0 = np.array([0.5, 0.4, 0.3])
T0 = np.eye(4)


def _calls():
    pts = np.zeros((4, 3))
    return {
        "dual_quadric": lambda R, c, r: q.dual_quadric(R, c, r),
        "primal_quadric": lambda R, c, r: q.primal_quadric(R, c, r),
        "project_bbox": lambda R, c, r: q.project_bbox(R, c, r, K, T0),
        "texture_plane_depth": lambda R, c, r: q.texture_plane_depth(R, c, r, T0),
        "algebraic_distance": lambda R, c, r: q.algebraic_distance(pts, R, c, r),
        "ground_conic": lambda R, c, r: q.ground_conic(R, c, r),
        "ground_bounds": lambda R, c, r: q.ground_bounds(R, c, r),
        "rasterize_footprint": lambda R, c, r: q.rasterize_footprint(R, c, r, 1, (8, 8), np.zeros(2), 0.5),
        "surface_points": lambda R, c, r: q.surface_points(jax.random.PRNGKey(0), R, c, r, 4),
        "cuboid_corners": lambda R, c, r: q.cuboid_corners(R, c, r),
    }


@pytest.mark.parametrize("fn", sorted(_calls()))
@pytest.mark.parametrize(
    "arg, bad, match",
    [
        ("rotation", np.full((3, 3), np.nan), "rotation: must be finite"),
        ("rotation", np.zeros((3, 3)), "rotation: expected rotation"),
        ("rotation", 2 * np.eye(3), "rotation: expected rotation"),
        ("rotation", np.diag([1.0, 1.0, -1.0]), "rotation: expected rotation"),
        ("center", np.array([0.0, np.inf, 1.0]), "center: must be finite"),
        ("radii", np.array([0.5, np.nan, 0.3]), "radii: must be finite"),
        ("radii", np.array([0.5, -0.4, 0.3]), "radii"),
    ],
)
def test_bad_ellipsoids_are_rejected_naming_the_argument(fn, arg, bad, match):
    if fn == "cuboid_corners" and match == "radii":
        match = "half_extents"
    if fn == "cuboid_corners" and arg == "radii" and "finite" in match:
        match = "half_extents: must be finite"
    if fn == "cuboid_corners" and arg == "rotation" and "expected rotation" in match:
        pytest.skip("cuboid_corners accepts any frame, left-handed ones included (FAT's)")
    args = {"rotation": R0, "center": C0, "radii": r0}
    args[arg] = bad
    with pytest.raises(ValueError, match=match):
        _calls()[fn](args["rotation"], args["center"], args["radii"])


def test_texture_plane_depth_with_nan_radii_is_not_a_valid_depth():
    with pytest.raises(ValueError, match="radii"):
        q.texture_plane_depth(R0, C0, np.array([0.5, np.nan, 0.3]), T0)
    depth, ok = jax.jit(q.texture_plane_depth)(R0, C0, jnp.array([0.5, jnp.nan, 0.3]), T0)
    assert not (bool(ok) and bool(jnp.isfinite(depth)))


@pytest.mark.parametrize(
    "K_bad, match",
    [
        (np.diag([0.0, 520.0, 1.0]), "focal"),
        (np.diag([-525.0, 520.0, 1.0]), "focal"),
        (np.full((3, 3), np.nan), "K: must be finite"),
    ],
)
def test_bad_intrinsics_are_rejected(K_bad, match):
    with pytest.raises(ValueError, match=match):
        q.project_bbox(R0, C0, r0, K_bad, T0)
    with pytest.raises(ValueError, match=match):
        q.project_points(C0, K_bad, T0)


def test_bad_pose_is_rejected():
    T = np.eye(4)
    T[:3, :3] *= 3.0
    with pytest.raises(ValueError, match="camera_T_world"):
        q.project_bbox(R0, C0, r0, K, T)


def test_quaternion_nan_is_rejected_or_stays_nan():
    with pytest.raises(ValueError, match="quaternion_wxyz"):
        q.quaternion_wxyz_to_rotation(np.array([np.nan, 0, 0, 0]))
    out = jax.jit(q.quaternion_wxyz_to_rotation)(jnp.array([jnp.nan, 0.0, 0.0, 0.0]))
    assert bool(jnp.all(jnp.isnan(out)))
    np.testing.assert_allclose(q.quaternion_wxyz_to_rotation(np.zeros(4)), np.eye(3))  # documented


def test_look_at_rejects_a_degenerate_view():
    with pytest.raises(ValueError, match="target: must differ from eye"):
        q.look_at(np.ones(3), np.ones(3))
    with pytest.raises(ValueError, match="eye: must be finite"):
        q.look_at(np.array([np.nan, 0, 0]), np.ones(3))
    # straight down (view parallel to up) is still a proper rotation
    T = np.asarray(q.look_at(np.array([0.0, 0, 5]), np.zeros(3)))
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    assert np.linalg.det(T[:3, :3]) > 0


@pytest.mark.parametrize("res", [0.0, -0.1, np.nan, np.inf])
def test_rasterize_footprint_rejects_bad_resolution(res):
    with pytest.raises(ValueError, match="resolution"):
        q.rasterize_footprint(R0, C0, r0, 1, (8, 8), np.zeros(2), res)


def test_points_must_be_finite():
    with pytest.raises(ValueError, match="points: must be finite"):
        q.algebraic_distance(np.array([[np.nan, 0.0, 0.0]]), R0, C0, r0)
    with pytest.raises(ValueError, match="points: must be finite"):
        q.project_points(np.array([np.nan, 0.0, 0.0]), K, T0)


def test_validation_is_skipped_under_jit_without_recompiling():
    f = jax.jit(q.project_bbox)
    f(R0, C0, r0, K, T0)[0].block_until_ready()
    n = f._cache_size()
    f(R0, C0 + 1.0, r0, K, T0)[0].block_until_ready()
    assert f._cache_size() == n


@pytest.mark.parametrize("arg", ["rotation", "center", "radii"])
def test_nan_under_jit_is_never_a_valid_finite_answer(arg):
    # Regression: safe_sqrt mapped NaN to 0, so NaN radii gave texture depth 5.025 and valid=True.
    args = {"rotation": jnp.eye(3), "center": jnp.array([0.0, 0.0, 5.0]), "radii": jnp.array([0.5, 0.4, 0.3])}
    args[arg] = args[arg].at[..., 0].set(jnp.nan)
    R, c, r = args["rotation"], args["center"], args["radii"]
    box, ok = jax.jit(q.project_bbox)(R, c, r, K, T0)
    assert not bool(ok)
    depth, ok = jax.jit(q.texture_plane_depth)(R, c, r, T0)
    assert not bool(ok)
    _, ok = jax.jit(lambda R, c, r: q.conic_bbox(q.project_dual_conic(q.dual_quadric(R, c, r), K, T0)))(R, c, r)
    assert not bool(ok)
    assert bool(jnp.isnan(q.safe_sqrt(jnp.nan)))


def test_typed_pytrees_pass_through_transforms_and_check_their_input():
    e = q.Ellipsoid.create(np.eye(3), np.array([0.0, 0.0, 5.0]), np.array([0.5, 0.4, 0.3]))
    cam = q.Camera.create(K, np.eye(4))
    box, ok = jax.jit(lambda e, cam: q.project_bbox(*e, *cam))(e, cam)
    assert bool(ok) and box.shape == (4,)
    batched = jax.tree_util.tree_map(lambda x: jnp.stack([x, x]), e)
    boxes, _ = jax.vmap(lambda e: q.project_bbox(*e, *cam))(batched)
    np.testing.assert_allclose(boxes[0], box)
    np.testing.assert_allclose(e.sizes, [1.0, 0.8, 0.6])
    with pytest.raises(ValueError, match="radii"):
        q.Ellipsoid.create(np.eye(3), np.zeros(3), np.array([1.0, 0.0, 1.0]))
    with pytest.raises(ValueError, match="focal"):
        q.Camera.create(np.diag([0.0, 1.0, 1.0]), np.eye(4))


# --------------------------------------------------------------------------------------------
# Host path (xp=numpy), camera_matrix, rigid_transform and cylinder_bbox.


def _host_scene(rng, n):
    R = np.asarray(q.random_rotation(jax.random.PRNGKey(int(rng.integers(1 << 30))), (n,)))
    c = rng.uniform(-0.5, 0.5, (n, 3)) + np.array([0.0, 0.0, 6.0])
    r = rng.uniform(0.2, 1.0, (n, 3))
    return R, c, r


_HOST_CALLS = {
    "project_points": lambda R, c, r, T, xp: q.project_points(c, K, T, xp=xp),
    "transform_points": lambda R, c, r, T, xp: q.transform_points(T, c, xp=xp),
    "invert_pose": lambda R, c, r, T, xp: q.invert_pose(T, xp=xp),
    "rigid_transform": lambda R, c, r, T, xp: q.rigid_transform(R, c, xp=xp),
    "back_project": lambda R, c, r, T, xp: q.back_project(c[..., :2] * 50, c[..., 2], K, T, xp=xp),
    "camera_matrix": lambda R, c, r, T, xp: q.camera_matrix(K, T, xp=xp),
    "cuboid_corners": lambda R, c, r, T, xp: q.cuboid_corners(R, c, r, xp=xp),
    "quaternion_wxyz_to_rotation": lambda R, c, r, T, xp: q.quaternion_wxyz_to_rotation(
        np.concatenate([c, r[..., :1]], -1), xp=xp
    ),
    "quaternion_xyzw_to_rotation": lambda R, c, r, T, xp: q.quaternion_xyzw_to_rotation(
        np.concatenate([c, r[..., :1]], -1), xp=xp
    ),
    "rotation_to_quaternion_wxyz": lambda R, c, r, T, xp: q.rotation_to_quaternion_wxyz(R, xp=xp),
    "rotation_to_quaternion_xyzw": lambda R, c, r, T, xp: q.rotation_to_quaternion_xyzw(R, xp=xp),
    "look_at": lambda R, c, r, T, xp: q.look_at(c + r, c, xp=xp),
    "dual_conic_bbox": lambda R, c, r, T, xp: q.conic_bbox(
        q.project_dual_conic(q.dual_quadric(R, c, r, xp=xp), K, T, xp=xp), xp=xp
    ),
    "cylinder_bbox": lambda R, c, r, T, xp: q.cylinder_bbox(R, c, r, K, T, xp=xp),
}


@pytest.mark.parametrize("name", sorted(_HOST_CALLS))
def test_numpy_path_is_the_same_function(name):
    """``xp=np`` evaluates the same formulas on the host: numpy arrays out, jax's values."""
    rng = np.random.default_rng(3)
    R, c, r = _host_scene(rng, 4)
    T = _random_pose(rng, (4,))
    T[..., :3, 3] = [0.0, 0.0, 0.5]  # the objects stay in front of the camera
    host, dev = _HOST_CALLS[name](R, c, r, T, np), _HOST_CALLS[name](R, c, r, T, jnp)
    host, dev = (host, dev) if isinstance(host, tuple) else ((host,), (dev,))
    for h, d in zip(host, dev):
        assert isinstance(h, np.ndarray) and h.shape == d.shape
        np.testing.assert_allclose(h, np.asarray(d), rtol=1e-10, atol=1e-9)


def test_xp_must_be_numpy_or_jax_numpy():
    with pytest.raises(ValueError, match="xp"):
        q.project_points(np.zeros(3), K, np.eye(4), xp=list)


def test_numpy_path_checks_its_arguments_too():
    with pytest.raises(ValueError, match="points"):
        q.project_points(np.full(3, np.nan), K, np.eye(4), xp=np)
    with pytest.raises(ValueError, match="camera_T_world"):
        q.project_points(np.zeros(3), K, 2 * np.eye(4), xp=np)


def test_camera_matrix_projects_like_opencv():
    rng = np.random.default_rng(4)
    T = _random_pose(rng)
    world = (np.concatenate([rng.uniform(-2, 2, (20, 2)), rng.uniform(1, 8, (20, 1))], -1) - T[:3, 3]) @ T[:3, :3]
    x = np.concatenate([world, np.ones((20, 1))], -1) @ np.asarray(q.camera_matrix(K, T)).T
    rvec, _ = cv2.Rodrigues(T[:3, :3])
    ref, _ = cv2.projectPoints(world, rvec, T[:3, 3], K, None)
    np.testing.assert_allclose(x[:, :2] / x[:, 2:], ref[:, 0, :], rtol=1e-10, atol=1e-8)


def test_rigid_transform_builds_the_pose_and_checks_its_rotation():
    rng = np.random.default_rng(5)
    T = _random_pose(rng, (3,))
    np.testing.assert_allclose(q.rigid_transform(T[..., :3, :3], T[..., :3, 3]), T, atol=1e-15)
    with pytest.raises(ValueError, match="rotation"):
        q.rigid_transform(2 * np.eye(3), np.zeros(3))
    with pytest.raises(ValueError, match="translation"):
        q.rigid_transform(np.eye(3), np.zeros(2))


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_cylinder_bbox_matches_densely_sampled_rims(seed):
    """Reference: the box of 20,000 projected points on each rim circle (OpenCV's projection)."""
    rng = np.random.default_rng(seed)
    R, c, r = _host_scene(rng, 1)
    T = _random_pose(rng)
    T[:3, 3] = [0.0, 0.0, 0.5]
    world = (c[0] - T[:3, 3]) @ T[:3, :3]  # the centre 6.5 m in front of the camera
    a = np.linspace(0.0, 2 * np.pi, 20000)
    rims = np.concatenate(
        [np.stack([r[0, 0] * np.cos(a), r[0, 1] * np.sin(a), np.full_like(a, s * r[0, 2])], -1) for s in (-1, 1)]
    )
    pts = rims @ R[0].T + world
    rvec, _ = cv2.Rodrigues(T[:3, :3])
    uv, _ = cv2.projectPoints(pts, rvec, T[:3, 3], K, None)
    ref = np.concatenate([uv[:, 0].min(0), uv[:, 0].max(0)])
    for xp in (np, jnp):
        box, valid = q.cylinder_bbox(R[0], world, r[0], K, T, xp=xp)
        assert bool(valid)
        np.testing.assert_allclose(np.asarray(box), ref, atol=1e-2)


def test_cylinder_bbox_of_a_rim_seen_edge_on_is_still_its_segment():
    # axis along the camera's y, one rim in the plane y = 0 through the camera: seen edge-on (a
    # segment, a degenerate conic), the other rim at y = 2
    R = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    box, valid = q.cylinder_bbox(R, np.array([0.0, 1.0, 4.0]), np.array([0.5, 0.5, 1.0]), K, np.eye(4), xp=np)
    # both rims: x / z extremes on the tangents from the camera, sin = 0.5 / 4; v from y = 0 to 2 / 3.5
    t = 0.125 / np.sqrt(1 - 0.125**2)
    ref = [K[0, 2] - K[0, 0] * t, K[1, 2], K[0, 2] + K[0, 0] * t, K[1, 2] + K[1, 1] * 2 / 3.5]
    assert bool(valid)
    np.testing.assert_allclose(box, ref, atol=1e-6)


def test_shape_bbox_matches_dense_surface_sampling_for_every_shape():
    """Each shape's box against the box of densely sampled surface points (independent reference)."""
    from jaxsem.quadrics import SHAPE_CUBOID, SHAPE_CYLINDER, SHAPE_ELLIPSOID, shape_bbox

    rng = np.random.default_rng(11)
    K = np.array([[500.0, 0, 320], [0, 480.0, 240], [0, 0, 1]])
    pose = np.eye(4)
    u = np.linspace(-1.0, 1.0, 41)
    a, b = np.meshgrid(u, u, indexing="ij")
    face = np.stack([a.ravel(), b.ravel()], -1)
    cube = np.concatenate(
        [np.insert(face, i, s, axis=1) for i in range(3) for s in (-1.0, 1.0)]
    )  # points on the unit cube's faces
    th = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    rim = np.stack([np.cos(th), np.sin(th)], -1)
    cyl = np.concatenate([np.concatenate([rim, np.full((720, 1), z)], 1) for z in (-1.0, 1.0)])
    ph = np.linspace(0, np.pi, 181)
    sph = np.stack(
        [
            np.outer(np.sin(ph), np.cos(th)).ravel(),
            np.outer(np.sin(ph), np.sin(th)).ravel(),
            np.outer(np.cos(ph), np.ones_like(th)).ravel(),
        ],
        -1,
    )
    for _ in range(6):
        R = np.asarray(q.random_rotation(jax.random.PRNGKey(int(rng.integers(1 << 30)))))
        t = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(1.5, 3.0)])
        r = rng.uniform(0.1, 0.4, 3)
        for shape, unit in ((SHAPE_CUBOID, cube), (SHAPE_CYLINDER, cyl), (SHAPE_ELLIPSOID, sph)):
            box, valid = shape_bbox(R, t, r, shape, K, pose)
            pts = (unit * r) @ R.T + t
            uv = pts[:, :2] / pts[:, 2:] * K[[0, 1], [0, 1]] + K[:2, 2]
            ref = np.concatenate([uv.min(0), uv.max(0)])
            assert bool(valid)
            np.testing.assert_allclose(np.asarray(box), ref, atol=0.05)


class _CompileLog(logging.Handler):
    """Names of the programs JAX compiles while installed (``jax.log_compiles``)."""

    def __init__(self):
        super().__init__(logging.DEBUG)
        self.names = []

    def emit(self, record):
        message = record.getMessage()
        if message.startswith("Compiling "):
            self.names.append(message.split(" ")[1])


def _eager_cases(batch=(7, 5)):
    # Each test case gets a batch shape of its own: nothing it calls was compiled before.
    R = jnp.broadcast_to(jnp.eye(3), batch + (3, 3))
    c = jnp.broadcast_to(jnp.array([0.1, -0.2, 5.0]), batch + (3,))
    r = jnp.broadcast_to(jnp.array([0.5, 0.4, 0.3]), batch + (3,))
    conic = jnp.asarray(q.project_dual_conic(q.dual_quadric(R, c, r, xp=np), K, T0, xp=np))
    eye = jnp.broadcast_to(jnp.array([1.0, 2.0, 3.0]), batch + (3,))
    quat = jnp.broadcast_to(jnp.array([0.9, 0.1, -0.2, 0.3]), batch + (4,))
    return {
        "project_bbox": (q.project_bbox, (R, c, r, jnp.asarray(K), jnp.asarray(T0)), {}),
        "dual_quadric": (q.dual_quadric, (R, c, r), {}),
        "conic_bbox": (q.conic_bbox, (conic,), {}),
        "ellipsoid_valid": (q.ellipsoid_valid, (R, c, r), {}),
        "look_at": (q.look_at, (eye, jnp.zeros(3)), {}),
        "look_at_valid": (q.look_at, (eye, jnp.zeros(3)), {"with_valid": True}),
        "rotation_to_quaternion": (q.rotation_to_quaternion, (R,), {}),
        "rotation_to_quaternion_valid": (q.rotation_to_quaternion, (R,), {"with_valid": True}),
        "quaternion_wxyz_to_rotation": (q.quaternion_wxyz_to_rotation, (quat,), {}),
        "quaternion_xyzw_to_rotation": (q.quaternion_xyzw_to_rotation, (quat,), {}),
    }


@pytest.mark.parametrize("name", sorted(_eager_cases()))
def test_eager_call_runs_one_compiled_program_with_the_traced_answer(name):
    # Regression (issue 23, friction 4): eager calls ran op by op (project_bbox 19.8 ms eagerly
    # against 0.012 ms jitted, look_at 5 ms): one dispatch, and one compile, per primitive.
    fn, args, kwargs = _eager_cases((7, 11 + sorted(_eager_cases()).index(name)))[name]
    jax.block_until_ready(args)
    log = _CompileLog()
    logger = logging.getLogger("jax")
    level = logger.level
    logger.addHandler(log)
    logger.setLevel(logging.DEBUG)
    try:
        with jax.log_compiles():
            eager = jax.block_until_ready(fn(*args, **kwargs))
    finally:
        logger.removeHandler(log)
        logger.setLevel(level)
    assert len(log.names) == 1, log.names
    traced = jax.jit(lambda *a: fn(*a, **kwargs))(*args)
    for x, y in zip(jax.tree.leaves(eager), jax.tree.leaves(traced)):
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-12, atol=1e-12)


def test_eager_checks_still_name_the_argument_before_the_compiled_program():
    with pytest.raises(ValueError, match="target: must differ"):
        q.look_at(jnp.ones(3), jnp.ones(3))
    with pytest.raises(ValueError, match="rotation: expected rotation"):
        q.rotation_to_quaternion(2.0 * jnp.eye(3), with_valid=True)
    with pytest.raises(ValueError, match="radii: expected positive"):
        q.project_bbox(jnp.eye(3), jnp.array([0.0, 0.0, 5.0]), jnp.array([1.0, -1.0, 1.0]), K, T0)


def test_look_at_default_up_follows_float32_eye_and_target_under_strict_promotion():
    # Regression: the default up (a Python tuple) became float64 under x64 and strict dtype
    # promotion refused float32 eye and target.
    T = q.look_at(np.array([1.0, 2.0, 3.0], np.float32), np.zeros(3, np.float32))
    assert T.dtype == np.float32
    np.testing.assert_allclose(np.asarray(T)[:3, 3], -np.asarray(T)[:3, :3] @ [1.0, 2.0, 3.0], atol=1e-5)
