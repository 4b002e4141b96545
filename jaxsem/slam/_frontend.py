r"""OpenCV front end for real image sequences (thesis section 4.5.1).

Turns a stream of posed images with 2D detections into ROSHAN measurements: each detection is
associated with a landmark id (an existing one or a new one), and gets a texture-plane depth when
the object's features can be triangulated well enough.

Per frame, :meth:`FrontEnd.process` does:

1. **Tracking.** The ORB corners of every landmark are tracked from the previous image into the
   current one with pyramidal Lucas-Kanade (``cv2.calcOpticalFlowPyrLK``); a forward-backward
   check drops tracks that do not return to where they started.
2. **Association.** Each landmark's image centroid is predicted, from the current ellipsoid
   estimate when the caller passes one (``jaxsem.quadrics.project_bbox``, centre of the predicted
   box), otherwise from the landmark's last box moved by the median flow of its tracks. A
   detection is a candidate for a landmark of the same class whose predicted centroid lies within
   ``gate_pixels`` of the detection's box centre; among candidates, the one with the highest
   hue-saturation histogram correlation (``cv2.compareHist``, ``HISTCMP_CORREL``, best over the
   landmark's last few detections) at or above ``min_correlation`` wins. Pairs are assigned
   greedily by correlation, one detection per landmark per frame; an unmatched detection starts a
   new landmark.
3. **Texture plane.** Every tracked corner remembers the pose of the frame where it was detected
   (its anchor). For an associated detection, the corners inside the box are triangulated between
   their anchor view and the current view (linear DLT, both poses known), the depth of each point
   is taken in the current camera frame, points that reproject badly or lie far from the median
   depth (robust 3-sigma, mostly background corners at the box edge) are dropped, and the
   texture-plane depth is the mean of the rest (the thesis' "texture plane fit to the mean depth
   of the points"). The measurement is rejected, with a
   reason, when the baseline between the two views is too short, too few points survive, or the
   variance of the point depths is too large (an oblong, rotated object breaks the single-plane
   assumption). The variance is returned in every case where it could be computed, so the texture
   factor can use it as its sigma^2.
4. **Re-seeding.** When fewer than ``redetect_fraction * max_features`` corners of a detected
   landmark survive inside its box, new ORB corners are detected in the box (away from the
   surviving ones) and anchored at the current pose; surviving corners keep their older anchors,
   hence their longer baselines.

The front end is plain numpy/OpenCV, stateful and not jittable by nature (a Python object fed
one frame at a time). Its output is plain data that converts into the online smoother's frame.

Conventions: ``camera_T_world`` (4, 4) maps world points into the camera frame (OpenCV axes);
``K`` (3, 3); boxes ``[u_min, v_min, u_max, v_max]`` in pixels with pixel centres at integer
coordinates (OpenCV's convention); images (H, W, 3) uint8, RGB unless ``color_order="bgr"``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import cv2
import numpy as np

from .. import quadrics

__all__ = [
    "FrontEndConfig",
    "FrontEnd",
    "AssociatedDetection",
    "LandmarkEstimates",
    "triangulate_points",
    "hs_histogram",
    "to_frame",
    "TEXTURE_OK",
    "TEXTURE_NEW_LANDMARK",
    "TEXTURE_NO_TRACKS",
    "TEXTURE_SHORT_BASELINE",
    "TEXTURE_TOO_FEW_POINTS",
    "TEXTURE_HIGH_VARIANCE",
]

# Reasons attached to each detection's texture measurement (``AssociatedDetection.texture_status``).
TEXTURE_OK = "ok"
TEXTURE_NEW_LANDMARK = "new_landmark"  # first sighting: nothing to triangulate against yet
TEXTURE_NO_TRACKS = "no_tracks"  # no tracked corner of the landmark lies inside the box
TEXTURE_SHORT_BASELINE = "short_baseline"  # corners exist, but no anchor view is far enough
TEXTURE_TOO_FEW_POINTS = "too_few_points"  # fewer than min_points good triangulated points
TEXTURE_HIGH_VARIANCE = "high_variance"  # point depths vary more than max_depth_variance


# --------------------------------------------------------------------------------------------
# Configuration and output types.


@dataclasses.dataclass(frozen=True)
class FrontEndConfig:
    """Thresholds of the front end. Defaults suit images of 160x120 to 640x480 pixels.

    Features and tracking:
      max_features: ORB corners detected per box when (re-)seeding a landmark.
      orb_fast_threshold, orb_levels, orb_patch_size: ``cv2.ORB_create`` arguments (FAST
        threshold, pyramid levels, patch size, also used as its edge threshold); the small patch
        keeps corners near the borders of small boxes.
      box_shrink: fraction of the box width/height removed on each side before detecting corners
        and computing histograms, so that background at the box edges is mostly left out.
      lk_window, lk_levels: Lucas-Kanade window size (pixels) and pyramid levels.
      max_forward_backward_error: pixels; a track whose backward flow misses its start by more is
        dropped.
      redetect_fraction: re-seed a landmark when fewer than this fraction of ``max_features``
        corners survive inside its box.
      max_missed_frames: a landmark's corners are forgotten after this many consecutive frames
        without a detection (its histograms and id are kept for re-association).

    Texture plane:
      min_baseline: metres; shortest distance between the anchor and current camera centres for a
        corner to be triangulated. A detection whose corners all have shorter baselines is
        rejected as ``"short_baseline"``.
      min_points: fewest triangulated points for a measurement.
      max_reprojection_error: pixels; a triangulated point reprojecting further than this in
        either view is dropped.
      max_outlier_deviations: points whose depth lies further than this many robust standard
        deviations (1.4826 MAD) from the median depth are dropped before the mean and variance
        (background corners at the box edge); ``math.inf`` disables it.
      max_depth_variance: m^2; measurements whose point-depth variance exceeds it are rejected as
        ``"high_variance"``. The default (0.2 m standard deviation) suits objects of up to a metre
        or so a few metres away; for cars tens of metres away raise it or use
        ``max_relative_depth_std``, since triangulation noise grows with depth squared.
      max_relative_depth_std: the same rejection when the points' depth standard deviation exceeds
        this fraction of their mean depth; scale-free, for scenes whose depths span a wide range
        (cars at 5-30 m). ``math.inf`` (default) disables it.
      min_depth: metres; points closer than this to either camera are dropped.

    Association:
      gate_pixels: largest distance between a detection's box centre and a landmark's predicted
        centroid for the landmark to be a candidate.
      hist_bins: (hue bins, saturation bins) of the HS histogram (OpenCV hue is 0..180).
      min_correlation: lowest histogram correlation (-1..1) accepted for a match.
      max_histograms: histograms of the last detections kept per landmark.
      same_class_only: only associate detections with landmarks of the same class id.

    Input:
      color_order: ``"rgb"`` (MuJoCo, PIL, imageio) or ``"bgr"`` (``cv2.imread``).
      box_tolerance: pixels a box may extend beyond the image (it is clipped); further out raises.
    """

    max_features: int = 80
    orb_fast_threshold: int = 10
    orb_levels: int = 3
    orb_patch_size: int = 15
    box_shrink: float = 0.05
    lk_window: int = 15
    lk_levels: int = 2
    max_forward_backward_error: float = 1.0
    redetect_fraction: float = 0.5
    max_missed_frames: int = 5
    min_baseline: float = 0.05
    min_points: int = 8
    max_reprojection_error: float = 2.0
    max_outlier_deviations: float = 3.0
    max_depth_variance: float = 0.04
    max_relative_depth_std: float = math.inf
    min_depth: float = 0.05
    gate_pixels: float = 60.0
    hist_bins: tuple = (30, 32)
    min_correlation: float = 0.5
    max_histograms: int = 5
    same_class_only: bool = True
    color_order: str = "rgb"
    box_tolerance: float = 2.0

    def __post_init__(self):
        positive_ints = ("max_features", "orb_levels", "lk_levels", "min_points", "max_histograms")
        for name in positive_ints:
            value = getattr(self, name)
            if not (isinstance(value, (int, np.integer)) and value >= 1):
                raise ValueError(f"FrontEndConfig.{name}: expected an integer >= 1, got {value!r}")
        for name in ("orb_fast_threshold", "max_missed_frames"):
            value = getattr(self, name)
            if not (isinstance(value, (int, np.integer)) and value >= 0):
                raise ValueError(f"FrontEndConfig.{name}: expected an integer >= 0, got {value!r}")
        for name in ("orb_patch_size", "lk_window"):
            value = getattr(self, name)
            if not (isinstance(value, (int, np.integer)) and value >= 3):
                raise ValueError(f"FrontEndConfig.{name}: expected an integer >= 3, got {value!r}")
        positive = (
            "max_forward_backward_error",
            "max_reprojection_error",
            "max_outlier_deviations",
            "max_depth_variance",
            "max_relative_depth_std",
            "min_depth",
            "gate_pixels",
        )
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and value > 0 and not math.isnan(value)):
                raise ValueError(f"FrontEndConfig.{name}: expected a number > 0, got {value!r}")
        for name in ("min_baseline", "box_tolerance"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"FrontEndConfig.{name}: expected a finite number >= 0, got {value!r}")
        if not (isinstance(self.box_shrink, (int, float)) and 0 <= self.box_shrink < 0.5):
            raise ValueError(f"FrontEndConfig.box_shrink: expected 0 <= value < 0.5, got {self.box_shrink!r}")
        if not (isinstance(self.redetect_fraction, (int, float)) and 0 <= self.redetect_fraction <= 1):
            raise ValueError(
                f"FrontEndConfig.redetect_fraction: expected 0 <= value <= 1, got {self.redetect_fraction!r}"
            )
        if not (isinstance(self.min_correlation, (int, float)) and -1 <= self.min_correlation <= 1):
            raise ValueError(f"FrontEndConfig.min_correlation: expected -1 <= value <= 1, got {self.min_correlation!r}")
        bins = tuple(self.hist_bins) if isinstance(self.hist_bins, (tuple, list)) else None
        if bins is None or len(bins) != 2 or not all(isinstance(b, (int, np.integer)) and b >= 1 for b in bins):
            raise ValueError(
                f"FrontEndConfig.hist_bins: expected (hue_bins, saturation_bins) positive ints, got {self.hist_bins!r}"
            )
        object.__setattr__(self, "hist_bins", (int(bins[0]), int(bins[1])))
        if self.color_order not in ("rgb", "bgr"):
            raise ValueError(f"FrontEndConfig.color_order: expected 'rgb' or 'bgr', got {self.color_order!r}")


@dataclasses.dataclass(frozen=True, eq=False)  # eq on an array field would be ambiguous
class AssociatedDetection:
    """One input detection after association and texture-plane measurement.

    Attributes:
      index: position of the detection in the ``boxes`` passed to :meth:`FrontEnd.process`.
      box: (4,) float64 ``[u_min, v_min, u_max, v_max]``, clipped to the image.
      class_id: the detection's class (int id or name, as passed).
      landmark_id: association id (stable across frames; new ids count up from 0).
      is_new: True when this detection created the landmark.
      texture_depth: metres, mean depth of the triangulated points in the current camera frame,
        or None when the measurement was rejected (see ``texture_status``).
      texture_variance: m^2, variance of those point depths (the texture factor's sigma^2), or None
        when there were too few points to compute it. Set also for ``"high_variance"``.
      texture_status: one of ``"ok"``, ``"new_landmark"``, ``"no_tracks"``,
        ``"short_baseline"``, ``"too_few_points"``, ``"high_variance"``.
      num_points: triangulated points used (after outlier removal).
      baseline: metres, median anchor-to-current baseline of the points used (0.0 when none).
      correlation: HS histogram correlation with the matched landmark (None for a new landmark).
      centroid_distance: pixels between the box centre and the landmark's predicted centroid
        (None for a new landmark).
    """

    index: int
    box: np.ndarray
    class_id: Any
    landmark_id: int
    is_new: bool
    texture_depth: float | None
    texture_variance: float | None
    texture_status: str
    num_points: int
    baseline: float
    correlation: float | None
    centroid_distance: float | None

    @property
    def has_texture(self) -> bool:
        return self.texture_depth is not None


class LandmarkEstimates(NamedTuple):
    """Current ellipsoid estimates used to predict landmark centroids, in padded-array form.

    Attributes:
      ids: (L,) int landmark ids as issued by the front end; entries < 0 are padding.
      rotation: (L, 3, 3) object-to-world; center: (L, 3) world; radii: (L, 3) semi-axes, metres.

    Ids the front end never issued are ignored. Build one from a mapping with
    :meth:`from_mapping`.
    """

    ids: Any
    rotation: Any
    center: Any
    radii: Any

    @classmethod
    def from_mapping(cls, estimates: Mapping[int, Sequence[Any]]) -> LandmarkEstimates:
        """``{landmark_id: (rotation (3, 3), center (3,), radii (3,))}`` -> padded arrays."""
        ids = np.array(sorted(int(k) for k in estimates), dtype=np.int64)
        rot = np.zeros((len(ids), 3, 3))
        cen = np.zeros((len(ids), 3))
        rad = np.ones((len(ids), 3))
        for i, k in enumerate(ids):
            value = estimates[int(k)]
            if len(value) != 3:
                raise ValueError(
                    f"landmark_estimates[{int(k)}]: expected (rotation, center, radii), got {len(value)} items"
                )
            rot[i], cen[i], rad[i] = (np.asarray(v, dtype=np.float64) for v in value)
        return cls(ids, rot, cen, rad)

    @classmethod
    def from_estimate(cls, estimate, mask=None) -> LandmarkEstimates:
        """From an estimate whose object slot ``j`` holds landmark id ``j``.

        Args:
          estimate: anything with ``rotation`` (J, 3, 3), ``center`` (J, 3), ``radii`` (J, 3), e.g.
            :class:`jaxsem.slam.SlamEstimate` of the online smoother, whose object slots are the
            front end's association ids.
          mask: optional (J,) bool; False slots are padding.
        """
        rot = np.asarray(estimate.rotation, dtype=np.float64)
        j = rot.shape[0] if rot.ndim == 3 else 0
        ids = np.arange(j, dtype=np.int64)
        if mask is not None:
            mask = np.asarray(mask, dtype=bool).reshape(-1)
            if mask.shape != (j,):
                raise ValueError(f"mask: expected shape ({j},) to match the estimate's objects, got {mask.shape}")
            ids = np.where(mask, ids, -1)
        return cls(ids, rot, np.asarray(estimate.center, np.float64), np.asarray(estimate.radii, np.float64))


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
# Input checks at the Python boundary.


def _check_K(K):
    try:
        K = np.asarray(K, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"K: cannot be converted to a float array ({exc})") from None
    if K.shape != (3, 3):
        raise ValueError(f"K: expected shape (3, 3), got {K.shape}")
    if not np.all(np.isfinite(K)):
        raise ValueError(f"K: must be finite, got {K.tolist()}")
    if not (np.allclose(K[2], [0, 0, 1]) and K[1, 0] == 0 and K[0, 0] > 0 and K[1, 1] > 0):
        raise ValueError(f"K: expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, got {K.tolist()}")
    return K


def _check_pose(pose):
    if hasattr(pose, "as_matrix") and callable(pose.as_matrix):  # jaxlie.SE3, as in jaxsem.quadrics
        pose = pose.as_matrix()
    try:
        pose = np.asarray(pose, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"camera_T_world: cannot be converted to a float array ({exc})") from None
    if pose.shape != (4, 4):
        raise ValueError(f"camera_T_world: expected shape (4, 4), got {pose.shape}")
    if not np.all(np.isfinite(pose)):
        raise ValueError(f"camera_T_world: must be finite, got {pose.tolist()}")
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


# --------------------------------------------------------------------------------------------
# Centroid prediction through the geometry core (jitted once per capacity bucket).

_PROJECT_CACHE: dict = {}


def _predicted_centroids(K, pose, estimates):
    """Predicted box centres (L, 2) and validity (L,) of the estimated ellipsoids."""
    import jax

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


# --------------------------------------------------------------------------------------------
# The stateful front end.


@dataclasses.dataclass
class _Landmark:
    id: int
    class_id: Any
    histograms: list
    last_box: np.ndarray
    last_frame: int
    missed: int = 0
    # per tracked corner: current pixel, pixel and pose at its anchor frame
    points: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 2), np.float32))
    anchor_uv: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 2)))
    anchor_pose: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 4, 4)))
    # image centroid predicted without an estimate: last box centre moved by the tracks' flow
    centre: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(2))


class FrontEnd:
    """ROSHAN's per-frame OpenCV front end: association ids and texture-plane depths.

    Usage with the online smoother (the landmark ids are its object slots)::

        from jaxsem.slam import (Capacity, FrontEnd, LandmarkEstimates, SolverConfig,
                                 online_estimate, online_init, online_update, to_frame)

        cap = Capacity()
        state = online_init(SolverConfig(), cap, K, (width, height))
        fe = FrontEnd(K)
        for image, pose, boxes, classes in sequence:
            est = LandmarkEstimates.from_estimate(online_estimate(state), state.problem.object_mask)
            dets = fe.process(image, pose, boxes, classes, landmark_estimates=est)
            # dets[i].landmark_id, .texture_depth, .texture_variance, .texture_status ...
            frame = to_frame(dets, pose, max_detections=cap.max_detections,
                             max_objects=cap.max_objects)
            state = online_update(state, frame)

    Args:
      K: (3, 3) intrinsics of the (single) camera.
      config: :class:`FrontEndConfig`; defaults when omitted.
    """

    def __init__(self, K, config: FrontEndConfig | None = None):
        self.K = _check_K(K)
        if config is None:
            config = FrontEndConfig()
        if not isinstance(config, FrontEndConfig):
            raise ValueError(f"config: expected a FrontEndConfig, got {type(config).__name__}")
        self.config = config
        self._orb = cv2.ORB.create(
            nfeatures=config.max_features,
            scaleFactor=1.2,
            nlevels=config.orb_levels,
            edgeThreshold=config.orb_patch_size,
            patchSize=config.orb_patch_size,
            fastThreshold=config.orb_fast_threshold,
        )
        self.reset()

    def reset(self) -> None:
        """Forgets every landmark, track and image; ids restart at 0."""
        self._landmarks: dict[int, _Landmark] = {}
        self._next_id = 0
        self._frame = -1
        self._prev_gray = None
        self._shape = None

    @property
    def landmark_ids(self) -> list[int]:
        """Ids of all landmarks created so far."""
        return sorted(self._landmarks)

    @property
    def frame_index(self) -> int:
        """Index of the last processed frame (-1 before the first)."""
        return self._frame

    def num_tracks(self, landmark_id: int) -> int:
        """Number of corners currently tracked for a landmark."""
        if landmark_id not in self._landmarks:
            raise ValueError(f"landmark_id: unknown id {landmark_id!r}; known {self.landmark_ids}")
        return int(self._landmarks[landmark_id].points.shape[0])

    # ---------------------------------------------------------------------------------------

    def process(self, image, camera_T_world, boxes, class_ids=None, landmark_estimates=None):
        """Associates and measures the detections of one frame.

        Args:
          image: (H, W, 3) uint8 colour image (RGB unless ``config.color_order == "bgr"``); the
            same size in every frame.
          camera_T_world: (4, 4) world-to-camera pose of this frame (OpenCV axes), finite and
            rigid, or a ``jaxlie.SE3``.
          boxes: (M, 4) detections ``[u_min, v_min, u_max, v_max]`` in pixels (M may be 0).
          class_ids: (M,) class ids (ints, e.g. indices of :data:`jaxsem.factors.CLASS_NAMES`, or
            names), or None for a single class.
          landmark_estimates: the smoother's current ellipsoids (:class:`LandmarkEstimates`,
            ``{id: (rotation, center, radii)}``, or a :class:`jaxsem.slam.SlamEstimate` whose
            object slot ``j`` is landmark ``j``), or None. Ids this front end never issued are
            ignored. Used to
            predict landmark centroids; landmarks without an estimate (or behind the camera) fall
            back on their last box centre moved by their tracks' median flow since then.

        Returns:
          list of :class:`AssociatedDetection`, one per box, in input order.

        Raises:
          ValueError: naming the argument, for a wrong image dtype/shape, a non-finite or
            non-rigid pose, a non-finite, inverted or out-of-image box, mismatched class ids or
            malformed estimates. The front end's state is left untouched.
        """
        cfg = self.config
        image = _check_image(image, self._shape)
        pose = _check_pose(camera_T_world)
        boxes = _check_boxes(boxes, image.shape[:2], cfg.box_tolerance)
        class_ids = _check_class_ids(class_ids, boxes.shape[0])
        estimates = _check_estimates(landmark_estimates, self._landmarks)

        code_gray = cv2.COLOR_RGB2GRAY if cfg.color_order == "rgb" else cv2.COLOR_BGR2GRAY
        code_hsv = cv2.COLOR_RGB2HSV if cfg.color_order == "rgb" else cv2.COLOR_BGR2HSV
        gray = cv2.cvtColor(image, code_gray)
        hsv = cv2.cvtColor(image, code_hsv)
        self._shape = image.shape
        self._frame += 1

        self._track(gray)
        predicted = self._predict(pose, estimates)
        hists = [hs_histogram(hsv, b, cfg.hist_bins, cfg.box_shrink) for b in boxes]
        assignment, scores = self._associate(boxes, class_ids, hists, predicted)

        results = []
        for i, box in enumerate(boxes):
            lid = assignment.get(i)
            if lid is None:
                lid = self._next_id
                self._next_id += 1
                self._landmarks[lid] = _Landmark(
                    id=lid,
                    class_id=class_ids[i],
                    histograms=[],
                    last_box=box,
                    last_frame=self._frame,
                )
                lm = self._landmarks[lid]
                depth, variance, status, n, baseline = None, None, TEXTURE_NEW_LANDMARK, 0, 0.0
                corr, dist = None, None
                is_new = True
            else:
                lm = self._landmarks[lid]
                depth, variance, status, n, baseline = self._texture(lm, box, pose)
                corr, dist = scores[i]
                is_new = False
            lm.histograms = (lm.histograms + [hists[i]])[-cfg.max_histograms :]
            lm.last_box = box
            lm.centre = 0.5 * (box[:2] + box[2:])
            lm.last_frame = self._frame
            lm.missed = 0
            self._reseed(lm, gray, box, pose)
            results.append(
                AssociatedDetection(
                    index=i,
                    box=box.copy(),
                    class_id=class_ids[i],
                    landmark_id=lid,
                    is_new=is_new,
                    texture_depth=depth,
                    texture_variance=variance,
                    texture_status=status,
                    num_points=n,
                    baseline=baseline,
                    correlation=corr,
                    centroid_distance=dist,
                )
            )

        detected = {r.landmark_id for r in results}
        for lm in self._landmarks.values():
            if lm.id not in detected:
                lm.missed += 1
                if lm.missed > cfg.max_missed_frames:
                    lm.points = lm.points[:0]
                    lm.anchor_uv = lm.anchor_uv[:0]
                    lm.anchor_pose = lm.anchor_pose[:0]
        self._prev_gray = gray
        return results

    # ---------------------------------------------------------------------------------------

    def _track(self, gray):
        """Pyramidal LK of every landmark's corners from the previous image, forward-backward."""
        cfg = self.config
        owners = [lm for lm in self._landmarks.values() if lm.points.shape[0] > 0]
        if self._prev_gray is None or not owners:
            return
        p0 = np.concatenate([lm.points for lm in owners]).astype(np.float32).reshape(-1, 1, 2)
        win, levels = (cfg.lk_window, cfg.lk_window), cfg.lk_levels
        # LK builds image pyramids of whatever it is given: crop both images to the corners'
        # bounding box plus the tracker's reach (window times the coarsest level's scale).
        h, w = gray.shape
        reach = cfg.lk_window * 2**cfg.lk_levels + 8
        lo = np.floor(p0.reshape(-1, 2).min(axis=0)) - reach
        hi = np.ceil(p0.reshape(-1, 2).max(axis=0)) + reach + 1
        x0, y0 = int(max(lo[0], 0)), int(max(lo[1], 0))
        x1, y1 = int(min(hi[0], w)), int(min(hi[1], h))
        prev_crop = np.ascontiguousarray(self._prev_gray[y0:y1, x0:x1])
        crop = np.ascontiguousarray(gray[y0:y1, x0:x1])
        offset = np.array([x0, y0], dtype=np.float32)
        p1, st1, _ = _pyramidal_lk(prev_crop, crop, p0 - offset, win, levels)
        p0r, st2, _ = _pyramidal_lk(crop, prev_crop, p1, win, levels)
        p1 = p1 + offset
        p0r = p0r + offset
        p0, p1, p0r = p0.reshape(-1, 2), p1.reshape(-1, 2), p0r.reshape(-1, 2)
        fb = np.linalg.norm(p0 - p0r, axis=-1)
        keep = (
            (st1.reshape(-1) == 1)
            & (st2.reshape(-1) == 1)
            & (fb <= cfg.max_forward_backward_error)
            & np.all(np.isfinite(p1), axis=-1)
            & (p1[:, 0] >= 0)
            & (p1[:, 0] <= w - 1)
            & (p1[:, 1] >= 0)
            & (p1[:, 1] <= h - 1)
        )
        start = 0
        for lm in owners:
            stop = start + lm.points.shape[0]
            k = keep[start:stop]
            if np.any(k):
                lm.centre = lm.centre + np.median(p1[start:stop][k] - p0[start:stop][k], axis=0)
            lm.points = p1[start:stop][k]
            lm.anchor_uv = lm.anchor_uv[k]
            lm.anchor_pose = lm.anchor_pose[k]
            start = stop

    def _predict(self, pose, estimates):
        """Predicted centroid (2,) per landmark id: from the estimate, else last box + flow since."""
        predicted = {lm.id: lm.centre for lm in self._landmarks.values()}
        if estimates is not None and estimates.ids.shape[0] > 0:
            centres, valid = _predicted_centroids(self.K, pose, estimates)
            for lid, c, v in zip(estimates.ids, centres, valid):
                if v:
                    predicted[int(lid)] = c
        return predicted

    def _associate(self, boxes, class_ids, hists, predicted):
        """Greedy one-to-one assignment by histogram correlation among gated candidates."""
        cfg = self.config
        pairs = []
        for i, box in enumerate(boxes):
            centre = 0.5 * (box[:2] + box[2:])
            for lm in self._landmarks.values():
                if cfg.same_class_only and lm.class_id != class_ids[i]:
                    continue
                dist = float(np.linalg.norm(centre - predicted[lm.id]))
                if dist > cfg.gate_pixels or not lm.histograms:
                    continue
                corr = max(float(cv2.compareHist(hists[i], h, cv2.HISTCMP_CORREL)) for h in lm.histograms)
                if not math.isfinite(corr):  # constant histograms have no defined correlation
                    corr = -1.0
                if corr >= cfg.min_correlation:
                    pairs.append((corr, -dist, i, lm.id))
        pairs.sort(reverse=True)
        assignment, scores, used = {}, {}, set()
        for corr, neg_dist, i, lid in pairs:
            if i in assignment or lid in used:
                continue
            assignment[i] = lid
            scores[i] = (corr, -neg_dist)
            used.add(lid)
        return assignment, scores

    def _texture(self, lm, box, pose):
        """Texture-plane measurement of a re-detected landmark from its tracked corners."""
        cfg = self.config
        inside = (
            (lm.points[:, 0] >= box[0])
            & (lm.points[:, 0] <= box[2])
            & (lm.points[:, 1] >= box[1])
            & (lm.points[:, 1] <= box[3])
        )
        # corners that left the box belong to something else now
        lm.points, lm.anchor_uv, lm.anchor_pose = lm.points[inside], lm.anchor_uv[inside], lm.anchor_pose[inside]
        if lm.points.shape[0] == 0:
            return None, None, TEXTURE_NO_TRACKS, 0, 0.0
        baselines = np.linalg.norm(_camera_center(lm.anchor_pose) - _camera_center(pose), axis=-1)
        far = baselines >= max(cfg.min_baseline, 1e-9)
        if not np.any(far):
            return None, None, TEXTURE_SHORT_BASELINE, 0, float(np.max(baselines))
        uv_now = lm.points[far].astype(np.float64)
        uv_anchor = lm.anchor_uv[far]
        pose_anchor = lm.anchor_pose[far]
        points, ok = triangulate_points(self.K, pose_anchor, pose, uv_anchor, uv_now)
        points, uv_now, uv_anchor, pose_anchor = points[ok], uv_now[ok], uv_anchor[ok], pose_anchor[ok]
        depth, variance, status, n, good = _texture_from_points(
            points, self.K, pose, uv_now, pose_anchor, uv_anchor, cfg
        )
        used = baselines[far][ok][good] if good.size else np.zeros(0)
        baseline = float(np.median(used)) if used.size else float(np.max(baselines[far]))
        return depth, variance, status, n, baseline

    def _reseed(self, lm, gray, box, pose):
        """Tops up a landmark's corners with fresh ORB corners anchored at this frame."""
        cfg = self.config
        if lm.points.shape[0] >= cfg.redetect_fraction * cfg.max_features and lm.points.shape[0] > 0:
            return
        x0, y0, x1, y1 = _box_pixels(box, gray.shape, cfg.box_shrink)
        # ORB on a crop around the box, not the whole image (its cost scales with the area); the
        # margin covers ORB's border exclusion at its coarsest level, so corners near the box
        # edge survive as they would on the full image.
        h, w = gray.shape
        margin = int(math.ceil(cfg.orb_patch_size * 1.2 ** (cfg.orb_levels - 1))) + 2
        cx0, cy0 = max(x0 - margin, 0), max(y0 - margin, 0)
        cx1, cy1 = min(x1 + margin, w), min(y1 + margin, h)
        crop = np.ascontiguousarray(gray[cy0:cy1, cx0:cx1])
        mask = np.zeros(crop.shape, dtype=np.uint8)
        mask[y0 - cy0 : y1 - cy0, x0 - cx0 : x1 - cx0] = 255
        for u, v in lm.points:  # keep new corners away from surviving ones
            cv2.circle(mask, (int(round(float(u))) - cx0, int(round(float(v))) - cy0), 3, 0, -1)
        keypoints = self._orb.detect(crop, mask)
        if not keypoints:
            return
        keypoints = sorted(keypoints, key=lambda kp: -kp.response)
        new = np.array([kp.pt for kp in keypoints], dtype=np.float32).reshape(-1, 2)
        new += np.array([cx0, cy0], dtype=np.float32)
        budget = max(cfg.max_features - lm.points.shape[0], 0)
        new = new[:budget]
        if new.shape[0] == 0:
            return
        lm.points = np.concatenate([lm.points, new]).astype(np.float32)
        lm.anchor_uv = np.concatenate([lm.anchor_uv, new.astype(np.float64)])
        lm.anchor_pose = np.concatenate([lm.anchor_pose, np.broadcast_to(pose, (new.shape[0], 4, 4))])


def to_frame(detections, camera_T_world, *, max_detections: int = 16, max_objects: int | None = None, dtype=None):
    """Converts one frame of :meth:`FrontEnd.process` output into the online smoother's ``Frame``.

    Args:
      detections: list of :class:`AssociatedDetection` of one frame.
      camera_T_world: (4, 4) the frame's pose (the pose prior of the smoother).
      max_detections: padded number of detections of the smoother (``Capacity.max_detections``).
      max_objects: the smoother's object capacity; landmark ids must be below it.
      dtype: float dtype of the frame's arrays.

    Returns:
      :class:`jaxsem.slam.Frame` with ``object_id = landmark_id``, ``box_class = class_id``
      (indices or names of :data:`jaxsem.factors.CLASS_NAMES`) and a texture depth where the
      front end accepted one. The frame has no per-detection texture sigma: the smoother's
      ``NoiseModel.texture_sigma`` applies; ``AssociatedDetection.texture_variance`` is there for
      callers that build their own weighting.

    Raises:
      ValueError: from :func:`jaxsem.slam.make_frame` (too many detections, ids beyond
        ``max_objects``, unknown class names).
    """
    from ._problem import make_frame

    n = len(detections)
    box = np.array([d.box for d in detections], dtype=np.float64).reshape(n, 4)
    classes = [d.class_id for d in detections]
    box_class = np.array(classes) if n else np.zeros((0,), np.int64)
    object_id = np.array([d.landmark_id for d in detections], dtype=np.int64)
    depth = np.array([d.texture_depth if d.texture_depth is not None else np.nan for d in detections], dtype=np.float64)
    return make_frame(
        _check_pose(camera_T_world),
        box,
        box_class,
        object_id,
        depth,
        max_detections=max_detections,
        max_objects=max_objects,
        dtype=dtype,
    )
