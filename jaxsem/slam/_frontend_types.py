"""The OpenCV front end's configuration and output types (:class:`FrontEndConfig`,
:class:`AssociatedDetection`, :class:`LandmarkEstimates`) and the texture status codes.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np

from .._checks import check_fields, finite_nonnegative, int_at_least
from ..quadrics import EllipsoidView

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

    Matching:
      matcher: ``"lk"`` (the thesis: corners tracked frame to frame with Lucas-Kanade) or
        ``"orb"`` (corners matched by ORB descriptor between the landmark's last sighting and
        this one: Hamming distance, Lowe's ratio ``match_ratio``, mutual best). Use ``"orb"``
        for frames far apart (large rotations between frames, as on LM-O's real desk, where LK
        loses most of its tracks and most detections get no texture plane;
        ``benchmarks/roshan/HISTORY.md``, "ROSHAN on the real LM-O desk").
      match_ratio: Lowe's ratio of the best to the second-best descriptor distance.

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
    matcher: str = "lk"
    match_ratio: float = 0.8

    def __post_init__(self):
        prefix = "FrontEndConfig."
        positive_ints = ("max_features", "orb_levels", "lk_levels", "min_points", "max_histograms")
        check_fields(self, positive_ints, "an integer >= 1", int_at_least(1), prefix=prefix)
        check_fields(
            self, ("orb_fast_threshold", "max_missed_frames"), "an integer >= 0", int_at_least(0), prefix=prefix
        )
        check_fields(self, ("orb_patch_size", "lk_window"), "an integer >= 3", int_at_least(3), prefix=prefix)
        positive = (
            "max_forward_backward_error",
            "max_reprojection_error",
            "max_outlier_deviations",
            "max_depth_variance",
            "max_relative_depth_std",
            "min_depth",
            "gate_pixels",
        )
        check_fields(
            self,
            positive,
            "a number > 0",
            lambda v: isinstance(v, (int, float)) and v > 0 and not math.isnan(v),
            prefix=prefix,
        )
        check_fields(self, ("min_baseline", "box_tolerance"), "a finite number >= 0", finite_nonnegative, prefix=prefix)
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
        if self.matcher not in ("lk", "orb"):
            raise ValueError(f"FrontEndConfig.matcher: expected 'lk' or 'orb', got {self.matcher!r}")
        if not (isinstance(self.match_ratio, (int, float)) and 0 < self.match_ratio <= 1):
            raise ValueError(f"FrontEndConfig.match_ratio: expected 0 < value <= 1, got {self.match_ratio!r}")
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

    ellipsoid = EllipsoidView()

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
