"""TUM RGB-D folders + a detections JSON-lines file -> ROSHAN's Sequence: images paired with the
nearest pose in time, poses inverted into camera_T_world, bad lines named by file, line and field."""

import json

import numpy as np
import pytest

from jaxsem import quadrics as q, slam
from jaxsem.slam._tum import TUM_INTRINSICS  # layers: white-box


def _folder(tmp_path, gt_lines=None):
    root = tmp_path / "rgbd_dataset_freiburg1_desk"
    root.mkdir()
    (root / "rgb.txt").write_text(
        "# color images\n# file: 'x'\n10.000 rgb/10.000.png\n10.033 rgb/10.033.png\n11.000 rgb/11.000.png\n"
    )
    # Camera at (1, 2, 3) looking along +z of the world at 10.00, turned 90 deg about z at 10.04.
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    gt = gt_lines or ["# ground truth", "10.004 1 2 3 0 0 0 1", f"10.040 1 2 3 0 0 {s} {c}"]
    (root / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    return root


def _detections(tmp_path, lines):
    path = tmp_path / "dets.jsonl"
    path.write_text("\n".join(json.dumps(x) if not isinstance(x, str) else x for x in lines) + "\n")
    return path


DET = {"box": [100, 100, 200, 220], "class": "cereal_box", "score": 0.9, "id": 3}


def test_frames_pair_with_the_nearest_pose_and_poses_invert(tmp_path):
    root = _folder(tmp_path)
    dets = _detections(
        tmp_path,
        [
            {"frame": "rgb/10.033.png", "detections": [DET, {**DET, "id": 4, "score": 0.1}]},
            {"timestamp": 10.0001, "detections": [DET]},
            {"frame": "rgb/11.000.png", "detections": [DET]},  # no pose within 0.02 s: skipped
        ],
    )
    seq = slam.load_tum_sequence(root, dets, min_score=0.5)
    assert [f.image for f in seq.frames] == ["rgb/10.000.png", "rgb/10.033.png"]  # time order
    first, second = seq.frames
    # camera_T_world maps the camera centre to the origin of the camera frame.
    centre = np.array([1.0, 2.0, 3.0])
    for frame in (first, second):
        np.testing.assert_allclose(np.asarray(q.transform_points(frame.camera_T_world, centre)), 0, atol=1e-9)
    np.testing.assert_allclose(first.camera_T_world[:3, :3], np.eye(3), atol=1e-12)
    # The second pose is turned 90 deg about z: the world x axis is the camera's -y.
    np.testing.assert_allclose(second.camera_T_world[:3, :3] @ [1.0, 0, 0], [0, -1, 0], atol=1e-9)
    assert second.ids == (3,)  # the 0.1-score detection dropped
    assert np.all(np.isnan(first.texture_depth))
    np.testing.assert_allclose(seq.K[0, 0], TUM_INTRINSICS["freiburg1"][0])
    assert seq.object_ids == (3,) and seq.object_classes == ("cereal_box",)


@pytest.mark.parametrize(
    ("line", "words"),
    [
        ("{ broken", ["line 1", "JSON"]),
        ({"frame": "rgb/nope.png", "detections": []}, ["line 1", "frame", "nope.png"]),
        (
            {"frame": "rgb/10.000.png", "detections": [{**DET, "class": "spaceship"}]},
            ["detections[0].class", "spaceship"],
        ),
        ({"frame": "rgb/10.000.png", "detections": [{"box": DET["box"], "class": "cup_x"}]}, ["detections[0]"]),
        (
            {"frame": "rgb/10.000.png", "detections": [{k: v for k, v in DET.items() if k != "id"}]},
            ["detections[0].id"],
        ),
        ({"frame": "rgb/10.000.png", "detections": [{**DET, "box": [0, 0, 1e9, 1e9]}]}, ["detections[0].box"]),
        ({"frame": "rgb/11.000.png", "detections": [DET]}, ["no frame with both a pose"]),
        ({"frame": "rgb/10.000.png", "detections": [{**DET, "score": "high"}]}, ["detections[0].score"]),
    ],
    ids=["json", "frame", "class", "class-unknown", "no-id", "huge-box", "no-pose", "score"],
)
def test_bad_detection_lines_are_named(tmp_path, line, words):
    root = _folder(tmp_path)
    with pytest.raises(ValueError) as info:
        slam.load_tum_sequence(root, _detections(tmp_path, [line]))
    assert "dets.jsonl" in str(info.value)
    for word in words:
        assert word in str(info.value)


def test_bad_ground_truth_and_camera(tmp_path):
    root = _folder(tmp_path, ["10.004 1 2 3 0 0 0"])
    with pytest.raises(ValueError, match=r"groundtruth.txt: line 1: expected 8 fields"):
        slam.load_tum_sequence(root, _detections(tmp_path, [{"frame": "rgb/10.000.png", "detections": [DET]}]))
    other = tmp_path / "my_scan"
    other.mkdir()
    with pytest.raises(ValueError, match="K: my_scan"):
        slam.load_tum_sequence(other, tmp_path / "dets.jsonl")


def test_ground_truth_with_a_word_for_a_number_is_named(tmp_path):
    # Was "could not convert string to float: 'a'", naming neither the file nor the line.
    root = _folder(tmp_path, ["# ground truth", "10.004 1 2 3 0 0 0 1", "10.040 1 a 3 0 0 0 1"])
    with pytest.raises(ValueError, match=r"groundtruth\.txt: line 3: field 3 'a' is not a number"):
        slam.load_tum_sequence(root, _detections(tmp_path, [{"frame": "rgb/10.000.png", "detections": [DET]}]))


def test_roshan_command_needs_detections_with_tum(tmp_path, run_cli):
    root = _folder(tmp_path)
    status, _, err = run_cli(["roshan", "--tum", str(root), "--out", str(tmp_path / "o")])
    assert status != 0 and "Traceback" not in err
    assert "--detections" in [line for line in err.splitlines() if line.strip()][-1]


@pytest.mark.slow
def test_roshan_command_on_a_tum_folder(tmp_path, run_cli):
    cv2 = pytest.importorskip("cv2")
    root = _folder(tmp_path)
    (root / "rgb").mkdir()
    for name in ("10.000", "10.033"):
        cv2.imwrite(str(root / "rgb" / f"{name}.png"), np.full((480, 640, 3), 128, np.uint8))
    dets = _detections(
        tmp_path,
        [{"frame": f"rgb/{n}.png", "detections": [DET]} for n in ("10.000", "10.033")],
    )
    status, out, err = run_cli(
        ["roshan", "--tum", str(root), "--detections", str(dets), "--out", str(tmp_path / "o"), "--quiet"]
    )
    assert status == 0, err[-2000:]
    result = json.loads((tmp_path / "o" / "map.json").read_text())
    assert [o["class"] for o in result["objects"]] == ["cereal_box"]
