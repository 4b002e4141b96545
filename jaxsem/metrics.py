"""Metrics: ellipsoid errors with symmetries, exact 3D IoU of oriented boxes, ADI, pass-rate AUC,
detection average precision, and the statistics of plan-cost ratios.

All array functions are jnp, broadcast over leading batch axes and work under ``jit`` and ``vmap``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ._checks import as_float_array as _as_float_array, batch_shape as _batch_shape
from .quadrics import box_iou, rotation_to_quaternion_wxyz, safe_norm, safe_sqrt

__all__ = [
    "ellipsoid_errors",
    "rotation_angle",
    "iou_3d_boxes",
    "box_volume_intersection",
    "adi",
    "add",
    "pass_rate_curve",
    "auc_pass_rate",
    "average_precision",
    "mean_sem",
    "zero_intercept_slope",
]


def rotation_angle(rotation_a, rotation_b):
    """Geodesic angle (radians, in [0, pi]) between rotations (..., 3, 3); NaN-free everywhere."""
    rel = jnp.matmul(jnp.swapaxes(rotation_a, -1, -2), rotation_b)
    q = rotation_to_quaternion_wxyz(rel)
    return 2.0 * jnp.arctan2(safe_norm(q[..., 1:], axis=-1), jnp.abs(q[..., 0]))


def _line_angle(a, b):
    """Angle (radians, [0, pi/2]) between the unsigned lines along unit vectors a, b (..., 3)."""
    return jnp.arctan2(safe_norm(jnp.cross(a, b), axis=-1), jnp.abs(jnp.sum(a * b, axis=-1)))


_SIGN_FLIPS = np.array([np.diag(d) for d in ([1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1])], dtype=np.float64)


def _sorted_axes(rotation, radii):
    order = jnp.argsort(radii, axis=-1)
    radii_sorted = jnp.take_along_axis(radii, order, axis=-1)
    axes = jnp.take_along_axis(rotation, order[..., None, :], axis=-1)
    # Sorting can turn a rotation into a reflection; flipping the last axis keeps it proper and is
    # itself a symmetry of the ellipsoid.
    det = jnp.linalg.det(axes)
    axes = axes.at[..., :, 2].multiply(jnp.where(det < 0, -1.0, 1.0)[..., None])
    return axes, radii_sorted


def ellipsoid_errors(
    pred_rotation, pred_center, pred_radii, true_rotation, true_center, true_radii, *, equal_rtol=0.05
):
    """Shape, position and orientation errors between ellipsoids, with their symmetries handled.

    Both ellipsoids are canonicalised by sorting their axes by radius (an ellipsoid is unchanged by
    permuting its axes together with its radii), radii are compared as absolute values (a
    parameterisation through r^2 cannot tell r from -r). Then:

    - ``shape``: Euclidean norm of the difference of the sorted radii (metres);
    - ``position``: distance between the centres (metres);
    - ``orientation``: degrees. With three distinct true radii (relative gaps above
      ``equal_rtol``), the smallest geodesic angle over the four axis sign flips. With two equal
      true radii, rotation about the distinct axis is a symmetry, so only the angle between the
      distinct axes (as lines) counts; with three equal radii it is 0.

    Args:
      pred_rotation, true_rotation: (..., 3, 3) object-to-world.
      pred_center, true_center: (..., 3).
      pred_radii, true_radii: (..., 3) semi-axes.
      equal_rtol: relative tolerance under which two true radii count as equal.

    Returns:
      dict of (...) arrays ``shape``, ``position``, ``orientation``. A non-finite prediction (a
      failed estimate) gives NaN errors, never a finite-looking one; non-finite concrete ground
      truth raises ``ValueError`` naming the argument.
    """
    Rp = _as_float_array("pred_rotation", pred_rotation, (3, 3))
    Rt = _as_float_array("true_rotation", true_rotation, (3, 3), check_finite=True)
    cp = _as_float_array("pred_center", pred_center, (3,))
    ct = _as_float_array("true_center", true_center, (3,), check_finite=True)
    rp = jnp.abs(_as_float_array("pred_radii", pred_radii, (3,)))
    rt = jnp.abs(_as_float_array("true_radii", true_radii, (3,), check_finite=True))
    batch = _batch_shape(
        pred_rotation=Rp.shape[:-2],
        true_rotation=Rt.shape[:-2],
        pred_center=cp.shape[:-1],
        true_center=ct.shape[:-1],
        pred_radii=rp.shape[:-1],
        true_radii=rt.shape[:-1],
    )
    Rp, rp = _sorted_axes(jnp.broadcast_to(Rp, batch + (3, 3)), jnp.broadcast_to(rp, batch + (3,)))
    Rt, rt = _sorted_axes(jnp.broadcast_to(Rt, batch + (3, 3)), jnp.broadcast_to(rt, batch + (3,)))
    shape_err = safe_norm(rp - rt, axis=-1)
    position_err = safe_norm(cp - ct, axis=-1)

    flips = jnp.asarray(_SIGN_FLIPS, Rp.dtype)
    full = jnp.min(rotation_angle(Rt[..., None, :, :], jnp.matmul(Rp[..., None, :, :], flips)), -1)
    scale = jnp.maximum(rt[..., 2], jnp.finfo(rt.dtype).tiny)
    eq01 = (rt[..., 1] - rt[..., 0]) <= equal_rtol * scale
    eq12 = (rt[..., 2] - rt[..., 1]) <= equal_rtol * scale
    axis2 = _line_angle(Rt[..., :, 2], Rp[..., :, 2])  # distinct axis when r0 == r1
    axis0 = _line_angle(Rt[..., :, 0], Rp[..., :, 0])  # distinct axis when r1 == r2
    angle = jnp.where(eq01 & eq12, 0.0, jnp.where(eq01, axis2, jnp.where(eq12, axis0, full)))
    return {"shape": shape_err, "position": position_err, "orientation": jnp.degrees(angle)}


# --------------------------------------------------------------------------------------------
# Exact intersection volume of two oriented boxes by polygon clipping.

_MAX_VERTS = 12  # a quad clipped by the six planes of a box has at most 10 vertices

# Face vertex indices of the unit cube corners (+-1, +-1, +-1), counter-clockwise seen from
# outside, so the divergence theorem gives a positive volume.
_CORNERS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)
_FACES = np.array(
    [
        [4, 6, 7, 5],  # +x
        [0, 1, 3, 2],  # -x
        [2, 3, 7, 6],  # +y
        [0, 4, 5, 1],  # -y
        [1, 5, 7, 3],  # +z
        [0, 2, 6, 4],  # -z
    ]
)
_FACE_NORMALS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], np.float64)


def _box_planes(rotation, center, half):
    """Outward normals (6, 3) and offsets (6,) with ``n . x <= o`` inside."""
    normals = jnp.asarray(_FACE_NORMALS, rotation.dtype) @ rotation.T
    half_per_face = jnp.repeat(half, 2)
    offsets = normals @ center + half_per_face
    return normals, offsets


def _box_faces(rotation, center, half):
    corners = (jnp.asarray(_CORNERS, rotation.dtype) * half) @ rotation.T + center
    polys = corners[jnp.asarray(_FACES)]  # (6, 4, 3)
    verts = jnp.zeros((6, _MAX_VERTS, 3), rotation.dtype).at[:, :4].set(polys)
    count = jnp.full((6,), 4, jnp.int32)
    return verts, count


def _clip_polygon(verts, count, normal, offset, tol):
    """Sutherland-Hodgman clip of one convex polygon (fixed-size, masked) by ``n.x <= o + tol``."""
    V = verts.shape[0]
    count = jnp.asarray(count, jnp.int32)
    idx = jnp.arange(V, dtype=jnp.int32)
    valid = idx < count
    nxt = jnp.where(idx + 1 < count, idx + 1, 0)
    cur_v, next_v = verts, verts[nxt]
    d_cur = verts @ normal - offset
    d_next = d_cur[nxt]
    in_cur = d_cur <= tol
    in_next = d_next <= tol
    denom = d_cur - d_next
    t = jnp.clip(jnp.where(jnp.abs(denom) > 0, d_cur / jnp.where(jnp.abs(denom) > 0, denom, 1.0), 0.0), 0.0, 1.0)
    crossing = cur_v + t[:, None] * (next_v - cur_v)
    emit_cur = valid & in_cur
    emit_cross = valid & (in_cur != in_next)
    cand = jnp.stack([cur_v, crossing], axis=1).reshape(2 * V, 3)
    emit = jnp.stack([emit_cur, emit_cross], axis=1).reshape(2 * V)
    pos = jnp.cumsum(emit) - 1
    pos = jnp.where(emit, pos, V)  # out of range: dropped
    out = jnp.zeros_like(verts).at[pos].set(cand, mode="drop")
    return out, jnp.minimum(jnp.sum(emit), V).astype(jnp.int32)


def _polygon_volume_term(verts, count):
    """Signed volume contribution ``sum v0 . (vi x vi+1) / 6`` of a polygon fan."""
    V = verts.shape[0]
    i = jnp.arange(1, V - 1, dtype=jnp.int32)
    tri = jnp.cross(verts[i], verts[i + 1])
    terms = jnp.sum(verts[0] * tri, axis=-1) / 6.0
    return jnp.sum(jnp.where(i + 1 < count, terms, 0.0))


def _clipped_faces_volume(faces, counts, planes, tol, face_weights):
    normals, offsets = planes

    def clip_face(v, c):
        def body(carry, plane):
            v, c = carry
            return _clip_polygon(v, c, plane[0], plane[1], tol), None

        (v, c), _ = jax.lax.scan(body, (v, c), (normals, offsets))
        return _polygon_volume_term(v, c)

    return jnp.sum(jax.vmap(clip_face)(faces, counts) * face_weights)


def _intersection_volume(Ra, ca, ha, Rb, cb, hb):
    # Work around centre a so that the divergence-theorem sum has no large cancellations.
    cb = cb - ca
    ca = jnp.zeros_like(ca)
    scale = jnp.maximum(jnp.max(ha), jnp.max(hb))
    tol = 64 * jnp.finfo(ha.dtype).eps * scale
    fa, na = _box_faces(Ra, ca, ha)
    fb, nb = _box_faces(Rb, cb, hb)
    pa, pb = _box_planes(Ra, ca, ha), _box_planes(Rb, cb, hb)
    # A face of b lying on a face plane of a with the same outward normal would be counted twice
    # (a's face already covers it): drop it. Opposite-facing coincident faces cancel by themselves.
    same_normal = (pb[0] @ pa[0].T) > 1 - 1e-6
    same_offset = jnp.abs(pb[1][:, None] - pa[1][None, :]) <= tol
    wb = jnp.where(jnp.any(same_normal & same_offset, axis=1), 0.0, 1.0)
    vol = _clipped_faces_volume(fa, na, pb, tol, jnp.ones(6, ha.dtype))
    vol = vol + _clipped_faces_volume(fb, nb, pa, tol, wb)
    return jnp.maximum(vol, 0.0)


def box_volume_intersection(rotation_a, center_a, half_extents_a, rotation_b, center_b, half_extents_b):
    """Exact intersection volume of oriented boxes (..., ) by clipping each box's faces against the
    other's half-spaces and summing the closed surface with the divergence theorem."""
    args = _box_args(rotation_a, center_a, half_extents_a, rotation_b, center_b, half_extents_b)
    return _batched(_intersection_volume, args)


#: The arguments of the oriented-box functions, in their order, with their trailing shapes.
_BOX_ARGS = (
    ("rotation_a", (3, 3)),
    ("center_a", (3,)),
    ("half_extents_a", (3,)),
    ("rotation_b", (3, 3)),
    ("center_b", (3,)),
    ("half_extents_b", (3,)),
)


def _box_args(*values):
    """The six box arguments (:data:`_BOX_ARGS`) as finite float arrays (half extents made
    positive), cast to one dtype and flattened over their broadcast batch; and that batch. One
    table gives each argument's name (for the error) and trailing shape."""
    arrays = []
    for (name, tail), x in zip(_BOX_ARGS, values):
        x = _as_float_array(name, x, tail, check_finite=True)
        arrays.append(jnp.abs(x) if name.startswith("half_extents") else x)
    batch = _batch_shape(**{name: x.shape[: x.ndim - len(tail)] for (name, tail), x in zip(_BOX_ARGS, arrays)})
    dtype = jnp.result_type(*arrays)
    out = [
        jnp.broadcast_to(x.astype(dtype), batch + tail).reshape((-1,) + tail) for (_, tail), x in zip(_BOX_ARGS, arrays)
    ]
    return out, batch


def _batched(fn, args_batch):
    args, batch = args_batch
    return jax.vmap(fn)(*args).reshape(batch)


def iou_3d_boxes(rotation_a, center_a, half_extents_a, rotation_b, center_b, half_extents_b):
    """Exact 3D IoU of oriented boxes.

    Args:
      rotation_*: (..., 3, 3) box-to-world; center_*: (..., 3); half_extents_*: (..., 3) (for an
        ellipsoid's bounding cuboid these are its radii; for a cuboid, half its dimensions).

    Returns:
      (...) IoU in [0, 1].
    """
    (args, batch) = _box_args(rotation_a, center_a, half_extents_a, rotation_b, center_b, half_extents_b)
    inter = jax.vmap(_intersection_volume)(*args)
    va = 8 * jnp.prod(args[2], axis=-1)
    vb = 8 * jnp.prod(args[5], axis=-1)
    union = va + vb - inter
    iou = jnp.where(union > 0, inter / jnp.where(union > 0, union, 1.0), 0.0)
    return jnp.clip(iou, 0.0, 1.0).reshape(batch)


# --------------------------------------------------------------------------------------------
# Point-set and pass-rate metrics.


def add(model_points_true, model_points_pred):
    """ADD: mean distance between corresponding points (..., N, 3) under two poses."""
    a = _as_float_array("model_points_true", model_points_true, (3,), check_finite=True)
    b = _as_float_array("model_points_pred", model_points_pred, (3,))
    return jnp.mean(safe_norm(a - b, axis=-1), axis=-1)


def adi(true_points, pred_points, true_mask=None, pred_mask=None):
    """ADI / ADD-S (eq. 5.16): mean over true points of the distance to the nearest predicted point.

    Args:
      true_points: (..., N, 3) ground-truth model points.
      pred_points: (..., M, 3) points of the estimate (e.g. dense surface samples of an ellipsoid).
      true_mask, pred_mask: optional (..., N) / (..., M) bool masks for padded sets.

    Returns:
      (...) mean nearest-neighbour distance (metres); 0 where no true point is valid.
    """
    a = _as_float_array("true_points", true_points, (3,), check_finite=True)
    b = _as_float_array("pred_points", pred_points, (3,))
    d2 = jnp.sum(jnp.square(a[..., :, None, :] - b[..., None, :, :]), axis=-1)
    if pred_mask is not None:
        d2 = jnp.where(jnp.asarray(pred_mask, bool)[..., None, :], d2, jnp.inf)
    nearest = safe_sqrt(jnp.min(d2, axis=-1))
    if true_mask is None:
        return jnp.mean(nearest, axis=-1)
    m = jnp.asarray(true_mask, bool)
    total = jnp.sum(jnp.where(m, nearest, 0.0), axis=-1)
    n = jnp.sum(m, axis=-1)
    return jnp.where(n > 0, total / jnp.maximum(n, 1).astype(total.dtype), 0.0)


def pass_rate_curve(errors, max_threshold=0.1, num_thresholds=1000):
    """Pass rate ``mean(error < t)`` at thresholds ``t = max_threshold * k / num_thresholds``,
    ``k = 1..num_thresholds``; NaN or infinite errors count as failures.

    Returns:
      thresholds (num_thresholds,), rates (..., num_thresholds) over the last axis of ``errors``.
    """
    e = jnp.asarray(errors)
    e = jnp.where(jnp.isfinite(e), e, jnp.inf)
    t = max_threshold * jnp.arange(1, num_thresholds + 1, dtype=jnp.result_type(e, float)) / num_thresholds
    rates = jnp.mean(e[..., None, :] < t[:, None], axis=-1)
    return t, rates


def auc_pass_rate(errors, max_threshold=0.1, num_thresholds=1000):
    """Area under the pass-rate curve by the rectangle rule, scaled to 10 (DOPE / thesis style):
    10 means every error is below every threshold; for 10 cm pass ``max_threshold=0.1`` (metres)."""
    _, rates = pass_rate_curve(errors, max_threshold, num_thresholds)
    return 10.0 * jnp.mean(rates, axis=-1)


# --------------------------------------------------------------------------------------------
# Plan-cost statistics (Table 3.1): host-side numpy, as they summarise finished trials.


def mean_sem(values):
    """Mean and standard error of the mean of a 1-D sample (NaN-free for n < 2: sem = 0)."""
    v = np.asarray(values, np.float64).ravel()
    if v.size == 0:
        return float("nan"), float("nan")
    sem = float(v.std(ddof=1) / np.sqrt(v.size)) if v.size > 1 else 0.0
    return float(v.mean()), sem


def zero_intercept_slope(x, y):
    """Least-squares slope of ``y = k x`` (no intercept): ``sum(x y) / sum(x^2)``."""
    x = np.asarray(x, np.float64).ravel()
    y = np.asarray(y, np.float64).ravel()
    if x.shape != y.shape:
        raise ValueError(f"x, y: expected equal shapes, got {x.shape} and {y.shape}")
    denom = float(np.dot(x, x))
    return float(np.dot(x, y) / denom) if denom > 0 else float("nan")


def average_precision(detections, truth, num_classes: int, iou_threshold: float = 0.5):
    """Detection average precision per class (PASCAL VOC's all-point rule) over a set of images.

    Detections are taken in descending score over all images; each is a true positive when its
    IoU with a not yet matched true box of its class in its image is at least ``iou_threshold``
    (the best such box), else a false positive. AP is the area under the precision envelope
    (precision made non-increasing) over recall. Host-side numpy (a set of images of any sizes).

    Args:
      detections: ``(image, box, class_id, score)`` arrays (D,), (D, 4), (D,), (D,).
      truth: ``(image, box, class_id)`` arrays (T,), (T, 4), (T,).
      num_classes: N; classes with no true box get NaN.

    Returns:
      ``(ap, recall)``: (N,) AP per class and (N,) the recall of all detections (NaN without truth).
    """
    d_img, d_box, d_cls, d_score = (np.asarray(x) for x in detections)
    t_img, t_box, t_cls = (np.asarray(x) for x in truth)
    ap = np.full(int(num_classes), np.nan)
    recall = np.full(int(num_classes), np.nan)
    for c in range(int(num_classes)):
        tc = np.flatnonzero(t_cls == c)
        if not len(tc):
            continue
        dc = np.flatnonzero(d_cls == c)
        dc = dc[np.argsort(-d_score[dc], kind="stable")]
        used = np.zeros(len(tc), bool)
        tp = np.zeros(len(dc), bool)
        if len(dc):
            iou = np.asarray(box_iou(d_box[dc][:, None].astype(np.float64), t_box[tc][None].astype(np.float64)))
            same = d_img[dc][:, None] == t_img[tc][None]
            iou = np.where(same, iou, -1.0)
            for i in range(len(dc)):
                cand = np.where(used, -1.0, iou[i])
                j = int(np.argmax(cand))
                if cand[j] >= iou_threshold:
                    used[j] = True
                    tp[i] = True
        ctp = np.cumsum(tp)
        rec = ctp / len(tc)
        prec = ctp / np.arange(1, len(dc) + 1)
        env = np.maximum.accumulate(prec[::-1])[::-1] if len(dc) else prec
        steps = np.diff(np.concatenate([[0.0], rec]))
        ap[c] = float(np.sum(steps * env))
        recall[c] = float(rec[-1]) if len(dc) else 0.0
    return ap, recall
