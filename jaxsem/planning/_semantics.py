"""Semantics for a scanned map: doors found from the occupancy, the building's footprint, hand
annotations, and a figure of what was found.

A scanned occupancy grid has walls but no objects. The LSD network reads doors, windows and exit
signs (thesis 3.2), so a real map needs them from somewhere:

- **Doors** (:func:`find_doors`): narrow passages of door width between two open regions. The
  free space is opened with a disk of half the widest door (``width[1] / 2``): what the disk
  cannot reach is narrow (doorways, gaps beside columns, corners). A connected narrow part is a
  door when it touches two different open regions of at least ``min_region`` square metres, its
  widest point is a door's width (``width``) and it is short (a doorway through a wall, not a
  long narrow corridor: its extent along the passage at most ``max_depth``). Gaps beside a
  column or furniture join one region to itself and are not doors; rooms a scan never entered
  give no doors (nothing free on the far side).
- **Footprint** (:func:`building_footprint`): the walls are closed over gaps up to ``gap`` metres
  (doors, laser gaps), and what the outside (the map's border, through unknown and free cells)
  cannot reach is the building. Free cells outside it are outdoors (laser fans through doors and
  windows, courtyards open to the outside); where there are none (a map of one building's
  inside), the largest open region (a hall) stands in for the outside, so that
  Inside-Outside tasks still have a goal region: they end there.
- **Annotations** (:func:`apply_annotations`): a JSON file of world-frame boxes
  ``{"doors": [[x0, y0, x1, y1], ...], "windows": [...], "exit_signs": [...], "outdoor": [...],
  "indoor": [...]}`` (the thesis annotated windows and exit signs by hand). Doors make their
  cells free and DOOR; windows and exit signs make the occupied cells of their box WINDOW /
  EXIT_SIGN (a box with no occupied cell is reported); ``outdoor`` / ``indoor`` boxes override
  the footprint.

All of it is numpy / scipy on the host (once per map, seconds for a campus).
"""

from __future__ import annotations

import json
import math
import pathlib
from collections.abc import Mapping

import numpy as np
import scipy.ndimage as ndi

from .. import quadrics as Q
from .._checks import require_type
from .._files import check_budget
from ._grid import DOOR, EXIT_SIGN, FREE, MAX_CELLS, OCCUPIED, UNKNOWN, WALL, WINDOW, read_text_as

DOOR_WIDTH = (0.6, 1.4)  # metres: the narrowest door a robot passes, the widest double door
_EIGHT = np.ones((3, 3), bool)


def _edt(mask) -> np.ndarray:
    """Distance (cells) from each True cell to the nearest False cell (scipy's EDT, typed)."""
    return np.asarray(ndi.distance_transform_edt(mask), np.float64)


def _label(mask) -> tuple[np.ndarray, int]:
    """8-connected components of ``mask`` (scipy's label, typed)."""
    out = ndi.label(mask, _EIGHT)
    return np.asarray(out[0]), int(out[1])  # type: ignore[index]


def _disk_reach(mask: np.ndarray, radius_cells: float) -> np.ndarray:
    """Opening of ``mask`` by a disk of ``radius_cells``: the cells a disk inside ``mask`` covers."""
    inside = _edt(mask)
    centres = inside > radius_cells
    if not centres.any():
        return np.zeros_like(mask)
    to_centre = _edt(~centres)
    return mask & (to_centre <= radius_cells + 0.5)


def find_doors(
    occupancy,
    resolution: float,
    *,
    width: tuple = DOOR_WIDTH,
    min_region: float = 2.0,
    max_depth: float = 1.5,
) -> np.ndarray:
    """(H, W) bool door cells of a three-state grid (``FREE`` cells are free).

    The cells farther than half the widest door from any obstacle fall into connected open
    regions (rooms, halls, corridor stretches wider than a door) that a door's narrowness
    separates. Every free cell takes the region of its nearest such cell; where two free
    neighbours take different regions (both of at least ``min_region`` m^2), there is a passage
    between them: its seam runs across it. A seam is a door when its length (the passage's
    width) is within ``width`` and the passage is short: the free cells no region covers (a
    region covers the cells within half the widest door of it) around the seam reach at most
    ``max_depth`` metres along it (a doorway through a wall, not a long narrow corridor).
    The door's cells are the passage's cells within half its width of the seam. Gaps beside
    a column join one region to itself and give no seam; rooms a scan never entered give no
    door (nothing free on the far side).

    occupancy: (H, W) int in {UNKNOWN, FREE, OCCUPIED} (or bool, True blocked); resolution:
    metres per cell; width: (narrowest, widest) door in metres; min_region: square metres an open
    region needs to count; max_depth: longest doorway passage in metres.
    """
    occ = np.asarray(occupancy)
    if occ.ndim != 2:
        raise ValueError(f"occupancy: expected an (H, W) grid, got shape {occ.shape}")
    if not (math.isfinite(resolution) and resolution > 0):
        raise ValueError(f"resolution: expected a positive number of metres per cell, got {resolution}")
    lo, hi = (float(w) for w in width)
    if not 0 < lo < hi:
        raise ValueError(f"width: expected (narrowest, widest) door in metres with 0 < narrowest < widest, got {width}")
    free = ~occ if occ.dtype == bool else occ == FREE
    doors = np.zeros(free.shape, bool)
    clearance = _edt(free)  # cells to the nearest blocked cell
    r = 0.5 * hi / resolution
    centres = clearance > r
    regions, n = _label(centres)
    if n < 2:
        return doors
    area = np.bincount(regions.ravel(), minlength=n + 1) * resolution**2
    dist_idx = ndi.distance_transform_edt(~centres, return_indices=True)
    dist, (ir, ic) = np.asarray(dist_idx[0]), np.asarray(dist_idx[1])  # type: ignore[index]
    owner = np.where(free, regions[ir, ic], 0)
    owner = np.where(area[owner] >= min_region, owner, 0)
    uncovered = free & (dist > r + 0.5)
    seam = np.zeros(free.shape, bool)
    for axis in (0, 1):
        a = owner[:-1, :] if axis == 0 else owner[:, :-1]
        b = owner[1:, :] if axis == 0 else owner[:, 1:]
        cut = (a > 0) & (b > 0) & (a != b)
        if axis == 0:
            seam[:-1, :] |= cut
            seam[1:, :] |= cut
        else:
            seam[:, :-1] |= cut
            seam[:, 1:] |= cut
    seams, n_seams = _label(seam)
    lanes, _ = _label(uncovered)
    for j, sl in enumerate(ndi.find_objects(seams), start=1):
        if sl is None:
            continue
        pad = int(math.ceil(r)) + 2
        box = tuple(slice(max(s.start - pad, 0), s.stop + pad) for s in sl)
        part = seams[box] == j
        rc = np.argwhere(part)
        # The passage's width: the seam's length (two cells thick, so its longest extent).
        extent = (rc.max(0) - rc.min(0) + 1) * resolution
        passage = float(np.hypot(*extent)) if min(extent) > 2 * resolution else float(max(extent))
        if not lo <= passage <= hi + 2 * resolution:
            continue
        # Depth: the uncovered free cells of the passage touching the seam.
        touching = np.unique(lanes[box][np.asarray(ndi.binary_dilation(part, _EIGHT), bool)])
        touching = touching[touching > 0]
        if touching.size:
            lane = np.isin(lanes[box], touching)
            ext = (np.argwhere(lane).max(0) - np.argwhere(lane).min(0) + 1) * resolution
            if float(ext.max()) > max_depth + passage:
                continue
            if float(ext.max()) > passage + resolution and float(ext.min()) > max_depth:
                continue
        near_seam = _edt(~part) * resolution <= 0.5 * passage + resolution
        doors[box] |= near_seam & free[box] & (clearance[box] * resolution <= 0.5 * passage + resolution)
    return doors


def building_footprint(
    occupancy, resolution: float, *, gap: float = 2.0, method: str = "auto", max_cells: int = MAX_CELLS
) -> np.ndarray:
    """(H, W) bool: inside the building. occupancy: three-state grid; gap: the widest wall opening
    (metres) closed when separating inside from outside.

    method 'walls': the walls are closed over gaps up to ``gap`` and what the map's border
    cannot reach (through free and unknown cells) is inside: right for a drawn plan or a clean
    map whose walls are closed. 'density': a laser scan's walls are broken and its outside is
    seen only as fans of rays through doors and windows, so the inside is the largest connected
    part of the densely observed free space (at least 60 % free over ``gap`` x ``gap`` metres;
    walls included), closed over ``gap`` and with its holes filled: the fans' sparse tips are
    outside. 'auto': 'density' when the grid has unknown cells (a scan), else 'walls'.

    max_cells: 'density' closes the gaps on the grid padded by ``gap / 2`` metres of cells on each
    side; a padded grid over this budget is refused (a resolution off by orders of magnitude
    turns 2 m into billions of cells).
    """
    occ = np.asarray(occupancy)
    if occ.ndim != 2:
        raise ValueError(f"occupancy: expected an (H, W) grid, got shape {occ.shape}")
    if method not in ("auto", "walls", "density"):
        raise ValueError(f"method: expected 'auto', 'walls' or 'density', got {method!r}")
    if not (isinstance(gap, (int, float, np.number)) and math.isfinite(gap) and gap >= 0):
        raise ValueError(f"gap: expected a finite number of metres >= 0, got {gap!r}")
    if not (isinstance(resolution, (int, float, np.number)) and math.isfinite(resolution) and resolution > 0):
        raise ValueError(f"resolution: expected a positive number of metres per cell, got {resolution!r}")
    max_cells = check_budget("max_cells", max_cells)
    walls = occ == OCCUPIED
    if method == "auto":
        method = "density" if (occ == UNKNOWN).any() else "walls"
    if method == "density":
        radius = max(int(round(0.5 * gap / resolution)), 1)
        padded_cells = footprint_cells(occ.shape, gap, resolution)
        if padded_cells > max_cells:
            raise ValueError(
                f"gap: {gap:g} m at resolution {resolution:g} m per cell pads the {occ.shape[1]} x {occ.shape[0]} grid "
                f"to {padded_cells:,} cells, more than max_cells={max_cells:,}; check the resolution"
            )
        free = occ == FREE
        k = max(int(round(gap / resolution)) | 1, 3)
        dense = free & (ndi.uniform_filter(free.astype(np.float32), k) >= 0.6)
        near_dense = _edt(~dense) * resolution <= 0.5 * gap
        solid = dense | (walls & near_dense)
        labels, n = _label(solid)
        if n == 0:
            return np.zeros(occ.shape, bool)
        area = np.bincount(labels.ravel(), minlength=n + 1)
        area[0] = 0
        # The density window rounds the building's corners off: they are given back (cells
        # within half a window of the dense part), then gaps are closed and holes filled.
        main = _edt(labels != int(np.argmax(area))) <= k // 2
        padded = np.pad(main, radius + 1)
        closed = ndi.binary_closing(padded, ndi.generate_binary_structure(2, 1), iterations=radius)
        return np.asarray(ndi.binary_fill_holes(closed), bool)[radius + 1 : -radius - 1, radius + 1 : -radius - 1]
    barrier = walls.copy()
    ring = np.concatenate([walls[0], walls[-1], walls[:, 0], walls[:, -1]])
    if ring.all():  # a fence around the whole map (the generator's) bounds no building
        barrier[[0, -1], :] = False
        barrier[:, [0, -1]] = False
    closed = _edt(~barrier) * resolution <= 0.5 * gap
    passable = np.pad(~closed, 1, constant_values=True)
    outside = np.asarray(ndi.label(passable)[0])  # type: ignore[index]
    reached = (outside == outside[0, 0])[1:-1, 1:-1]
    # The closing's band is given back to the outside: a cell within ``gap / 2`` of a reached cell
    # is outside too (walls excepted). A thin wall's inner face is farther than that from any
    # reached cell, so the band never crosses a wall; it enters a closed doorway by under a metre.
    near = _edt(~reached) * resolution <= 0.5 * gap
    return ~((reached | near) & ~walls)


def footprint_cells(shape, gap: float, resolution: float) -> int:
    """Cells of the padded grid :func:`building_footprint` closes gaps on ('density'): the grid
    with ``gap / 2`` metres of cells (at least one) and one more on each side."""
    radius = max(int(round(0.5 * gap / resolution)), 1)
    return (int(shape[0]) + 2 * radius + 2) * (int(shape[1]) + 2 * radius + 2)


def largest_open_region(occupancy, resolution: float, *, across: float = 5.0) -> np.ndarray:
    """(H, W) bool: the largest open area of the free space, a hall: the connected part of the
    cells at least ``across / 2`` metres from any obstacle, grown back by that much (within the
    free space: a disk of ``across / 2`` sweeps it, so its corners are cut). The stand-in for the
    outside of a map that has none; corridors narrower than ``across`` are not part of it."""
    occ = np.asarray(occupancy)
    free = ~occ if occ.dtype == bool else occ == FREE
    r = 0.5 * across / resolution
    centres = _edt(free) >= r
    labels, n = _label(centres)
    if n == 0:
        return np.zeros_like(free)
    area = np.bincount(labels.ravel(), minlength=n + 1)
    area[0] = 0
    hall = labels == int(np.argmax(area))
    return free & (_edt(~hall) <= r)


_ANNOTATION_KEYS = ("doors", "windows", "exit_signs", "outdoor", "indoor")


def read_annotations(source) -> dict:
    """The boxes of an annotation JSON file, or of its already parsed dict (see the module
    docstring), validated: a dict of ``(K, 4)`` float arrays ``[x0, y0, x1, y1]`` (world metres)
    per key present.

    Raises:
      ValueError: naming the file (or ``annotations`` for a dict) and the field: an unknown key
        (a misspelt ``"door"`` would otherwise mark nothing), a value that is not a list of
        4-number boxes, a non-finite box or one with ``x1 < x0`` / ``y1 < y0``.
    """
    if isinstance(source, Mapping):
        where, data = "annotations", source
    else:
        path = pathlib.Path(source)
        where = str(path)
        data = read_text_as(path, json.loads, (json.JSONDecodeError,), "JSON annotation file")
    if not isinstance(data, Mapping):
        raise ValueError(f"{where}: expected an object with keys {', '.join(_ANNOTATION_KEYS)}")
    unknown = sorted(str(k) for k in set(data) - set(_ANNOTATION_KEYS))
    if unknown:
        raise ValueError(f"{where}: unknown field(s) {unknown}; expected {', '.join(_ANNOTATION_KEYS)}")
    out = {}
    for key, boxes in data.items():
        try:
            arr = np.asarray(boxes, float)
            arr = arr.reshape(-1, 4) if arr.size else np.zeros((0, 4))
        except (TypeError, ValueError):
            raise ValueError(f"{where}: field {key!r} must be a list of [x0, y0, x1, y1] boxes in metres") from None
        bad = ~np.all(np.isfinite(arr), axis=1) | (arr[:, 2] < arr[:, 0]) | (arr[:, 3] < arr[:, 1])
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(
                f"{where}: field {key!r}[{i}]: boxes must be finite with x0 <= x1 and y0 <= y1, got {arr[i].tolist()}"
            )
        out[key] = arr
    return out


def _box_cells(box, grid):
    r0, r1, c0, c1 = Q.box_to_cells(box, grid.origin, grid.resolution, grid.shape)
    return slice(r0, r1), slice(c0, c1)


def apply_annotations(occupancy, semantic, indoor, annotations: dict, grid):
    """Copies of (occupancy three-state, semantic, indoor) with the annotation boxes applied on
    ``grid`` (:class:`jaxsem.quadrics.Grid` of the maps' cells, e.g. a map's ``.grid``).
    Returns (occupancy, semantic, indoor, unused) where ``unused`` lists the boxes that touched
    no cell they could mark (``"windows[2]"``). ``annotations`` is checked as
    :func:`read_annotations` checks it."""
    grid = require_type("grid", grid, Q.Grid)
    annotations = read_annotations(annotations)
    occ, sem, ind = np.array(occupancy), np.array(semantic), np.array(indoor)
    if tuple(grid.shape) != occ.shape:
        raise ValueError(f"grid: expected the maps' shape {occ.shape}, got shape {tuple(grid.shape)}")
    unused = []
    for key, cls in (("doors", DOOR), ("windows", WINDOW), ("exit_signs", EXIT_SIGN)):
        for i, box in enumerate(annotations.get(key, ())):
            sl = _box_cells(box, grid)
            if cls == DOOR:
                if occ[sl].size == 0:
                    unused.append(f"{key}[{i}]")
                occ[sl] = FREE
                sem[sl] = DOOR
            else:
                hit = occ[sl] == OCCUPIED
                if not hit.any():
                    unused.append(f"{key}[{i}]")
                sem[sl] = np.where(hit, cls, sem[sl])
    for key, value in (("outdoor", False), ("indoor", True)):
        for i, box in enumerate(annotations.get(key, ())):
            sl = _box_cells(box, grid)
            if ind[sl].size == 0:
                unused.append(f"{key}[{i}]")
            ind[sl] = value
    return occ, sem, ind, unused


def semantic_grid(occupancy, doors) -> np.ndarray:
    """(H, W) int8 semantic grid of a three-state grid: WALL on occupied cells, DOOR on doors."""
    occ = np.asarray(occupancy)
    sem = np.where(occ == OCCUPIED, WALL, 0).astype(np.int8)
    sem[np.asarray(doors, bool)] = DOOR
    return sem


def plot_semantics(building, path, title: str = "") -> None:
    """A figure of a map's occupancy, footprint, doors, windows and exit signs (PNG at ``path``,
    written atomically)."""
    import matplotlib  # deferred: matplotlib is slow to import and only the figures need it

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    occ = np.asarray(building.occupancy, bool)
    sem = np.asarray(building.semantic)
    rgb = np.ones(occ.shape + (3,))
    rgb[~building.indoor & ~occ] = (0.80, 0.90, 1.0)  # outdoors
    rgb[occ] = (0.55, 0.55, 0.55)
    rgb[sem == WALL] = (0.0, 0.0, 0.0)
    for cls, colour in ((DOOR, (0.9, 0.1, 0.1)), (WINDOW, (0.1, 0.4, 0.9)), (EXIT_SIGN, (0.1, 0.7, 0.1))):
        m = np.asarray(ndi.binary_dilation(sem == cls, iterations=2), bool)
        rgb[m] = colour
    h, w = occ.shape
    res = building.resolution
    x0, y0 = building.origin
    fig, ax = plt.subplots(figsize=(8, 8 * h / max(w, 1) + 0.6), dpi=110)
    ax.imshow(rgb, origin="lower", extent=(x0, x0 + w * res, y0, y0 + h * res), interpolation="nearest")
    n_doors = _label(sem == DOOR)[1]
    ax.set_title(
        title or f"{n_doors} doors (red), windows (blue), exit signs (green); outdoors light blue; unknown grey",
        fontsize=9,
    )
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    fig.tight_layout()
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        fig.savefig(tmp, format="png")
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)
        plt.close(fig)


__all__ = [
    "DOOR_WIDTH",
    "apply_annotations",
    "building_footprint",
    "find_doors",
    "largest_open_region",
    "plot_semantics",
    "read_annotations",
    "semantic_grid",
]
