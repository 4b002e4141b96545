"""VoluMon evaluation batches from a BOP scene: the real photographs, their visible boxes, the truth.

:func:`bop_eval_batch` turns the frames of a :class:`BopScene` (one split of it) into one batch of
:func:`jaxsem.volumon.evaluate_scene_batch`: per object at least ``min_visible`` visible, the
network inputs of its visible box (the detector-free box: exact, from the labels or the render),
its true pose and mesh extent, its mesh points in the camera frame (ADD-S), class and visible
fraction.
"""

from __future__ import annotations

import pathlib

import numpy as np

from ..._files import MAX_PIXELS, read_image
from ...data import BopFrame, BopScene, fat_writer, load_bop_scene
from .._inputs import prepare_inputs

__all__ = [
    "BOP_SPLITS",
    "LMO_TUNE_BELOW",
    "bop_class_extents",
    "bop_eval_batch",
    "bop_split_frames",
    "load_bop_split",
    "read_rgb",
]

#: The fixed split of LM-O scene 000002: frame ids below this are the tuning split.
LMO_TUNE_BELOW = 600
BOP_SPLITS = ("tune", "test", "all")
#: Mesh points per object kept for ADD-S (evenly strided over the vertices).
NUM_MESH_POINTS = 500


def _split_filter(split: str, below: int):
    fat_writer.check_split(split, BOP_SPLITS)
    if split == "tune":
        return lambda fid: fid < below
    if split == "test":
        return lambda fid: fid >= below
    return None


def load_bop_split(scene_dir, split: str, below: int = LMO_TUNE_BELOW, **kwargs) -> BopScene:
    """:func:`load_bop_scene` reading only the frames of ``split`` (``"tune"``: ids below
    ``below``, ``"test"``: the rest, ``"all"``), so the other split's boxes are never rendered."""
    return load_bop_scene(scene_dir, frame_filter=_split_filter(split, int(below)), **kwargs)


def bop_split_frames(scene: BopScene, split: str, below: int = LMO_TUNE_BELOW) -> tuple[BopFrame, ...]:
    """The frames of ``split`` of a loaded scene (see :func:`load_bop_split`)."""
    keep = _split_filter(split, int(below))
    return tuple(f for f in scene.frames if keep is None or keep(f.frame_id))


def read_rgb(path, *, max_pixels: int = MAX_PIXELS) -> np.ndarray:
    """An image file as (H, W, 3) uint8 RGB; ValueError naming the file when it cannot be read or
    its header declares more than ``max_pixels`` pixels (default 8192 x 8192; checked before any
    pixel is decoded)."""
    import cv2  # deferred: cv2 is slow to import and only this function needs it

    path = pathlib.Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: cannot read the frame's image (missing)")
    return cv2.cvtColor(read_image(path, cv2.IMREAD_COLOR, max_pixels=max_pixels), cv2.COLOR_BGR2RGB)


def _nearest_rotation(R) -> np.ndarray:
    """The rotation nearest to ``R`` (3, 3) (BOP files round ``cam_R_m2c``: |R^T R - I| ~ 1e-3)."""
    U, _, Vt = np.linalg.svd(np.asarray(R, np.float64))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def _mesh_points(vertices: np.ndarray, n: int) -> np.ndarray:
    idx = np.linspace(0, len(vertices) - 1, min(n, len(vertices))).round().astype(np.int64)
    pts = vertices[idx]
    if len(pts) < n:  # few vertices: repeat (ADD-S is a mean over points, unchanged by repeats)
        pts = pts[np.arange(n) % len(pts)]
    return pts


def bop_eval_batch(
    scene: BopScene,
    frames=None,
    *,
    input_size: int,
    global_padding: float,
    min_visible: float = 0.5,
    num_mesh_points: int = NUM_MESH_POINTS,
) -> dict:
    """One batch of every object of ``frames`` (default: all of ``scene``) at least ``min_visible``
    visible, for :func:`jaxsem.volumon.evaluate_scene_batch` and
    :func:`jaxsem.volumon.summarise_detections`.

    Keys (numpy, B rows): ``local``, ``global`` (B, S, S, 3) float32 (:func:`jaxsem.volumon.prepare_inputs`
    of the frame's image and the visible box, clipped to the image); ``box_input`` (B, 4);
    ``K`` (B, 3, 3); ``gt_rotation`` (B, 3, 3) object-to-camera (the nearest exact rotation to the
    file's rounded one); ``gt_center``, ``gt_half_extents``
    (B, 3): the mesh extent's box (scored as a cuboid: ``gt_shape_id`` 0); ``gt_points`` (B, N, 3)
    the mesh's points in the camera frame (ADI = ADD-S); ``sample_mask`` (all True);
    ``class_name`` (B,) str; ``visible_fraction``, ``frame_id``, ``obj_id`` (B,).

    Raises:
      ValueError: ``min_visible`` outside [0, 1]; a frame image that cannot be read (naming it);
        no object left (naming the count and the threshold).
    """
    min_visible = float(min_visible)
    if not 0.0 <= min_visible <= 1.0:
        raise ValueError(f"min_visible: expected a fraction in [0, 1], got {min_visible}")
    frames = scene.frames if frames is None else tuple(frames)
    rows: dict[str, list] = {k: [] for k in ("local", "global", "box_input", "K", "gt_rotation", "gt_center")}
    rows.update(
        {k: [] for k in ("gt_half_extents", "gt_points", "class_name", "visible_fraction", "frame_id", "obj_id")}
    )
    total = 0
    for frame in frames:
        total += len(frame.objects)
        objs = [
            o
            for o in frame.objects
            if o.visible_fraction >= min_visible and o.visible_fraction > 0 and np.all(np.isfinite(o.visible_box))
        ]
        if not objs:
            continue
        image = read_rgb(frame.image_path)
        H, W = image.shape[:2]
        lo, hi = np.array([-0.5, -0.5]), np.array([W - 0.5, H - 0.5])
        boxes = []
        for o in objs:
            b = np.asarray(o.visible_box, np.float64)
            b = np.concatenate([np.clip(b[:2], lo, hi - 1.0), np.clip(b[2:], lo + 1.0, hi)])
            b[2:] = np.maximum(b[2:], b[:2] + 1.0)
            boxes.append(b)
        boxes = np.stack(boxes)
        local, glob = prepare_inputs(image, boxes, int(input_size), float(global_padding))
        rows["local"].append(np.asarray(local))
        rows["global"].append(np.asarray(glob))
        for o, b in zip(objs, boxes):
            mesh = scene.meshes[o.obj_id]
            rows["box_input"].append(b)
            rows["K"].append(np.asarray(frame.K, np.float64))
            rows["gt_rotation"].append(_nearest_rotation(o.rotation))
            rows["gt_center"].append(np.asarray(o.center, np.float64))
            rows["gt_half_extents"].append(np.asarray(o.radii, np.float64))
            pts = _mesh_points(mesh.vertices, int(num_mesh_points))
            rows["gt_points"].append(pts @ np.asarray(o.rotation).T + np.asarray(o.translation))
            rows["class_name"].append(o.class_name)
            rows["visible_fraction"].append(float(o.visible_fraction))
            rows["frame_id"].append(frame.frame_id)
            rows["obj_id"].append(o.obj_id)
    if not rows["box_input"]:
        raise ValueError(
            f"min_visible: none of the {total} objects of the {len(frames)} frames is at least {min_visible:g} visible"
        )
    out: dict[str, np.ndarray] = {k: np.concatenate(rows[k]).astype(np.float32) for k in ("local", "global")}
    out.update({k: np.stack(rows[k]) for k in ("box_input", "K", "gt_rotation", "gt_center", "gt_half_extents")})
    out["gt_points"] = np.stack(rows["gt_points"])
    out["gt_shape_id"] = np.zeros(len(out["box_input"]), np.int32)
    out["sample_mask"] = np.ones(len(out["box_input"]), bool)
    out["class_name"] = np.asarray(rows["class_name"], dtype=str)
    out["visible_fraction"] = np.asarray(rows["visible_fraction"], np.float64)
    out["frame_id"] = np.asarray(rows["frame_id"], np.int64)
    out["obj_id"] = np.asarray(rows["obj_id"], np.int64)
    return out


def bop_class_extents(scene: BopScene) -> dict:
    """Class name -> full extents (3,) of its mesh (metres), for the classes of ``scene``'s frames."""
    out = {}
    for f in scene.frames:
        for o in f.objects:
            out.setdefault(o.class_name, 2.0 * np.asarray(scene.meshes[o.obj_id].radii, np.float64))
    return out
