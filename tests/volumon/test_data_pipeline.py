"""VoluMon input pipeline: shapes, determinism, surface points on the object, crops, bad input."""

import dataclasses

import numpy as np
import pytest

from jaxsem import quadrics
from jaxsem.data import load_fat_scene
from jaxsem.volumon._train import TRAIN_KEYS  # layers: white-box
from jaxsem.volumon.data import PipelineConfig, VolumonDataset, write_synthetic_dataset
from jaxsem.volumon.data._pipeline import as_volumon_batch, crop_inputs, mask_depth_points  # layers: white-box

CFG = PipelineConfig(patch_size=32, global_size=40, n_points=64, box_noise=0.1)


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    root = tmp_path_factory.mktemp("pipe")
    dirs = write_synthetic_dataset(
        root, 5, seed=11, split="train", image_size=(128, 96), frames_per_scene=5, image_format="png", progress=False
    )
    return list(load_fat_scene(dirs[0]))


@pytest.fixture(scope="module")
def dataset(frames):
    return VolumonDataset(frames, CFG, augment=True, seed=4)


def test_batch_shapes_and_dtypes(dataset):
    B = 4
    b = dataset.batch(0, 0, B)
    shapes = {
        "patch": (B, 32, 32, 3),
        "global_image": (B, 40, 40, 3),
        "input_box": (B, 4),
        "box": (B, 4),
        "box_right": (B, 4),
        "has_right_box": (B,),
        "K": (B, 3, 3),
        "baseline": (B,),
        "class_id": (B,),
        "points": (B, 64, 3),
        "points_mask": (B, 64),
        "has_points": (B,),
        "rotation": (B, 3, 3),
        "center": (B, 3),
        "dimensions": (B, 3),
    }
    for k, s in shapes.items():
        assert b[k].shape == s, k
        if b[k].dtype.kind == "f":
            assert np.all(np.isfinite(b[k])), k
    assert b["patch"].dtype == np.float32 and 0 <= b["patch"].min() and b["patch"].max() <= 1
    assert b["class_id"].dtype == np.int32 and set(b["class_id"]) <= {0, 1, 2}
    assert dataset.class_names == ("ball", "cracker_box", "soup_can")
    np.testing.assert_allclose(b["baseline"], 0.06)
    # Box noise moves the input box only; the loss box stays the clean one.
    assert np.abs(b["input_box"] - b["box"]).max() > 0.1
    for i, row in enumerate(b["index"]):
        np.testing.assert_allclose(b["box"][i], dataset._rows[row]["box"], rtol=1e-6)


def test_determinism_given_seed_epoch_step(frames, dataset):
    a = dataset.batch(1, 2, 2)
    again = VolumonDataset(frames, CFG, augment=True, seed=4).batch(1, 2, 2)
    for k in a:
        np.testing.assert_array_equal(a[k], again[k], err_msg=k)
    steps = dataset.steps_per_epoch(2)
    assert steps >= 3
    resumed = dataset.batch_at(1 * steps + 2, 2)
    np.testing.assert_array_equal(resumed["patch"], a["patch"])
    assert not np.array_equal(dataset.batch(1, 1, 2)["index"], a["index"])
    # The same sample gets fresh augmentations in another epoch.
    assert not np.array_equal(dataset.epoch_order(0), dataset.epoch_order(1))
    other = VolumonDataset(frames, CFG, augment=True, seed=5).batch(1, 2, 2)
    assert not np.array_equal(other["patch"], a["patch"])
    # Every sample appears once per epoch.
    seen = np.concatenate([b["index"] for b in dataset.epoch(0, 2)])
    assert len(np.unique(seen)) == len(seen) == 2 * dataset.steps_per_epoch(2)


def test_surface_points_lie_on_the_object(frames):
    ds = VolumonDataset(frames, CFG, augment=False)
    b = next(ds.eval_batches(ds.num_samples))
    assert b["valid"].all() and b["has_points"].all() and b["points_mask"].all()
    for i in range(ds.num_samples):
        name = ds.class_names[b["class_id"][i]]
        R, c, d = (b[k][i].astype(np.float64) for k in ("rotation", "center", "dimensions"))
        pts = b["points"][i].astype(np.float64)
        local = (pts - c) @ R
        if name == "ball":  # the ellipsoid class: points on the true ellipsoid
            alg = np.asarray(quadrics.algebraic_distance(pts, R, c, d / 2))
            assert np.median(np.abs(alg)) < 0.03, alg
        # Every class: points inside the object's cuboid and on its surface (some coordinate
        # at the boundary for the box).
        assert np.all(np.abs(local) <= d / 2 + 2e-3)
        if name == "cracker_box":
            assert np.all(np.min(d / 2 - np.abs(local), axis=1) < 2e-3)


def test_crop_is_exact_and_global_is_masked():
    h, w = 48, 64
    yy, xx = np.mgrid[0:h, 0:w]
    image = np.stack([xx * 3, yy * 5, np.full_like(xx, 200)], -1).astype(np.uint8)
    # A box of whole pixels 10..19 x 20..29 at size 10 is an exact copy.
    patch, glob = crop_inputs(image, [9.5, 19.5, 19.5, 29.5], patch_size=10, global_size=w, margin=0, margin_px=0)
    np.testing.assert_allclose(patch * 255, image[20:30, 10:20], atol=1e-3)
    assert patch.dtype == np.float32 and glob.shape == (w, w, 3)
    # Twice the size: output pixel centre j sits at input x = 9.5 + (j + 0.5) / 2 (bilinear).
    patch2, _ = crop_inputs(image, [9.5, 19.5, 19.5, 29.5], patch_size=20)
    x_in = 9.5 + (np.arange(20) + 0.5) / 2
    np.testing.assert_allclose(patch2[5, 1:-1, 0] * 255, 3 * x_in[1:-1], atol=1e-3)
    # Global: everything outside the (unpadded) box is zero; inside kept (non-uniform resize).
    _, glob = crop_inputs(image, [9.5, 19.5, 19.5, 29.5], patch_size=8, global_size=96, margin=0, margin_px=0)
    big = np.zeros((h, w), bool)
    big[20:30, 10:20] = True
    sy, sx = 96 / h, 96 / w
    assert glob[int(5 * sy), int(5 * sx)].max() == 0 and glob[int(45 * sy), int(60 * sx)].max() == 0
    assert glob[int(25 * sy), int(15 * sx), 2] > 0.7
    # Batched boxes, partially outside the image: zero outside, no error.
    patches, globs = crop_inputs(image, [[-10, -10, 10, 10], [0, 0, 63, 47]], patch_size=16, global_size=16)
    assert patches.shape == (2, 16, 16, 3) and globs.shape == (2, 16, 16, 3)
    assert patches[0, 0, 0].max() == 0 and patches[0, -1, -1].max() > 0


def test_bad_input_is_named_and_skips_are_documented(frames):
    image = frames[0].image
    with pytest.raises(ValueError, match="image: expected dtype uint8"):
        crop_inputs(image.astype(np.float32), [0, 0, 10, 10])
    with pytest.raises(ValueError, match=r"image: expected shape \(H, W, 3\)"):
        crop_inputs(image[..., 0], [0, 0, 10, 10])
    with pytest.raises(ValueError, match="outside"):
        crop_inputs(image, [500, 10, 600, 20])
    with pytest.raises(ValueError, match="u_max > u_min"):
        crop_inputs(image, [20, 10, 10, 20])
    with pytest.raises(ValueError, match="finite"):
        crop_inputs(image, [np.nan, 10, 10, 20])
    K = frames[0].K
    assert mask_depth_points(frames[0].depth, np.zeros_like(frames[0].seg, bool), K).shape == (0, 3)
    assert mask_depth_points(np.zeros_like(frames[0].depth), frames[0].seg == 0, K).shape == (0, 3)
    with pytest.raises(ValueError, match="depth: expected floating"):
        mask_depth_points(np.zeros(frames[0].seg.shape, np.uint16), frames[0].seg == 0, K)

    # Empty mask / zero depth: kept, with no points (mask False), all finite.
    f0 = dataclasses.replace(frames[0], seg=np.full_like(frames[0].seg, -1))
    f1 = dataclasses.replace(frames[1], depth=np.zeros_like(frames[1].depth))
    # A box past the image border is dropped (as the thesis filters FAT).
    k = next(i for i, f in enumerate(frames) if i >= 2 and f.num_objects >= 2)
    boxes = frames[k].boxes_left.copy()
    boxes[0, 2] = 500.0
    right = frames[k].boxes_right.copy()
    right[-1, 0] = -3.0  # truncated in the right image only: kept, right term masked
    f2 = dataclasses.replace(frames[k], boxes_left=boxes, boxes_right=right)
    ds = VolumonDataset([f0, f1, f2], CFG, augment=True, seed=0)
    assert ds.skipped["truncated"] == 1
    assert ds.num_samples == frames[0].num_objects + frames[1].num_objects + frames[k].num_objects - 1
    b = next(ds.eval_batches(8))
    n01 = frames[0].num_objects + frames[1].num_objects
    assert not b["has_points"][:n01].any() and not b["points_mask"][:n01].any()
    assert np.all(b["points"][:n01] == 0)
    for k, v in b.items():
        if v.dtype.kind == "f":
            assert np.all(np.isfinite(v)), k
    assert b["valid"].sum() == ds.num_samples and b["patch"].shape[0] == 8
    assert b["has_right_box"][: ds.num_samples].tolist() == [True] * (ds.num_samples - 1) + [False]
    with pytest.raises(ValueError, match="image: expected dtype uint8"):
        VolumonDataset([dataclasses.replace(frames[0], image=frames[0].image.astype(np.float64))], CFG)
    with pytest.raises(ValueError, match="step"):
        ds.batch(0, 99, 2)
    with pytest.raises(ValueError, match="batch_size"):
        ds.batch(0, 0, 1000)
    with pytest.raises(ValueError, match="patch_size"):
        PipelineConfig(patch_size=0)


def test_image_scale_and_point_cap(frames):
    """Half-size images: K and boxes follow, so the crop of a box shows the same content."""
    full = VolumonDataset(frames[:2], PipelineConfig(patch_size=16, global_size=16, n_points=8))
    half = VolumonDataset(
        frames[:2], PipelineConfig(patch_size=16, global_size=16, n_points=8, image_scale=0.5, max_points_per_object=5)
    )
    a, b = next(full.eval_batches(4)), next(half.eval_batches(4))
    np.testing.assert_allclose(b["K"][:, 0, 0], a["K"][:, 0, 0] / 2, rtol=1e-6)
    # The principal point (W - 1) / 2 of the full image maps to (W / 2 - 1) / 2 of the half one.
    np.testing.assert_allclose(b["K"][:, 0, 2], (a["image_size"][:, 0] / 2 - 1) / 2, rtol=1e-6)
    np.testing.assert_allclose((b["box"] + 0.5), (a["box"] + 0.5) / 2, rtol=1e-5)
    assert np.abs(a["patch"] - b["patch"]).mean() < 0.08
    assert all(len(r["points"]) <= 5 for r in half._rows)


def test_colour_jitter_keeps_value_and_identity_at_zero():
    rng = np.random.default_rng(0)
    im = rng.uniform(0, 1, (16, 16, 3)).astype(np.float32)
    still = VolumonDataset([], PipelineConfig(hue_jitter=0.0, saturation_jitter=0.0))
    np.testing.assert_allclose(still._colour_jitter(rng, [im])[0], im, atol=1e-5)
    moved = VolumonDataset([], PipelineConfig(hue_jitter=0.5, saturation_jitter=0.5))
    a, b = moved._colour_jitter(np.random.default_rng(3), [im, im[::-1]])
    # HSV's V = max(R, G, B) is untouched; hue and saturation move; both inputs get the same jitter.
    np.testing.assert_allclose(a.max(-1), im.max(-1), atol=1e-5)
    assert np.abs(a - im).max() > 0.1
    np.testing.assert_allclose(b, a[::-1], atol=1e-6)
    assert a.min() >= 0 and a.max() <= 1


def test_shape_ids_and_volumon_keys(frames):
    ds = VolumonDataset(frames, CFG, augment=False)
    b = next(ds.eval_batches(4))
    names = [ds.class_names[c] for c in b["class_id"]]
    expected = {"cracker_box": 0, "ball": 1, "soup_can": 2}
    assert b["shape_id"].tolist() == [expected[n] for n in names]
    v = as_volumon_batch(b)
    np.testing.assert_array_equal(v["local"], b["patch"])
    np.testing.assert_array_equal(v["box_left"], b["box"])
    np.testing.assert_allclose(v["gt_half_extents"], b["dimensions"] / 2)
    assert v["gt_shape_id"].tolist() == [1 if n == "ball" else 0 for n in names]
    np.testing.assert_array_equal(v["sample_mask"], b["valid"] & b["has_right_box"])
    # every key of the training loop but the class shapes, which the loop fills from the config
    assert set(v) >= set(TRAIN_KEYS) - {"class_shape"}
