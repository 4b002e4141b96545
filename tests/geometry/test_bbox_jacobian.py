"""``project_bbox_jacobian``: the box's closed-form Jacobians against two independent references,
central finite differences of ``project_bbox`` through SciPy's and jaxlie's exponential maps,
and forward-mode autodiff of the plain closed form (``project_bbox_reference``, without the
custom JVP rule), over random ellipsoids, cameras and batch shapes.
"""

import hypothesis.extra.numpy as hnp
import jax
import jaxlie
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.spatial.transform import Rotation

from jaxsem import quadrics as q


def _scene(rng, shape):
    """Random views with the ellipsoid well in front of the camera (valid boxes)."""
    n = int(np.prod(shape, dtype=int))
    T = np.zeros((n, 4, 4))
    T[:, :3, :3] = Rotation.random(n, random_state=rng).as_matrix()
    T[:, :3, 3] = rng.normal(size=(n, 3))
    T[:, 3, 3] = 1.0
    in_camera = np.concatenate([rng.uniform(-1, 1, (n, 2)), rng.uniform(3, 8, (n, 1))], -1)
    center = np.einsum("nji,nj->ni", T[:, :3, :3], in_camera - T[:, :3, 3])
    R = Rotation.random(n, random_state=rng).as_matrix()
    radii = rng.uniform(0.1, 1.0, (n, 3))
    K = np.array([[rng.uniform(300, 900), rng.uniform(-2, 2), rng.uniform(200, 400)], [0, 0, 0], [0, 0, 1]])
    K[1, 1:] = rng.uniform(300, 900), rng.uniform(150, 300)
    re = lambda x: x.reshape(shape + x.shape[1:])
    return re(R), re(center), re(radii), K, re(T)


def _finite_differences(R, c, r, K, T, h=1e-6):
    """(..., 4, 15) central differences of the box for ``[dw, dc, dr, v, w]`` perturbations."""
    shape = c.shape[:-1]
    cols = []
    for i in range(15):
        boxes = []
        for sign in (1.0, -1.0):
            d = np.zeros(15)
            d[i] = sign * h
            R2 = R @ Rotation.from_rotvec(d[0:3]).as_matrix()
            T2 = T @ np.asarray(jaxlie.SE3.exp(d[9:15]).as_matrix())
            boxes.append(np.asarray(q.project_bbox(R2, c + d[3:6], r + d[6:9], K, T2)[0]))
        cols.append((boxes[0] - boxes[1]) / (2 * h))
    return np.stack(cols, -1).reshape(shape + (4, 15))


def _autodiff(R, c, r, K, T):
    """(..., 4, 15) forward-mode Jacobian of the plain closed form for the same perturbations."""

    def box(d, R, c, r, T):
        R2 = R @ jaxlie.SO3.exp(d[0:3]).as_matrix()
        T2 = T @ jaxlie.SE3.exp(d[9:15]).as_matrix()
        return q.project_bbox_reference(R2, c + d[3:6], r + d[6:9], K, T2)[0]

    flat = lambda x, k: x.reshape((-1,) + x.shape[x.ndim - k :])
    J = jax.vmap(jax.jacfwd(box), in_axes=(None, 0, 0, 0, 0))(
        np.zeros(15), flat(R, 2), flat(c, 1), flat(r, 1), flat(T, 2)
    )
    return np.asarray(J).reshape(c.shape[:-1] + (4, 15))


def _check(R, c, r, K, T):
    box, valid, d_object, d_pose = q.project_bbox_jacobian(R, c, r, K, T)
    ref_box, ref_valid = q.project_bbox(R, c, r, K, T)
    shape = c.shape[:-1]
    assert d_object.shape == shape + (4, 9) and d_pose.shape == shape + (4, 6)
    np.testing.assert_array_equal(np.asarray(valid), np.asarray(ref_valid))
    np.testing.assert_allclose(box, ref_box, rtol=1e-12, atol=1e-9)
    J = np.concatenate([np.asarray(d_object), np.asarray(d_pose)], -1)
    scale = np.max(np.abs(J)) + 1.0
    np.testing.assert_allclose(J, _autodiff(R, c, r, K, T), rtol=1e-9, atol=1e-9 * scale)
    np.testing.assert_allclose(J, _finite_differences(R, c, r, K, T), rtol=1e-5, atol=1e-5 * scale)


@pytest.mark.slow
def test_jacobian_matches_finite_differences_and_autodiff():
    _check(*_scene(np.random.default_rng(0), (6,)))


@pytest.mark.slow
@settings(max_examples=6, deadline=None)
@given(shape=hnp.array_shapes(min_dims=0, max_dims=3, min_side=1, max_side=3), seed=st.integers(0, 2**31 - 1))
def test_jacobian_matches_references_over_batch_shapes(shape, seed):
    _check(*_scene(np.random.default_rng(seed), shape))


@pytest.mark.slow
def test_jacobian_broadcasts_one_camera_over_many_ellipsoids():
    R, c, r, K, T = _scene(np.random.default_rng(1), (4,))
    T = T[0]
    one = q.project_bbox_jacobian(R, c, r, K, T)
    for n in range(4):
        each = q.project_bbox_jacobian(R[n], c[n], r[n], K, T)
        for a, b in zip(one, each):
            np.testing.assert_allclose(np.asarray(a)[n], b, rtol=1e-12, atol=1e-12)


@pytest.mark.slow
def test_jacobian_is_finite_for_bad_geometry_and_zero_for_nan_inputs():
    R, c, r, K, T = _scene(np.random.default_rng(2), (3,))
    c[0] = -T[0, :3, :3].T @ T[0, :3, 3]  # the camera at the ellipsoid's centre (inside it)
    c[1] = np.nan  # a non-finite input, read under jit
    _, valid, d_object, d_pose = jax.jit(q.project_bbox_jacobian)(R, c, r, K, T)
    assert not valid[0] and not valid[1] and valid[2]
    assert np.all(np.isfinite(d_object)) and np.all(np.isfinite(d_pose))
    assert not np.any(d_object[1]) and not np.any(d_pose[1])
