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


def test_stereo_boxes_follow_both_cameras():
    """A second camera (moved and turned) sees each labelled point where its moved box says,
    through the zoomed intrinsics: the dual loss's labels stay true."""
    batch = _batch()
    n = len(batch["image"])
    c, s = np.cos(0.2), np.sin(0.2)
    rtl = np.array([[c, 0, s, -0.25], [0, 1, 0, 0.02], [-s, 0, c, 0.05], [0, 0, 0, 1]], np.float32)
    batch["right_T_left"] = np.tile(rtl, (n, 1, 1))
    half = np.array([-20.0, -15.0, 20.0, 15.0], np.float32)

    def seen(K, T, X):
        p = K @ (T[:3, :3] @ X + T[:3, 3])
        return p[:2] / p[2]

    batch["box_left"] = np.zeros_like(batch["boxes"])
    batch["box_right"] = np.zeros_like(batch["boxes"])
    for i in range(n):
        for key, T in (("box_left", np.eye(4)), ("box_right", rtl)):
            batch[key][i, 0] = np.tile(seen(batch["K"][i], T, batch["gt_center"][i, 0]), 2) + half
    out = df.augment_batch(batch, np.random.default_rng(4), scale_range=(0.75, 1.33))
    assert out["stereo_valid"][:, 0].all()
    np.testing.assert_array_equal(out["right_T_left"], batch["right_T_left"])
    zooms = []
    for i in range(n):
        for key, T in (("box_left", np.eye(4)), ("box_right", rtl)):
            box = out[key][i, 0]
            np.testing.assert_allclose((box[:2] + box[2:]) / 2, seen(out["K"][i], T, out["gt_center"][i, 0]), atol=1e-3)
        zooms.append((box[2] - box[0]) / 40.0)
    assert np.ptp(zooms) > 0.1  # the cameras did zoom


def test_a_box_zoomed_out_of_view_is_no_label():
    batch = _batch(n=40)
    out = df.augment_batch(batch, np.random.default_rng(2), scale_range=(1.3, 1.33), min_kept=0.99)
    moved_out = ~out["box_valid"][:, 0]
    assert moved_out.any() and (~moved_out).any()
    assert np.all(out["visible_fraction"][moved_out, 0] < 0.99 + 1e-6)


def test_jitter_changes_colours_only():
    batch = _batch()
    batch["image"] = batch["image"] * 0.6 + 0.2  # room to brighten and darken
    out = df.jitter_batch(batch, np.random.default_rng(3))
    for key in ("K", "boxes", "box_valid", "stereo_valid", "gt_center"):
        np.testing.assert_array_equal(out[key], batch[key])
    assert out["image"].dtype == batch["image"].dtype and out["image"].shape == batch["image"].shape
    assert out["image"].min() >= 0.0 and out["image"].max() <= 1.0
    changed = [not np.allclose(a, b) for a, b in zip(out["image"], batch["image"])]
    assert all(changed)
    # Each image keeps its picture: the rectangle stays where it was, brighter than the rest.
    for img, box in zip(out["image"], batch["boxes"][:, 0].astype(int)):
        lum = img.mean(-1)
        inside = lum[box[1] : box[3], box[0] : box[2]].mean()
        assert inside > lum.mean()
