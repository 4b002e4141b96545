"""The shipped 448 R-CNN's lift through a camera of another focal length: on real LM-O tuning photos
(``JAXSEM_DATA_DIR`` pointing at ``jaxsem data fetch lmo``'s folder; else skipped) zoomed about the
principal point with the intrinsics to match (what a longer lens sees), the depths it gives the same
objects stay where they were (a median log-ratio within 0.07). A lift that learnt depth through one
focal length reads it partly from how the object looks at that focal length, and moves them (a lift
trained on unzoomed renders: +0.12 here)."""

import os
import pathlib

import cv2
import numpy as np
import pytest

from jaxsem.volumon import data as vdata, rcnn


def _zoomed(image, K, boxes, s):
    """The photo through a focal length ``s`` times as long (same principal point), and the boxes."""
    cx, cy = K[0, 2], K[1, 2]
    M = np.array([[s, 0.0, (1 - s) * cx], [0.0, s, (1 - s) * cy]])
    h, w = image.shape[:2]
    out = cv2.warpAffine(image, M, (w, h), flags=cv2.INTER_LINEAR)
    Kz = K.copy()
    Kz[:2, :2] *= s
    return out, Kz, boxes * s + np.array([(1 - s) * cx, (1 - s) * cy] * 2)


@pytest.mark.slow
def test_the_shipped_448_lift_gives_the_same_depths_through_a_longer_lens():
    root = pathlib.Path(os.environ.get("JAXSEM_DATA_DIR", "/nonexistent")) / "lmo" / "test" / "000002"
    if not (root / "scene_gt.json").is_file():
        pytest.skip("LM-O absent (set JAXSEM_DATA_DIR to the folder of `jaxsem data fetch lmo`)")
    loaded = rcnn.load_rcnn("lmo-rcnn-448")
    names = list(loaded.config.class_names)
    scene = vdata.load_bop_split(root, "tune")
    ratios = []
    for f in scene.frames[:12]:  # tuning photos only (ids below 600)
        assert f.frame_id < 600
        objs = [o for o in f.objects if o.visible_fraction >= 0.5 and np.all(np.isfinite(o.visible_box))]
        image = vdata.read_rgb(f.image_path)
        h, w = image.shape[:2]
        boxes = np.array([o.visible_box for o in objs]).reshape(-1, 4)
        img_z, K_z, boxes_z = _zoomed(image, np.asarray(f.K, np.float64), boxes, 1.4)
        inside = np.all((boxes_z[:, :2] >= 0) & (boxes_z[:, 2:] <= [w - 1, h - 1]), axis=1)
        if not inside.any():
            continue
        cls = np.array([names.index(o.class_name) for o in objs])[inside]
        a = rcnn.lift_boxes(loaded, image, f.K, boxes[inside], cls)["center"][:, 2]
        b = rcnn.lift_boxes(loaded, img_z, K_z, boxes_z[inside], cls)["center"][:, 2]
        ratios.extend(np.log(b / a))
    assert len(ratios) >= 20
    assert abs(float(np.median(ratios))) < 0.07, np.median(ratios)
