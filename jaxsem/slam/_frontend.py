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
from typing import Any

import cv2
import numpy as np

# The configuration and output types, the stateless pieces and the input checks live in their own
# modules (_frontend_types.py, _frontend_vision.py, _frontend_checks.py).
from ._frontend_checks import (
    _check_boxes,
    _check_class_ids,
    _check_estimates,
    _check_image,
    _check_K,
    _check_pose,
)
from ._frontend_types import (
    TEXTURE_NEW_LANDMARK,
    TEXTURE_NO_TRACKS,
    TEXTURE_SHORT_BASELINE,
    AssociatedDetection,
    FrontEndConfig,
)
from ._frontend_vision import (
    _box_pixels,
    _camera_center,
    _predicted_centroids,
    _pyramidal_lk,
    _texture_from_points,
    hs_histogram,
    triangulate_points,
)
from ._problem import make_frame

__all__ = [
    "FrontEnd",
    "to_frame",
]


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
    # matcher "orb": the descriptors (N, 32) of the corners of the last sighting
    descriptors: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 32), np.uint8))


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
                             max_objects=cap.max_objects, image_size=(width, height))
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

    def process(self, image, camera_T_world, boxes, class_ids=None, landmark_estimates=None, track_ids=None):
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
          track_ids: optional (M,) non-negative ints, distinct within the frame: the association
            of a tracker that came with the detections (a detections file's ``id``). The front
            end then measures texture planes only: detection ``i`` is landmark ``track_ids[i]``
            (created on its first sighting), and the histogram association is skipped. Do not
            mix calls with and without it on one front end.

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
        if track_ids is not None:
            track_ids = [
                int(i) if isinstance(i, (int, np.integer)) and not isinstance(i, bool) else i for i in track_ids
            ]
            if len(track_ids) != boxes.shape[0]:
                raise ValueError(f"track_ids: expected {boxes.shape[0]} ids (one per box), got {len(track_ids)}")
            if not all(isinstance(i, int) and i >= 0 for i in track_ids) or len(set(track_ids)) != len(track_ids):
                raise ValueError(f"track_ids: expected distinct non-negative ints, got {list(track_ids)[:8]}")

        code_gray = cv2.COLOR_RGB2GRAY if cfg.color_order == "rgb" else cv2.COLOR_BGR2GRAY
        code_hsv = cv2.COLOR_RGB2HSV if cfg.color_order == "rgb" else cv2.COLOR_BGR2HSV
        gray = cv2.cvtColor(image, code_gray)
        hsv = cv2.cvtColor(image, code_hsv)
        self._shape = image.shape
        self._frame += 1

        if cfg.matcher == "lk":
            self._track(gray)
        predicted = self._predict(pose, estimates)
        hists = [hs_histogram(hsv, b, cfg.hist_bins, cfg.box_shrink) for b in boxes]
        if track_ids is None:
            assignment, scores = self._associate(boxes, class_ids, hists, predicted)
        else:  # the caller's tracker associates; new ids become new landmarks below
            assignment = {i: lid for i, lid in enumerate(track_ids) if lid in self._landmarks}
            scores = {i: (None, None) for i in assignment}
            self._next_id = max([self._next_id] + [lid + 1 for lid in track_ids])

        results = []
        for i, box in enumerate(boxes):
            lid = assignment.get(i)
            if lid is None:
                if track_ids is None:
                    lid = self._next_id
                    self._next_id += 1
                else:
                    lid = track_ids[i]
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
                if cfg.matcher == "orb":
                    self._match(lm, gray, box)
                depth, variance, status, n, baseline = self._texture(lm, box, pose)
                corr, dist = scores[i]
                is_new = False
            lm.histograms = (lm.histograms + [hists[i]])[-cfg.max_histograms :]
            lm.last_box = box
            lm.centre = 0.5 * (box[:2] + box[2:])
            lm.last_frame = self._frame
            lm.missed = 0
            if cfg.matcher == "orb":
                self._describe(lm, gray, box, pose)
            else:
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
                    lm.descriptors = lm.descriptors[:0]
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

    def _orb_crop(self, gray, box):
        """``(crop, mask, cx0, cy0)``: ORB runs on a crop around the box, not the whole image
        (its cost scales with the area); the margin covers ORB's border exclusion at its coarsest
        level, so corners near the box edge survive as they would on the full image. ``mask``
        (uint8, 255 inside the box shrunk by ``box_shrink``); ``(cx0, cy0)`` the crop's corner."""
        cfg = self.config
        x0, y0, x1, y1 = _box_pixels(box, gray.shape, cfg.box_shrink)
        h, w = gray.shape
        margin = int(math.ceil(cfg.orb_patch_size * 1.2 ** (cfg.orb_levels - 1))) + 2
        cx0, cy0 = max(x0 - margin, 0), max(y0 - margin, 0)
        cx1, cy1 = min(x1 + margin, w), min(y1 + margin, h)
        crop = np.ascontiguousarray(gray[cy0:cy1, cx0:cx1])
        mask = np.zeros(crop.shape, dtype=np.uint8)
        mask[y0 - cy0 : y1 - cy0, x0 - cx0 : x1 - cx0] = 255
        return crop, mask, cx0, cy0

    def _orb_in_box(self, gray, box):
        """ORB keypoints (K, 2) and descriptors (K, 32) inside ``box`` (shrunk by box_shrink)."""
        crop, mask, cx0, cy0 = self._orb_crop(gray, box)
        keypoints, desc = self._orb.detectAndCompute(crop, mask)
        if desc is None or not keypoints:
            return np.zeros((0, 2), np.float32), np.zeros((0, 32), np.uint8)
        uv = np.array([kp.pt for kp in keypoints], np.float32).reshape(-1, 2) + np.array([cx0, cy0], np.float32)
        return uv, np.asarray(desc, np.uint8)

    def _match(self, lm, gray, box):
        """Matcher "orb": the landmark's stored corners moved to their descriptor matches in
        this frame's box (unmatched corners dropped); anchors are kept."""
        cfg = self.config
        if lm.descriptors.shape[0] == 0 or lm.descriptors.shape[0] != lm.anchor_uv.shape[0]:
            lm.points, lm.anchor_uv, lm.anchor_pose = lm.points[:0], lm.anchor_uv[:0], lm.anchor_pose[:0]
            lm.descriptors = lm.descriptors[:0]
            return
        uv, desc = self._orb_in_box(gray, box)
        if desc.shape[0] < 2:
            lm.points, lm.anchor_uv, lm.anchor_pose = lm.points[:0], lm.anchor_uv[:0], lm.anchor_pose[:0]
            lm.descriptors = lm.descriptors[:0]
            return
        bf = cv2.BFMatcher(cv2.NORM_HAMMING)
        knn = bf.knnMatch(lm.descriptors, desc, k=2)
        back = {m.queryIdx: m.trainIdx for m in bf.match(desc, lm.descriptors)}
        src, dst = [], []
        for pair in knn:
            if len(pair) < 2:
                continue
            m, second = pair
            if m.distance < cfg.match_ratio * second.distance and back.get(m.trainIdx) == m.queryIdx:
                src.append(m.queryIdx)
                dst.append(m.trainIdx)
        src_i, dst_i = np.asarray(src, np.int64), np.asarray(dst, np.int64)
        lm.points = uv[dst_i]
        lm.anchor_uv = lm.anchor_uv[src_i]
        lm.anchor_pose = lm.anchor_pose[src_i]
        lm.descriptors = lm.descriptors[src_i]

    def _describe(self, lm, gray, box, pose):
        """Matcher "orb": the landmark's corners become this sighting's ORB corners, anchored here
        (the next sighting triangulates against this one)."""
        uv, desc = self._orb_in_box(gray, box)
        lm.points = uv
        lm.anchor_uv = uv.astype(np.float64)
        lm.anchor_pose = np.broadcast_to(pose, (uv.shape[0], 4, 4)).copy()
        lm.descriptors = desc

    def _reseed(self, lm, gray, box, pose):
        """Tops up a landmark's corners with fresh ORB corners anchored at this frame."""
        cfg = self.config
        if lm.points.shape[0] >= cfg.redetect_fraction * cfg.max_features and lm.points.shape[0] > 0:
            return
        crop, mask, cx0, cy0 = self._orb_crop(gray, box)
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


def to_frame(
    detections,
    camera_T_world,
    *,
    max_detections: int = 16,
    max_objects: int | None = None,
    dtype=None,
    image_size=None,
):
    """Converts one frame of :meth:`FrontEnd.process` output into the online smoother's ``Frame``.

    Args:
      detections: list of :class:`AssociatedDetection` of one frame.
      camera_T_world: (4, 4) the frame's pose (the pose prior of the smoother).
      max_detections: padded number of detections of the smoother (``Capacity.max_detections``).
      max_objects: the smoother's object capacity; landmark ids must be below it.
      dtype: float dtype of the frame's arrays.
      image_size: ``(width, height)`` of the frame's image; given, a box off the image is refused
        (as :func:`jaxsem.slam.make_frame`) instead of reaching the smoother, where a box far
        outside the image pulls its object along a ray it was never seen on.

    Returns:
      :class:`jaxsem.slam.Frame` with ``object_id = landmark_id``, ``box_class = class_id``
      (indices or names of :data:`jaxsem.factors.CLASS_NAMES`) and a texture depth where the
      front end accepted one. The frame has no per-detection texture sigma: the smoother's
      ``NoiseModel.texture_sigma`` applies; ``AssociatedDetection.texture_variance`` is there for
      callers that build their own weighting.

    Raises:
      ValueError: from :func:`jaxsem.slam.make_frame` (too many detections, ids beyond
        ``max_objects``, unknown class names, given ``image_size`` a box off the image).
    """
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
        image_size=image_size,
    )
