"""Ground-truth objects of a generated building (doors, windows, exit signs) as boxes and ellipsoids.

The building generator of :mod:`jaxsem.planning` stores its objects only as cells of the semantic
grid. Each 4-connected component of one class is one object; its cells' extent is the object's
footprint box (cell edges, world metres), and a per-class height range (:class:`ObjectHeights`)
makes it a 3D box. The ellipsoid of a box is the one inscribed in it (axis-aligned, radii = half
the box's extents), so its footprint misses only the corner cells of the box: a one-cell error at
the boundary (``tests/integration/test_mapping.py`` checks this on generated buildings).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from ..planning import DOOR, EXIT_SIGN, WINDOW
from ._store import Ellipsoids, ObjectMap, init, update

__all__ = [
    "BuildingObjects",
    "ObjectHeights",
    "box_ellipsoids",
    "building_objects",
    "ground_truth_map",
]


@dataclasses.dataclass(frozen=True)
class ObjectHeights:
    """Vertical extents (z_min, z_max) in metres of each object class and of the walls."""

    wall: tuple = (0.0, 2.7)
    door: tuple = (0.0, 2.1)  # the opening (negative space, as thesis 5.8.1 notes)
    window: tuple = (0.9, 2.1)
    exit_sign: tuple = (1.9, 2.2)


@dataclasses.dataclass(frozen=True)
class BuildingObjects:
    """Objects of one building (numpy).

    class_id: (K,) int32 semantic id (``DOOR``, ``WINDOW`` or ``EXIT_SIGN`` of jaxsem.planning).
    cells: (K, 4) int64 cell boxes ``[r0, c0, r1, c1)``.
    box_min, box_max: (K, 3) world corners (x, y, z) in metres.
    """

    class_id: np.ndarray
    cells: np.ndarray
    box_min: np.ndarray
    box_max: np.ndarray

    def __len__(self) -> int:
        return int(self.class_id.shape[0])

    def ellipsoids(self, capacity: int | None = None) -> Ellipsoids:
        """The inscribed ellipsoids as :class:`Ellipsoids`, padded to ``capacity`` slots."""
        return box_ellipsoids(self.box_min, self.box_max, self.class_id, capacity)


def building_objects(building, heights: ObjectHeights = ObjectHeights()) -> BuildingObjects:
    """Doors, windows and exit signs of ``building`` (a :class:`jaxsem.planning.Building` or any
    object with ``semantic`` (H, W), ``origin`` (2,) and ``resolution``) as boxes."""
    from scipy import ndimage  # deferred: scipy.ndimage is slow to import and only this function needs it

    sem = np.asarray(building.semantic)
    if sem.ndim != 2:
        raise ValueError(f"building.semantic: expected an (H, W) grid, got shape {sem.shape}")
    origin = np.asarray(building.origin, np.float64).reshape(2)
    res = float(building.resolution)
    zs = {DOOR: heights.door, WINDOW: heights.window, EXIT_SIGN: heights.exit_sign}
    classes, cells, lo, hi = [], [], [], []
    for cls in (DOOR, WINDOW, EXIT_SIGN):
        labels = ndimage.label(sem == cls)[0]  # type: ignore[index]
        for sl in ndimage.find_objects(labels):
            r0, r1, c0, c1 = sl[0].start, sl[0].stop, sl[1].start, sl[1].stop
            classes.append(cls)
            cells.append((r0, c0, r1, c1))
            lo.append((origin[0] + c0 * res, origin[1] + r0 * res, zs[cls][0]))
            hi.append((origin[0] + c1 * res, origin[1] + r1 * res, zs[cls][1]))
    return BuildingObjects(
        class_id=np.asarray(classes, np.int32),
        cells=np.asarray(cells, np.int64).reshape(-1, 4),
        box_min=np.asarray(lo, np.float64).reshape(-1, 3),
        box_max=np.asarray(hi, np.float64).reshape(-1, 3),
    )


def box_ellipsoids(box_min, box_max, class_id, capacity: int | None = None) -> Ellipsoids:
    """Axis-aligned boxes (K, 3) corners -> their inscribed ellipsoids, padded to ``capacity``."""
    box_min = np.asarray(box_min, np.float64)
    box_max = np.asarray(box_max, np.float64)
    class_id = np.asarray(class_id)
    if box_min.ndim != 2 or box_min.shape[-1] != 3 or box_max.shape != box_min.shape:
        raise ValueError(f"box_min, box_max: expected two (K, 3) arrays, got {box_min.shape} and {box_max.shape}")
    if not np.all(box_max > box_min):
        raise ValueError("box_max: expected box_max > box_min in every coordinate (no flat boxes)")
    if class_id.shape != box_min.shape[:1]:
        raise ValueError(f"class_id: expected shape {box_min.shape[:1]}, got {class_id.shape}")
    k = box_min.shape[0]
    n = k if capacity is None else int(capacity)
    if n < k or n < 1:
        raise ValueError(f"capacity: expected at least {max(k, 1)} slots for {k} boxes, got {capacity}")
    pad = n - k
    dtype = jnp.result_type(float)
    center = np.pad(0.5 * (box_min + box_max), ((0, pad), (0, 0)))
    radii = np.pad(0.5 * (box_max - box_min), ((0, pad), (0, 0)), constant_values=1.0)
    return Ellipsoids(
        rotation=jnp.broadcast_to(jnp.eye(3, dtype=dtype), (n, 3, 3)),
        center=jnp.asarray(center, dtype),
        radii=jnp.asarray(radii, dtype),
        class_id=jnp.asarray(np.pad(class_id.astype(np.int32), (0, pad))),
        valid=jnp.asarray(np.arange(n) < k),
    )


def ground_truth_map(building, capacity: int | None = None, heights: ObjectHeights = ObjectHeights()) -> ObjectMap:
    """An :class:`ObjectMap` holding every object of ``building`` (one update from empty)."""
    objs = building_objects(building, heights)
    n = max(len(objs), 1) if capacity is None else int(capacity)
    dets = objs.ellipsoids(n)
    return update(init(n, dets.center.dtype), dets, gate=0.0)
