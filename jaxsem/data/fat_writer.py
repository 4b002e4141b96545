"""The Falling Things (FAT) layout, written: the pieces every FAT-layout writer shares (VoluMon's
synthetic, textured-object and desk writers, the door writer of :mod:`jaxsem.mapping`).

A scene directory holds ``_camera_settings.json`` and ``_object_settings.json``
(:func:`write_settings`) and per frame and camera ``<stem>.<left|right>.<jpg|png>``,
``.depth.png`` (uint16, 0.1 mm), ``.seg.png`` and ``.json`` (:func:`write_camera`,
:func:`frame_json`); :func:`partial_dir` writes a scene atomically. The reader is
:func:`jaxsem.data.load_fat_annotations` / :func:`jaxsem.data.load_fat_frame`.
"""

from __future__ import annotations

import contextlib
import json
import math
import pathlib
import shutil

import cv2
import numpy as np

from .. import classes as _classes, quadrics as Q
from ._fat import cuboid_corners

_EYE4 = np.eye(4)


def _project(K, pts):
    return Q.project_points(pts, K, _EYE4, xp=np)[0]


def _quat_xyzw(R) -> list:
    return [float(x) for x in Q.rotation_to_quaternion_xyzw(R, xp=np)]


def _bbox_json(box, bbox_order):
    tl, br = [box[0], box[1]], [box[2], box[3]]
    if bbox_order == "yx":
        tl, br = tl[::-1], br[::-1]
    return {"top_left": [float(x) for x in tl], "bottom_right": [float(x) for x in br]}


def frame_json(placed, classes, K, camera_T_world, offset, bbox_order):
    """FAT frame JSON for one camera; ``offset`` (3,) moves left-camera points into this camera."""
    world_T_cam = Q.invert_pose(camera_T_world, xp=np)
    eye = world_T_cam[:3, 3]
    objs = []
    for ci, R, c, ext, bl, br in placed:
        cls = classes[ci]
        cc = c + offset
        box = bl if not offset.any() else br
        corners = cuboid_corners(R, cc, ext)
        objs.append(
            {
                "class": cls.name,
                "instance_id": int(cls.segmentation_class_id),
                "visibility": 1.0,
                "location": (cc * 100).tolist(),
                "quaternion_xyzw": _quat_xyzw(R),
                "cuboid_centroid": (cc * 100).tolist(),
                "projected_cuboid_centroid": _project(K, cc[None])[0].tolist(),
                "bounding_box": _bbox_json(box, bbox_order),
                "cuboid": (corners * 100).tolist(),
                "projected_cuboid": _project(K, corners).tolist(),
                "shape": cls.shape,
                "dimensions": (ext * 100).tolist(),
            }
        )
    return {
        "camera_data": {
            "location_worldframe": (eye * 100).tolist(),
            "quaternion_xyzw_worldframe": _quat_xyzw(world_T_cam[:3, :3]),
        },
        "objects": objs,
    }


def _write_image(path, array):
    """``cv2.imwrite`` that raises ``OSError`` naming the file instead of returning False."""
    if not cv2.imwrite(str(path), array):
        raise OSError(f"could not write {path}")


@contextlib.contextmanager
def partial_dir(final: pathlib.Path):
    """Yields an empty ``<final>.partial`` directory to write a scene into; on success it replaces
    ``final``, on an exception it is removed: a failed or killed writer leaves no half scene."""
    tmp = final.with_name(final.name + ".partial")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if final.exists():
        shutil.rmtree(final)
    tmp.rename(final)


def check_image_size(image_size) -> tuple:
    """``(W, H)`` of a writer's ``image_size`` (``ValueError`` below 32 px a side)."""
    width, height = (int(x) for x in image_size)
    if width < 32 or height < 32:
        raise ValueError(f"image_size: expected (W, H) of at least 32 px each, got {image_size}")
    return width, height


def check_split(split: str, splits) -> str:
    """``split`` when it is one of ``splits`` (a writer's split names); ``ValueError`` listing
    them otherwise."""
    if split not in splits:
        raise ValueError(f"split: expected one of {tuple(splits)}, got {split!r}")
    return split


def check_scenes(num_scenes, frames_per_scene) -> tuple:
    """``(num_scenes, frames_per_scene)`` as ints, each at least 1 (``ValueError`` naming it)."""
    num_scenes, frames_per_scene = int(num_scenes), int(frames_per_scene)
    if num_scenes < 1:
        raise ValueError(f"num_scenes: expected >= 1, got {num_scenes}")
    if frames_per_scene < 1:
        raise ValueError(f"frames_per_scene: expected >= 1, got {frames_per_scene}")
    return num_scenes, frames_per_scene


def check_formats(image_format, bbox_order):
    """The output options every FAT-layout writer takes (``ValueError`` naming the argument)."""
    if image_format not in ("jpg", "png"):
        raise ValueError(f"image_format: expected 'jpg' or 'png', got {image_format!r}")
    if bbox_order not in ("yx", "xy"):
        raise ValueError(f"bbox_order: expected 'yx' or 'xy', got {bbox_order!r}")


def write_camera(base, image_format, rgb, depth, seg, frame):
    """One camera's files of a frame in the FAT layout (module docstring), the one encoding of the
    writers of :mod:`jaxsem.volumon.data`: ``<base>.<image_format>`` from RGB ``rgb`` (H, W, 3) uint8,
    ``<base>.depth.png`` from ``depth`` (H, W) metres as uint16 0.1 mm (0 beyond 6.5535 m),
    ``<base>.seg.png`` the uint8 labels ``seg``, ``<base>.json`` the dict ``frame``."""
    _write_image(f"{base}.{image_format}", rgb[..., ::-1])
    depth = np.round(depth.astype(np.float64) / 1e-4)
    _write_image(f"{base}.depth.png", np.where(depth > 65535, 0, depth).astype(np.uint16))
    _write_image(f"{base}.seg.png", seg)
    with open(f"{base}.json", "w") as fh:
        json.dump(frame, fh)


def write_settings(scene_dir, classes, K, width, height):
    intr = {
        "resX": width,
        "resY": height,
        "fx": float(K[0, 0]),
        "fy": float(K[1, 1]),
        "cx": float(K[0, 2]),
        "cy": float(K[1, 2]),
        "s": 0.0,
    }
    hfov = math.degrees(2 * math.atan(0.5 * width / K[0, 0]))
    cams = {
        "camera_settings": [
            {
                "name": name,
                "horizontal_fov": hfov,
                "intrinsic_settings": intr,
                "captured_image_size": {"width": width, "height": height},
            }
            for name in ("left", "right")
        ]
    }
    objs = {
        "exported_object_classes": [c.name for c in classes],
        "exported_objects": [
            {
                "class": c.name,
                "segmentation_class_id": int(c.segmentation_class_id),
                "segmentation_instance_id": int(c.segmentation_class_id),
                "fixed_model_transform": np.eye(4).tolist(),
                "cuboid_dimensions": [float(x) * 100 for x in c.extents],
                "shape": c.shape,
            }
            for c in classes
        ],
    }
    with open(scene_dir / "_camera_settings.json", "w") as fh:
        json.dump(cams, fh, indent=1)
    with open(scene_dir / "_object_settings.json", "w") as fh:
        json.dump(objs, fh, indent=1)


def segmentation_id(name: str) -> int:
    return 12 * (_classes.index(name) + 1)
