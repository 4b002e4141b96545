"""Depth points of rendered labels for the detect-and-lift network's primal term.

A rendered frame carries its depth and per-object segmentation; ``frame_arrays(...,
num_points=P)`` keeps up to P of each label's visible surface points (camera frame), which must
land where the depth and the intrinsics put them, and never on another object's pixels or on
the silhouette. A photograph has none.
"""

import numpy as np
import pytest

from jaxsem.volumon.data import frame_arrays, frames_batch


def _frame(depth_with_object: bool = True):
    H, W = 48, 64
    K = np.array([[80.0, 0, 31.5], [0, 80.0, 23.5], [0, 0, 1]])
    depth = np.full((H, W), 2.0, np.float32)  # the background wall
    seg = np.zeros((H, W), np.int16)
    seg[10:30, 8:28] = 5  # object 5: a plane at 0.8 m
    depth[10:30, 8:28] = 0.8
    seg[20:26, 40:44] = 9  # object 9: 24 pixels at 1.2 m, fewer than asked for
    depth[20:26, 40:44] = 1.2
    obj = lambda i, box: {"class_name": "a", "visible_box": np.asarray(box, float), "obj_id": i,
                          "rotation": np.eye(3), "center": np.zeros(3), "radii": np.ones(3)}  # fmt: skip
    fr = {"rgb": np.zeros((H, W, 3), np.uint8), "K": K,
          "objects": [obj(5, [8, 10, 28, 30]), obj(9, [40, 20, 44, 26])]}  # fmt: skip
    if depth_with_object:
        fr.update(depth=depth, seg=seg)
    return fr


def test_each_labels_points_lie_on_its_own_visible_surface():
    fr = _frame()
    a = frame_arrays([fr], (64, 48), ["a"], max_objects=3, num_points=40)
    pts, mask = a["points"][0], a["point_mask"][0]
    assert pts.shape == (3, 40, 3) and mask.shape == (3, 40)
    assert mask[0].sum() == 40  # 18 x 18 pixels after the erosion: enough
    assert mask[1].sum() == 4 * 2  # 6 x 4 pixels eroded by one: 4 x 2
    assert not mask[2].any()  # the padding label
    K = fr["K"]
    for j, (z, (u0, v0, u1, v1)) in enumerate([(0.8, (9, 11, 26, 28)), (1.2, (41, 21, 42, 24))]):
        p = pts[j][mask[j]]
        np.testing.assert_allclose(p[:, 2], z, rtol=1e-6)
        u = K[0, 0] * p[:, 0] / p[:, 2] + K[0, 2]
        v = K[1, 1] * p[:, 1] / p[:, 2] + K[1, 2]
        assert np.all((u >= u0 - 1e-4) & (u <= u1 + 1e-4) & (v >= v0 - 1e-4) & (v <= v1 + 1e-4)), j
    assert len({tuple(x) for x in pts[0]}) == 40  # drawn without replacement
    again = frame_arrays([fr], (64, 48), ["a"], max_objects=3, num_points=40)
    np.testing.assert_array_equal(again["points"], a["points"])  # a fixed draw
    # the network's image size does not move camera-frame points
    small = frame_arrays([fr], (32, 24), ["a"], max_objects=3, num_points=40)
    np.testing.assert_array_equal(small["points"], a["points"])


def test_a_photograph_has_no_points_and_batches_carry_them():
    a = frame_arrays([_frame(False), _frame()], (64, 48), ["a"], max_objects=2, num_points=8)
    assert not a["point_mask"][0].any() and a["point_mask"][1].all()
    b = frames_batch(a, [1])
    assert b["points"].shape == (1, 2, 8, 3) and b["point_mask"].all()
    assert "points" not in frame_arrays([_frame()], (64, 48), ["a"], max_objects=2)


def test_a_negative_point_count_is_refused():
    with pytest.raises(ValueError, match="num_points"):
        frame_arrays([_frame()], (64, 48), ["a"], max_objects=2, num_points=-1)


def test_stored_chunks_bring_their_points_back_and_older_chunks_none(tmp_path):
    from jaxsem.volumon.data import load_frame_chunks

    with_points = frame_arrays([_frame(), _frame()], (64, 48), ["a"], max_objects=2, num_points=8)
    for i in range(2):
        np.savez(tmp_path / f"frames_{i:04d}.npz", **{k: v[i : i + 1] for k, v in with_points.items()})
    back = load_frame_chunks(tmp_path)
    np.testing.assert_array_equal(back["points"], with_points["points"])
    np.testing.assert_array_equal(back["point_mask"], with_points["point_mask"])
    older = tmp_path / "older"
    older.mkdir()
    plain = frame_arrays([_frame()], (64, 48), ["a"], max_objects=2)
    np.savez(older / "frames_0000.npz", **plain)
    assert "points" not in load_frame_chunks(older)
