"""A detector's output into tracks: ids stable across a moving camera, depth-wrong lifts pinned
down by the viewing rays, strays dropped, bad input named."""

from __future__ import annotations

import numpy as np
import pytest

from jaxsem import quadrics as q, slam
from jaxsem.slam._sequence_types import Sequence, SequenceFrame  # layers: white-box

K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
#: Four objects on a desk, two of one class side by side (world frame, metres).
CENTERS = np.array([[0.0, 0.0, 0.05], [0.25, 0.05, 0.04], [-0.2, 0.15, 0.06], [0.1, -0.25, 0.05]])
RADII = np.array([[0.04, 0.03, 0.05], [0.05, 0.05, 0.04], [0.03, 0.03, 0.06], [0.05, 0.04, 0.05]])
CLASSES = ["mug", "bowl", "mug", "box"]


def _poses(n=12, radius=0.9, height=0.5, arc=0.8 * np.pi):
    angles = np.linspace(0.0, arc, n)
    eyes = np.stack([radius * np.cos(angles), radius * np.sin(angles), np.full(n, height)], axis=1)
    return np.stack([np.asarray(q.look_at(e, np.zeros(3), xp=np)) for e in eyes])


def _detections(poses, depth_scale=1.2, seed=0):
    """Each visible object's true box and its ellipsoid in the camera frame, the centre pushed
    along the viewing ray by ``depth_scale`` (a lift's typical error), in a shuffled order."""
    rng = np.random.default_rng(seed)
    out, truth_order = [], []
    R = np.broadcast_to(np.eye(3), (len(CENTERS), 3, 3))
    for P in poses:
        box, valid = q.project_bbox(R, CENTERS, RADII, K, np.broadcast_to(P, (len(CENTERS), 4, 4)))
        box, valid = np.asarray(box), np.asarray(valid)
        order = rng.permutation(len(CENTERS))
        order = order[valid[order]]
        c_cam = CENTERS @ P[:3, :3].T + P[:3, 3]
        out.append(
            {
                "box": box[order] + rng.normal(0.0, 1.0, (len(order), 4)),
                "class_name": [CLASSES[k] for k in order],
                "score": np.full(len(order), 0.9),
                "rotation": np.einsum("ij,njk->nik", P[:3, :3], R[order]),
                "center": depth_scale * c_cam[order],
                "radii": RADII[order],
            }
        )
        truth_order.append(order)
    return out, truth_order


def test_every_object_keeps_one_track_as_the_camera_moves():
    poses = _poses()
    dets, truth = _detections(poses)
    ids, tracks = slam.associate_detections(K, poses, dets)
    assert len(tracks) == len(CENTERS)
    track_of = {}
    for i, order in zip(ids, truth):
        assert np.all(i >= 0)
        for j, k in zip(i, order):
            assert track_of.setdefault(int(k), int(j)) == int(j)
    assert sorted(track_of.values()) == list(range(len(CENTERS)))
    for k, j in track_of.items():
        assert tracks[j]["class"] == CLASSES[k]
        assert tracks[j]["views"] == len(poses)


def test_the_rays_pin_down_lifts_twenty_percent_off_in_depth():
    poses = _poses()
    dets, truth = _detections(poses, depth_scale=1.2)
    ids, tracks = slam.associate_detections(K, poses, dets)
    first = {int(k): int(j) for j, k in zip(ids[0], truth[0])}
    for k, j in first.items():
        lifted = np.linalg.inv(poses[0]) @ np.append(1.2 * (poses[0][:3, :3] @ CENTERS[k] + poses[0][:3, 3]), 1.0)
        err_lift = np.linalg.norm(lifted[:3] - CENTERS[k])
        err_track = np.linalg.norm(tracks[j]["center"] - CENTERS[k])
        assert err_lift > 0.1
        assert err_track < 0.25 * err_lift


def test_a_stray_and_a_weak_detection_start_no_track():
    poses = _poses()
    dets, _ = _detections(poses)
    stray = {
        "box": np.array([[10.0, 10.0, 40.0, 50.0]]),
        "class_name": ["bowl"],
        "score": np.array([0.9]),
        "rotation": np.eye(3)[None],
        "center": np.array([[0.0, 0.0, 2.0]]),
        "radii": np.array([[0.05, 0.05, 0.05]]),
    }
    dets[5] = {k: (v + stray[k] if k == "class_name" else np.concatenate([v, stray[k]])) for k, v in dets[5].items()}
    dets[7]["score"] = np.where(np.arange(len(dets[7]["score"])) == 0, 0.2, dets[7]["score"])
    ids, tracks = slam.associate_detections(K, poses, dets, min_score=0.5)
    assert len(tracks) == len(CENTERS)
    assert ids[5][-1] == -1
    assert ids[7][0] == -1 and np.all(ids[7][1:] >= 0)


def test_without_lifts_the_last_box_carries_a_slowly_moving_view():
    poses = _poses(n=10, arc=0.1 * np.pi)
    dets, truth = _detections(poses)
    plain = [{"box": d["box"], "class_name": d["class_name"]} for d in dets]
    ids, tracks = slam.associate_detections(K, poses, plain)
    assert all(t["center"] is None for t in tracks.values())
    track_of = {}
    for i, order in zip(ids, truth):
        for j, k in zip(i, order):
            assert track_of.setdefault(int(k), int(j)) == int(j)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"min_iou": 0.0}, "min_iou"),
        ({"min_views": 0}, "min_views"),
        ({"min_score": 1.5}, "min_score"),
    ],
)
def test_bad_thresholds_are_named(kwargs, name):
    poses = _poses(n=3)
    dets, _ = _detections(poses)
    with pytest.raises(ValueError, match=name):
        slam.associate_detections(K, poses, dets, **kwargs)


def test_bad_detections_are_named():
    poses = _poses(n=3)
    dets, _ = _detections(poses)
    with pytest.raises(ValueError, match="detections"):
        slam.associate_detections(K, poses, dets[:2])
    bad = [dict(d) for d in dets]
    bad[1]["box"] = np.full((len(bad[1]["class_name"]), 4), np.nan)
    with pytest.raises(ValueError, match=r"detections\[1\]"):
        slam.associate_detections(K, poses, bad)
    with pytest.raises(ValueError, match="camera_T_world"):
        slam.associate_detections(K, poses[:, :3], dets)


def _sequence(poses, classes):
    frames = tuple(
        SequenceFrame(camera_T_world=P, boxes=np.zeros((0, 4)), classes=(), ids=(), texture_depth=np.zeros(0))
        for P in poses
    )
    return Sequence(K=K, image_size=(640, 480), frames=frames, classes=classes)


def test_detected_sequence_holds_the_tracks_and_their_ellipsoids():
    from jaxsem.classes import ClassTable

    table = ClassTable.from_dict(
        [{"name": c, "dimensions": [0.1, 0.1, 0.1], "sigma": [0.03] * 3} for c in sorted(set(CLASSES))]
    )
    poses = _poses()
    dets, _ = _detections(poses)
    seq = slam.detected_sequence(_sequence(poses, table), dets)
    assert len(seq.object_ids) == len(CENTERS)
    assert sum(len(f.ids) for f in seq.frames) == sum(len(d["box"]) for d in dets)
    assert set(seq.initial) == set(seq.object_ids)
    for f, d in zip(seq.frames, dets):
        np.testing.assert_allclose(f.boxes, d["box"])
    other = ClassTable.from_dict([{"name": "mug", "dimensions": [0.1, 0.1, 0.1], "sigma": [0.03] * 3}])
    with pytest.raises(ValueError, match="class table"):
        slam.detected_sequence(_sequence(poses, other), dets)


def _broken_tracks(seed=3, lateral=0.004):
    """Lifts at the true depth but a few millimetres beside their rays, and a threshold few frame
    pairs reach: the objects' tracks break into many of a view or two."""
    poses = _poses(n=6)
    dets, truth = _detections(poses, depth_scale=1.0, seed=seed)
    rng = np.random.default_rng(seed)
    for d in dets:
        d["center"] = d["center"] + rng.normal(0.0, lateral, d["center"].shape)
    return poses, dets, truth


@pytest.mark.parametrize("merge", [1.0, 20.0])
def test_tracks_of_one_object_are_joined_and_two_objects_seen_together_never(merge):
    poses, dets, truth = _broken_tracks()
    _, apart = slam.associate_detections(K, poses, dets, min_iou=0.99, min_views=1)
    assert len(apart) > 3 * len(CENTERS)  # broken into many
    ids, tracks = slam.associate_detections(K, poses, dets, min_iou=0.99, merge=merge)
    # Both mugs (six semi-axes apart, seen together in every frame) stay two even at merge=20.
    assert len(tracks) == len(CENTERS)
    track_of = {}
    for i, order in zip(ids, truth):
        for j, k in zip(i, order):
            assert track_of.setdefault(int(k), int(j)) == int(j)
    for k, j in track_of.items():
        assert tracks[j]["class"] == CLASSES[k]
        assert tracks[j]["views"] == len(poses)
        assert np.linalg.norm(tracks[j]["center"] - CENTERS[k]) < 0.01


def test_no_track_is_joined_without_merge_and_a_bad_merge_is_named():
    poses, dets, _ = _broken_tracks()
    _, tracks = slam.associate_detections(K, poses, dets, min_iou=0.99)
    assert len(tracks) < len(CENTERS)  # most pieces below min_views
    for bad in (-1.0, float("nan"), "far"):
        with pytest.raises(ValueError, match="merge"):
            slam.associate_detections(K, poses, dets, merge=bad)
