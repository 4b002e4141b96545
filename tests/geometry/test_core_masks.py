"""Issue 26: the unmasked quadric algebra can say, under ``jit``, that its input was invalid
(``with_valid=True`` and the public masks ``ellipsoid_valid`` / ``camera_valid``)."""

import jax
import jax.numpy as jnp
import numpy as np

from jaxsem import quadrics as q

K = jnp.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
R = q.so3_exp(jnp.array([0.2, -0.1, 0.4]))
C = jnp.array([0.3, -0.2, 4.0])
RADII = jnp.array([0.5, 0.3, 0.2])
POSE = jnp.eye(4)

DUAL = jax.jit(lambda R, c, r: q.dual_quadric(R, c, r, with_valid=True))
CAM = jax.jit(lambda K, T: q.camera_matrix(K, T, with_valid=True))


def test_dual_quadric_flags_what_its_matrix_cannot_show():
    Q, ok = DUAL(R, C, RADII)
    assert bool(ok)
    np.testing.assert_allclose(Q, q.dual_quadric(R, C, RADII))
    # A negated radius would give the very same matrix (only r^2 enters): the matrix of an invalid
    # ellipsoid is zero instead, so a conic made from it reads invalid too.
    Q_neg, ok_neg = DUAL(R, C, RADII * jnp.array([-1.0, 1, 1]))
    np.testing.assert_array_equal(Q_neg, np.zeros((4, 4)))
    assert not bool(ok_neg)
    np.testing.assert_array_equal(jax.jit(q.dual_quadric)(R, C, -RADII), np.zeros((4, 4)))  # no mask asked
    for bad in (
        (2.0 * R, C, RADII),  # not a rotation
        (R, C.at[0].set(jnp.nan), RADII),  # NaN centre
        (R, C, RADII.at[2].set(0.0)),  # zero radius
    ):
        Qb, okb = DUAL(*bad)
        assert not bool(okb) and bool(jnp.all(jnp.isfinite(Qb)))
    assert bool(q.ellipsoid_valid(R, C, RADII)) and not bool(q.ellipsoid_valid(R, C, -RADII))


def test_camera_matrix_flags_bad_intrinsics_and_poses():
    P, ok = CAM(K, POSE)
    assert bool(ok) and P.shape == (3, 4)
    scaled = POSE.at[:3, :3].multiply(2.0)  # not rigid
    for Kb, Tb in ((K.at[0, 0].set(-500.0), POSE), (K, scaled), (K, POSE.at[3, 0].set(1.0)), (K * jnp.nan, POSE)):
        Pb, okb = CAM(Kb, Tb)
        assert not bool(okb) and bool(jnp.all(jnp.isfinite(Pb)))
        assert not bool(q.camera_valid(Kb, Tb))


def test_masks_batch_and_float32():
    Rb = jnp.stack([R, 2.0 * R]).astype(jnp.float32)
    Cb = jnp.stack([C, C]).astype(jnp.float32)
    rb = jnp.stack([RADII, RADII]).astype(jnp.float32)
    _, ok = DUAL(Rb, Cb, rb)
    assert ok.shape == (2,) and ok.tolist() == [True, False]
