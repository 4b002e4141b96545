"""Loader for the Falling Things (FAT) on-disk layout; the synthetic writer uses the same layout.

A scene directory holds ``_camera_settings.json``, ``_object_settings.json`` and, per frame
``XXXXXX``, the files ``XXXXXX.{left,right}.{jpg,json,seg.png,depth.png}``. The loader returns
arrays in jaxsem conventions (metres, OpenCV camera axes, boxes ``[u_min, v_min, u_max, v_max]``,
rotations object-to-camera). FAT's per-object poses are taken to be in the left camera's frame
with OpenCV axes (x right, y down, z forward), as DOPE's PnP uses them. The layout's quirks, each
a documented option:

- Depth PNGs are uint16 in units of 0.1 mm: metres = value * ``depth_scale`` (1e-4). 0 = no depth.
- Lengths in the JSON (``location``, ``cuboid_centroid``, ``cuboid``, ``cuboid_dimensions``) are in
  centimetres: metres = value * ``length_scale`` (0.01).
- ``bounding_box.top_left`` / ``bottom_right`` are stored ``[y, x]`` (row, column) by FAT's
  exporter: ``bbox_order='yx'`` (default) swaps them; ``'xy'`` reads them as they are.
- Stereo: the right camera sits ``baseline`` (0.06 m) to the right of the left one, i.e. at
  ``+baseline`` along the left camera's x axis, with the same orientation and intrinsics. A point
  ``X_left`` in the left camera frame is ``X_left - [baseline, 0, 0]`` in the right one, so
  ``right_T_left = [[I, (-baseline, 0, 0)], [0, 1]]``.
- Object pose: ``center`` is the cuboid centroid (``cuboid_centroid``, else the mean of the 8
  ``cuboid`` corners), not ``location`` (the mesh origin, which for YCB models is not the box
  centre). ``rotation_from='cuboid'`` (default) reads the rotation and the three extents off the
  8 exported cuboid corners. Their order and frame are those of NVIDIA's Dataset_Utilities
  (``nvdu/core/cuboid.py``, ``Cuboid3d.generate_vertexes``): FrontTopRight, FrontTopLeft,
  FrontBottomLeft, FrontBottomRight, then the same four on the rear face, in the object frame
  x right, y down, z forward (OpenCV axes, right-handed), so x = c0 - c1, y = c3 - c0, z = c0 - c4
  and the corners are ``R(quaternion_xyzw) @ local + cuboid_centroid``. Checked on an object of a
  published NDDS export (``tests/data/test_data_fat_published.py``): that frame is proper and equals
  ``R(quaternion_xyzw)`` to 1e-4, the corners rebuilt from it are the file's within 0.1 mm, and
  ``pose_transform`` (stored row-vector style) is ``(R @ [[0, 1, 0], [0, 0, -1], [1, 0, 0]])^T``,
  the exporter's own axes; this loader does not use it. A mirrored corner list (left-handed
  frame) is refused naming the file. ``rotation_from='quaternion'`` instead returns
  ``R(quaternion_xyzw) @ quaternion_axes`` (``quaternion_axes`` (3, 3), default identity, which is
  the exporter's convention) with the extents of ``_object_settings.json``.
- :func:`load_fat_annotations` reads the labels of every frame without opening an image.

Missing files raise ``FileNotFoundError`` and unreadable or malformed ones raise
:class:`FatFormatError` (a ``ValueError``), both naming the file's path.
"""

from __future__ import annotations

import dataclasses
import json
import os
import pathlib
import re
from collections.abc import Iterator, Sequence
from typing import Any, overload

import cv2
import numpy as np

from .. import quadrics as Q
from .._files import read_image

__all__ = [
    "FatAnnotation",
    "FatFormatError",
    "FatFrame",
    "FatSequence",
    "load_fat_annotations",
    "load_fat_frame",
    "load_fat_scene",
    "FAT_BASELINE",
    "FAT_DEPTH_SCALE",
    "FAT_LENGTH_SCALE",
    "right_T_left",
    "cuboid_corners",
]

FAT_BASELINE = 0.06  # metres between the left and right cameras
FAT_DEPTH_SCALE = 1e-4  # metres per depth-PNG unit (0.1 mm)
FAT_LENGTH_SCALE = 0.01  # metres per JSON length unit (cm)

_FRAME_RE = re.compile(r"^(\d+)\.left\.json$")


class FatFormatError(ValueError):
    """A FAT-layout file exists but cannot be read or does not hold what the layout promises."""


def cuboid_corners(rotation, center, dimensions) -> np.ndarray:
    """(..., 8, 3) cuboid corners in FAT's order for a pose and full extents (x, y, z).

    ``rotation`` (..., 3, 3) maps the object frame (x right, y down, z forward) to the camera:
    the corners are :func:`jaxsem.quadrics.cuboid_corners` (the exporter's order, evaluated by numpy).
    """
    half = np.asarray(dimensions, np.float64) / 2
    return Q.cuboid_corners(np.asarray(rotation, np.float64), center, half, xp=np)


def right_T_left(baseline: float = FAT_BASELINE) -> np.ndarray:
    """(4, 4) transform from the left camera frame to the right one (right camera at +x)."""
    return np.asarray(Q.stereo_right_T_left(float(baseline), np.float64))


@dataclasses.dataclass(frozen=True)
class _FatLabels:
    """The labels of one stereo frame that both :class:`FatAnnotation` and :class:`FatFrame` hold
    (each documents them); a frame carries these of its annotation."""

    path: pathlib.Path
    K: np.ndarray
    baseline: float
    right_T_left: np.ndarray
    class_names: tuple
    boxes_left: np.ndarray
    boxes_right: np.ndarray
    has_right_box: np.ndarray
    rotation: np.ndarray
    center: np.ndarray
    dimensions: np.ndarray
    visibility: np.ndarray

    @property
    def num_objects(self) -> int:
        return len(self.class_names)


@dataclasses.dataclass(frozen=True)
class FatAnnotation(_FatLabels):
    """The labels of one stereo frame (no images). ``n`` objects, jaxsem conventions.

    Attributes:
      path: the left JSON file; K: (3, 3) intrinsics of both cameras; ``baseline`` metres;
        ``right_T_left`` (4, 4).
      class_names: n class names.
      boxes_left, boxes_right: (n, 4) ``[u_min, v_min, u_max, v_max]`` pixels (``has_right_box``
        False and zeros where the right JSON lacks the object).
      rotation: (n, 3, 3) object-to-left-camera; center: (n, 3) cuboid centre (m) in the left
        camera frame; dimensions: (n, 3) full extents along the rotation's axes (m).
      has_right: (n,) bool, the right JSON annotates the object; then ``rotation_right`` (n, 3, 3)
        and ``center_right`` (n, 3) are its pose in the right camera frame (identity / zeros else).
      visibility: (n,) the exporter's visible fraction (1 where absent).
    """

    has_right: np.ndarray
    rotation_right: np.ndarray
    center_right: np.ndarray


@dataclasses.dataclass(frozen=True)
class FatFrame(_FatLabels):
    """One stereo frame in jaxsem conventions. ``n`` objects, image ``H x W``.

    Attributes:
      path: the left JSON file this frame was read from.
      image: (H, W, 3) uint8 RGB left image; ``right_image`` the same or ``None`` if not loaded.
      depth: (H, W) float32 left depth in metres (z-depth), 0 where unknown.
      seg: (H, W) int32 index of the object (into the per-object arrays) or -1.
      K: (3, 3) float64 intrinsics of both cameras; ``baseline`` metres; ``right_T_left`` (4, 4).
      class_names: n class names; ``segmentation_ids`` (n,) int the labels of the seg PNG.
      boxes_left, boxes_right: (n, 4) ``[u_min, v_min, u_max, v_max]`` pixels (NaN-free; a box
        missing from the right JSON is ``[0, 0, 0, 0]`` with ``has_right_box`` False).
      rotation: (n, 3, 3) object-to-left-camera; center: (n, 3) cuboid centre in the left camera
        frame (m); dimensions: (n, 3) full cuboid extents along the rotation's axes (m).
      visibility: (n,) float, the exporter's visible fraction (1 where absent).
      extra: per-object dicts of fields this loader does not interpret (e.g. a synthetic
        ``shape``), from ``_object_settings.json``.
    """

    image: np.ndarray
    right_image: np.ndarray | None
    depth: np.ndarray
    seg: np.ndarray
    segmentation_ids: np.ndarray
    extra: tuple = ()


_LABEL_FIELDS = tuple(f.name for f in dataclasses.fields(_FatLabels))


def _read_json(path: pathlib.Path) -> dict:
    if not path.is_file():
        raise FileNotFoundError(f"FAT file missing: {path}")
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FatFormatError(f"{path}: not valid JSON ({exc})") from None


def _read_image(path: pathlib.Path, flags: int) -> np.ndarray:
    """An image's pixels, its header's size checked against the default pixel budget first."""
    if not path.is_file():
        raise FileNotFoundError(f"FAT file missing: {path}")
    try:
        return read_image(path, flags)
    except ValueError as exc:
        raise FatFormatError(str(exc)) from None


def _get(d: dict, key: str, path, what: str = "field"):
    try:
        return d[key]
    except (KeyError, TypeError):
        raise FatFormatError(f"{path}: missing {what} {key!r}") from None


def _array(value, shape, path, name) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise FatFormatError(f"{path}: {name} is not numeric: {value!r}") from None
    if arr.shape != tuple(shape) or not np.all(np.isfinite(arr)):
        raise FatFormatError(f"{path}: {name} expected {tuple(shape)} finite numbers, got {arr.tolist()}")
    return arr


def _pose_from_cuboid(corners: np.ndarray, path) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (proper, nearest by SVD) and full extents from 8 corners in FAT's order."""
    axes = np.stack(
        [
            corners[[0, 3, 7, 4]] - corners[[1, 2, 6, 5]],  # right minus left: x
            corners[[3, 2, 6, 7]] - corners[[0, 1, 5, 4]],  # bottom minus top: y
            corners[[0, 1, 2, 3]] - corners[[4, 5, 6, 7]],  # front minus rear: z
        ],
        axis=-1,
    ).mean(axis=0)  # (3, 3): columns are the edge vectors
    dims = np.linalg.norm(axes, axis=0)
    if np.any(dims <= 0):
        raise FatFormatError(f"{path}: degenerate cuboid corners {corners.tolist()}")
    axes = axes / dims
    if np.linalg.det(axes) < 0:
        raise FatFormatError(
            f"{path}: cuboid corners are not in FAT's corner order (FrontTopRight, FrontTopLeft, "
            "FrontBottomLeft, FrontBottomRight, then the rear face, in a right-handed x right, y down, "
            "z forward frame): their frame is mirrored"
        )
    u, _, vt = np.linalg.svd(axes)
    rot = u @ vt
    return rot, dims


def _box(obj: dict, path, bbox_order: str) -> np.ndarray:
    bb = _get(obj, "bounding_box", path)
    tl = _array(_get(bb, "top_left", path), (2,), path, "bounding_box.top_left")
    br = _array(_get(bb, "bottom_right", path), (2,), path, "bounding_box.bottom_right")
    if bbox_order == "yx":
        tl, br = tl[::-1], br[::-1]
    box = np.array([tl[0], tl[1], br[0], br[1]])
    if box[2] < box[0] or box[3] < box[1]:
        raise FatFormatError(f"{path}: bounding box has max < min: {box.tolist()} (bbox_order={bbox_order!r})")
    return box


def _check_options(bbox_order, rotation_from, quaternion_axes):
    if bbox_order not in ("yx", "xy"):
        raise ValueError(f"bbox_order: expected 'yx' (FAT) or 'xy', got {bbox_order!r}")
    if rotation_from not in ("cuboid", "quaternion"):
        raise ValueError(f"rotation_from: expected 'cuboid' or 'quaternion', got {rotation_from!r}")
    axes = np.eye(3) if quaternion_axes is None else np.asarray(quaternion_axes, np.float64)
    if axes.shape != (3, 3) or not np.allclose(axes @ axes.T, np.eye(3), atol=1e-6):
        raise ValueError(f"quaternion_axes: expected a (3, 3) orthogonal matrix, got {axes.tolist()}")
    return axes


class FatSequence(Sequence[FatFrame]):
    """A FAT scene directory: its camera and object settings, and its frames in name order.

    ``len(seq)``, ``seq[i]`` (a :class:`FatFrame`, read on access), ``seq.stems`` (frame names
    like ``'000000'``), ``seq.K``, ``seq.image_size`` (W, H), ``seq.object_settings`` (class name
    -> dict with ``segmentation_class_id``, ``cuboid_dimensions`` (3,) in metres, and any extra
    fields). Loader options are those of :func:`load_fat_frame`.
    """

    def __init__(
        self,
        scene_dir,
        *,
        bbox_order: str = "yx",
        depth_scale: float = FAT_DEPTH_SCALE,
        length_scale: float = FAT_LENGTH_SCALE,
        baseline: float = FAT_BASELINE,
        rotation_from: str = "cuboid",
        quaternion_axes=None,
        load_right_image: bool = False,
    ):
        self.scene_dir = pathlib.Path(scene_dir)
        if not self.scene_dir.is_dir():
            raise FileNotFoundError(f"FAT scene directory missing: {self.scene_dir}")
        self._axes = _check_options(bbox_order, rotation_from, quaternion_axes)
        self.options: dict[str, Any] = dict(
            bbox_order=bbox_order,
            depth_scale=float(depth_scale),
            length_scale=float(length_scale),
            baseline=float(baseline),
            rotation_from=rotation_from,
            load_right_image=bool(load_right_image),
        )
        cam_path = self.scene_dir / "_camera_settings.json"
        cams = _get(_read_json(cam_path), "camera_settings", cam_path)
        if not isinstance(cams, list) or not cams:
            raise FatFormatError(f"{cam_path}: 'camera_settings' must be a non-empty list")
        intr = _get(cams[0], "intrinsic_settings", cam_path)
        fx, fy, cx, cy = (float(_get(intr, k, cam_path)) for k in ("fx", "fy", "cx", "cy"))
        s = float(intr.get("s", 0.0))
        if not (fx > 0 and fy > 0):
            raise FatFormatError(f"{cam_path}: focal lengths must be positive, got fx={fx}, fy={fy}")
        self.K = np.array([[fx, s, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        size = cams[0].get("captured_image_size", {})
        self.image_size = (int(size.get("width", intr.get("resX", 0))), int(size.get("height", intr.get("resY", 0))))

        obj_path = self.scene_dir / "_object_settings.json"
        exported = _get(_read_json(obj_path), "exported_objects", obj_path)
        self.object_settings = {}
        for ob in exported:
            name = str(_get(ob, "class", obj_path))
            entry = dict(ob)
            entry["segmentation_class_id"] = int(_get(ob, "segmentation_class_id", obj_path))
            entry["cuboid_dimensions"] = (
                _array(_get(ob, "cuboid_dimensions", obj_path), (3,), obj_path, f"{name} cuboid_dimensions")
                * self.options["length_scale"]
            )
            self.object_settings[name] = entry

        stems = []
        for entry in os.listdir(self.scene_dir):
            m = _FRAME_RE.match(entry)
            if m:
                stems.append(m.group(1))
        self.stems = tuple(sorted(stems))

    def __len__(self) -> int:
        return len(self.stems)

    @overload
    def __getitem__(self, index: int) -> FatFrame: ...

    @overload
    def __getitem__(self, index: slice) -> list[FatFrame]: ...

    def __getitem__(self, index: int | slice) -> FatFrame | list[FatFrame]:
        if isinstance(index, slice):
            return [self[i] for i in range(*index.indices(len(self)))]
        if not -len(self) <= index < len(self):
            raise IndexError(f"frame index {index} out of range for {len(self)} frames in {self.scene_dir}")
        return self.load(self.stems[index])

    def __iter__(self) -> Iterator[FatFrame]:
        for stem in self.stems:
            yield self.load(stem)

    def _pose(self, ob: dict, path: pathlib.Path, name: str, settings: dict):
        """(rotation (3, 3) object-to-camera, centre (3,) m, full extents (3,) m) of one JSON object."""
        o = self.options
        L = o["length_scale"]
        corners = None
        if "cuboid" in ob:
            corners = _array(ob["cuboid"], (8, 3), path, f"{name} cuboid") * L
        if "cuboid_centroid" in ob:
            center = _array(ob["cuboid_centroid"], (3,), path, f"{name} cuboid_centroid") * L
        elif corners is not None:
            center = corners.mean(axis=0)
        else:
            center = _array(_get(ob, "location", path), (3,), path, f"{name} location") * L
        if o["rotation_from"] == "cuboid":
            if corners is None:
                raise FatFormatError(f"{path}: object {name!r} has no 'cuboid' (use rotation_from='quaternion')")
            rot, dim = _pose_from_cuboid(corners, path)
        else:
            q = _array(_get(ob, "quaternion_xyzw", path), (4,), path, f"{name} quaternion_xyzw")
            rot, dim = Q.quaternion_xyzw_to_rotation(q, xp=np) @ self._axes, settings["cuboid_dimensions"].copy()
        return rot, center, dim

    def annotations(self, stem: str, *, require_right: bool = False) -> FatAnnotation:
        """The labels of frame ``stem`` (no image, depth or segmentation file is opened).

        ``require_right``: a missing right JSON is an error (else its objects count as absent)."""
        base = self.scene_dir / stem
        left_json = pathlib.Path(f"{base}.left.json")
        right_json = pathlib.Path(f"{base}.right.json")
        left = _read_json(left_json)
        right = _read_json(right_json) if require_right or right_json.exists() else {"objects": []}
        right_by_class = {}
        for ob in _get(right, "objects", right_json):
            right_by_class.setdefault(str(_get(ob, "class", right_json)), ob)
        bbox_order = self.options["bbox_order"]
        rows = []
        for ob in _get(left, "objects", left_json):
            name = str(_get(ob, "class", left_json))
            if name not in self.object_settings:
                raise FatFormatError(
                    f"{left_json}: object class {name!r} not in {self.scene_dir / '_object_settings.json'}"
                )
            settings = self.object_settings[name]
            rot, center, dim = self._pose(ob, left_json, name, settings)
            ob_r = right_by_class.get(name)
            if ob_r is not None:
                rot_r, center_r, _ = self._pose(ob_r, right_json, name, settings)
                box_r = _box(ob_r, right_json, bbox_order)
                has_box_r = True
            else:
                rot_r, center_r, box_r, has_box_r = np.eye(3), np.zeros(3), np.zeros(4), False
            rows.append(
                (
                    name,
                    _box(ob, left_json, bbox_order),
                    box_r,
                    has_box_r,
                    rot,
                    center,
                    dim,
                    ob_r is not None,
                    rot_r,
                    center_r,
                    float(ob.get("visibility", 1.0)),
                )
            )
        n = len(rows)
        col = list(zip(*rows)) if rows else [()] * 11
        return FatAnnotation(
            path=left_json,
            K=self.K.copy(),
            baseline=self.options["baseline"],
            right_T_left=right_T_left(self.options["baseline"]),
            class_names=tuple(col[0]),
            boxes_left=np.asarray(col[1], np.float64).reshape(n, 4),
            boxes_right=np.asarray(col[2], np.float64).reshape(n, 4),
            has_right_box=np.asarray(col[3], bool).reshape(n),
            rotation=np.asarray(col[4], np.float64).reshape(n, 3, 3),
            center=np.asarray(col[5], np.float64).reshape(n, 3),
            dimensions=np.asarray(col[6], np.float64).reshape(n, 3),
            has_right=np.asarray(col[7], bool).reshape(n),
            rotation_right=np.asarray(col[8], np.float64).reshape(n, 3, 3),
            center_right=np.asarray(col[9], np.float64).reshape(n, 3),
            visibility=np.asarray(col[10], np.float64).reshape(n),
        )

    def load(self, stem: str) -> FatFrame:
        """Read frame ``stem`` (e.g. ``'000012'``): its labels (:meth:`annotations`) and images."""
        o = self.options
        base = self.scene_dir / stem
        ann = self.annotations(stem, require_right=True)
        image = _read_image(_first_existing(base, "left"), cv2.IMREAD_COLOR)[..., ::-1].copy()
        right_image = None
        if o["load_right_image"]:
            right_image = _read_image(_first_existing(base, "right"), cv2.IMREAD_COLOR)[..., ::-1].copy()
        depth_path = pathlib.Path(f"{base}.left.depth.png")
        raw_depth = _read_image(depth_path, cv2.IMREAD_UNCHANGED)
        if raw_depth.dtype != np.uint16 or raw_depth.ndim != 2:
            raise FatFormatError(
                f"{depth_path}: expected a single-channel uint16 PNG (0.1 mm units), got {raw_depth.dtype} "
                f"with shape {raw_depth.shape}"
            )
        seg_path = pathlib.Path(f"{base}.left.seg.png")
        raw_seg = _read_image(seg_path, cv2.IMREAD_UNCHANGED)
        if raw_seg.ndim == 3:  # some exports write the label into every channel
            raw_seg = raw_seg[..., 0]
        if raw_seg.shape != image.shape[:2] or raw_depth.shape != image.shape[:2]:
            raise FatFormatError(
                f"{base}: image {image.shape[:2]}, depth {raw_depth.shape} and seg {raw_seg.shape} sizes differ"
            )
        settings = [self.object_settings[name] for name in ann.class_names]
        seg_ids = [st["segmentation_class_id"] for st in settings]
        skip = ("class", "segmentation_class_id", "cuboid_dimensions", "fixed_model_transform")
        extra = tuple({k: v for k, v in st.items() if k not in skip} for st in settings)
        seg = np.full(raw_seg.shape, -1, np.int32)
        for i, sid in enumerate(seg_ids):
            seg[raw_seg == sid] = i
        labels = {name: getattr(ann, name) for name in _LABEL_FIELDS}
        return FatFrame(
            **labels,
            image=image,
            right_image=right_image,
            depth=(raw_depth.astype(np.float64) * o["depth_scale"]).astype(np.float32),
            seg=seg,
            segmentation_ids=np.asarray(seg_ids, np.int64).reshape(ann.num_objects),
            extra=extra,
        )


def _first_existing(base: pathlib.Path, side: str) -> pathlib.Path:
    """FAT images are JPEG; the synthetic writer may write PNG. The JPEG path is named if neither."""
    for ext in ("jpg", "png"):
        p = pathlib.Path(f"{base}.{side}.{ext}")
        if p.is_file():
            return p
    return pathlib.Path(f"{base}.{side}.jpg")


def load_fat_scene(scene_dir, **options) -> FatSequence:
    """Open a FAT scene directory (settings read now, frames on access). See :class:`FatSequence`."""
    return FatSequence(scene_dir, **options)


def load_fat_annotations(scene_dir, **options) -> list[FatAnnotation]:
    """The labels of every frame of a FAT scene directory, without reading any image.

    Per frame (sorted by stem) a :class:`FatAnnotation`: per object the class name, rotation
    (3, 3) object-to-camera, centre (3,) m, full dimensions (3,) m and box ``[u_min, v_min,
    u_max, v_max]`` for the left camera and, where the right JSON has the object, the right one;
    and K. Options as :func:`load_fat_frame`.
    """
    seq = FatSequence(scene_dir, **options)
    return [seq.annotations(stem) for stem in seq.stems]


def load_fat_frame(scene_dir, frame, **options) -> FatFrame:
    """Read one frame of a FAT scene directory.

    Args:
      scene_dir: directory with ``_camera_settings.json``, ``_object_settings.json`` and frames.
      frame: an int index into the sorted frames, or a stem string such as ``'000000'``.
      **options: ``bbox_order`` ('yx' | 'xy'), ``depth_scale`` (m per unit, 1e-4),
        ``length_scale`` (m per JSON unit, 0.01), ``baseline`` (m, 0.06), ``rotation_from``
        ('cuboid' | 'quaternion'), ``quaternion_axes`` ((3, 3) or None), ``load_right_image``.

    Returns:
      :class:`FatFrame`.
    """
    seq = FatSequence(scene_dir, **options)
    if isinstance(frame, str):
        return seq.load(frame)
    return seq[int(frame)]
