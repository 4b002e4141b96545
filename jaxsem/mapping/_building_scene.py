"""A generated LSD building as a MuJoCo scene: walls, door frames, windows and exit signs, rendered
from the robot's camera (RGB, depth, segmentation), with door / sign boxes read off the
segmentation as a stand-in detector (thesis 5.8.1 used the simulator's boxes the same way).

Host-side numpy + MuJoCo (not jittable), like :mod:`jaxsem.data` 's object renderer. The scene is
an MJCF string (:func:`building_mjcf`), so it can be saved, inspected or loaded by other tools.

Geometry (metres, world z up, the building grid's ``origin`` / ``resolution``):

- walls: the wall cells of ``building.semantic`` (the outer fence ring excluded) merged into
  rectangles, extruded from the floor to ``heights.wall[1]``;
- doors (openings): a frame of two jambs (5 cm deep along the wall) and a head piece inside the
  opening, up to ``heights.door[1]``, with wall above; the frame is labelled as the door, so the
  door's box in the segmentation is the box of its frame, i.e. of the opening;
- windows: a glass pane over ``heights.window`` with wall below and above;
- exit signs: wall cells with a green plate at ``heights.exit_sign`` that stands 3 cm proud of
  both faces of the wall layer it is on;
- a floor plane at z = 0 (label -1) and no ceiling.

Object ``k`` of :func:`jaxsem.mapping.building_objects` is segmentation label ``k``; walls,
floor and sky are -1 (``seg_class`` tells walls apart). Cameras are jaxsem's (OpenCV axes,
``camera_T_world``; an OpenCV camera rotation is MuJoCo's ``cam_xmat @ diag(1, -1, -1)``,
depth is z-depth); any pinhole ``K`` without skew is rendered exactly through MuJoCo's
``cam_intrinsic`` as in :class:`jaxsem.data.SceneRenderer`.
"""

from __future__ import annotations

import dataclasses
import importlib
import math
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from .. import quadrics
from .._checks import require_type
from ..data import RENDER_OUTPUTS, MujocoScene
from ..planning import DOOR, EXIT_SIGN, WALL, WINDOW
from ..quadrics import Camera
from ._building import ObjectHeights, box_ellipsoids, building_objects

os.environ.setdefault("MUJOCO_GL", "egl")

__all__ = [
    "BuildingRenderer",
    "SceneDetections",
    "building_mjcf",
    "detect_from_segmentation",
    "ellipsoids_from_depth",
    "robot_camera",
    "robot_intrinsics",
]

_JAMB = 0.05  # door frame depth along the wall (m)
_HEAD = 0.1  # door frame head height (m)
_PROUD = 0.03  # exit-sign plate stands this far off the wall faces (m)


def _mujoco() -> Any:
    """``mujoco``, imported on first use (after ``MUJOCO_GL`` is set; typed loosely: its stubs
    miss most of the module)."""
    return importlib.import_module("mujoco")


def _rectangles(mask: np.ndarray) -> list:
    """Cell rectangles ``(r0, c0, r1, c1)`` (half-open) covering ``mask`` exactly: row runs,
    merged downwards while the next row has the same run."""
    H = mask.shape[0]
    rects, open_runs = [], {}
    for r in range(H + 1):
        runs = set()
        if r < H:
            row = np.concatenate([[False], mask[r], [False]]).astype(np.int8)
            d = np.diff(row)
            runs = set(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))
        new = {run: open_runs.pop(run, r) for run in runs}
        rects += [(r0, c0, r, c1) for (c0, c1), r0 in open_runs.items()]
        open_runs = new
    return rects


def _box_xml(name, lo, hi, material):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    pos = " ".join(f"{v:.4f}" for v in 0.5 * (lo + hi))
    size = " ".join(f"{v:.4f}" for v in np.maximum(0.5 * (hi - lo), 1e-4))
    return f'    <geom name="{name}" type="box" pos="{pos}" size="{size}" material="{material}"/>'


def building_mjcf(building, heights=None, *, width: int = 640, height: int = 480):
    """The MJCF model of ``building`` and its label tables.

    building: a :class:`jaxsem.planning.Building`; heights: a
    :class:`jaxsem.mapping.ObjectHeights` (default heights); width, height: the largest image
    the offscreen buffer must hold.

    Returns:
      ``(xml, geom_object, geom_class, objects)``: the MJCF string; dicts from geom name to
      object index (-1 for walls) and to semantic class id; the
      :class:`jaxsem.mapping.BuildingObjects` whose order the object indices follow.
    """

    heights = heights or ObjectHeights()
    sem = np.asarray(building.semantic)
    origin = np.asarray(building.origin, float).reshape(2)
    res = float(building.resolution)
    objects = building_objects(building, heights)
    wall_top = float(heights.wall[1])
    geoms, geom_object, geom_class = [], {}, {}

    def cell_box(r0, c0, r1, c1, z0, z1, pad=(0.0, 0.0)):
        lo = (origin[0] + c0 * res - pad[0], origin[1] + r0 * res - pad[1], z0)
        hi = (origin[0] + c1 * res + pad[0], origin[1] + r1 * res + pad[1], z1)
        return lo, hi

    def add(name, lo, hi, material, obj, cls):
        geoms.append(_box_xml(name, lo, hi, material))
        geom_object[name], geom_class[name] = obj, cls

    inner = np.zeros(sem.shape, bool)
    inner[1:-1, 1:-1] = True  # the outermost ring is the generator's fence: not drawn
    full = inner & ((sem == WALL) | (sem == EXIT_SIGN))
    for i, (r0, c0, r1, c1) in enumerate(_rectangles(full)):
        add(f"wall{i}", *cell_box(r0, c0, r1, c1, 0.0, wall_top), "wall", -1, WALL)
    for k, (cls, (r0, c0, r1, c1)) in enumerate(zip(objects.class_id, objects.cells)):
        along_x = (c1 - c0) >= (r1 - r0)
        if cls == DOOR:
            z1 = float(heights.door[1])
            add(
                f"door{k}_above",
                *cell_box(r0, c0, r1, c1, z1, wall_top),
                "wall",
                -1,
                WALL,
            )
            lo, hi = cell_box(r0, c0, r1, c1, 0.0, z1)
            ax = 0 if along_x else 1
            a_hi = np.array(hi, float)
            a_hi[ax] = lo[ax] + _JAMB
            add(f"door{k}_jamb0", lo, a_hi, "frame", k, DOOR)
            b_lo = np.array(lo, float)
            b_lo[ax] = hi[ax] - _JAMB
            add(f"door{k}_jamb1", b_lo, hi, "frame", k, DOOR)
            h_lo = np.array(lo, float)
            h_lo[2] = z1 - _HEAD
            add(f"door{k}_head", h_lo, hi, "frame", k, DOOR)
        elif cls == WINDOW:
            z0, z1 = map(float, heights.window)
            add(f"window{k}_below", *cell_box(r0, c0, r1, c1, 0.0, z0), "wall", -1, WALL)
            add(
                f"window{k}_above",
                *cell_box(r0, c0, r1, c1, z1, wall_top),
                "wall",
                -1,
                WALL,
            )
            add(f"window{k}", *cell_box(r0, c0, r1, c1, z0, z1), "glass", k, WINDOW)
        elif cls == EXIT_SIGN:
            z0, z1 = map(float, heights.exit_sign)
            pad = (0.0, _PROUD) if along_x else (_PROUD, 0.0)
            add(f"sign{k}", *cell_box(r0, c0, r1, c1, z0, z1, pad), "sign", k, EXIT_SIGN)
    centre = origin + 0.5 * res * np.array(sem.shape[::-1], float)
    xml = f"""<mujoco model="jaxsem_building_{building.family}_{building.seed}">
  <visual>
    <global offwidth="{max(int(width), 64)}" offheight="{max(int(height), 64)}"/>
    <quality shadowsize="0"/>
    <map znear="0.001" zfar="10"/>
    <headlight ambient="0.45 0.45 0.45" diffuse="0.35 0.35 0.35"/>
  </visual>
  <statistic extent="10" center="{centre[0]:.3f} {centre[1]:.3f} 1"/>
  <asset>
    <texture name="floor_tex" type="2d" builtin="checker" rgb1="0.55 0.52 0.48" rgb2="0.45 0.43 0.40"
             width="64" height="64"/>
    <texture name="sky" type="skybox" builtin="gradient" rgb1="0.75 0.85 0.95" rgb2="0.35 0.45 0.6"
             width="64" height="64"/>
    <material name="floor" texture="floor_tex" texrepeat="1 1" texuniform="true"/>
    <material name="wall" rgba="0.86 0.84 0.80 1"/>
    <material name="frame" rgba="0.45 0.28 0.15 1"/>
    <material name="glass" rgba="0.55 0.75 0.9 1" specular="0.6"/>
    <material name="sign" rgba="0.05 0.75 0.2 1" emission="0.6"/>
  </asset>
  <worldbody>
    <light directional="true" dir="0.3 0.2 -1" diffuse="0.5 0.5 0.5" castshadow="false"/>
    <geom name="floor" type="plane" size="0 0 0.05" material="floor"/>
{chr(10).join(geoms)}
    <camera name="robot" pos="0 0 1" fovy="60"/>
  </worldbody>
</mujoco>
"""
    return xml, geom_object, geom_class, objects


def robot_intrinsics(width: int, height: int, hfov_deg: float = 69.4) -> np.ndarray:
    """Square-pixel pinhole ``K`` (3, 3) with horizontal field of view ``hfov_deg`` (69.4 deg is
    the planning world's object camera) and the principal point at the image centre."""
    if not 1.0 <= float(hfov_deg) < 179.0:
        raise ValueError(f"hfov_deg: expected a field of view in [1, 179) degrees, got {hfov_deg}")
    f = 0.5 * int(width) / math.tan(math.radians(float(hfov_deg)) / 2)
    return np.array([[f, 0.0, (int(width) - 1) / 2], [0.0, f, (int(height) - 1) / 2], [0, 0, 1.0]])


def robot_camera(xy, yaw: float, height: float = 1.2, pitch_deg: float = 0.0) -> np.ndarray:
    """``camera_T_world`` (4, 4) of a camera ``height`` metres above the robot at world ``xy``
    looking along heading ``yaw`` (radians, from world x towards y), tilted down by ``pitch_deg``."""
    xy = np.asarray(xy, float)
    if xy.shape != (2,) or not np.all(np.isfinite(xy)):
        raise ValueError(f"xy: expected a finite world point (2,), got {np.asarray(xy).tolist()}")
    eye = np.array([xy[0], xy[1], float(height)])
    p = math.radians(float(pitch_deg))
    look = np.array([math.cos(yaw) * math.cos(p), math.sin(yaw) * math.cos(p), -math.sin(p)])
    return np.asarray(quadrics.look_at(eye, eye + look, xp=np), np.float64)


@dataclasses.dataclass(frozen=True)
class SceneDetections:
    """Boxes read off a segmentation image (numpy).

    box: (D, 4) ``[u_min, v_min, u_max, v_max]`` in pixels (pixel-centre coordinates, the
      outermost labelled pixel centres -/+ half a pixel); class_id: (D,) semantic id;
    object_index: (D,) index into the scene's objects; area: (D,) labelled pixels.
    """

    box: np.ndarray
    class_id: np.ndarray
    object_index: np.ndarray
    area: np.ndarray

    def __len__(self) -> int:
        return int(self.box.shape[0])


def detect_from_segmentation(seg, object_class, classes=None, *, min_area: int = 1, border: int = 0) -> SceneDetections:
    """The stand-in detector: one box per object visible in ``seg``.

    seg: (H, W) int object indices (-1 none); object_class: (K,) semantic id of each object;
    classes: which semantic ids to report (default door and exit sign); min_area: fewest
    labelled pixels; border: drop boxes closer than this many pixels to the image edge (the
    thesis dropped boxes under 2000 px^2 or within 50 px of the border, section 5.8.1).
    """

    seg = np.asarray(seg)
    if seg.ndim != 2:
        raise ValueError(f"seg: expected an (H, W) segmentation, got shape {seg.shape}")
    object_class = np.asarray(object_class)
    classes = (DOOR, EXIT_SIGN) if classes is None else tuple(classes)
    H, W = seg.shape
    boxes, cls, idx, area = [], [], [], []
    for k in np.unique(seg[seg >= 0]):
        if k >= len(object_class):
            raise ValueError(f"seg: label {int(k)} but object_class has only {len(object_class)} entries")
        if object_class[k] not in classes:
            continue
        rows, cols = np.nonzero(seg == k)
        if len(rows) < min_area:
            continue
        box = [cols.min() - 0.5, rows.min() - 0.5, cols.max() + 0.5, rows.max() + 0.5]
        if border > 0 and (
            cols.min() < border or rows.min() < border or cols.max() >= W - border or rows.max() >= H - border
        ):
            continue
        boxes.append(box)
        cls.append(int(object_class[k]))
        idx.append(int(k))
        area.append(len(rows))
    return SceneDetections(
        box=np.asarray(boxes, np.float64).reshape(-1, 4),
        class_id=np.asarray(cls, np.int32),
        object_index=np.asarray(idx, np.int64),
        area=np.asarray(area, np.int64),
    )


def ellipsoids_from_depth(
    seg,
    depth,
    camera: Camera,
    object_class,
    classes=None,
    *,
    min_pixels: int = 20,
    min_extent: float = 0.02,
    capacity: int | None = None,
):
    """A stand-in 3D estimator: each visible object's segmented depth pixels, back-projected
    (:func:`jaxsem.quadrics.back_project`), give a world-axis-aligned box whose inscribed
    ellipsoid (:func:`jaxsem.mapping.box_ellipsoids`) is the estimate.

    Building objects are axis-aligned, so this is exact for a fully seen object; a partly seen
    one shrinks to its seen part. It is what the object map receives in place of VoluMon or
    ROSHAN when the pipeline is checked from pixels (``tests/integration/test_building_scene.py``).

    seg: (H, W) object indices (-1 none); depth: (H, W) z-depth (0 = none); camera: the view's
    :class:`jaxsem.quadrics.Camera` (``K`` (3, 3), ``camera_T_world`` (4, 4)); object_class: (K,) semantic ids; classes: ids to report (default door
    and exit sign); min_pixels: fewest pixels with depth; min_extent: smallest box side in metres
    (flat point sets are thickened to it); capacity: pad to this many slots.
    Returns ``(ellipsoids, object_index)``: :class:`jaxsem.mapping.Ellipsoids` and the (D,)
    object index of each estimate.
    """

    K, camera_T_world = require_type("camera", camera, Camera)
    seg, depth = np.asarray(seg), np.asarray(depth, np.float64)
    if seg.ndim != 2 or depth.shape != seg.shape:
        raise ValueError(f"seg, depth: expected two (H, W) images of one shape, got {seg.shape} and {depth.shape}")
    object_class = np.asarray(object_class)
    classes = (DOOR, EXIT_SIGN) if classes is None else tuple(classes)
    lo, hi, cls, idx = [], [], [], []
    for k in np.unique(seg[seg >= 0]):
        if k >= len(object_class) or object_class[k] not in classes:
            continue
        rows, cols = np.nonzero((seg == k) & (depth > 0))
        if len(rows) < min_pixels:
            continue
        uv = np.stack([cols, rows], -1).astype(np.float64)
        pts = np.asarray(quadrics.back_project(uv, depth[rows, cols], K, camera_T_world, xp=np))
        lo.append(pts.min(0))
        hi.append(pts.max(0))
        cls.append(int(object_class[k]))
        idx.append(int(k))
    n = len(idx)
    lo_a, hi_a = np.asarray(lo).reshape(-1, 3), np.asarray(hi).reshape(-1, 3)
    # Points of one flat face (a jamb seen edge-on, a sign's front) have no thickness: give every
    # box at least min_extent so the ellipsoid has positive radii.
    mid, half = 0.5 * (lo_a + hi_a), np.maximum(0.5 * (hi_a - lo_a), 0.5 * min_extent)
    cap = capacity if capacity is not None else max(n, 1)
    ell = box_ellipsoids(
        mid - half,
        mid + half,
        np.asarray(cls, np.int32),
        cap,
    )
    return ell, np.asarray(idx, np.int64)


class BuildingRenderer(MujocoScene):
    """A compiled building scene and its offscreen renderer; use as a context manager.

    Args:
      building: a :class:`jaxsem.planning.Building`.
      width, height: image size in pixels.
      heights: :class:`jaxsem.mapping.ObjectHeights` (default heights).

    Attributes:
      xml: the MJCF string; objects: :class:`jaxsem.mapping.BuildingObjects` (segmentation label k
      is ``objects`` entry k); model, data: MuJoCo's.
    """

    def __init__(self, building, width: int = 320, height: int = 240, *, heights=None):
        mujoco = _mujoco()

        width, height = int(width), int(height)
        if width < 8 or height < 8:
            raise ValueError(f"width, height: expected at least 8 px each, got {width}x{height}")
        self.width, self.height = width, height
        self.xml, geom_object, geom_class, self.objects = building_mjcf(building, heights, width=width, height=height)
        self.model = mujoco.MjModel.from_xml_string(self.xml)
        self.data = mujoco.MjData(self.model)
        n = self.model.ngeom
        self._label = np.full(n + 1, -1, np.int32)  # index -1 (no geom) hits the trailing -1
        self._class = np.zeros(n + 1, np.int8)
        for name, k in geom_object.items():
            gid = self.model.geom(name).id
            self._label[gid] = k
            self._class[gid] = geom_class[name]
        self._cam = self.model.camera("robot").id
        self._open_renderer(width, height)

    def render(self, K, camera_T_world, *, outputs: Sequence[str] = RENDER_OUTPUTS) -> dict:
        """One view. ``K`` (3, 3) pinhole without skew; ``camera_T_world`` (4, 4), OpenCV axes.

        Returns a dict of the passes asked for: ``rgb`` (H, W, 3) uint8; ``depth`` (H, W)
        float32 z-depth in metres (0 on the sky); ``seg`` (H, W) int32 object index or -1, and
        ``seg_class`` (H, W) int8 semantic id (``WALL`` on walls, 0 on floor and sky).
        """
        out, view = self._view(self._cam, K, camera_T_world, outputs)
        if "seg" in out:
            out["seg_class"] = self._class[view["geom"]]
        return out

    def detect(self, seg, classes=None, *, min_area: int = 1, border: int = 0) -> SceneDetections:
        """:func:`detect_from_segmentation` with this scene's object classes."""
        return detect_from_segmentation(seg, self.objects.class_id, classes, min_area=min_area, border=border)
