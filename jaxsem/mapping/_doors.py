"""Stereo views of the doors of generated LSD buildings, written in the FAT layout (thesis 5.8.1).

The thesis trained its door model on stereo pairs of a simulated office, with the simulator's
boxes as detections (doors with boxes under 2000 px^2 or within 50 px of the image border left
out) and a 2 m stereo baseline. This writer does the same in the buildings of
:mod:`jaxsem.planning` rendered by :class:`jaxsem.mapping.BuildingRenderer`: one scene directory per
building (``<out_dir>/<split>/scene_NNN/``, ``scene_NNN`` = the NNN-th building of the split),
each frame a left / right pair of the robot's camera (:func:`jaxsem.mapping.robot_intrinsics`, 69.4
degree horizontal field of view, principal point at the image centre) looking at one door.

Frames. A door of the building is drawn; the left camera stands ``distance`` metres from the
door's centre, on a random side of its wall, within ``max_view_angle`` degrees of the wall's
normal, ``height`` metres above the floor, tilted by ``pitch_deg``, and turned so that the door
lands anywhere across the image (heading towards the door plus a jitter up to most of the half
field of view). The right camera sits ``baseline`` metres along the left camera's x axis
(:func:`jaxsem.quadrics.stereo_right_T_left`). Both cameras must stand in free space at least
``clearance`` metres from any wall. A frame is kept only when, in both images, the door's box read
off the segmentation (:func:`jaxsem.mapping.detect_from_segmentation`, the stand-in detector) has at
least ``min_area`` pixels, keeps ``border`` pixels from the image edge, and agrees within
``max_occlusion_px`` pixels with the exact projection of the door's true box (so the door is
neither occluded nor cut: the box is its full extent, as the thesis' simulator boxes were);
otherwise another pose is drawn.

Ground truth (from the building generator, :func:`jaxsem.mapping.building_objects`): the door is
its opening, the axis-aligned box of its cells from the floor to the door height (the frame of
jambs and head the renderer draws lies inside it); the object frame is the world's axes (x east,
y north, z up), so ``dimensions`` are the box's world extents and the rotation is the camera's.
Written per frame as the object writer does (:func:`jaxsem.volumon.data.write_object_dataset`): FAT's
fields in centimetres, ``bounding_box`` the segmentation box (``[y, x]`` unless
``bbox_order='xy'``), ``visibility`` 1, ``shape`` ``"box"``, plus ``building_object`` (the door's
index in the building's objects). Other doors in view are background (only one door is labelled
per frame, so the FAT layout's one-instance-per-class segmentation holds). ``_doors.json`` in each
scene records the building's family and seed, the baseline and the writer's settings.

Splits: ``'train'`` and ``'val'`` use train-family buildings (seeds from ``seed * 100_000`` for
train and ``seed * 100_000 + 50_000`` for val), ``'test'`` uses test-family buildings (seeds from
``seed * 100_000``), so test doors come from buildings of another size and room distribution that
no training frame saw. Load with ``baseline`` set to this writer's (``loader_options={"baseline":
b}``; FAT's own is 6 cm; :func:`door_data_baseline` reads it back), or train on it with
:func:`train_door_model`. Host-side numpy + MuJoCo, not jittable. A scene is written into
``scene_NNN.partial`` and renamed into place when complete.
"""

from __future__ import annotations

import json
import math
import pathlib
from collections.abc import Callable
from typing import Any

import numpy as np

from .. import quadrics as Q
from ..data import fat_writer
from ..planning import DOOR, generate_building
from ..volumon import train_and_evaluate
from ..volumon.data import ObjectClass, object_box, volumon_batch_source, volumon_eval_batch
from ._building import building_objects
from ._building_scene import BuildingRenderer, robot_camera, robot_intrinsics

__all__ = [
    "DOOR_BASELINE",
    "door_building",
    "door_data_baseline",
    "door_eval_batch",
    "train_door_model",
    "write_door_dataset",
]

#: Default stereo baseline (m) of the door pairs: the thesis used 2 m; 1 m keeps both cameras of a
#: pair inside the buildings' rooms and corridors more often, and still gives 40 px of disparity
#: at 4 m with 224 px wide images.
DOOR_BASELINE = 1.0
_SPLITS = {"train": ("train", 0), "val": ("train", 50_000), "test": ("test", 0)}
_CLASS = "door"


def door_building(split: str, index: int, seed: int = 0):
    """The building of scene ``index`` of ``split`` (the same one :func:`write_door_dataset` renders)."""

    fat_writer.check_split(split, _SPLITS)
    family, offset = _SPLITS[split]
    return generate_building(int(seed) * 100_000 + offset + int(index), family)


def _cam_position(camera_T_world) -> np.ndarray:
    return Q.invert_pose(camera_T_world, xp=np)[:3, 3]


class _Clearance:
    """Distance (m) from each free cell to the nearest occupied cell of a building."""

    def __init__(self, building):
        from scipy import ndimage  # deferred: scipy.ndimage is slow to import and only this function needs it

        self.res = float(building.resolution)
        self.origin = np.asarray(building.origin, np.float64).reshape(2)
        self.dist = ndimage.distance_transform_edt(~np.asarray(building.occupancy)) * self.res  # type: ignore[operator]

    def __call__(self, xy) -> float:
        rc = Q.world_to_cell(np.asarray(xy, np.float64), self.origin, self.res, xp=np)
        if not Q.cell_in_grid(rc, self.dist.shape, xp=np):
            return 0.0
        return float(self.dist[rc[0], rc[1]])

    def sees(self, a, b, k, objects) -> bool:
        """No wall cell on the segment from ``a`` to ``b`` (world xy) outside object ``k``'s cells."""
        a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
        n = max(int(np.linalg.norm(b - a) / (0.5 * self.res)), 2)
        pts = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
        cells = Q.world_to_cell(pts, self.origin, self.res, xp=np)
        r0, c0, r1, c1 = objects.cells[k]
        inside = (cells[:, 0] >= r0 - 1) & (cells[:, 0] < r1 + 1) & (cells[:, 1] >= c0 - 1) & (cells[:, 1] < c1 + 1)
        H, W = self.dist.shape
        rows, cols = np.clip(cells[:, 0], 0, H - 1), np.clip(cells[:, 1], 0, W - 1)
        return bool(np.all((self.dist[rows, cols] > 0) | inside))


def _door_box(det, k):
    i = np.flatnonzero(det.object_index == k)
    return None if i.size == 0 else (det.box[i[0]], int(det.area[i[0]]))


def write_door_dataset(
    out_dir,
    num_scenes: int,
    seed: int = 0,
    split: str = "train",
    *,
    frames_per_scene: int = 40,
    image_size: tuple = (224, 168),
    baseline: float = DOOR_BASELINE,
    distance: tuple = (2.5, 8.0),
    max_view_angle: float = 60.0,
    height: tuple = (1.0, 1.4),
    pitch_deg: tuple = (-5.0, 10.0),
    clearance: float = 0.3,
    min_area: int = 150,
    border: int = 4,
    max_occlusion_px: float = 3.0,
    image_format: str = "jpg",
    bbox_order: str = "yx",
    progress: bool = True,
) -> list:
    """Render ``num_scenes`` buildings' doors, ``frames_per_scene`` stereo frames each, into
    ``<out_dir>/<split>/scene_NNN/`` (see the module docstring for what a frame shows).

    Args:
      out_dir: root directory (created).
      num_scenes: buildings (scene directories) to render.
      seed: dataset seed; with ``split`` it fixes the buildings and every random choice.
      split: ``'train'``, ``'val'`` (train-family buildings) or ``'test'`` (test family).
      frames_per_scene: stereo frames per building.
      image_size: ``(W, H)`` pixels.
      baseline: stereo baseline (m), right camera along the left one's +x.
      distance: (min, max) metres from the left camera to the door centre.
      max_view_angle: largest angle (deg) between the door's wall normal and the direction to the camera.
      height, pitch_deg: (min, max) camera height (m) and downward tilt (deg).
      clearance: least distance (m) of both cameras from a wall.
      min_area, border, max_occlusion_px: the frame filter (pixels; see the module docstring).
      image_format: ``'jpg'`` (as FAT) or ``'png'``.
      bbox_order: ``'yx'`` (FAT's quirk) or ``'xy'``.
      progress: show a tqdm bar.

    Returns:
      The scene directories written (``pathlib.Path``).
    """

    fat_writer.check_split(split, _SPLITS)
    num_scenes, frames_per_scene = fat_writer.check_scenes(num_scenes, frames_per_scene)
    width, height_px = fat_writer.check_image_size(image_size)
    if not (math.isfinite(float(baseline)) and 0 < float(baseline) <= 5):
        raise ValueError(f"baseline: expected 0 < baseline <= 5 m, got {baseline}")
    for name, rng_ in (("distance", distance), ("height", height), ("pitch_deg", pitch_deg)):
        lo, hi = (float(x) for x in rng_)
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise ValueError(f"{name}: expected (min, max) with min <= max, got {rng_}")
    if not 0.5 <= float(distance[0]):
        raise ValueError(f"distance: expected a minimum of at least 0.5 m, got {distance}")
    if not 0 <= float(max_view_angle) < 90:
        raise ValueError(f"max_view_angle: expected 0 to 90 degrees, got {max_view_angle}")
    fat_writer.check_formats(image_format, bbox_order)

    from tqdm.auto import tqdm  # deferred: tqdm.auto is slow to import and only the writer needs it

    K = robot_intrinsics(width, height_px)
    T_rl = np.asarray(Q.stereo_right_T_left(float(baseline)), np.float64)
    root = pathlib.Path(out_dir) / split
    root.mkdir(parents=True, exist_ok=True)
    settings = dict(
        baseline=float(baseline),
        distance=[float(x) for x in distance],
        max_view_angle=float(max_view_angle),
        height=[float(x) for x in height],
        pitch_deg=[float(x) for x in pitch_deg],
        clearance=float(clearance),
        min_area=int(min_area),
        border=int(border),
        max_occlusion_px=float(max_occlusion_px),
    )
    bar = tqdm(total=num_scenes * frames_per_scene, desc=f"doors {split}", disable=not progress, unit="frame")
    scene_dirs = []
    for s in range(num_scenes):
        building = door_building(split, s, seed)
        objects = building_objects(building)
        doors = np.flatnonzero(objects.class_id == DOOR)
        if doors.size == 0:  # pragma: no cover - every generated building has doors
            raise RuntimeError(f"building {building.family} {building.seed} has no door")
        final = root / f"scene_{s:03d}"
        rng = np.random.default_rng([int(seed), ("train", "val", "test").index(split), s, 0xD00])
        with fat_writer.partial_dir(final) as tmp:
            with BuildingRenderer(building, width, height_px) as renderer:
                _write_scene(
                    tmp, rng, building, objects, doors, renderer, K, T_rl, frames_per_scene, settings,
                    image_format, bbox_order, bar,
                )  # fmt: skip
            meta = {"family": building.family, "building_seed": int(building.seed), "split": split, **settings}
            (tmp / "_doors.json").write_text(json.dumps(meta, indent=1))
        scene_dirs.append(final)
    bar.close()
    return scene_dirs


def _sample_pose(rng, objects, doors, clear, K, T_rl, st):
    """A left camera pose looking at a random door, both cameras in free space; or None."""
    k = int(doors[rng.integers(len(doors))])
    lo, hi = objects.box_min[k], objects.box_max[k]
    centre = 0.5 * (lo + hi)
    ext = hi - lo
    normal = np.array([0.0, 1.0]) if ext[0] >= ext[1] else np.array([1.0, 0.0])
    normal *= 1 if rng.random() < 0.5 else -1
    ang = math.radians(rng.uniform(-st["max_view_angle"], st["max_view_angle"]))
    tangent = np.array([-normal[1], normal[0]])
    d = rng.uniform(*st["distance"])
    xy = centre[:2] + d * (math.cos(ang) * normal + math.sin(ang) * tangent)
    if clear(xy) < st["clearance"]:
        return None
    half_fov = math.atan(0.5 * K[0, 2] * 2 / K[0, 0])
    to_door = centre[:2] - xy
    yaw = math.atan2(to_door[1], to_door[0]) + rng.uniform(-0.7, 0.7) * half_fov
    T = np.asarray(
        _robot_camera(xy, yaw, rng.uniform(*st["height"]), rng.uniform(*st["pitch_deg"])),
        np.float64,
    )
    T_right = T_rl @ T
    if clear(_cam_position(T_right)[:2]) < st["clearance"]:
        return None
    return k, T, T_right


def _robot_camera(xy, yaw, height, pitch):
    return robot_camera(xy, yaw, height, pitch)


def _write_scene(
    scene_dir, rng, building, objects, doors, renderer, K, T_rl, frames, st, image_format, bbox_order, bar
):  # fmt: skip

    width, height = renderer.width, renderer.height
    seg_id = fat_writer.segmentation_id(_CLASS)
    clear = _Clearance(building)
    first = objects.box_max[doors[0]] - objects.box_min[doors[0]]
    table = [ObjectClass(_CLASS, "box", tuple(float(x) for x in first), (0.45, 0.28, 0.15), seg_id)]
    fat_writer.write_settings(scene_dir, table, K, width, height)
    written, tries = 0, 0
    while written < frames:
        tries += 1
        if tries > 200 * frames:
            raise RuntimeError(
                f"building {building.family} {building.seed}: only {written} of {frames} door views passed the filter "
                f"in {tries - 1} poses; loosen distance / clearance / min_area"
            )
        pose = _sample_pose(rng, objects, doors, clear, K, T_rl, st)
        if pose is None:
            continue
        k, T, T_right = pose
        lo, hi = objects.box_min[k], objects.box_max[k]
        c_world, ext = 0.5 * (lo + hi), hi - lo
        R_cam = T[:3, :3]  # object frame = world axes
        c_cam = Q.transform_points(T, c_world, xp=np)
        corners = Q.cuboid_corners(R_cam, c_cam, ext / 2, xp=np)
        if np.min(corners[:, 2]) < 0.2:
            continue
        # cheap geometric checks before rendering: both exact boxes inside the image and large
        # enough, and clear lines of sight on the grid from both cameras to the door
        exact = [object_box("box", R_cam, c_cam + off, ext, K) for off in (np.zeros(3), T_rl[:3, 3])]
        b = float(st["border"])
        if any(
            e[0] < b - 0.5 or e[1] < b - 0.5 or e[2] > width - b - 0.5 or e[3] > height - b - 0.5
            or (e[2] - e[0]) * (e[3] - e[1]) < st["min_area"]
            for e in exact
        ):  # fmt: skip
            continue
        if not all(clear.sees(_cam_position(p)[:2], c_world[:2], k, objects) for p in (T, T_right)):
            continue
        views, boxes, ok = [], [], True
        for pose_T in (T, T_right):
            view = renderer.render(K, pose_T, outputs=("seg",))  # the filter first: one pass
            det = renderer.detect(view["seg"], (DOOR,), min_area=int(st["min_area"]), border=int(st["border"]))
            found = _door_box(det, k)
            if found is None or np.max(np.abs(found[0] - exact[len(views)])) > st["max_occlusion_px"]:
                ok = False
                break
            views.append(view)
            boxes.append(found[0])
        if not ok:
            continue
        for view, pose_T in zip(views, (T, T_right)):
            view.update(renderer.render(K, pose_T, outputs=("rgb", "depth")))
        stem = f"{written:06d}"
        placed = [(0, R_cam, c_cam, ext, boxes[0], boxes[1])]
        for side, view, pose_T, offset in (
            ("left", views[0], T, np.zeros(3)),
            ("right", views[1], T_right, T_rl[:3, 3]),
        ):
            frame = fat_writer.frame_json(placed, table, K, pose_T, offset, bbox_order)
            frame["objects"][0]["building_object"] = int(k)
            seg = np.where(view["seg"] == k, seg_id, 0).astype(np.uint8)
            fat_writer.write_camera(scene_dir / f"{stem}.{side}", image_format, view["rgb"], view["depth"], seg, frame)
        written += 1
        bar.update(1)


def door_data_baseline(path) -> float:
    """The stereo baseline (m) recorded in the ``_doors.json`` of the scenes at or below ``path``.

    Raises ValueError naming ``path`` when it holds no door scene or its scenes disagree.
    """
    path = pathlib.Path(path)
    files = [path / "_doors.json"] if (path / "_doors.json").exists() else sorted(path.rglob("_doors.json"))
    if not files:
        raise ValueError(f"data: {path} holds no door scene (no _doors.json; write one with jaxsem.mapping.make_doors)")
    values = {float(json.loads(f.read_text())["baseline"]) for f in files}
    if len(values) != 1:
        raise ValueError(f"data: the door scenes under {path} have different baselines {sorted(values)}")
    return values.pop()


def _sizes(config) -> dict[str, Any]:
    return dict(
        input_size=config.model.input_size,
        global_padding=config.model.global_padding,
        num_points=config.scene.num_points,
        class_names=config.class_names or None,
    )


def door_eval_batch(path, config, num: int | None = None) -> dict:
    """Every door of the directory ``path`` once (the first ``num``), as one batch sized for the
    VoluMon ``config`` (:func:`jaxsem.volumon.data.volumon_eval_batch` with the writer's baseline)."""

    return volumon_eval_batch(
        path, num=num, loader_options={"baseline": door_data_baseline(path)}, **_sizes(config)
    )  # fmt: skip


def train_door_model(
    config,
    data,
    workdir,
    *,
    eval_data=None,
    stop_after: int | None = None,
    log: Callable[[str], None] | None = print,
    force: bool = False,
) -> dict:
    """Train the VoluMon ``config`` (e.g. ``jaxsem.volumon.get_config("dual", "door")``) on the door
    directory ``data`` (classes ``config.class_names``, the stereo baseline of its ``_doors.json``).

    ``eval_data``: directory the periodic evaluation scores (default: ``data``, a fit check);
    ``stop_after``: steps of this call (a chunk; re-running with the same ``workdir`` resumes).
    Returns :func:`jaxsem.volumon.train_and_evaluate` 's dict.
    """

    data = pathlib.Path(data).resolve()
    config = config.replace(data="directory", data_dir=str(data))
    batch_fn, n = volumon_batch_source(
        data,
        batch_size=config.batch_size,
        seed=config.seed,
        loader_options={"baseline": door_data_baseline(data)},
        **_sizes(config),
    )
    if log is not None:
        log(f"training on {n} doors of {data}")
    eval_batch = door_eval_batch(eval_data or data, config, config.num_eval) if config.num_eval > 0 else None
    return train_and_evaluate(
        config,
        workdir,
        stop_after=stop_after,
        progress=False,
        log=log,
        force=force,
        batch_fn=batch_fn,
        eval_batch=eval_batch,
    )
