"""Stateless pieces of the OpenCV front end, usable on their own: two-view triangulation,
hue-saturation histograms, pyramidal Lucas-Kanade, the texture-plane depth of triangulated points,
and box centres predicted from ellipsoid estimates through the geometry core.
"""

from __future__ import annotations

import math

import cv2
import jax
import numpy as np

from .. import quadrics
from ._frontend_types import TEXTURE_HIGH_VARIANCE, TEXTURE_OK, TEXTURE_TOO_FEW_POINTS

# --------------------------------------------------------------------------------------------
# Stateless pieces (usable on their own).


def triangulate_points(K, pose_a, pose_b, uv_a, uv_b):
    """Linear (DLT) triangulation of pixel correspondences between two posed views.

    Args:
      K: (3, 3) intrinsics.
      pose_a: (N, 4, 4) or (4, 4) ``camera_T_world`` of the first view of each point.
      pose_b: (N, 4, 4) or (4, 4) ``camera_T_world`` of the second view.
      uv_a, uv_b: (N, 2) pixel coordinates in the two views.

    Returns:
      points: (N, 3) world points (finite; zeros where the system is degenerate).
      ok: (N,) bool, False where the homogeneous solution is at infinity (parallel rays, e.g. a
        zero baseline).

    Each point solves the 4x4 homogeneous system of ``x ~ P X`` in both views by SVD, with
    ``P = K [I | 0] camera_T_world`` per view; the rows are normalised so that the two views weigh
    the same.
    """
    K = np.asarray(K, dtype=np.float64)
    uv_a = np.asarray(uv_a, dtype=np.float64).reshape(-1, 2)
    uv_b = np.asarray(uv_b, dtype=np.float64).reshape(-1, 2)
    n = uv_a.shape[0]
    P_a = np.broadcast_to(quadrics.camera_matrix(K, pose_a, xp=np), (n, 3, 4))
    P_b = np.broadcast_to(quadrics.camera_matrix(K, pose_b, xp=np), (n, 3, 4))
    rows = np.stack(
        [
            uv_a[:, :1] * P_a[:, 2] - P_a[:, 0],
            uv_a[:, 1:] * P_a[:, 2] - P_a[:, 1],
            uv_b[:, :1] * P_b[:, 2] - P_b[:, 0],
            uv_b[:, 1:] * P_b[:, 2] - P_b[:, 1],
        ],
        axis=1,
    )
    rows = rows / np.maximum(np.linalg.norm(rows, axis=-1, keepdims=True), 1e-300)
    if n == 0:
        return np.zeros((0, 3)), np.zeros((0,), dtype=bool)
    _, _, vt = np.linalg.svd(rows)
    homog = vt[:, -1, :]
    w = homog[:, 3]
    scale = np.max(np.abs(homog[:, :3]), axis=-1)
    ok = np.abs(w) > 1e-9 * np.maximum(scale, 1e-300)
    points = np.where(ok[:, None], homog[:, :3] / np.where(ok, w, 1.0)[:, None], 0.0)
    return points, ok


def hs_histogram(hsv, box, bins=(30, 32), shrink: float = 0.0):
    """Normalised hue-saturation histogram (``cv2.calcHist``) of an HSV image inside a box.

    Args:
      hsv: (H, W, 3) uint8 image in OpenCV's HSV (hue 0..180).
      box: (4,) ``[u_min, v_min, u_max, v_max]`` pixels (already inside the image).
      bins: (hue bins, saturation bins).
      shrink: fraction of the box removed on each side.

    Returns:
      (bins[0], bins[1]) float32 histogram with unit L1 norm (all zeros for an empty box).
    """
    x0, y0, x1, y1 = _box_pixels(box, hsv.shape[:2], shrink)
    patch = np.ascontiguousarray(hsv[y0:y1, x0:x1])
    hist = cv2.calcHist([patch], [0, 1], None, list(bins), [0, 180, 0, 256])
    total = float(hist.sum())
    return hist / total if total > 0 else hist


def _pyramidal_lk(prev, image, points, window, levels):
    """``cv2.calcOpticalFlowPyrLK`` of ``points`` (N, 1, 2) float32: (new points, status, error)."""
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
    # nextPts=None lets OpenCV allocate the output (documented); its stub types it as a required array
    return cv2.calcOpticalFlowPyrLK(prev, image, points, None, winSize=window, maxLevel=levels, criteria=criteria)  # pyright: ignore[reportCallIssue, reportArgumentType]


def _box_pixels(box, shape, shrink):
    """Integer pixel slice bounds ``x0, y0, x1, y1`` (exclusive ends) of a box, at least 1 px."""
    h, w = shape
    u0, v0, u1, v1 = (float(b) for b in box)
    du, dv = shrink * (u1 - u0), shrink * (v1 - v0)
    x0 = int(np.clip(np.floor(u0 + du), 0, w - 1))
    y0 = int(np.clip(np.floor(v0 + dv), 0, h - 1))
    x1 = int(np.clip(np.ceil(u1 - du) + 1, x0 + 1, w))
    y1 = int(np.clip(np.ceil(v1 - dv) + 1, y0 + 1, h))
    return x0, y0, x1, y1


def _camera_center(pose):
    """World position of the camera centre of ``camera_T_world`` (..., 4, 4)."""
    return quadrics.invert_pose(pose, xp=np)[..., :3, 3]


def _texture_from_points(points, K, pose_now, uv_now, pose_anchor, uv_anchor, config):
    """Texture-plane depth and variance of triangulated points; returns (depth, var, status, n)."""
    # host code, once per landmark and frame: the geometry core runs on numpy here (xp=np)
    uv_a, z_a = quadrics.project_points(points, K, pose_anchor, xp=np)
    uv_b, z_b = quadrics.project_points(points, K, pose_now, xp=np)
    err = np.maximum(np.linalg.norm(uv_a - uv_anchor, axis=-1), np.linalg.norm(uv_b - uv_now, axis=-1))
    good = (z_a > config.min_depth) & (z_b > config.min_depth) & (err <= config.max_reprojection_error)
    depths = z_b[good]
    if depths.size >= 3 and math.isfinite(config.max_outlier_deviations):
        median = np.median(depths)
        spread = 1.4826 * np.median(np.abs(depths - median))
        # a floor on the spread so that a perfectly flat face keeps all its points
        spread = max(spread, 1e-3 * abs(median) + 1e-9)
        depths = depths[np.abs(depths - median) <= config.max_outlier_deviations * spread]
    n = int(depths.size)
    if n < config.min_points:
        variance = float(np.var(depths)) if n >= 2 else None
        return None, variance, TEXTURE_TOO_FEW_POINTS, n, good
    mean = float(np.mean(depths))
    variance = float(np.var(depths))
    if variance > config.max_depth_variance or math.sqrt(variance) > config.max_relative_depth_std * mean:
        return None, variance, TEXTURE_HIGH_VARIANCE, n, good
    return mean, variance, TEXTURE_OK, n, good


# --------------------------------------------------------------------------------------------
# Centroid prediction through the geometry core (jitted once per capacity bucket).

_PROJECT_CACHE: dict = {}


def _predicted_centroids(K, pose, estimates):
    """Predicted box centres (L, 2) and validity (L,) of the estimated ellipsoids."""
    fn = _PROJECT_CACHE.get("fn")
    if fn is None:
        fn = jax.jit(quadrics.project_bbox)
        _PROJECT_CACHE["fn"] = fn
    n = estimates.ids.shape[0]
    # pad to a power-of-two capacity so that a growing map compiles O(log L) times, not L times
    capacity = max(8, 1 << (n - 1).bit_length())
    rot = np.tile(np.eye(3), (capacity, 1, 1))
    cen = np.zeros((capacity, 3))
    cen[:, 2] = 10.0
    rad = np.ones((capacity, 3))
    rot[:n], cen[:n], rad[:n] = estimates.rotation, estimates.center, estimates.radii
    box, valid = fn(rot, cen, rad, K, pose)
    box = np.asarray(box, dtype=np.float64)[:n]
    valid = np.asarray(valid)[:n]
    centres = 0.5 * (box[:, :2] + box[:, 2:])
    valid = valid & np.all(np.isfinite(centres), axis=-1)
    return centres, valid
