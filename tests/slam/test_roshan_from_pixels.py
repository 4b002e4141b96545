"""``jaxsem roshan --detector``: posed photos with no detection in them become a map, the
network's detections associated and lifted by the command (a stand-in network here: the shipped
one is exercised by the R-CNN tests)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from test_associate import CENTERS, CLASSES, K, _detections, _poses

from jaxsem._commands import roshan as roshan_command  # layers: white-box
from jaxsem.volumon import rcnn


def _write_posed_photos(folder, poses):
    """sequence.json with poses and images only; each image's first pixel is its frame number."""
    folder.mkdir()
    frames = []
    for t, P in enumerate(poses):
        name = f"{t:04d}.png"
        cv2.imwrite(str(folder / name), np.full((480, 640, 3), t, np.uint8))
        frames.append({"camera_T_world": P.tolist(), "image": name})
    seq = {"K": K.tolist(), "image_size": [640, 480], "frames": frames}
    (folder / "sequence.json").write_text(json.dumps(seq))


@pytest.fixture
def stand_in_detector(monkeypatch):
    poses = _poses()
    dets, _ = _detections(poses)
    monkeypatch.setattr(rcnn, "load_rcnn", lambda path=None: "stand-in")
    monkeypatch.setattr(rcnn, "detect_image", lambda loaded, image, K: dets[int(image[0, 0, 0])])
    return poses


@pytest.mark.slow
def test_posed_photos_become_a_map_of_every_object(tmp_path, stand_in_detector):
    _write_posed_photos(tmp_path / "desk", stand_in_detector)
    out = tmp_path / "out"
    code = roshan_command.main(
        [
            "--sequence",
            str(tmp_path / "desk"),
            "--detector",
            "lmo-rcnn",
            "--out",
            str(out),
            "--quiet",
            "--overlays",
            "0",
        ]
    )
    assert code == 0
    objects = json.loads((out / "map.json").read_text())["objects"]
    assert sorted(o["class"] for o in objects) == sorted(CLASSES)
    for o in objects:
        near = np.min(np.linalg.norm(CENTERS - np.asarray(o["center"]), axis=1))
        assert near < 0.03, o


def test_photos_without_images_are_refused_by_name(tmp_path, stand_in_detector):
    folder = tmp_path / "desk"
    _write_posed_photos(folder, stand_in_detector)
    seq = json.loads((folder / "sequence.json").read_text())
    del seq["frames"][2]["image"]
    (folder / "sequence.json").write_text(json.dumps(seq))
    with pytest.raises(ValueError, match=r"frames\[2\]\.image"):
        roshan_command.main(
            ["--sequence", str(folder), "--detector", "lmo-rcnn", "--out", str(tmp_path / "o"), "--quiet"]
        )


def test_a_detector_that_finds_nothing_is_reported(tmp_path, monkeypatch):
    poses = _poses(n=4)
    _write_posed_photos(tmp_path / "desk", poses)
    empty = {"box": np.zeros((0, 4)), "class_name": [], "score": np.zeros(0)}
    monkeypatch.setattr(rcnn, "load_rcnn", lambda path=None: "stand-in")
    monkeypatch.setattr(rcnn, "detect_image", lambda loaded, image, K: empty)
    with pytest.raises(ValueError, match="--detector"):
        roshan_command.main(
            ["--sequence", str(tmp_path / "desk"), "--detector", "lmo-rcnn", "--out", str(tmp_path / "o"), "--quiet"]
        )


@pytest.mark.parametrize(
    ("extra", "flag"),
    [(["--simulate", "orbit"], "--detector"), (["--sequence", "x", "--min-score", "2"], "--min-score")],
)
def test_detector_flags_are_checked_first(tmp_path, extra, flag, capsys):
    with pytest.raises(SystemExit):
        roshan_command.parse_args([*extra, "--detector", "lmo-rcnn", "--out", str(tmp_path / "o")])
    assert flag in capsys.readouterr().err
