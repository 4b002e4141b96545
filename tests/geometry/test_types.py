"""The typed core: ``quadrics.Ellipsoid`` and ``quadrics.Camera`` methods against independent
references (surface samples, stereo disparity, round trips), under jit and vmap, and the typed
arguments of the methods' functions (loose arrays are refused with the argument's name)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from jaxsem import mapping, quadrics, slam
from jaxsem.slam import sim
from jaxsem.volumon._draw import box_corners_2d, ellipsoid_outline  # layers: white-box
from jaxsem.volumon._refine import phi_from_ellipsoid  # layers: white-box

K = np.array([[500.0, 0.0, 320.0], [0.0, 480.0, 240.0], [0.0, 0.0, 1.0]])


def _random_ellipsoid(rng, batch=()):
    rotation = np.asarray(quadrics.random_rotation(jax.random.PRNGKey(int(rng.integers(1 << 30))), batch))
    center = rng.normal(size=batch + (3,)) * 0.5
    radii = rng.uniform(0.2, 1.0, size=batch + (3,))
    return quadrics.Ellipsoid(rotation, center, radii)


def _random_pose(rng):
    R = np.asarray(quadrics.random_rotation(jax.random.PRNGKey(int(rng.integers(1 << 30)))))
    return np.asarray(quadrics.rigid_transform(R, rng.normal(size=3)))


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_transformed_ellipsoid_holds_the_transformed_surface(seed):
    rng = np.random.default_rng(seed)
    e = _random_ellipsoid(rng)
    a_T_b = _random_pose(rng)
    points_b = np.asarray(e.surface_points(jax.random.PRNGKey(seed % 1000), 50), np.float64)
    points_a = points_b @ a_T_b[:3, :3].T + a_T_b[:3, 3]
    moved = e.transform(a_T_b)
    assert np.max(np.abs(np.asarray(moved.algebraic_distance(points_a)))) < 1e-4
    # the radii are the body's: a rigid motion keeps them
    np.testing.assert_array_equal(np.asarray(moved.radii), e.radii)


def test_camera_position_back_projection_and_stereo_disparity():
    rng = np.random.default_rng(3)
    cam = quadrics.Camera.look_at(K, np.array([1.0, -4.0, 1.5]), np.array([0.0, 0.0, 0.5]))
    # the optical centre maps to the camera frame's origin
    p = cam.camera_T_world @ np.append(np.asarray(cam.position), 1.0)
    np.testing.assert_allclose(p[:3], 0.0, atol=1e-5)
    uv = rng.uniform([50, 50], [590, 430], size=(20, 2))
    z = rng.uniform(1.0, 6.0, size=20)
    points = cam.back_project(uv, z)
    uv2, z2 = cam.project(points)
    np.testing.assert_allclose(np.asarray(uv2), uv, atol=1e-3)
    np.testing.assert_allclose(np.asarray(z2), z, rtol=1e-5)
    np.testing.assert_allclose(np.asarray(cam.depth(points)), z, rtol=1e-5)
    # a rectified pair: same rows, disparity fx * baseline / z
    right = cam.stereo_right(0.12)
    uv_r, z_r = right.project(points)
    np.testing.assert_allclose(np.asarray(uv_r)[:, 1], uv[:, 1], atol=1e-3)
    np.testing.assert_allclose(uv[:, 0] - np.asarray(uv_r)[:, 0], K[0, 0] * 0.12 / z, rtol=1e-3)


def test_outline_touches_the_projected_box_and_lies_in_the_camera_frame_view():
    e = quadrics.Ellipsoid(
        np.asarray(quadrics.so3_exp(np.array([0.3, -0.2, 0.5]))), np.array([0.2, 0.1, 0.3]), np.array([0.6, 0.3, 0.2])
    )
    cam = quadrics.Camera.look_at(K, np.array([0.5, -4.0, 1.0]), np.array([0.2, 0.1, 0.3]))

    @jax.jit  # one program for the whole check (eager calls would compile one each)
    def seen(e, cam):
        box, valid = e.project_bbox(cam)
        outline, ok = e.outline(cam, 4000)
        box_c, _ = e.in_camera(cam).project_bbox(quadrics.Camera(cam.K, jnp.eye(4)))
        corners_uv, _ = cam.project(e.corners())
        surface_uv, _ = cam.project(e.surface_points(jax.random.PRNGKey(0), 500))
        return box, valid, outline, ok, box_c, corners_uv, surface_uv

    box, valid, outline, ok, box_c, corners_uv, surface_uv = seen(e, cam)
    assert bool(valid) and bool(ok)
    extent = np.concatenate([np.min(outline, 0), np.max(outline, 0)])
    np.testing.assert_allclose(extent, np.asarray(box), atol=0.05)
    # the same ellipsoid moved into the camera frame, seen by a camera at the identity
    np.testing.assert_allclose(np.asarray(box_c), np.asarray(box), atol=1e-3)
    # the corners of the bounding box contain every surface point's projection
    assert np.all(np.min(surface_uv, 0) >= np.min(corners_uv, 0) - 1e-3)
    assert np.all(np.max(surface_uv, 0) <= np.max(corners_uv, 0) + 1e-3)


def test_methods_jit_and_vmap_over_typed_batches():
    rng = np.random.default_rng(0)
    es = _random_ellipsoid(rng, (5,))
    es = es._replace(center=es.center + np.array([0.0, 0.0, 6.0]))
    cams = quadrics.Camera(np.broadcast_to(K, (5, 3, 3)), np.broadcast_to(np.eye(4), (5, 4, 4)))
    batched, valid = jax.jit(lambda e, c: e.project_bbox(c))(es, cams)
    mapped, _ = jax.vmap(lambda e, c: e.project_bbox(c))(es, cams)
    np.testing.assert_allclose(np.asarray(mapped), np.asarray(batched), rtol=1e-5)
    assert valid.shape == (5,) and bool(jnp.all(valid))
    bounds = jax.vmap(quadrics.Ellipsoid.ground_bounds)(es)
    assert bounds.shape == (5, 4)
    # a bad ellipsoid reads invalid under jit; the checked constructor refuses it eagerly
    bad = es._replace(radii=-es.radii)
    assert not bool(jnp.any(jax.jit(quadrics.Ellipsoid.valid)(bad)))
    with pytest.raises(ValueError, match="radii"):
        quadrics.Ellipsoid.create(*bad)


def test_containers_give_the_typed_views():
    rng = np.random.default_rng(1)
    objects = _random_ellipsoid(rng, (3,))
    poses = np.stack(
        [np.asarray(quadrics.look_at(np.array([x, -6.0, 1.0]), np.zeros(3))) for x in (-1.0, 0.0, 1.0, 2.0)]
    )
    truth = slam.SlamEstimate(jnp.asarray(poses), *(jnp.asarray(x) for x in objects))
    e = truth.ellipsoid
    assert isinstance(e, quadrics.Ellipsoid)
    cams = truth.cameras(K)
    boxes, valid = e.project_bbox(quadrics.Camera(cams.K, cams.camera_T_world[:, None]))
    assert boxes.shape == (4, 3, 4) and valid.shape == (4, 3)
    store = mapping.ellipsoids(e, np.full(3, 2, np.int32))
    assert isinstance(store.ellipsoid, quadrics.Ellipsoid)
    np.testing.assert_array_equal(np.asarray(store.ellipsoid.center), np.asarray(e.center))


def test_loose_arrays_where_a_typed_argument_belongs_are_named():
    R, c, r = np.eye(3)[None], np.zeros((1, 3)), np.ones((1, 3))
    cases = [
        ("ellipsoid", lambda: mapping.ellipsoids(c, [2])),
        ("ellipsoid", lambda: slam.map_to_json([1], ["car"], R)),
        ("ellipsoid", lambda: box_corners_2d(R[0], K)),
        ("ellipsoid", lambda: ellipsoid_outline(c[0], K)),
        ("ellipsoid", lambda: phi_from_ellipsoid(R, np.zeros((1, 4)), K)),
        ("camera", lambda: sim.detect(jax.random.PRNGKey(0), quadrics.Ellipsoid(R, c, r), np.ones(1, bool), K, None)),
    ]
    for name, call in cases:
        with pytest.raises(ValueError, match=rf"{name}: expected a jaxsem\.quadrics\."):
            call()
