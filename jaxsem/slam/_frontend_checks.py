"""Input checks of the OpenCV front end at the Python boundary (``ValueError`` naming the argument)."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ._frontend_types import LandmarkEstimates

# --------------------------------------------------------------------------------------------
# Input checks at the Python boundary.


def _finite_matrix(name: str, value, shape: tuple) -> np.ndarray:
    """``value`` as a finite float64 array of ``shape``; a ``ValueError`` naming ``name``
    otherwise (the checks every matrix argument starts with)."""
    try:
        value = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: cannot be converted to a float array ({exc})") from None
    if value.shape != shape:
        raise ValueError(f"{name}: expected shape {shape}, got {value.shape}")
    if not np.all(np.isfinite(value)):
        raise ValueError(f"{name}: must be finite, got {value.tolist()}")
    return value


def _check_K(K):
    K = _finite_matrix("K", K, (3, 3))
    if not (np.allclose(K[2], [0, 0, 1]) and K[1, 0] == 0 and K[0, 0] > 0 and K[1, 1] > 0):
        raise ValueError(f"K: expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, got {K.tolist()}")
    return K


def _check_pose(pose):
    if hasattr(pose, "as_matrix") and callable(pose.as_matrix):  # jaxlie.SE3, as in jaxsem.quadrics
        pose = pose.as_matrix()
    pose = _finite_matrix("camera_T_world", pose, (4, 4))
    if not np.allclose(pose[3], [0, 0, 0, 1], atol=1e-6):
        raise ValueError(f"camera_T_world: expected last row [0, 0, 0, 1], got {pose[3].tolist()}")
    R = pose[:3, :3]
    if not (np.allclose(R @ R.T, np.eye(3), atol=1e-4) and np.linalg.det(R) > 0):
        raise ValueError(
            f"camera_T_world: expected a rotation (orthonormal, det +1) in the top-left 3x3, got {R.tolist()}"
        )
    return pose


def _check_image(image, expected_shape):
    if not isinstance(image, np.ndarray):
        try:
            image = np.asarray(image)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"image: cannot be converted to an array ({exc})") from None
    if image.dtype != np.uint8:
        raise ValueError(f"image: expected dtype uint8 (H, W, 3), got dtype {image.dtype}")
    if image.ndim != 3 or image.shape[2] != 3 or image.shape[0] < 8 or image.shape[1] < 8:
        raise ValueError(f"image: expected shape (H, W, 3) with H, W >= 8, got {image.shape}")
    if expected_shape is not None and image.shape != expected_shape:
        raise ValueError(f"image: expected the same shape as the previous frames {expected_shape}, got {image.shape}")
    return np.ascontiguousarray(image)


def _check_boxes(boxes, shape, tolerance):
    try:
        boxes = np.asarray(boxes, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"boxes: cannot be converted to a float array ({exc})") from None
    if boxes.size == 0:
        boxes = boxes.reshape(0, 4)
    if boxes.ndim != 2 or boxes.shape[1] != 4:
        raise ValueError(f"boxes: expected shape (M, 4) [u_min, v_min, u_max, v_max], got {boxes.shape}")
    h, w = shape
    for i, b in enumerate(boxes):
        if not np.all(np.isfinite(b)):
            raise ValueError(f"boxes[{i}]: must be finite, got {b.tolist()}")
        if not (b[0] < b[2] and b[1] < b[3]):
            raise ValueError(f"boxes[{i}]: expected u_min < u_max and v_min < v_max, got {b.tolist()}")
        if b[0] < -tolerance or b[1] < -tolerance or b[2] > w - 1 + tolerance or b[3] > h - 1 + tolerance:
            raise ValueError(
                f"boxes[{i}]: {b.tolist()} lies outside the image (width {w}, height {h}; pixels "
                f"0..{w - 1} x 0..{h - 1}, tolerance {tolerance} px)"
            )
    clipped = boxes.copy()
    clipped[:, [0, 2]] = np.clip(clipped[:, [0, 2]], 0, w - 1)
    clipped[:, [1, 3]] = np.clip(clipped[:, [1, 3]], 0, h - 1)
    return clipped


def _check_class_ids(class_ids, m):
    if class_ids is None:
        return [0] * m
    arr = np.asarray(class_ids)
    if arr.shape != (m,) or (m > 0 and arr.dtype.kind not in "iuUSO"):
        raise ValueError(
            f"class_ids: expected shape ({m},) of integer ids or class names (one per box), got "
            f"shape {arr.shape} dtype {arr.dtype}"
        )
    return [c.item() if isinstance(c, np.generic) else c for c in arr.tolist()]


def _check_estimates(estimates, known_ids):
    """Validated estimates restricted to the ids the front end issued (others are ignored)."""
    if estimates is None:
        return None
    if isinstance(estimates, Mapping):
        estimates = LandmarkEstimates.from_mapping(estimates)
    elif not isinstance(estimates, LandmarkEstimates):
        if isinstance(estimates, tuple) and len(estimates) == 4:
            estimates = LandmarkEstimates(*estimates)
        elif all(hasattr(estimates, a) for a in ("rotation", "center", "radii")):
            estimates = LandmarkEstimates.from_estimate(estimates)
        else:
            raise ValueError(
                "landmark_estimates: expected LandmarkEstimates(ids, rotation, center, radii), a "
                "mapping id -> (rotation, center, radii), an estimate with rotation/center/radii "
                f"indexed by id (jaxsem.slam.SlamEstimate), or None; got {type(estimates).__name__}"
            )
    ids = np.asarray(estimates.ids)
    if ids.ndim != 1 or not (np.issubdtype(ids.dtype, np.integer) or ids.size == 0):
        raise ValueError(f"landmark_estimates.ids: expected shape (L,) integers, got {ids.shape} {ids.dtype}")
    n = ids.shape[0]
    arrays = {}
    for name, trailing in (("rotation", (3, 3)), ("center", (3,)), ("radii", (3,))):
        try:
            value = np.asarray(getattr(estimates, name), dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"landmark_estimates.{name}: cannot be converted to a float array ({exc})") from None
        if value.shape != (n, *trailing):
            raise ValueError(
                f"landmark_estimates.{name}: expected shape {(n, *trailing)} to match ids, got {value.shape}"
            )
        arrays[name] = value
    keep = np.array([int(i) in known_ids for i in ids], dtype=bool).reshape(-1)
    for name, value in arrays.items():
        bad = keep & ~np.all(np.isfinite(value.reshape(n, int(np.prod(value.shape[1:])))), axis=-1)
        if bad.any():
            raise ValueError(
                f"landmark_estimates.{name}: must be finite, got non-finite values for ids {ids[bad][:5].tolist()}"
            )
    bad = keep & np.any(arrays["radii"] <= 0, axis=-1)
    if bad.any():
        raise ValueError(
            f"landmark_estimates.radii: expected positive semi-axes, got {arrays['radii'][bad][0].tolist()} "
            f"for id {int(ids[bad][0])}"
        )
    return LandmarkEstimates(
        ids[keep].astype(np.int64), arrays["rotation"][keep], arrays["center"][keep], arrays["radii"][keep]
    )
