"""FAT loader on a hand-made sample in the real layout (written here, independently of the writer)."""

import json
import pathlib

import cv2
import numpy as np
import pytest

from jaxsem.data import FatFormatError, load_fat_frame, load_fat_scene

W, H = 96, 64
FX, CX, CY = 76.816, 48.0, 32.0
DIMS_CM = np.array([16.4036, 21.3437, 7.18])
SEG_ID = 12
# FAT's corner order (FrontTopRight, FrontTopLeft, FrontBottomLeft, FrontBottomRight, then rear)
# in an object frame with x right, y down, z out of the front.
SIGNS = np.array([[1, -1, 1], [-1, -1, 1], [-1, 1, 1], [1, 1, 1], [1, -1, -1], [-1, -1, -1], [-1, 1, -1], [1, 1, -1]])


def _rot(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


R_TRUE = _rot([0.3, -0.5, 0.8], 0.9)  # object-to-camera, z = the axis of 7.18 cm
CENTER_CM = np.array([4.0, -3.0, 80.0])


def _quat_xyzw(R):
    w = np.sqrt(1 + np.trace(R)) / 2
    return [(R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w), w]


def _object(center_cm, box_uv):
    # NVIDIA's Dataset_Utilities: corners = R(quaternion) @ (signs * dims / 2) + centroid, the
    # object frame x right, y down, z forward (right-handed; see test_data_fat_published.py)
    corners = center_cm + (SIGNS * DIMS_CM / 2) @ R_TRUE.T
    u0, v0, u1, v1 = box_uv
    return {
        "class": "003_cracker_box_16k",
        "visibility": 0.93,
        "location": (center_cm + np.array([1.0, 2.0, 3.0])).tolist(),  # mesh origin != centroid
        "quaternion_xyzw": _quat_xyzw(R_TRUE),
        "pose_transform_permuted": np.eye(4).tolist(),
        "cuboid_centroid": center_cm.tolist(),
        "projected_cuboid_centroid": [0, 0],
        "bounding_box": {"top_left": [v0, u0], "bottom_right": [v1, u1]},  # [y, x]
        "cuboid": corners.tolist(),
        "projected_cuboid": np.zeros((8, 2)).tolist(),
    }


@pytest.fixture()
def scene(tmp_path):
    d = tmp_path / "kitchen_0"
    d.mkdir()
    intr = {"resX": W, "resY": H, "fx": FX, "fy": FX, "cx": CX, "cy": CY, "s": 0}
    cams = {
        "camera_settings": [
            {
                "name": n,
                "horizontal_fov": 64,
                "intrinsic_settings": intr,
                "captured_image_size": {"width": W, "height": H},
            }
            for n in ("left", "right")
        ]
    }
    (d / "_camera_settings.json").write_text(json.dumps(cams))
    objs = {
        "exported_object_classes": ["003_cracker_box_16k"],
        "exported_objects": [
            {
                "class": "003_cracker_box_16k",
                "segmentation_class_id": SEG_ID,
                "fixed_model_transform": np.eye(4).tolist(),
                "cuboid_dimensions": DIMS_CM.tolist(),
            }
        ],
    }
    (d / "_object_settings.json").write_text(json.dumps(objs))
    for stem, shift in (("000000", 0.0), ("000001", 1.0)):
        left = {
            "camera_data": {"location_worldframe": [0, 0, 0], "quaternion_xyzw_worldframe": [0, 0, 0, 1]},
            "objects": [_object(CENTER_CM + shift, (10 + shift, 20, 40, 50))],
        }
        right = {
            "camera_data": left["camera_data"],
            "objects": [_object(CENTER_CM + shift - np.array([6.0, 0, 0]), (4 + shift, 20, 34, 50))],
        }
        (d / f"{stem}.left.json").write_text(json.dumps(left))
        (d / f"{stem}.right.json").write_text(json.dumps(right))
        img = np.zeros((H, W, 3), np.uint8)
        img[..., 2] = 200  # BGR on disk: red
        for side in ("left", "right"):
            cv2.imwrite(str(d / f"{stem}.{side}.jpg"), img)
            depth = np.zeros((H, W), np.uint16)
            depth[20:50, 10:40] = 8000
            depth[0, 0] = 12345
            cv2.imwrite(str(d / f"{stem}.{side}.depth.png"), depth)
            seg = np.zeros((H, W), np.uint8)
            seg[20:50, 10:40] = SEG_ID
            seg[0:3, 90:] = 7  # a label of no exported object
            cv2.imwrite(str(d / f"{stem}.{side}.seg.png"), seg)
    return d


def test_units_axes_and_conventions(scene):
    seq = load_fat_scene(scene, load_right_image=True)
    assert len(seq) == 2 and seq.stems == ("000000", "000001")
    np.testing.assert_allclose(seq.K, [[FX, 0, CX], [0, FX, CY], [0, 0, 1]])
    fr = seq[0]
    assert fr.image.shape == (H, W, 3) and fr.image.dtype == np.uint8
    assert fr.image[5, 5, 0] > 180 and fr.image[5, 5, 2] < 30  # RGB order
    assert fr.right_image is not None
    # Depth: uint16 in 0.1 mm -> metres.
    assert fr.depth.dtype == np.float32
    assert fr.depth[0, 0] == pytest.approx(1.2345, abs=1e-6)
    assert fr.depth[30, 20] == pytest.approx(0.8, abs=1e-6)
    # Segmentation: the object's class id -> its index; other labels -> -1.
    assert fr.seg.dtype == np.int32 and fr.seg[30, 20] == 0 and fr.seg[0, 0] == -1 and fr.seg[1, 95] == -1
    assert fr.class_names == ("003_cracker_box_16k",)
    # Boxes stored [y, x] -> [u_min, v_min, u_max, v_max].
    np.testing.assert_allclose(fr.boxes_left, [[10, 20, 40, 50]])
    np.testing.assert_allclose(fr.boxes_right, [[4, 20, 34, 50]])
    assert fr.has_right_box.tolist() == [True]
    # Centre is the cuboid centroid in metres (not the mesh origin 'location').
    np.testing.assert_allclose(fr.center, [CENTER_CM / 100], atol=1e-12)
    np.testing.assert_allclose(fr.dimensions, [DIMS_CM / 100], atol=1e-9)
    np.testing.assert_allclose(fr.rotation[0], R_TRUE, atol=1e-9)
    assert np.linalg.det(fr.rotation[0]) == pytest.approx(1.0)
    assert fr.visibility.tolist() == [0.93]
    # Stereo: the right camera is 6 cm along +x; the right JSON's object is at x - 6 cm.
    assert fr.baseline == 0.06
    x_right = fr.right_T_left @ np.append(fr.center[0], 1.0)
    np.testing.assert_allclose(x_right[:3], (CENTER_CM - [6.0, 0, 0]) / 100, atol=1e-12)
    np.testing.assert_allclose(seq[1].center, [(CENTER_CM + 1) / 100])
    assert load_fat_frame(scene, "000001").boxes_left[0, 0] == 11


def test_options(scene):
    fr = load_fat_frame(scene, 0, bbox_order="xy")
    np.testing.assert_allclose(fr.boxes_left, [[20, 10, 50, 40]])
    fr = load_fat_frame(scene, 0, rotation_from="quaternion")
    np.testing.assert_allclose(fr.rotation[0], R_TRUE, atol=1e-9)
    np.testing.assert_allclose(fr.dimensions[0], DIMS_CM / 100)
    P = np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0]], float)
    fr = load_fat_frame(scene, 0, rotation_from="quaternion", quaternion_axes=P)
    np.testing.assert_allclose(fr.rotation[0], R_TRUE @ P, atol=1e-9)
    fr = load_fat_frame(scene, 0, depth_scale=1e-3, baseline=0.1)
    assert fr.depth[30, 20] == pytest.approx(8.0) and fr.right_T_left[0, 3] == -0.1
    with pytest.raises(ValueError, match="bbox_order"):
        load_fat_scene(scene, bbox_order="uv")
    with pytest.raises(ValueError, match="rotation_from"):
        load_fat_scene(scene, rotation_from="euler")


@pytest.mark.parametrize(
    "name, action, error",
    [
        ("000000.left.depth.png", "delete", FileNotFoundError),
        ("000000.left.seg.png", "garbage", FatFormatError),
        ("000000.left.jpg", "garbage", FatFormatError),
        ("000000.right.json", "garbage", FatFormatError),
        ("000000.left.depth.png", "uint8", FatFormatError),
        ("_camera_settings.json", "delete", FileNotFoundError),
        ("_object_settings.json", "garbage", FatFormatError),
    ],
)
def test_missing_or_corrupt_file_names_its_path(scene, name, action, error):
    path = scene / name
    if action == "delete":
        path.unlink()
    elif action == "garbage":
        path.write_bytes(b"\x00\x01 not what it claims {")
    else:
        cv2.imwrite(str(path), np.zeros((H, W), np.uint8))
    with pytest.raises(error) as info:
        load_fat_scene(scene)[0]
    assert str(path) in str(info.value)


def test_malformed_fields_name_the_file(scene):
    path = scene / "000000.left.json"
    data = json.loads(path.read_text())
    del data["objects"][0]["bounding_box"]
    path.write_text(json.dumps(data))
    with pytest.raises(FatFormatError, match="bounding_box") as info:
        load_fat_frame(scene, 0)
    assert str(path) in str(info.value)
    data["objects"][0]["bounding_box"] = {"top_left": [0, 0], "bottom_right": [0, "x"]}
    path.write_text(json.dumps(data))
    with pytest.raises(FatFormatError, match=str(pathlib.Path(path).name)):
        load_fat_frame(scene, 0)
    with pytest.raises(FileNotFoundError, match="nowhere"):
        load_fat_scene(scene / "nowhere")
