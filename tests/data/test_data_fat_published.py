"""The FAT / NDDS conventions, checked on an annotation as NVIDIA's exporter writes it.

The object below is one object of an NDDS export (the exporter FAT was made with) as published
with its numbers: ``location``, ``quaternion_xyzw``, ``pose_transform``, ``cuboid_centroid``,
``bounding_box`` and six of its eight ``cuboid`` corners, in centimetres, in a 512 x 512 camera
with fx = fy = cx = cy = 256. The last two corners are completed by the parallelogram rule
(corner 6 = corner 5 + corner 2 - corner 1, corner 7 = corner 4 + corner 3 - corner 0).

What NVIDIA's Dataset_Utilities (``nvdu/core/cuboid.py``, ``Cuboid3d.generate_vertexes``) state
and these numbers confirm, independently of jaxsem's writer:

- corner order FrontTopRight, FrontTopLeft, FrontBottomLeft, FrontBottomRight, then the rear
  face, in the object frame x right, y down, z forward (OpenCV axes, right-handed); the corners
  are ``R(quaternion_xyzw) @ local + cuboid_centroid``;
- ``bounding_box`` ``top_left`` / ``bottom_right`` are ``[row, column]``;
- ``pose_transform`` is stored row-vector style (its transpose maps object to camera) and its
  axes are the exporter's own: its transpose is ``R @ [[0, 1, 0], [0, 0, -1], [1, 0, 0]]``.
"""

import json

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxsem.data import cuboid_corners, load_fat_annotations, load_fat_frame

N = 512
QUAT_XYZW = [0.075199998915195465, 0.89759999513626099, 0.40029999613761902, 0.16850000619888306]
CENTROID = [-3.901900053024292, -13.782299995422363, 267.12539672851562]
SIX_CORNERS = np.array(
    [
        [-19.205999374389648, -21.958599090576172, 207.91119384765625],
        [30.013900756835938, -36.213001251220703, 220.71449279785156],
        [30.013900756835938, 29.963399887084961, 294.39120483398438],
        [-19.205999374389648, 44.217800140380859, 281.587890625],
        [-37.817699432373047, -57.527999877929688, 239.85969543457031],
        [11.402199745178223, -71.782402038574219, 252.66299438476562],
    ]
)
CORNERS = np.vstack(
    [SIX_CORNERS, SIX_CORNERS[5] + SIX_CORNERS[2] - SIX_CORNERS[1], SIX_CORNERS[4] + SIX_CORNERS[3] - SIX_CORNERS[0]]
)
POSE_TRANSFORM = [
    [0.3628000020980835, 0.69330000877380371, -0.62269997596740723, 0],
    [-0.9319000244140625, 0.26989999413490295, -0.24240000545978546, 0],
    [0, -0.66820001602172852, -0.74400001764297485, 0],
    [-3.6275999546051025, 19.79640007019043, 303.45550537109375, 1],
]
BOX_YX = {"top_left": [190.71949768066406, 217.435302734375], "bottom_right": [294.18600463867188, 287.78350830078125]}
# full extents along the corner frame's x, y, z (cm): |c0 - c1|, |c3 - c0|, |c0 - c4|
DIMS_CM = [52.81771496, 99.03318365, 51.30579309]


def _write_scene(d, with_right=True, with_images=False):
    d.mkdir()
    intr = {"resX": N, "resY": N, "fx": 256, "fy": 256, "cx": 256, "cy": 256, "s": 0}
    cam = {"horizontal_fov": 90, "intrinsic_settings": intr, "captured_image_size": {"width": N, "height": N}}
    (d / "_camera_settings.json").write_text(
        json.dumps({"camera_settings": [dict(cam, name="left"), dict(cam, name="right")]})
    )
    objs = {
        "exported_object_classes": ["thing"],
        "exported_objects": [
            {
                "class": "thing",
                "segmentation_class_id": 3,
                "fixed_model_transform": np.eye(4).tolist(),
                "cuboid_dimensions": DIMS_CM,
            }
        ],
    }
    (d / "_object_settings.json").write_text(json.dumps(objs))
    ob = {
        "class": "thing",
        "instance_id": 15578836,
        "visibility": 1,
        "location": [-3.6275999546051025, 19.79640007019043, 303.45550537109375],
        "quaternion_xyzw": QUAT_XYZW,
        "pose_transform": POSE_TRANSFORM,
        "cuboid_centroid": CENTROID,
        "projected_cuboid_centroid": [252.26069641113281, 242.79170227050781],
        "bounding_box": BOX_YX,
        "cuboid": CORNERS.tolist(),
    }
    left = {"camera_data": {}, "objects": [ob]}
    (d / "000000.left.json").write_text(json.dumps(left))
    if with_right:
        shift = np.array([6.0, 0.0, 0.0])  # the right camera 6 cm along the left camera's x
        right_ob = dict(
            ob,
            location=(np.array(ob["location"]) - shift).tolist(),
            cuboid_centroid=(np.array(CENTROID) - shift).tolist(),
            cuboid=(CORNERS - shift).tolist(),
        )
        (d / "000000.right.json").write_text(json.dumps({"camera_data": {}, "objects": [right_ob]}))
    if with_images:
        for side in ("left", "right"):
            cv2.imwrite(str(d / f"000000.{side}.jpg"), np.zeros((N, N, 3), np.uint8))
            cv2.imwrite(str(d / f"000000.{side}.depth.png"), np.zeros((N, N), np.uint16))
            cv2.imwrite(str(d / f"000000.{side}.seg.png"), np.zeros((N, N), np.uint8))
    return d


def test_the_published_numbers_obey_the_stated_convention():
    """The fixture itself: nvdu's vertex rule with R(quaternion) rebuilds the exporter's corners."""
    R = Rotation.from_quat(QUAT_XYZW).as_matrix()
    signs = np.array(
        [[1, -1, 1], [-1, -1, 1], [-1, 1, 1], [1, 1, 1], [1, -1, -1], [-1, -1, -1], [-1, 1, -1], [1, 1, -1]]
    )
    rebuilt = (signs * np.array(DIMS_CM) / 2) @ R.T + np.array(CENTROID)
    assert np.abs(rebuilt - CORNERS).max() < 0.01  # cm
    P = np.array(POSE_TRANSFORM)[:3, :3]
    assert np.allclose(P.T, R @ np.array([[0, 1, 0], [0, 0, -1], [1, 0, 0]]), atol=1e-3)


@pytest.mark.parametrize("rotation_from", ["cuboid", "quaternion"])
def test_default_loader_accepts_the_exporters_annotation(tmp_path, rotation_from):
    scene = _write_scene(tmp_path / "scene", with_images=True)
    fr = load_fat_frame(scene, 0, rotation_from=rotation_from)
    R = fr.rotation[0]
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-9) and np.linalg.det(R) > 0
    assert np.allclose(R, Rotation.from_quat(QUAT_XYZW).as_matrix(), atol=2e-3)
    assert np.allclose(fr.center[0], np.array(CENTROID) / 100)
    assert np.allclose(fr.dimensions[0], np.array(DIMS_CM) / 100, atol=1e-4)
    # the corners rebuilt from the loaded pose are the file's, within 1 mm
    rebuilt = cuboid_corners(fr.rotation[0], fr.center[0], fr.dimensions[0])
    assert np.abs(rebuilt - CORNERS / 100).max() < 1e-3
    # bounding_box is [row, column]; ours is [u_min, v_min, u_max, v_max]
    assert np.allclose(fr.boxes_left[0], [217.435302734375, 190.71949768066406, 287.78350830078125, 294.18600463867188])


def test_annotations_without_images(tmp_path):
    scene = _write_scene(tmp_path / "scene")  # no image, depth or seg file
    (ann,) = load_fat_annotations(scene)
    assert ann.class_names == ("thing",)
    assert ann.K.shape == (3, 3) and ann.K[0, 0] == 256
    assert np.allclose(ann.rotation[0], Rotation.from_quat(QUAT_XYZW).as_matrix(), atol=2e-3)
    assert np.allclose(ann.center[0], np.array(CENTROID) / 100)
    assert np.allclose(ann.dimensions[0], np.array(DIMS_CM) / 100, atol=1e-4)
    assert ann.boxes_left.shape == (1, 4) and ann.has_right_box[0]
    # the right camera's own annotation: same orientation, centre 6 cm to the left in its frame
    assert ann.has_right[0]
    assert np.allclose(ann.rotation_right[0], ann.rotation[0], atol=1e-9)
    assert np.allclose(ann.center_right[0], ann.center[0] - [0.06, 0, 0])
    rebuilt = cuboid_corners(ann.rotation_right[0], ann.center_right[0], ann.dimensions[0])
    assert np.abs(rebuilt - (CORNERS - [6.0, 0, 0]) / 100).max() < 1e-3


def test_annotations_left_only_and_bad_corners(tmp_path):
    scene = _write_scene(tmp_path / "scene", with_right=False)
    (ann,) = load_fat_annotations(scene)
    assert not ann.has_right[0] and not ann.has_right_box[0]
    # a mirrored (left-handed) corner list is not the exporter's order: named, not silently flipped
    bad = json.loads((scene / "000000.left.json").read_text())
    bad["objects"][0]["cuboid"] = CORNERS[[1, 0, 3, 2, 5, 4, 7, 6]].tolist()
    (scene / "000000.left.json").write_text(json.dumps(bad))
    with pytest.raises(ValueError, match=r"000000\.left\.json.*corner order"):
        load_fat_annotations(scene)
