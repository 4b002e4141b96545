"""The real photos seen by other cameras: boxes and intrinsics move with the pixels."""

from __future__ import annotations

import numpy as np

from jaxsem.volumon import data as df


def _batch(n=6, W=320, H=240):
    """A black image with one white rectangle per frame, its box labelled, and a 3D point
    (the labels' centre) whose projection is the rectangle's centre."""
    rng = np.random.default_rng(0)
    img = np.zeros((n, H, W, 3), np.float32)
    boxes = np.zeros((n, 8, 4), np.float32)
    valid = np.zeros((n, 8), bool)
    K = np.tile(np.array([[300.0, 0, 160], [0, 300, 120], [0, 0, 1]], np.float32), (n, 1, 1))
    center = np.zeros((n, 8, 3), np.float32)
    for i in range(n):
        u0, v0 = rng.uniform(60, 200), rng.uniform(50, 140)
        w, h = rng.uniform(30, 80), rng.uniform(30, 70)
        img[i, int(v0) : int(v0 + h), int(u0) : int(u0 + w)] = 1.0
        boxes[i, 0] = [int(u0), int(v0), int(u0 + w), int(v0 + h)]
        valid[i, 0] = True
        cu, cv = (boxes[i, 0, 0] + boxes[i, 0, 2]) / 2, (boxes[i, 0, 1] + boxes[i, 0, 3]) / 2
        z = 0.8
        center[i, 0] = [(cu - 160) * z / 300, (cv - 120) * z / 300, z]
    return {
        "image": img,
        "K": K,
        "boxes": boxes,
        "box_valid": valid,
        "visible_fraction": valid.astype(np.float32),
        "stereo_valid": valid.copy(),
        "gt_center": center,
    }


def test_boxes_and_intrinsics_follow_the_pixels():
    batch = _batch()
    out = df.augment_batch(batch, np.random.default_rng(1), scale_range=(0.8, 1.25))
    assert not out["stereo_valid"].any()
    checked = 0
    for i in range(len(out["image"])):
        if not out["box_valid"][i, 0]:
            continue
        lit = np.argwhere(out["image"][i].mean(-1) > 0.9 * out["image"][i].max())
        (v0, u0), (v1, u1) = lit.min(0), lit.max(0) + 1
        np.testing.assert_allclose(out["boxes"][i, 0], [u0, v0, u1, v1], atol=2.5)
        p = out["K"][i] @ out["gt_center"][i, 0]
        centre = (out["boxes"][i, 0, :2] + out["boxes"][i, 0, 2:]) / 2
        if np.all(out["boxes"][i, 0] > 0) and out["boxes"][i, 0, 2] < 320 and out["boxes"][i, 0, 3] < 240:
            np.testing.assert_allclose(p[:2] / p[2], centre, atol=1.5)
        checked += 1
    assert checked >= 3
    assert np.all(batch["box_valid"][:, 0])  # the input is untouched


def test_a_box_zoomed_out_of_view_is_no_label():
    batch = _batch(n=40)
    out = df.augment_batch(batch, np.random.default_rng(2), scale_range=(1.3, 1.33), min_kept=0.99)
    moved_out = ~out["box_valid"][:, 0]
    assert moved_out.any() and (~moved_out).any()
    assert np.all(out["visible_fraction"][moved_out, 0] < 0.99 + 1e-6)


def test_kept_stereo_boxes_stay_the_projections_of_both_cameras():
    batch = _batch(n=12)
    baseline = 0.06
    K = batch["K"][0].astype(np.float64)
    rtl = np.eye(4)
    rtl[0, 3] = -baseline
    corners = lambda c: [np.array([c[0] + dx, c[1] + dy, c[2]]) for dx in (-0.03, 0.03) for dy in (-0.02, 0.02)]

    def box_of(points, K, T):
        uv = [(K @ (T[:3, :3] @ p + T[:3, 3]))[:2] / (K @ (T[:3, :3] @ p + T[:3, 3]))[2] for p in points]
        uv = np.array(uv)
        return np.concatenate([uv.min(0), uv.max(0)])

    left = np.zeros_like(batch["boxes"])
    right = np.zeros_like(batch["boxes"])
    for i in range(len(left)):
        pts = corners(batch["gt_center"][i, 0])
        left[i, 0], right[i, 0] = box_of(pts, K, np.eye(4)), box_of(pts, K, rtl)
    batch.update(box_left=left, box_right=right, right_T_left=np.tile(rtl, (len(left), 1, 1)))
    out = df.augment_batch(batch, np.random.default_rng(3), scale_range=(0.8, 1.25), keep_stereo=True)
    kept = np.flatnonzero(out["stereo_valid"][:, 0])
    assert len(kept) >= 3
    assert not np.any(out["stereo_valid"] & ~out["box_valid"])
    for i in kept:
        pts = corners(batch["gt_center"][i, 0])
        Ki = out["K"][i].astype(np.float64)
        np.testing.assert_allclose(out["box_left"][i, 0], box_of(pts, Ki, np.eye(4)), atol=1e-3)
        np.testing.assert_allclose(out["box_right"][i, 0], box_of(pts, Ki, rtl), atol=1e-3)
