"""2-D labels as a typed VoluMon training batch (``volumon.LabelBatch`` / ``label_batch``):
built from an image, its boxes and K; trains a weak variant; refused by the oracle."""

import numpy as np
import pytest

from jaxsem import volumon
from jaxsem.volumon._configs import tiny_config  # layers: white-box
from jaxsem.volumon._train import TRAIN_KEYS  # layers: white-box

K = np.array([[55.0, 0.0, 32.0], [0.0, 55.0, 24.0], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def image():
    rng = np.random.default_rng(0)
    return rng.uniform(0, 1, (48, 64, 3)).astype(np.float32)


def _labels(image, n=2, **kw):
    left = np.array([[10.0, 8.0, 30.0, 30.0], [34.0, 12.0, 50.0, 40.0]])[:n]
    right = left - np.array([4.0, 0.0, 4.0, 0.0])
    return volumon.label_batch(image, left, right, K, 0.06, np.arange(n) % 4, config=tiny_config(), **kw)


def test_label_batch_holds_the_labels_and_the_crops_of_the_boxes(image):
    b = _labels(image)
    s = tiny_config().model.input_size
    assert b.local.shape == (2, s, s, 3) and b.global_image.shape == (2, s, s, 3)
    np.testing.assert_array_equal(b.box_input, b.box_left)  # default: the labelled left box
    np.testing.assert_allclose(b.box_right[:, 0], b.box_left[:, 0] - 4.0)
    assert b.K.shape == (2, 3, 3) and np.all(b.baseline == np.float32(0.06))
    # shapes from the shipped class table: cracker_box (cuboid), ball (ellipsoid)
    np.testing.assert_array_equal(b.class_shape, [0, 1])
    assert not b.point_mask.any()  # no depth given
    # crops of different boxes differ; the same box gives the same crop
    assert not np.allclose(b.local[0], b.local[1])
    again = _labels(image)
    np.testing.assert_array_equal(again.local, b.local)


def test_as_train_batch_has_every_training_key_and_says_it_is_2d_only(image):
    out = _labels(image).as_train_batch()
    assert set(TRAIN_KEYS) <= set(out)
    assert out["labels_2d_only"] is True
    joined = volumon.LabelBatch.concatenate([_labels(image), _labels(image, n=1)])
    assert joined.box_left.shape == (3, 4) and joined.local.shape[0] == 3


def test_points_keep_only_finite_masked_entries(image):
    pts = np.zeros((2, 3, 3), np.float32) + [0.0, 0.0, 0.7]
    pts[0, 1] = np.nan
    b = _labels(image, points=pts, point_mask=np.array([[True, True, False], [True, True, True]]))
    np.testing.assert_array_equal(b.point_mask, [[True, False, False], [True, True, True]])
    assert np.all(np.isfinite(b.points))


@pytest.mark.parametrize(
    "change, word",
    [
        ({"boxes_right": np.zeros((1, 4))}, "boxes_right"),
        ({"boxes_left": np.array([[10.0, 8.0, 5.0, 30.0], [34.0, 12.0, 50.0, 40.0]])}, "boxes_left"),
        ({"baseline": 0.0}, "baseline"),
        ({"K": np.eye(2)}, "K"),
        ({"class_id": np.array([0.5, 1.0])}, "class_id"),
        ({"points": np.zeros((2, 3))}, "points"),
    ],
)
def test_label_batch_refuses_bad_labels_naming_the_argument(image, change, word):
    args = {
        "image": image,
        "boxes_left": np.array([[10.0, 8.0, 30.0, 30.0], [34.0, 12.0, 50.0, 40.0]]),
        "boxes_right": np.array([[6.0, 8.0, 26.0, 30.0], [30.0, 12.0, 46.0, 40.0]]),
        "K": K,
        "baseline": 0.06,
        "class_id": np.array([0, 1]),
    }
    args.update(change)
    with pytest.raises(ValueError, match=word):
        volumon.label_batch(**args, config=tiny_config())


@pytest.mark.slow  # a tiny VoluMon compiles and trains (about 12 s)
def test_a_weak_variant_trains_on_2d_labels_and_the_oracle_is_refused(image, tmp_path):
    batch = volumon.LabelBatch.concatenate([_labels(image), _labels(image)]).as_train_batch()
    cfg = volumon.get_config("both", "tiny").replace(data="directory", batch_size=4, num_steps=2)
    out = volumon.train_and_evaluate(cfg, tmp_path / "weak", batch_fn=lambda step: batch, progress=False)
    assert all(np.isfinite(float(v["total"])) for v in out["history"].values())
    oracle = volumon.get_config("oracle", "tiny").replace(data="directory", batch_size=4, num_steps=2)
    with pytest.raises(ValueError, match="2-D labels only"):
        volumon.train_and_evaluate(oracle, tmp_path / "oracle", batch_fn=lambda step: batch, progress=False)


def test_a_batch_with_fewer_rows_than_the_config_is_refused_naming_batch_size(image, tmp_path):
    batch = _labels(image).as_train_batch()  # 2 rows
    cfg = tiny_config().replace(data="directory", batch_size=32, num_steps=1)
    with pytest.raises(
        ValueError, match=r"batch_fn: the batch of step 0 has 2 rows in 'local', but config.batch_size is 32"
    ):
        volumon.train_and_evaluate(cfg, tmp_path / "run", batch_fn=lambda step: batch, progress=False)
