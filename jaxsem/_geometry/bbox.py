"""The exact image box of an ellipsoid, :func:`project_bbox` (eq. 4.5, 4.9-4.10, 5.10), with its
custom JVP, and its Jacobians in closed form, :func:`project_bbox_jacobian`.

Re-exported by :mod:`jaxsem.quadrics`.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._checks import (
    batch_shape as _batch_shape,
)
from ._common import (
    _camera_args,
    _eager_compiled,
    _ellipsoid_args,
    _ellipsoid_ok,
    _eps,
    _finite_or_zero,
    _intrinsics_ok,
    _pose_ok,
    safe_sqrt,
)

# --------------------------------------------------------------------------------------------
# project_bbox: a fused private path.
#
# Why not conic_bbox(project_dual_conic(dual_quadric(...))): that composition is the readable
# reference (and the tests check this path against it), but XLA on the CPU runs batched (4, 4)
# matmuls and size-3/4 trailing axes as many small, badly vectorised loops. Here everything is
# written on (...,) components, so that XLA emits a few elementwise loops. Two XLA:CPU habits
# shape the code (benchmarks/geometry.py measures it; see benchmarks/results/geometry.md):
#
# - A loop fusion has one output. The four box edges are therefore computed in a (..., 4) space
#   (the inputs broadcast along a last axis of size 4, each lane computing its own edge), which
#   vectorises across the lanes and reads every input once; the mask is a second, separate loop.
# - A value shared by two loops is materialised in memory, or, when cheap, recomputed per use.
#   The reverse mode (the transpose of the custom JVP below) is arranged so that the only
#   materialised intermediate is one (..., 2, 9) array of cotangents, and input tangents are only
#   multiplied by primal arrays and summed over their own axes (so the transpose is elementwise
#   in each input's own shape, without reductions or scatters).
#
# Notation (per pair): C* = K M K^T, with M = [I | 0] T Q* T^T [I | 0]^T = S - t t^T the dual conic
# in normalised camera coordinates (S = Rc diag(r^2) Rc^T, Rc = W R, t = W c + t_w the centre in
# the camera frame, T = [[W, t_w], [0, 1]] = camera_T_world). For one image axis let
# a = (fx, s, 0) for u, (0, fy, 0) for v, and c0 = cx or cy; the row h = a [I | 0] T (4 entries)
# and the depth row h3 = e3 [I | 0] T. With R_k the k-th column of R:
#   ra_k = r_k (h[:3] . R_k),  r3_k = r_k (h3[:3] . R_k),  alpha = h . [c, 1],  tz = h3 . [c, 1],
#   num = a M e3 = ra . r3 - alpha tz,      den = M33 = C33 = |r3|^2 - tz^2,
#   disc = num^2 - (a M a) M33 = |tz ra - alpha r3|^2 - |ra x r3|^2   (= C13^2 - C11 C33 of the
#          pixel conic; Lagrange's identity makes it a difference of two non-negative terms,
#          without the cancellation of the pixel-space form),
#   edges = c0 + (num -+ sqrt(disc)) / den   (eq. 4.10 with the origin moved to c0).

_BOX_COL_IS_U = np.array([True, False, True, False])  # [u_min, v_min, u_max, v_max]
_BOX_COL_SIGN = np.array([1.0, 1.0, -1.0, -1.0])


def _dot3(a, b) -> Any:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross3(a, b) -> Any:
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def _bbox_valid(R, c, r, K, T):
    """The ``valid`` mask of :func:`project_bbox`: the whole ellipsoid strictly in front of the
    principal plane (near tangent plane ``tz - sqrt(S33) > 0``, eq. 4.11) and both discriminants
    non-negative in floating point. One elementwise loop over (...,) components."""
    W = [[T[..., i, j] for j in range(3)] for i in range(3)]
    Ro = [[R[..., i, j] for j in range(3)] for i in range(3)]
    cc = [c[..., i] for i in range(3)]
    rr = [r[..., i] for i in range(3)]
    Rc = [[W[i][0] * Ro[0][j] + W[i][1] * Ro[1][j] + W[i][2] * Ro[2][j] for j in range(3)] for i in range(3)]
    tx, ty, tz = [W[i][0] * cc[0] + W[i][1] * cc[1] + W[i][2] * cc[2] + T[..., i, 3] for i in range(3)]
    fx, s, fy = K[..., 0, 0], K[..., 0, 1], K[..., 1, 1]
    r3 = [rr[k] * Rc[2][k] for k in range(3)]
    ra = [rr[k] * (fx * Rc[0][k] + s * Rc[1][k]) for k in range(3)]
    rb = [rr[k] * (fy * Rc[1][k]) for k in range(3)]
    s33 = _dot3(r3, r3)
    half_depth = safe_sqrt(s33)
    near = tz - half_depth  # texture-plane depth: the camera-facing tangent plane
    alpha = fx * tx + s * ty
    beta = fy * ty
    wa = [tz * ra[k] - alpha * r3[k] for k in range(3)]
    wb = [tz * rb[k] - beta * r3[k] for k in range(3)]
    cu, cv = _cross3(ra, r3), _cross3(rb, r3)
    disc_u = _dot3(wa, wa) - _dot3(cu, cu)
    disc_v = _dot3(wb, wb) - _dot3(cv, cv)
    eps = _eps(near.dtype)
    ok = _ellipsoid_ok(R, c, r) & _intrinsics_ok(K) & _pose_ok(T)  # the inputs, under jit
    return (near > eps * (jnp.abs(tz) + half_depth)) & (disc_u >= 0) & (disc_v >= 0) & ok


def _bbox_axis(R, c, r, K, T, valid, lift, is_u):
    """Per image axis the quantities of eq. 4.10 (see the notation above), computed in a
    broadcast space: ``lift`` broadcasts a (...,) array into it, ``is_u`` selects the u axis."""
    zero = jnp.zeros((), R.dtype)
    a0 = jnp.where(is_u, lift(K[..., 0, 0]), zero)
    a1 = jnp.where(is_u, lift(K[..., 0, 1]), lift(K[..., 1, 1]))
    h = [a0 * lift(T[..., 0, j]) + a1 * lift(T[..., 1, j]) for j in range(4)]
    h3 = [lift(T[..., 2, j]) for j in range(4)]
    c0 = jnp.where(is_u, lift(K[..., 0, 2]), lift(K[..., 1, 2]))
    col = [[lift(R[..., i, k]) for i in range(3)] for k in range(3)]
    rr = [lift(r[..., k]) for k in range(3)]
    ch = [lift(c[..., i]) for i in range(3)]
    ra = [rr[k] * _dot3(h, col[k]) for k in range(3)]
    r3 = [rr[k] * _dot3(h3, col[k]) for k in range(3)]
    alpha = _dot3(h, ch) + h[3]
    tz = _dot3(h3, ch) + h3[3]
    num = _dot3(ra, r3) - alpha * tz
    wa = [tz * ra[k] - alpha * r3[k] for k in range(3)]
    cr = _cross3(ra, r3)
    disc = _dot3(wa, wa) - _dot3(cr, cr)
    V = lift(valid)
    pos = V & (disc > jnp.finfo(R.dtype).tiny)
    sq = jnp.where(pos, jnp.sqrt(jnp.where(pos, disc, 1.0)), 0.0)  # safe_sqrt of the masked disc
    fallback = tz * tz
    den = jnp.where(V, _dot3(r3, r3) - fallback, -jnp.maximum(fallback, 1.0))
    return dict(
        c0=c0, ra=ra, r3=r3, alpha=alpha, tz=tz, num=num, wa=wa, cr=cr, sq=sq, den=den, V=V, pos=pos, fallback=fallback
    )


def _bbox_edges(R, c, r, K, T, valid):
    """(..., 4) ``[u_min, v_min, u_max, v_max]``: one lane per edge."""
    shape = R.shape[:-2] + (4,)
    lift = lambda x: jnp.broadcast_to(x[..., None], shape)
    q = _bbox_axis(R, c, r, K, T, valid, lift, jnp.asarray(_BOX_COL_IS_U))
    sign = jnp.asarray(_BOX_COL_SIGN, R.dtype)
    # (sign num + sq) / (sign den) is (num + sign sq) / den exactly (sign flips are exact); the
    # divisor differs per lane, which keeps XLA from hoisting 1 / den into a loop of its own.
    edges = q["c0"] + (sign * q["num"] + q["sq"]) / (sign * q["den"])
    # Non-finite only for a non-finite input (then ``valid`` is False): read as 0.
    return _finite_or_zero(edges)


def _bbox_sensitivities(R, c, r, K, T, valid):
    """``den * d edge / d x`` for the lower and the upper edge of each axis, with
    ``x = (ra_0, ra_1, ra_2, r3_0, r3_1, r3_2, alpha, tz, c0)``, and ``den``: three (..., 2, 9)
    arrays from one elementwise loop (axis along -2, entry of x along -1)."""
    shape = R.shape[:-2] + (2, 9)
    lift = lambda x: jnp.broadcast_to(x[..., None, None], shape)
    is_u = jnp.broadcast_to(jnp.asarray([[True], [False]]), (2, 9))
    q = _bbox_axis(R, c, r, K, T, valid, lift, is_u)
    num, sq, den, pos = q["num"], q["sq"], q["den"], q["pos"]
    d_num, d_disc, d_den = _bbox_partials(q)
    m = jnp.broadcast_to(jnp.arange(9), (2, 9))

    def pick(values):
        out = values[8]
        for i in range(7, -1, -1):
            out = jnp.where(m == i, values[i], out)
        return out

    dn, dd, dq = pick(d_num), pick(d_disc), pick(d_den)
    # d sqrt(disc) = d disc / (2 sqrt(disc)) where disc > tiny, else 0 (as safe_sqrt).
    ds = jnp.where(pos, 0.5 / jnp.where(pos, sq, 1.0), 0.0) * dd
    c0 = jnp.where(m == 8, den, 0.0)  # d edge / d c0 = 1
    lower = dn + ds - (num + sq) / den * dq + c0
    upper = dn - ds - (num - sq) / den * dq + c0
    return lower, upper, den


def _bbox_partials(q):
    """Partial derivatives of num, disc and den (see the notation above) with respect to the
    entries of ``x = (ra_0, ra_1, ra_2, r3_0, r3_1, r3_2, alpha, tz, c0)``: three lists of 9
    arrays, from :func:`_bbox_axis`'s quantities ``q``."""
    ra, r3, alpha, tz, wa, cr, V = q["ra"], q["r3"], q["alpha"], q["tz"], q["wa"], q["cr"], q["V"]
    zero = jnp.zeros_like(tz)
    d_num = r3 + ra + [-tz, -alpha, zero]
    r3_x_cr, cr_x_ra = _cross3(r3, cr), _cross3(cr, ra)  # d|ra x r3|^2 = 2 (r3 x cr) dra + 2 (cr x ra) dr3
    d_disc = (
        [2.0 * (tz * wa[k] - r3_x_cr[k]) for k in range(3)]
        + [2.0 * (-alpha * wa[k] - cr_x_ra[k]) for k in range(3)]
        + [-2.0 * _dot3(wa, r3), 2.0 * _dot3(wa, ra), zero]
    )
    fb = q["fallback"]  # where not valid, den = -max(tz^2, 1); jnp.maximum splits a tie evenly
    d_fb = jnp.where(fb > 1.0, 1.0, jnp.where(fb == 1.0, 0.5, 0.0))
    d_den = (
        [zero] * 3
        + [jnp.where(V, 2.0 * r3[k], 0.0) for k in range(3)]
        + [zero, -2.0 * tz * jnp.where(V, 1.0, d_fb), zero]
    )
    return d_num, d_disc, d_den


def _bbox_primitive_tangents(R, c, r, K, T, dR, dc, dr, dK, dT):
    """Tangents of x (see :func:`_bbox_sensitivities`) per axis, (..., 2, 9).

    Input tangents are only multiplied by primal arrays and summed over their own axes (or used
    one entry at a time), so that the transpose of this linear map (the reverse mode) is
    elementwise in each input's own shape: no reductions, and nothing but the (..., 2, 9)
    cotangent of x needs to be kept in memory."""
    zero = jnp.zeros(R.shape[:-2], R.dtype)
    fx, s, fy = K[..., 0, 0], K[..., 0, 1], K[..., 1, 1]
    dfx, ds, dfy = dK[..., 0, 0], dK[..., 0, 1], dK[..., 1, 1]
    W = [[T[..., j, i] for i in range(3)] for j in range(3)]
    tw = [T[..., j, 3] for j in range(3)]
    dW, dtw = dT[..., :3, :3], dT[..., :3, 3]
    # Rows h = A W (world axes) and h_t = A t_w of the u axis, the v axis and the depth row, as
    # (weights A, tangent of A) pairs; dh = A dW + dA W, dh_t = A dt_w + dA t_w.
    rows = [
        ([fx, s, zero], [dfx, ds, None]),
        ([zero, fy, zero], [None, dfy, None]),
        ([zero, zero, zero + 1.0], [None] * 3),
    ]
    proj, lin = [], []
    for A, dA in rows:
        h = [A[0] * W[0][i] + A[1] * W[1][i] + A[2] * W[2][i] for i in range(3)]
        Av = jnp.stack(A, -1)
        dh = jnp.sum(Av[..., :, None] * dW, -2)
        dht = jnp.sum(Av * dtw, -1)
        for j in range(3):
            if dA[j] is not None:
                dh = dh + jnp.stack([dA[j] * W[j][i] for i in range(3)], -1)
                dht = dht + dA[j] * tw[j]
        p = jnp.stack([h[0] * R[..., 0, k] + h[1] * R[..., 1, k] + h[2] * R[..., 2, k] for k in range(3)], -1)
        dp = jnp.stack([jnp.sum(dh * R[..., :, k], -1) for k in range(3)], -1) + jnp.sum(
            jnp.stack(h, -1)[..., :, None] * dR, -2
        )
        proj.append(dr * p + r * dp)  # d (r_k h . R_k)
        lin.append(jnp.sum(dh * c, -1) + dht + jnp.sum(jnp.stack(h, -1) * dc, -1))  # d (h . c + h_t)
    dx_u = jnp.concatenate([proj[0], proj[2], jnp.stack([lin[0], lin[2], dK[..., 0, 2]], -1)], -1)
    dx_v = jnp.concatenate([proj[1], proj[2], jnp.stack([lin[1], lin[2], dK[..., 1, 2]], -1)], -1)
    return jnp.stack([dx_u, dx_v], -2)


def _project_bbox_plain(R, c, r, K, T):
    """Eq. 4.9-4.10 in closed form on inputs that share one batch shape (see the notes above).
    Differentiating this directly is correct but slow; :func:`_project_bbox` adds the JVP rule."""
    valid = _bbox_valid(R, c, r, K, T)
    return _bbox_edges(R, c, r, K, T, valid), valid


_project_bbox = jax.custom_jvp(_project_bbox_plain)


def project_bbox_reference(rotation, center, radii, K, camera_T_world):
    """:func:`project_bbox`'s closed form differentiated by plain autodiff, without its hand-written
    JVP rule: the same boxes and masks, slower gradients. A reference for tests and benchmarks of
    the rule; the inputs must already share one batch shape (no broadcasting, no checks)."""
    return _project_bbox_plain(rotation, center, radii, K, camera_T_world)


@_project_bbox.defjvp
def _project_bbox_jvp(primals, tangents):
    R, c, r, K, T = primals
    box, valid = _project_bbox(R, c, r, K, T)
    lower, upper, den = _bbox_sensitivities(R, c, r, K, T, valid)
    # Dividing the tangent (not the sensitivities) by den puts the division at the end of the
    # reverse pass, which makes XLA keep that (..., 2, 9) cotangent in memory instead of
    # recomputing it in every consumer.
    # Items with a non-finite input (valid is False there) get a zero tangent, in both modes: the
    # input tangents are selected away (what the reverse mode's transpose applies last) and so
    # is the output tangent (what the forward mode returns). Selects, not products: 0 * NaN = NaN.
    # One sum of every entry that enters is finite iff they all are (barring an overflow of
    # values near the dtype's maximum): cheaper than a test per entry.
    entries = [R[..., i, j] for i in range(3) for j in range(3)] + [T[..., i, j] for i in range(3) for j in range(4)]
    entries += [c[..., i] for i in range(3)] + [r[..., i] for i in range(3)]
    entries += [K[..., 0, 0], K[..., 0, 1], K[..., 0, 2], K[..., 1, 1], K[..., 1, 2]]
    finite = jnp.isfinite(sum(entries[1:], entries[0]))
    keep = lambda dx, trailing: jnp.where(finite[(...,) + (None,) * trailing], dx, jnp.zeros((), dx.dtype))
    tangents = tuple(keep(t, t.ndim - finite.ndim) for t in tangents)
    dx = _bbox_primitive_tangents(*primals, *tangents) / den
    dbox = jnp.concatenate([jnp.sum(lower * dx, -1), jnp.sum(upper * dx, -1)], -1)
    return (box, valid), (keep(dbox, 1), np.zeros(valid.shape, jax.dtypes.float0))


def _project_bbox_jacobian_plain(R, c, r, K, T):
    """:func:`project_bbox_jacobian` on inputs that share one batch shape."""
    box, valid = _project_bbox_plain(R, c, r, K, T)
    # One lane per edge, [u_min, v_min, u_max, v_max]; S_i = d edge / d x_i (x as in
    # _bbox_sensitivities), each a (..., 4) array: a Jacobian needs every entry, so the entries
    # are not spread over lanes as in the JVP rule.
    shape = R.shape[:-2] + (4,)
    lift = lambda x: jnp.broadcast_to(x[..., None], shape)
    is_u = jnp.asarray(_BOX_COL_IS_U)
    q = _bbox_axis(R, c, r, K, T, valid, lift, is_u)
    d_num, d_disc, d_den = _bbox_partials(q)
    sign = jnp.asarray(_BOX_COL_SIGN, R.dtype)
    num, sq, den, pos = q["num"], q["sq"], q["den"], q["pos"]
    half_inv_sq = jnp.where(pos, 0.5 / jnp.where(pos, sq, 1.0), 0.0)  # d sqrt(disc) / d disc
    edge_off = (num + sign * sq) / den  # the edge minus c0
    S = [(d_num[i] + sign * half_inv_sq * d_disc[i] - edge_off * d_den[i]) / den for i in range(8)]
    zero = jnp.zeros((), R.dtype)
    a0 = jnp.where(is_u, lift(K[..., 0, 0]), zero)
    a1 = jnp.where(is_u, lift(K[..., 0, 1]), lift(K[..., 1, 1]))
    # The lane's image row h = a W and the depth row h3 = e3 W (world axes), and their object-frame
    # twins p = R^T h, p3 = R^T h3, so that x = (r * p, r * p3, h . c + h_t, h3 . c + h3_t, c0).
    h = [a0 * lift(T[..., 0, i]) + a1 * lift(T[..., 1, i]) for i in range(3)]
    h3 = [lift(T[..., 2, i]) for i in range(3)]
    col = [[lift(R[..., i, k]) for i in range(3)] for k in range(3)]
    p = [_dot3(h, col[k]) for k in range(3)]
    p3 = [_dot3(h3, col[k]) for k in range(3)]
    rr = [lift(r[..., k]) for k in range(3)]
    ch = [lift(c[..., i]) for i in range(3)]
    # Chain rule through x. With u_k = S_k r_k, w_k = S_(3+k) r_k (d edge / d ra_k, d r3_k times r_k):
    #   R <- R (I + [dw]x):  d p_k = (e_k x p) . dw           -> d edge / d dw = u x p + w x p3
    #   c <- c + dc:          d alpha = h . dc, d tz = h3 . dc  -> S_6 h + S_7 h3
    #   r <- r + dr:          d ra_k = p_k dr_k                 -> S_k p_k + S_(3+k) p3_k
    #   T <- T (I + [v, w]^): d h = h x w, d h_t = h . v        -> v: S_6 h + S_7 h3,
    #                         w: (R u) x h + (R w) x h3 + c x (S_6 h + S_7 h3)
    u = [S[k] * rr[k] for k in range(3)]
    w = [S[3 + k] * rr[k] for k in range(3)]
    d_w = [a + b for a, b in zip(_cross3(u, p), _cross3(w, p3))]
    d_c = [S[6] * h[i] + S[7] * h3[i] for i in range(3)]
    d_r = [S[k] * p[k] + S[3 + k] * p3[k] for k in range(3)]
    Ru = [col[0][i] * u[0] + col[1][i] * u[1] + col[2][i] * u[2] for i in range(3)]
    Rw = [col[0][i] * w[0] + col[1][i] * w[1] + col[2][i] * w[2] for i in range(3)]
    d_om = [a + b + e for a, b, e in zip(_cross3(Ru, h), _cross3(Rw, h3), _cross3(ch, d_c))]
    # Items with a non-finite input get zero derivatives, as in the JVP rule.
    entries = [R[..., i, j] for i in range(3) for j in range(3)] + [T[..., i, j] for i in range(3) for j in range(4)]
    entries += [c[..., i] for i in range(3)] + [r[..., i] for i in range(3)]
    entries += [K[..., 0, 0], K[..., 0, 1], K[..., 0, 2], K[..., 1, 1], K[..., 1, 2]]
    finite = jnp.isfinite(sum(entries[1:], entries[0]))[..., None, None]
    keep = lambda x: jnp.where(finite, x, jnp.zeros((), x.dtype))
    d_object = keep(jnp.stack(d_w + d_c + d_r, -1))
    d_pose = keep(jnp.stack(d_c + d_om, -1))
    return box, valid, d_object, d_pose


def project_bbox_jacobian(rotation, center, radii, K, camera_T_world):
    """:func:`project_bbox` and its Jacobians with respect to the object's 9 parameters and the
    camera pose, in closed form (the chain rule through the quantities of eq. 4.10).

    A least-squares solver that linearises many box factors needs these 4 x 15 blocks; forward-
    mode autodiff gets them column by column (one pass per parameter, each through every
    operation of the box), this in one elementwise pass from the same sensitivities as the JVP
    rule of :func:`project_bbox` (so the two agree to rounding).

    Args:
      rotation, center, radii, K, camera_T_world: as :func:`project_bbox` (batch axes broadcast).

    Returns:
      box: (..., 4) and valid: (...), as :func:`project_bbox`.
      d_object: (..., 4, 9) ``d box / d [dw, dc, dr]`` for the object perturbed as
        ``rotation @ SO3.exp(dw)`` (a rotation in the object's own frame), ``center + dc`` and
        ``radii + dr``.
      d_pose: (..., 4, 6) ``d box / d [v, w]`` for the camera perturbed as
        ``camera_T_world @ SE3.exp([v, w])`` (right perturbation, jaxlie's tangent order).

      Finite everywhere; zero for items with a non-finite input.
    """
    return _checked_call(_project_bbox_jacobian_compiled, rotation, center, radii, K, camera_T_world)


def _checked_call(compiled, rotation, center, radii, K, camera_T_world):
    """``compiled`` (a :func:`_cast_to_batch` kernel) on the checked, broadcast arguments of a
    box projection: the one argument path of :func:`project_bbox` and its Jacobian."""
    rotation, center, radii, batch = _ellipsoid_args(rotation, center, radii)
    K, pose = _camera_args(K, camera_T_world)
    batch = _batch_shape(ellipsoid=batch, K=K.shape[:-2], camera_T_world=pose.shape[:-2])
    return compiled(rotation, center, radii, K, pose, batch)


def _cast_to_batch(kernel):
    """``kernel(rotation, center, radii, K, pose)`` on arguments cast to one dtype and broadcast
    to ``batch`` (the last, static, argument of the returned function)."""

    def cast_and_call(rotation, center, radii, K, pose, batch):
        dtype = jnp.result_type(rotation.dtype, K.dtype, pose.dtype)
        cast = lambda x, trailing: jnp.broadcast_to(x.astype(dtype), batch + trailing)
        return kernel(
            cast(rotation, (3, 3)), cast(center, (3,)), cast(radii, (3,)), cast(K, (3, 3)), cast(pose, (4, 4))
        )

    return cast_and_call


_project_bbox_jacobian_compiled = _eager_compiled(_cast_to_batch(_project_bbox_jacobian_plain), static_argnums=(5,))


def project_bbox(rotation, center, radii, K, camera_T_world):
    """Image box of an ellipsoid seen by a pinhole camera (eq. 4.5, 4.9-4.10 and 5.10 in closed form).

    Args:
      rotation: (..., 3, 3) object-to-world; center: (..., 3) world; radii: (..., 3) semi-axes.
      K: (..., 3, 3) intrinsics ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``.
      camera_T_world: (..., 4, 4) world-to-camera transform (OpenCV axes).

    Returns:
      box: (..., 4) ``[u_min, v_min, u_max, v_max]`` in pixels, finite everywhere, with finite
        gradients. It is not truncated to any image size.
      valid: (...) bool, True iff the whole ellipsoid lies strictly in front of the camera's
        principal plane (so the camera is outside it and the outline is a real ellipse) and the
        inputs are what the eager checks accept: a proper rotation, a finite centre, positive
        finite radii, finite ``K`` with ``fx, fy > 0``, a rigid ``camera_T_world``. Where False
        (camera inside or on the ellipsoid, ellipsoid behind or straddling the image plane, or a
        bad input under ``jit``) the box is an arbitrary finite value, with finite gradients
        (non-finite input entries are read as 0).

    Only ``fx, s, cx, fy, cy`` of ``K`` and the first three rows of ``camera_T_world`` enter (the
    gradient with respect to the other entries is zero). The computation is a fused form of
    ``conic_bbox(project_dual_conic(dual_quadric(...)))`` written for speed (see the comment
    "project_bbox: a fused private path" in this module); the tests check that the two agree,
    gradients included. Its custom JVP serves both ``jvp``/``jacfwd`` and ``grad``/``jacrev``.
    """
    return _checked_call(_project_bbox_compiled, rotation, center, radii, K, camera_T_world)


_project_bbox_compiled = _eager_compiled(_cast_to_batch(_project_bbox), static_argnums=(5,))
