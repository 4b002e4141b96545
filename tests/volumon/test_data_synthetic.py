"""Synthetic FAT-layout writer -> FAT loader round trip."""

import json

import cv2
import numpy as np
import pytest

from jaxsem import quadrics
from jaxsem.data import load_fat_scene
from jaxsem.volumon.data import object_box, write_synthetic_dataset
from jaxsem.volumon.data._synthetic import DEFAULT_CLASSES  # layers: white-box
from jaxsem.volumon.data.make_synthetic import main as make_synthetic_main


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("synthetic")
    train = write_synthetic_dataset(
        root, 6, seed=3, split="train", image_size=(128, 96), frames_per_scene=3, progress=False
    )
    test = write_synthetic_dataset(
        root, 2, seed=3, split="test", image_size=(128, 96), frames_per_scene=2, image_format="png", progress=False
    )
    return root, train, test


def _mask_box(mask):
    ys, xs = np.nonzero(mask)
    return np.array([xs.min() - 0.5, ys.min() - 0.5, xs.max() + 0.5, ys.max() + 0.5])


def test_layout_and_round_trip(dataset):
    root, train, test = dataset
    assert [d.name for d in train] == ["scene_000", "scene_001"] and len(test) == 1
    names = sorted(p.name for p in train[0].iterdir())
    assert "_camera_settings.json" in names and "_object_settings.json" in names
    for side in ("left", "right"):
        for ext in ("jpg", "json", "seg.png", "depth.png"):
            assert f"000000.{side}.{ext}" in names
    assert (test[0] / "000000.left.png").is_file()
    raw = json.loads((train[0] / "000000.left.json").read_text())
    bb = raw["objects"][0]["bounding_box"]
    seq = load_fat_scene(train[0], load_right_image=True)
    fr = seq[0]
    # The [y, x] quirk is reproduced and undone by the loader.
    np.testing.assert_allclose(
        fr.boxes_left[0], [bb["top_left"][1], bb["top_left"][0], bb["bottom_right"][1], bb["bottom_right"][0]]
    )
    assert fr.image.shape == (96, 128, 3) and fr.right_image.shape == (96, 128, 3)
    classes = {c.name: c for c in DEFAULT_CLASSES}
    counts = {}
    for d in train + test:
        for fr in load_fat_scene(d):
            assert 1 <= fr.num_objects <= 3 and len(set(fr.class_names)) == fr.num_objects
            right_seg = cv2.imread(str(fr.path).replace(".left.json", ".right.seg.png"), cv2.IMREAD_UNCHANGED)
            for i, name in enumerate(fr.class_names):
                counts[name] = counts.get(name, 0) + 1
                cls = classes[name]
                # Sizes: the class's real size with a small variation; objects 0.4-1.5 m away.
                np.testing.assert_allclose(fr.dimensions[i], cls.extents, rtol=0.1)
                assert 0.4 <= fr.center[i, 2] <= 1.5
                # Exact boxes agree with the rendered masks (left and right) to a pixel.
                np.testing.assert_allclose(fr.boxes_left[i], _mask_box(fr.seg == i), atol=1.0)
                np.testing.assert_allclose(
                    fr.boxes_right[i], _mask_box(right_seg == cls.segmentation_class_id), atol=1.0
                )
                # ... and with an independent projection of the loaded pose for the ellipsoid class.
                if cls.shape == "ellipsoid":
                    ref, valid = quadrics.project_bbox(
                        fr.rotation[i], fr.center[i], fr.dimensions[i] / 2, fr.K, np.eye(4)
                    )
                    assert bool(valid)
                    np.testing.assert_allclose(fr.boxes_left[i], np.asarray(ref), atol=1e-6)
                    # Depth on the mask back-projects onto the true ellipsoid surface.
                    kernel = np.ones((3, 3), np.uint8)
                    inner = cv2.erode((fr.seg == i).astype(np.uint8), kernel) > 0
                    vs, us = np.nonzero(inner)
                    z = fr.depth[vs, us].astype(np.float64)
                    pts = np.stack([(us - fr.K[0, 2]) * z / fr.K[0, 0], (vs - fr.K[1, 2]) * z / fr.K[1, 1], z], 1)
                    alg = np.asarray(
                        quadrics.algebraic_distance(pts, fr.rotation[i], fr.center[i], fr.dimensions[i] / 2)
                    )
                    assert np.median(np.abs(alg)) < 0.03
                else:
                    ref = object_box(cls.shape, fr.rotation[i], fr.center[i], fr.dimensions[i], fr.K)
                    np.testing.assert_allclose(fr.boxes_left[i], ref, atol=1e-6)
                # Depth is stored in 0.1 mm and read back in metres.
                assert np.all(np.abs(np.median(fr.depth[fr.seg == i]) - fr.center[i, 2]) < 0.2)
    assert len(counts) == 3  # every class appears


def test_deterministic_and_splits_differ(dataset, tmp_path):
    root, train, test = dataset
    again = write_synthetic_dataset(
        tmp_path, 3, seed=3, split="train", image_size=(128, 96), frames_per_scene=3, progress=False
    )
    for name in ("000002.left.json", "000001.right.json"):
        assert (again[0] / name).read_text() == (train[0] / name).read_text()
    a = load_fat_scene(again[0])[1]
    b = load_fat_scene(train[0])[1]
    np.testing.assert_array_equal(a.seg, b.seg)
    assert np.mean(np.abs(a.image.astype(int) - b.image)) < 1.0  # same render (JPEG is deterministic)
    t = load_fat_scene(test[0])[0]
    bg_train = b.image[b.seg < 0].astype(float).mean(0)
    bg_test = t.image[t.seg < 0].astype(float).mean(0)
    assert np.abs(bg_train - bg_test).max() > 1.0  # a different background


def test_bad_arguments(tmp_path):
    with pytest.raises(ValueError, match="split"):
        write_synthetic_dataset(tmp_path, 1, split="dev")
    with pytest.raises(ValueError, match="image_size"):
        write_synthetic_dataset(tmp_path, 1, image_size=(16, 16))
    with pytest.raises(ValueError, match="max_objects"):
        write_synthetic_dataset(tmp_path, 1, max_objects=5)


def test_command_line_entry(tmp_path, capsys):
    make_synthetic_main(
        [
            "--out",
            str(tmp_path),
            "--frames",
            "1",
            "--split",
            "test",
            "--width",
            "64",
            "--height",
            "48",
            "--format",
            "png",
            "--bbox-order",
            "xy",
        ]
    )
    assert "test: 1 frames" in capsys.readouterr().out
    fr = load_fat_scene(tmp_path / "test" / "scene_000", bbox_order="xy")[0]
    assert fr.image.shape == (48, 64, 3) and fr.num_objects >= 1
    ys, xs = np.nonzero(fr.seg == 0)
    np.testing.assert_allclose(
        fr.boxes_left[0], [xs.min() - 0.5, ys.min() - 0.5, xs.max() + 0.5, ys.max() + 0.5], atol=1.0
    )
