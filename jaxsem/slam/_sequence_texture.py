"""Texture planes for a posed detection sequence with images: ROSHAN's front end run over it with
the sequence's own association (a tracker's ids), :func:`measure_texture`."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from ._frontend import FrontEnd
from ._frontend_vision import triangulate_points
from ._sequence_types import Sequence

__all__ = ["measure_texture", "support_height"]


def measure_texture(sequence: Sequence, config=None):
    """``(sequence with texture depths, detections)``: every frame's image through
    :class:`jaxsem.slam._frontend.FrontEnd` (``config``: a :class:`jaxsem.slam.FrontEndConfig`), each
    detection associated by the sequence's ids (``track_ids``), its texture-plane depth written
    where the front end accepted one (NaN elsewhere; depths already in the sequence are
    replaced). ``detections``: per frame, the front end's :class:`AssociatedDetection` list
    (status, point count, baseline of each measurement).

    Raises:
      ValueError: a frame without an image, an unreadable image, or an id that is not a
        non-negative int (the front end's landmark ids are ints).
    """
    if not isinstance(sequence, Sequence):
        raise ValueError(f"sequence: expected a Sequence, got {type(sequence).__name__}")
    fe = FrontEnd(sequence.K, config)
    frames, out = [], []
    for t, fr in enumerate(sequence.frames):
        if fr.image is None:
            raise ValueError(f"frames[{t}].image: the front end needs every frame's image")
        bad = [i for i in fr.ids if not isinstance(i, (int, np.integer)) or isinstance(i, bool) or i < 0]
        if bad:
            raise ValueError(f"frames[{t}].ids: the front end needs non-negative int ids, got {bad[0]!r}")
        dets = fe.process(sequence.image(t), fr.camera_T_world, fr.boxes, list(fr.classes), track_ids=list(fr.ids))
        depth = np.array([np.nan if d.texture_depth is None else d.texture_depth for d in dets], np.float64)
        frames.append(dataclasses.replace(fr, texture_depth=depth.reshape(len(fr.ids))))
        out.append(dets)
    return dataclasses.replace(sequence, frames=tuple(frames)), out


def support_height(
    sequence: Sequence,
    world_up=(0.0, 0.0, 1.0),
    *,
    max_features: int = 2000,
    frame_gap: int = 3,
    min_baseline: float = 0.03,
    max_reprojection_error: float = 2.0,
    box_margin: float = 5.0,
    band: float = 0.005,
    min_points: int = 50,
):
    """Height of the surface the objects rest on, from the images' features around them.

    For a tabletop sequence with known up (gravity): ORB corners outside every detection box
    (grown by ``box_margin`` pixels) are matched between each frame and the next ``frame_gap``
    frames whose cameras are at least ``min_baseline`` metres apart (ratio test), triangulated
    with the sequence's poses, kept where both reprojections are within
    ``max_reprojection_error`` pixels and in front of both cameras; the support is the densest
    height along ``world_up``: the height with the most points within ``band`` metres (a desk
    or floor is the largest horizontal surface in view), refined as their median. What the
    support prior (``SolverConfig(use_support=True, support_height=...)``) reads when no depth
    camera or AR plane gives the surface.

    Returns:
      ``(height, count)``: metres along ``world_up`` in the sequence's world frame, and the
      number of points within ``band`` of it; ``(nan, count)`` when fewer than ``min_points``
      triangulated points were found.

    Raises:
      ValueError: a frame without an image, or a bad argument (named).
    """
    if not isinstance(sequence, Sequence):
        raise ValueError(f"sequence: expected a Sequence, got {type(sequence).__name__}")
    up = np.asarray(world_up, np.float64).reshape(-1)
    if up.shape != (3,) or not np.isclose(np.linalg.norm(up), 1.0, atol=1e-6):
        raise ValueError(f"world_up: expected a unit 3-vector, got {world_up!r}")
    if int(frame_gap) < 1:
        raise ValueError(f"frame_gap: expected a positive int, got {frame_gap!r}")
    for name, v in (("min_baseline", min_baseline), ("band", band), ("max_reprojection_error", max_reprojection_error)):
        if not np.isfinite(v) or v <= 0:
            raise ValueError(f"{name}: expected a positive number, got {v!r}")
    K = np.asarray(sequence.K, np.float64)
    W, H = (int(x) for x in sequence.image_size)
    orb = cv2.ORB.create(nfeatures=int(max_features), fastThreshold=7)
    feats = []
    for t, fr in enumerate(sequence.frames):
        img = sequence.image(t)
        if img is None:
            raise ValueError(f"frames[{t}].image: support_height needs every frame's image")
        mask = np.full((H, W), 255, np.uint8)
        for b in np.asarray(fr.boxes, np.float64).reshape(-1, 4):
            if not np.all(np.isfinite(b)):
                continue
            x0, y0 = (max(int(np.floor(v - box_margin)), 0) for v in b[:2])
            x1, y1 = (int(np.ceil(v + box_margin)) for v in b[2:])
            mask[y0 : max(y1, y0), x0 : max(x1, x0)] = 0
        kp, des = orb.detectAndCompute(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), mask)
        feats.append((np.array([k.pt for k in kp], np.float64).reshape(-1, 2), des))
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    poses = [np.asarray(f.camera_T_world, np.float64) for f in sequence.frames]
    centres = [np.linalg.inv(p)[:3, 3] for p in poses]

    def reprojection(pose, X, uv):
        pc = X @ pose[:3, :3].T + pose[:3, 3]
        proj = pc @ K.T
        return np.linalg.norm(proj[:, :2] / np.maximum(proj[:, 2:], 1e-9) - uv, axis=1), pc[:, 2]

    heights = []
    for a in range(len(poses)):
        for b in range(a + 1, min(a + 1 + int(frame_gap), len(poses))):
            if np.linalg.norm(centres[a] - centres[b]) < min_baseline:
                continue
            if feats[a][1] is None or feats[b][1] is None or len(feats[b][0]) < 2:
                continue
            pairs = matcher.knnMatch(feats[a][1], feats[b][1], k=2)
            good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < 0.75 * p[1].distance]
            if not good:
                continue
            ua = feats[a][0][[m.queryIdx for m in good]]
            ub = feats[b][0][[m.trainIdx for m in good]]
            X, ok = triangulate_points(K, poses[a], poses[b], ua, ub)
            ea, za = reprojection(poses[a], X, ua)
            eb, zb = reprojection(poses[b], X, ub)
            keep = ok & (ea < max_reprojection_error) & (eb < max_reprojection_error) & (za > 0) & (zb > 0)
            heights.append(X[keep] @ up)
    z = np.concatenate(heights) if heights else np.zeros(0)
    if len(z) < int(min_points):
        return float("nan"), int(len(z))
    zs = np.sort(z)
    # densest band: for each point, how many lie within +-band of it (two binary searches)
    count = np.searchsorted(zs, zs + band, side="right") - np.searchsorted(zs, zs - band, side="left")
    mode = zs[int(np.argmax(count))]
    near = zs[np.abs(zs - mode) <= band]
    return float(np.median(near)), int(len(near))
