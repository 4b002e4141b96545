"""The core's small rotation helpers that methods used to carry copies of: ``skew``,
``yaw_rotation``, ``ray_rotation``, ``allocentric_rotation``, checked against independent
definitions (cross products, angles between vectors, the egocentric composition)."""

import jax
import jax.numpy as jnp
import numpy as np

from jaxsem import quadrics as Q


def test_skew_is_the_cross_product_in_numpy_and_jax():
    rng = np.random.default_rng(0)
    w, v = rng.normal(size=(2, 5, 3))
    expected = np.cross(w, v)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", Q.skew(w, xp=np), v), expected, atol=1e-12)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", np.asarray(Q.skew(jnp.asarray(w))), v), expected, atol=1e-12)


def test_yaw_rotation_turns_x_towards_y_and_keeps_up():
    yaw = np.array([0.0, 0.3, -1.2, np.pi / 2])
    R = np.asarray(Q.yaw_rotation(yaw))
    x_turned = R[:, :, 0]  # image of the x axis
    np.testing.assert_allclose(np.arctan2(x_turned[:, 1], x_turned[:, 0]), yaw, atol=1e-12)
    np.testing.assert_allclose(R[:, :, 2], np.tile([0.0, 0.0, 1.0], (4, 1)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    # grads are finite at zero (the Taylor branch of the exponential map)
    g = jax.grad(lambda a: jnp.sum(Q.yaw_rotation(a)))(0.0)
    assert np.isfinite(g)


def test_ray_rotation_takes_the_axis_to_the_ray_by_the_smallest_turn():
    rng = np.random.default_rng(1)
    d = rng.normal(size=(50, 3)) * [0.5, 0.5, 1.0] + [0.0, 0.0, 2.0]  # forward rays
    R = np.asarray(Q.ray_rotation(jnp.asarray(d)))
    n = d / np.linalg.norm(d, axis=-1, keepdims=True)
    np.testing.assert_allclose(R[:, :, 2], n, atol=1e-9)
    # smallest turn: the angle of R equals the angle between e_z and the ray
    angle = np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1))
    np.testing.assert_allclose(angle, np.arccos(n[:, 2]), atol=1e-6)
    # allocentric inverts the composition R_ray(c) @ R_allo
    R_allo = np.asarray(Q.random_rotation(jax.random.PRNGKey(0), (50,)))
    R_ego = R @ R_allo
    np.testing.assert_allclose(np.asarray(Q.allocentric_rotation(R_ego, d)), R_allo, atol=1e-9)
