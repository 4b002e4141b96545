"""Synthetic stereo dataset of textured household objects, written in the FAT layout.

Each scene directory (``<out_dir>/<split>/scene_NNN/``) has one compiled MuJoCo model holding one
instance of every class, with its own background, floor, lights and object textures; each frame
shows 1 to ``max_objects`` of them (the others are parked out of view) at random poses
0.4-1.5 m in front of a randomly placed and tilted camera, never occluding each other and never
cut by the image border (as the thesis filters FAT). Object sizes are the class size times a
small per-frame variation. Per frame the writer saves, as FAT does:

- ``XXXXXX.{left,right}.{jpg|png}`` RGB, ``XXXXXX.{left,right}.depth.png`` uint16 z-depth in
  units of 0.1 mm (0 = no depth: the skybox and anything beyond 6.5535 m),
  ``XXXXXX.{left,right}.seg.png`` uint8 with the class's ``segmentation_class_id`` (0 elsewhere),
- ``XXXXXX.{left,right}.json`` with FAT's fields in centimetres: ``location`` and
  ``cuboid_centroid`` (the object centre), ``quaternion_xyzw`` (object-to-camera rotation),
  ``cuboid`` / ``projected_cuboid`` (FAT's corner order), ``projected_cuboid_centroid``,
  ``bounding_box`` (exact amodal box of the projected object, stored ``[y, x]`` like FAT unless
  ``bbox_order='xy'``), ``visibility`` (1: nothing occludes the objects), and a ``shape`` field.
- ``_camera_settings.json`` (``fx == fy``, principal point ``((W-1)/2, (H-1)/2)``: exact for the
  renderer) and ``_object_settings.json`` (nominal ``cuboid_dimensions`` in cm, ``shape``).

Train and test splits draw backgrounds, lights, textures, poses and sizes from disjoint seed
streams (``split`` is part of every seed), so the test split shows unseen backgrounds.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
from collections.abc import Sequence

import numpy as np

from ... import classes as _classes, quadrics as Q
from ...data import FAT_BASELINE, SceneObject, SceneRenderer, fat_writer, right_T_left

__all__ = ["ObjectClass", "DEFAULT_CLASSES", "write_synthetic_dataset", "object_box", "synthetic_intrinsics"]


@dataclasses.dataclass(frozen=True)
class ObjectClass:
    """A class of objects: its rendered shape, nominal full extents (m) and colour.

    ``size_variation`` is the relative standard deviation of each instance's extents (clipped to
    2.5 sigma); a cylinder keeps its cross-section round.
    """

    name: str
    shape: str
    extents: tuple
    rgb: tuple
    segmentation_class_id: int
    size_variation: float = 0.03


def _from_table(name: str, segmentation_class_id: int) -> ObjectClass:
    """A class of :mod:`jaxsem.classes` (shape, full dimensions, colour) with its segmentation label."""
    c = _classes.get(name)
    shape = {"cuboid": "box"}.get(c.shape, c.shape)
    return ObjectClass(c.name, shape, tuple(c.dimensions), tuple(c.color), segmentation_class_id)


# From the one class table: the YCB cracker box of FAT (16.4036 x 21.3437 x 7.18 cm), the YCB
# tomato soup can (6.77 cm x 10.18 cm) and a slightly squashed 7 cm ball (distinct axes, so its
# orientation is defined).
DEFAULT_CLASSES = (
    _from_table("cracker_box", 40),
    _from_table("soup_can", 80),
    _from_table("ball", 120),
)

_SPLIT_STREAM = {"train": 0, "val": 1, "test": 2}


def synthetic_intrinsics(width: int, height: int, horizontal_fov_deg: float = 64.0) -> np.ndarray:
    """(3, 3) K with FAT's 64 degree horizontal field of view and a centred principal point."""
    f = 0.5 * width / math.tan(math.radians(horizontal_fov_deg) / 2)
    return np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])


# Host code in a per-object Python loop: the geometry core runs on numpy here (``xp=np``).
_EYE4 = np.eye(4)


def _project(K, pts):
    return Q.project_points(pts, K, _EYE4, xp=np)[0]


def object_box(shape: str, rotation, center, extents, K) -> np.ndarray:
    """Exact amodal image box ``[u_min, v_min, u_max, v_max]`` of a shape in the camera frame.

    Box: its 8 projected corners. Ellipsoid: the bounds of its dual conic (eq. 5.10). Cylinder:
    the bounds of its two rim ellipses' dual conics (:func:`jaxsem.quadrics.cylinder_bbox`).
    Requires the object entirely in front of the camera.
    """
    R, c, e = (np.asarray(a, np.float64) for a in (rotation, center, extents))
    if shape == "box":
        uv = _project(K, Q.cuboid_corners(R, c, e / 2, xp=np))
        return np.concatenate([uv.min(axis=0), uv.max(axis=0)])
    if shape == "ellipsoid":
        conic = Q.project_dual_conic(Q.dual_quadric(R, c, e / 2, xp=np), K, _EYE4, xp=np)
        return Q.conic_bbox(conic, xp=np)[0]
    if shape == "cylinder":
        return Q.cylinder_bbox(R, c, e / 2, K, _EYE4, xp=np)[0]
    raise ValueError(f"shape: expected 'box', 'cylinder' or 'ellipsoid', got {shape!r}")


def _random_rotation(rng) -> np.ndarray:
    return Q.quaternion_wxyz_to_rotation(rng.normal(size=4), xp=np)


def _camera_pose(rng) -> np.ndarray:
    """camera_T_world of a camera 0.5-1.4 m above the floor (z up), random yaw, tilted down."""
    h = rng.uniform(0.5, 1.4)
    yaw = rng.uniform(-np.pi, np.pi)
    pitch = np.radians(rng.uniform(10, 35))
    fwd = np.array([np.cos(yaw) * np.cos(pitch), np.sin(yaw) * np.cos(pitch), -np.sin(pitch)])
    eye = np.array([0.0, 0.0, h])
    return Q.look_at(eye, eye + fwd, xp=np)


def _boxes_overlap(a, b, margin=2.0) -> bool:
    return not (a[2] + margin < b[0] or b[2] + margin < a[0] or a[3] + margin < b[1] or b[3] + margin < a[1])


def _sample_frame(rng, classes, K, width, height, baseline, max_objects, depth_range, max_tries=60):
    """Poses for one frame; returns camera_T_world and a list of (class index, R_cam, c_cam, ext)."""
    T_rl = right_T_left(baseline)
    for _ in range(20):
        T = _camera_pose(rng)
        world_T_cam = Q.invert_pose(T, xp=np)
        k = int(rng.integers(1, max_objects + 1))
        chosen = rng.choice(len(classes), size=k, replace=False)
        placed = []
        for ci in chosen:
            cls = classes[ci]
            for _ in range(max_tries):
                scale = 1 + np.clip(rng.normal(size=3), -2.5, 2.5) * cls.size_variation
                if cls.shape == "cylinder":
                    scale[1] = scale[0]
                ext = np.asarray(cls.extents) * scale
                R = _random_rotation(rng)
                z = rng.uniform(*depth_range)
                u, v = rng.uniform(0.1, 0.9) * width, rng.uniform(0.1, 0.9) * height
                c = Q.back_project(np.array([u, v]), z, K, _EYE4, xp=np)
                half_diag = np.linalg.norm(ext) / 2
                if Q.transform_points(world_T_cam, c, xp=np)[2] - half_diag < 0.01:  # keep above the floor
                    continue
                bl = object_box(cls.shape, R, c, ext, K)
                br = object_box(cls.shape, R, c + T_rl[:3, 3], ext, K)
                inside = all(b[0] >= 1 and b[1] >= 1 and b[2] <= width - 2 and b[3] <= height - 2 for b in (bl, br))
                if not inside or c[2] - half_diag < 0.1:
                    continue
                if any(_boxes_overlap(bl, p[4]) or _boxes_overlap(br, p[5]) for p in placed):
                    continue
                placed.append((int(ci), R, c, ext, bl, br))
                break
        if placed:
            return T, placed
    raise RuntimeError("could not place any object in 20 camera poses; image too small for the classes?")


def write_synthetic_dataset(
    out_dir,
    num_frames: int,
    seed: int = 0,
    split: str = "train",
    image_size: tuple = (160, 120),
    *,
    frames_per_scene: int = 25,
    classes: Sequence[ObjectClass] = DEFAULT_CLASSES,
    max_objects: int = 3,
    depth_range: tuple = (0.4, 1.5),
    baseline: float = FAT_BASELINE,
    image_format: str = "jpg",
    bbox_order: str = "yx",
    progress: bool = True,
) -> list:
    """Render ``num_frames`` stereo frames into ``<out_dir>/<split>/scene_NNN/`` in the FAT layout.

    Args:
      out_dir: root directory (created).
      num_frames: total frames of this split, spread over scenes of ``frames_per_scene``.
      seed: dataset seed; with ``split`` it fixes every random choice (same arguments, same files).
      split: ``'train'``, ``'val'`` or ``'test'`` (disjoint seed streams: unseen backgrounds).
      image_size: ``(W, H)`` pixels; small by default for the CPU.
      frames_per_scene: frames sharing one background, lighting and set of object textures.
      classes: the :class:`ObjectClass` table (default: cracker box, soup can, ball).
      max_objects: at most this many objects per frame (at most one per class).
      depth_range: (min, max) metres of object centres in front of the camera.
      baseline: stereo baseline in metres (right camera at +x of the left one).
      image_format: ``'jpg'`` (as FAT; lossy) or ``'png'`` (exact).
      bbox_order: ``'yx'`` reproduces FAT's ``[y, x]`` box quirk; ``'xy'`` writes ``[x, y]``.
      progress: show a tqdm bar.

    Returns:
      List of the scene directories written (``pathlib.Path``).
    """
    fat_writer.check_split(split, _SPLIT_STREAM)
    num_frames, frames_per_scene, max_objects = int(num_frames), int(frames_per_scene), int(max_objects)
    if num_frames < 1 or frames_per_scene < 1:
        raise ValueError(f"num_frames, frames_per_scene: expected >= 1, got {num_frames}, {frames_per_scene}")
    if not 1 <= max_objects <= len(classes):
        raise ValueError(f"max_objects: expected 1..{len(classes)} (one per class), got {max_objects}")
    width, height = fat_writer.check_image_size(image_size)
    fat_writer.check_formats(image_format, bbox_order)
    ids = [c.segmentation_class_id for c in classes]
    if len(set(ids)) != len(ids) or not all(0 < i < 256 for i in ids):
        raise ValueError(f"classes: segmentation_class_id values must be distinct in 1..255, got {ids}")

    from tqdm.auto import tqdm  # deferred: tqdm.auto is slow to import and only the writer needs it

    K = synthetic_intrinsics(width, height)
    T_rl = right_T_left(baseline)
    root = pathlib.Path(out_dir) / split
    stream = _SPLIT_STREAM[split]
    num_scenes = -(-num_frames // frames_per_scene)
    scene_dirs = []
    bar = tqdm(total=num_frames, desc=f"synthetic {split}", disable=not progress, unit="frame")
    for s in range(num_scenes):
        rng = np.random.default_rng([int(seed), stream, s])
        scene_dir = root / f"scene_{s:03d}"
        scene_dir.mkdir(parents=True, exist_ok=True)
        scene_dirs.append(scene_dir)
        fat_writer.write_settings(scene_dir, classes, K, width, height)
        objects = [
            SceneObject(
                c.name,
                c.shape,
                np.asarray(c.extents),
                np.eye(3),
                np.array([0.0, 0.0, -1e4]),
                int(rng.integers(2**31)),
                np.asarray(c.rgb),
            )
            for c in classes
        ]
        n_here = min(frames_per_scene, num_frames - s * frames_per_scene)
        with SceneRenderer(
            objects,
            width,
            height,
            background_seed=int(rng.integers(2**31)),
            light_seed=int(rng.integers(2**31)),
            floor_z=0.0,
        ) as scene:
            for f in range(n_here):
                T, placed = _sample_frame(rng, classes, K, width, height, baseline, max_objects, depth_range)
                world_T_cam = Q.invert_pose(T, xp=np)
                world_R_cam = world_T_cam[:3, :3]
                shown = {p[0]: p for p in placed}
                for ci in range(len(classes)):
                    if ci in shown:
                        _, R, c, ext, _, _ = shown[ci]
                        scene.move_object(ci, world_R_cam @ R, Q.transform_points(world_T_cam, c, xp=np), ext)
                    else:
                        scene.move_object(ci, np.eye(3), np.zeros(3), hidden=True)
                stem = f"{f:06d}"
                for side, pose, offset in (("left", T, np.zeros(3)), ("right", T_rl @ T, T_rl[:3, 3])):
                    view = scene.render(K, pose)
                    seg = np.zeros(view["seg"].shape, np.uint8)
                    for ci in shown:
                        seg[view["seg"] == ci] = classes[ci].segmentation_class_id
                    frame = fat_writer.frame_json(placed, classes, K, pose, offset, bbox_order)
                    fat_writer.write_camera(
                        scene_dir / f"{stem}.{side}", image_format, view["rgb"], view["depth"], seg, frame
                    )
                bar.update(1)
    bar.close()
    return scene_dirs
