"""Distillation labels for the detect-and-lift network: a teacher VoluMon network's ellipsoids on
the 2D labels of photographs (``rcnn.teacher_labels``), carried by the frame arrays through
resizing and batching (``data.frame_arrays``, ``data.load_frame_chunks``)."""

from __future__ import annotations

import numpy as np
import pytest

from jaxsem.volumon import data as df, load_pretrained
from jaxsem.volumon.rcnn import teacher_labels

K = np.array([[500.0, 0.0, 160.0], [0.0, 500.0, 120.0], [0.0, 0.0, 1.0]])


def _frame(objects, seed=0):
    rgb = np.random.default_rng(seed).integers(0, 255, (240, 320, 3), dtype=np.uint8)
    return {"rgb": rgb, "K": K, "objects": objects}


def _object(name, box, **extra):
    return {"class_name": name, "visible_box": np.asarray(box, float), "rotation": np.eye(3),
            "center": np.array([0.0, 0.0, 1.0]), "radii": np.full(3, 0.04), **extra}  # fmt: skip


@pytest.fixture(scope="module")
def labelled():
    frames = [
        _frame([_object("ape", [40, 50, 90, 110]), _object("mug", [150, 60, 230, 170])]),
        _frame([_object("glue", [200, 30, 260, 120]), _object("can", [np.nan] * 4)], seed=1),
    ]
    teacher = load_pretrained(kind="lmo")
    return frames, teacher, teacher_labels(frames, teacher, batch=2)


def test_each_finite_label_gets_an_ellipsoid_in_front_of_its_box(labelled):
    frames, _, out = labelled
    assert all("teacher" not in o for f in frames for o in f["objects"])  # the input is left alone
    got = [(o["class_name"], "teacher" in o) for f in out for o in f["objects"]]
    assert got == [("ape", True), ("mug", True), ("glue", True), ("can", False)]
    for f in out:
        for o in f["objects"]:
            if "teacher" not in o:
                continue
            t = o["teacher"]
            assert t["center"][2] > 0 and np.all(t["radii"] > 0)
            np.testing.assert_allclose(t["rotation"] @ t["rotation"].T, np.eye(3), atol=1e-5)
            u, v, w = f["K"] @ t["center"]
            x0, y0, x1, y1 = o["visible_box"]
            assert x0 - 1e-3 <= u / w <= x1 + 1e-3 and y0 - 1e-3 <= v / w <= y1 + 1e-3


@pytest.mark.slow
def test_labels_do_not_depend_on_the_batch(labelled):
    frames, teacher, out = labelled
    again = teacher_labels(frames, teacher, batch=3)
    for fa, fb in zip(out, again):
        for a, b in zip(fa["objects"], fb["objects"]):
            if "teacher" in a:
                for k in ("rotation", "center", "radii"):
                    np.testing.assert_allclose(a["teacher"][k], b["teacher"][k], rtol=1e-5, atol=1e-6)


def test_frame_arrays_carry_teacher_labels_through_resizing(labelled, tmp_path):
    _, _, out = labelled
    arrays = df.frame_arrays(out, (160, 120), class_names=df.LMO_CLASS_NAMES + ("mug",), max_objects=3)
    np.testing.assert_array_equal(arrays["teacher_valid"], [[True, True, False], [True, False, False]])
    t = out[1]["objects"][0]["teacher"]  # camera-frame labels: unchanged by the image's scale
    np.testing.assert_allclose(arrays["teacher_center"][1, 0], t["center"], rtol=1e-6)
    np.testing.assert_allclose(arrays["teacher_half_extents"][1, 0], t["radii"], rtol=1e-6)
    np.testing.assert_allclose(arrays["teacher_rotation"][1, 0], t["rotation"], atol=1e-6)
    batch = df.frames_batch(arrays, [1, 0])
    np.testing.assert_array_equal(batch["teacher_valid"][0], arrays["teacher_valid"][1])
    # render chunks written before the teacher keys existed load with empty ones
    old = {k: v for k, v in arrays.items() if not k.startswith("teacher_")}
    np.savez(tmp_path / "frames_0000.npz", **old)
    loaded = df.load_frame_chunks(tmp_path)
    assert loaded["teacher_valid"].shape == (2, 3) and not loaded["teacher_valid"].any()
    assert loaded["teacher_rotation"].shape == (2, 3, 3, 3)
