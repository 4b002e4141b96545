"""Post-inference refinement and the optimisation-only baseline (thesis 5.4.4, 5.5.1).

Both minimise the primal loss (eq. 5.15) of one detection's free parameters ``phi`` (10,) with
Adam (learning rate 0.05, as the thesis), ``jax.lax.scan`` over the steps and ``jax.vmap`` over
the detections, jitted:

- :func:`postopt`: starts from the network's ``phi`` and updates only the pose parameters
  ``phi_R, phi_UV, phi_Z`` (size ``phi_D`` fixed), 50 steps by default.
- :func:`optimise_from_scratch`: starts from the point cloud (:func:`init_from_points`: mean
  depth, centroid at the box centre, sizes from the sorted extents of the points in the camera
  frame, identity allocentric rotation) and updates all ten parameters (50 or 500 steps).

Detections without any valid point keep their initial parameters (the loss is zero there).

Step size: Adam's first step is about ``learning_rate`` in every free parameter whatever the
gradient's size, and through the pseudo-disparity one unit of ``phi_Z`` is ``t_z (1 - sigmoid)``,
about 0.6 m at 0.8 m, so the thesis' 0.05 moves the depth by ~3 cm per step. Started at the exact
truth of ellipsoid-shaped objects, 50 steps at 0.05 leave about a third of them more than 5 mm
away (a few in the local minimum where the ellipsoid passes through the rim of the visible cap
from the camera's side, 7-11 cm off); at 0.01 all stay within 0.5 mm. The default stays the
thesis' value; pass ``learning_rate`` to change it.

What PostOpt's centre is worth on a box depends on the (fixed) size it refines with. Synthetic
cracker box, 64 held-out detections, network poses as the start, 50 steps: median centre error
3.2 cm with the true sizes (the box's inscribed ellipsoid fits the visible faces best ~2 cm
nearer the camera), 2.1 cm with 1.2 times, 10.5 cm with twice the true sizes (the centre is
pushed back until the oversized surface meets the visible faces), which is what a network
trained with the literal eq. 5.12 weight predicts (see :mod:`jaxsem.volumon._losses`).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import optax

from .._checks import require_type
from ..models import ReconstructionConfig, reconstruct
from ..quadrics import Ellipsoid, allocentric_rotation, rotation_to_quaternion_wxyz
from ._losses import SHAPE_ELLIPSOID, LossConfig, primal_loss_per_sample

POSE_MASK = jnp.array([0, 0, 0, 1, 1, 1, 1, 1, 1, 1], bool)
ALL_MASK = jnp.ones(10, bool)


def _logit(p):
    p = jnp.clip(p, 1e-6, 1 - 1e-6)
    return jnp.log(p) - jnp.log1p(-p)


def init_from_points(box, K, points, point_mask, recon: ReconstructionConfig = ReconstructionConfig()):
    """Free parameters (..., 10) of the point-cloud initialisation of *Optimise from scratch*.

    Args:
      box: (..., 4); K: (..., 3, 3); points: (..., J, 3) camera frame; point_mask: (..., J).
    """
    m = jnp.asarray(point_mask, bool)
    mf = m.astype(points.dtype)
    n = jnp.maximum(jnp.sum(mf, -1), 1.0)
    z = jnp.sum(points[..., 2] * mf, -1) / n
    z = jnp.where(jnp.any(m, -1), z, 1.0)
    if recon.depth_mode == "disparity":
        s = recon.baseline_focal / (recon.alpha_delta * jnp.maximum(z, 1e-6))
    else:
        s = (z - recon.min_depth) / (recon.max_depth - recon.min_depth)
    phi_z = _logit(s)
    big = jnp.finfo(points.dtype).max / 4
    lo = jnp.min(jnp.where(m[..., None], points, big), -2)
    hi = jnp.max(jnp.where(m[..., None], points, -big), -2)
    ext = jnp.sort(jnp.where(jnp.any(m, -1)[..., None], hi - lo, 0.0), -1)
    # invert d = alpha_y cumsum(exp(phi_D)) + eps_s; extents below the minimum size fall back to
    # (about) the minimum-size sphere, as the thesis
    inc = jnp.diff(ext, axis=-1, prepend=jnp.full(ext.shape[:-1] + (1,), recon.eps_s, ext.dtype))
    phi_d = jnp.log(jnp.maximum(inc / recon.alpha_y, 1e-3))
    phi_r = jnp.broadcast_to(jnp.array([1.0, 0, 0, 0], points.dtype), phi_d.shape[:-1] + (4,))
    phi_uv = jnp.zeros(phi_d.shape[:-1] + (2,), points.dtype)
    return jnp.concatenate([phi_d, phi_r, phi_uv, phi_z[..., None]], -1)


_RECON = ReconstructionConfig()


def phi_from_ellipsoid(ellipsoid: Ellipsoid, box, K, recon: ReconstructionConfig = _RECON):
    """Free parameters (..., 10) whose reconstruction (eq. 5.7, inside ``box``) is ``ellipsoid``
    (camera frame, the :class:`~jaxsem.quadrics.Ellipsoid` that :func:`jaxsem.models.reconstruct` returns).

    The inverse of :func:`jaxsem.models.reconstruct` for an object whose projected centre lies in
    the box: the axes are reordered so the radii increase (the network's convention; a column is
    negated where needed to keep a proper rotation), sizes below ``eps_s`` and equal sizes are
    clamped to tiny increments. Used to start PostOpt from the ground truth.
    """
    rotation, center, radii = require_type("ellipsoid", ellipsoid, Ellipsoid)
    order = jnp.argsort(radii, axis=-1)
    r = jnp.take_along_axis(radii, order, -1)
    R = jnp.take_along_axis(rotation, jnp.broadcast_to(order[..., None, :], rotation.shape), -1)
    det = jnp.linalg.det(R)
    R = R.at[..., :, 0].multiply(jnp.sign(det)[..., None])
    d = 2.0 * r
    inc = jnp.diff(d, axis=-1, prepend=jnp.full(d.shape[:-1] + (1,), recon.eps_s, d.dtype))
    phi_d = jnp.log(jnp.maximum(inc / recon.alpha_y, 1e-4))
    q = rotation_to_quaternion_wxyz(allocentric_rotation(R, center))
    uvw = jnp.einsum("...ij,...j->...i", K, center)
    uv = uvw[..., :2] / uvw[..., 2:]
    uv01 = (uv - box[..., :2]) / jnp.maximum(box[..., 2:] - box[..., :2], 1e-6)
    phi_uv = _logit(uv01)
    z = center[..., 2]
    if recon.depth_mode == "disparity":
        sdisp = recon.baseline_focal / (recon.alpha_delta * z)
    else:
        sdisp = (z - recon.min_depth) / (recon.max_depth - recon.min_depth)
    return jnp.concatenate([phi_d, q, phi_uv, _logit(sdisp)[..., None]], -1)


def _refine_one(phi0, box, K, points, mask, shape, free, recon, loss_cfg, num_steps, lr):
    opt = optax.adam(lr)

    def loss(phi):
        ell = reconstruct(phi, box, K, recon)
        per, _ = primal_loss_per_sample(ell, points, mask, loss_cfg, shape if loss_cfg.shape_aware else None)
        return per

    def step(carry, _):
        phi, state = carry
        val, g = jax.value_and_grad(loss)(phi)
        g = jnp.where(free, g, 0.0)
        with jax.numpy_dtype_promotion("standard"):  # optax's adam: decay ** int32 count (lsd/_train.py)
            upd, state = opt.update(g, state, phi)
        return (optax.apply_updates(phi, upd), state), val

    (phi, _), losses = jax.lax.scan(step, (phi0, opt.init(phi0)), None, length=num_steps)
    return phi, losses


@functools.partial(jax.jit, static_argnames=("recon", "loss_cfg", "num_steps"))
def _refine(phi0, box, K, points, mask, shape, free, recon, loss_cfg, num_steps, lr):
    fn = lambda p, b, k, x, m, s: _refine_one(p, b, k, x, m, s, free, recon, loss_cfg, num_steps, lr)
    return jax.vmap(fn)(phi0, box, K, points, mask, shape)


def refine(
    phi0,
    box,
    K,
    points,
    point_mask,
    free_mask=POSE_MASK,
    recon: ReconstructionConfig = ReconstructionConfig(),
    loss_config: LossConfig = LossConfig(),
    num_steps: int = 50,
    learning_rate: float = 0.05,
    shape=None,
):
    """Adam on the primal loss of each detection's ``phi`` (eq. 5.15), only entries in ``free_mask``.

    Args:
      phi0: (B, 10) initial free parameters; box: (B, 4); K: (B, 3, 3); points: (B, J, 3) camera
        frame; point_mask: (B, J); free_mask: (10,) bool.
      shape: optional (B,) class shapes (0 cuboid, 1 ellipsoid, 2 cylinder), used when
        ``loss_config.shape_aware`` (the loss the network was trained with): the primal distance
        to the class's own shape, so the true object is a zero of the objective. None: ellipsoids.
    """
    phi0 = jnp.asarray(phi0)
    if phi0.ndim != 2 or phi0.shape[-1] != 10:
        raise ValueError(f"phi0: expected shape (B, 10), got {tuple(phi0.shape)}")
    B = phi0.shape[0]
    for name, x, tail in (
        ("box", box, (4,)),
        ("K", K, (3, 3)),
        ("points", points, None),
        ("point_mask", point_mask, None),
    ):
        got = tuple(jnp.shape(x))
        if got[:1] != (B,) or (tail is not None and got[1:] != tail):
            raise ValueError(
                f"{name}: expected leading batch {B}{' and trailing ' + str(tail) if tail else ''}, got {got}"
            )
    if int(num_steps) < 1:
        raise ValueError(f"num_steps: expected >= 1, got {num_steps}")
    dtype = phi0.dtype
    shape = jnp.full((B,), SHAPE_ELLIPSOID, jnp.int32) if shape is None else jnp.asarray(shape, jnp.int32)
    if shape.shape != (B,):
        raise ValueError(f"shape: expected shape ({B},), got {tuple(shape.shape)}")
    phi, losses = _refine(
        phi0,
        jnp.asarray(box, dtype),
        jnp.asarray(K, dtype),
        jnp.asarray(points, dtype),
        jnp.asarray(point_mask, bool),
        shape,
        jnp.asarray(free_mask, bool),
        recon,
        loss_config,
        int(num_steps),
        jnp.asarray(learning_rate, dtype),
    )
    return phi, reconstruct(phi, jnp.asarray(box, dtype), jnp.asarray(K, dtype), recon), losses


def postopt(
    phi,
    box,
    K,
    points,
    point_mask,
    recon: ReconstructionConfig = ReconstructionConfig(),
    loss_config: LossConfig = LossConfig(),
    num_steps: int = 50,
    learning_rate: float = 0.05,
    shape=None,
):
    """VoluMon PostOpt: refine the pose parameters of network predictions, size fixed (50 steps).

    ``shape``: optional (B,) class shapes, see :func:`refine`."""
    return refine(phi, box, K, points, point_mask, POSE_MASK, recon, loss_config, num_steps, learning_rate, shape)


def optimise_from_scratch(
    box,
    K,
    points,
    point_mask,
    recon: ReconstructionConfig = ReconstructionConfig(),
    loss_config: LossConfig = LossConfig(),
    num_steps: int = 500,
    learning_rate: float = 0.05,
    shape=None,
):
    """The baseline: all ten parameters from the point-cloud initialisation (50 or 500 steps).

    ``shape``: optional (B,) class shapes, see :func:`refine`."""
    points = jnp.asarray(points)
    B = jnp.shape(box)[0] if jnp.ndim(box) == 2 else None
    for name, x in (("points", points), ("point_mask", point_mask), ("K", K)):
        if B is None or jnp.shape(x)[:1] != (B,):
            raise ValueError(
                f"{name}: expected the leading batch {B} of box {tuple(jnp.shape(box))}, got {tuple(jnp.shape(x))}"
            )
    phi0 = init_from_points(jnp.asarray(box, points.dtype), jnp.asarray(K, points.dtype), points, point_mask, recon)
    return refine(phi0, box, K, points, point_mask, ALL_MASK, recon, loss_config, num_steps, learning_rate, shape)


__all__ = ["Ellipsoid", "init_from_points", "optimise_from_scratch", "phi_from_ellipsoid", "postopt", "refine"]
