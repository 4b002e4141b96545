"""Occupancy maps in the formats robots use, read into the planner's :class:`Building`.

Three formats, chosen by the file name:

- **ROS map_server** (``*.yaml`` next to a PGM / PNG image): ``image``, ``resolution``,
  ``origin: [x, y, yaw]``, ``negate``, ``occupied_thresh``, ``free_thresh`` and ``mode``
  (``trinary``, the default, or ``scale``; ``raw`` is read as values 0..100 = occupancy percent).
  A pixel's occupancy probability is ``(255 - v) / 255`` (``v / 255`` with ``negate: 1``):
  above ``occupied_thresh`` it is occupied, below ``free_thresh`` free, else unknown. Image row 0
  is the top of the map (largest y). A rotated origin (``yaw != 0``) is refused: the planner's
  grids are axis-aligned.
- **MRPT** ``COccupancyGridMap2D`` (``*.gridmap`` or ``*.gridmap.gz``, serialisation version 3,
  8 bits per cell): a byte ``0x80 | len(name)``, the class name, the version and bits-per-cell
  bytes, ``size_x, size_y`` (uint32 LE), ``x_min, x_max, y_min, y_max, resolution`` (float32 LE),
  then ``size_x * size_y`` int8 cells, row-major with row 0 at ``y_min``. A cell holds MRPT's
  log-odds of being *free* (MRPT's ``getCell`` maps it to 1 = free, 0 = occupied): negative is
  occupied, 0 unknown (never observed), positive free.
- **A plain image** (``*.png``, ``*.pgm``, ``*.jpg``, ...) with ``resolution=`` given: dark pixels
  (below half the range) are occupied, the rest free, no unknown cells; origin ``(0, 0)`` at the
  bottom-left corner unless given.

:func:`load_occupancy` gives the raw three-state grid (:class:`OccupancyGrid`); :func:`load_map`
turns it into a :class:`Building` the navigation loop accepts: occupied and unknown cells are
obstacles (a robot cannot plan through space no sensor has seen; the thesis' real maps were
likewise closed), occupied cells are walls in the semantic grid, and the known (observed) area is
the indoor region. Such a building has no rooms or exterior doors (empty arrays) and family
``"scanned"``.

Every reader checks the size a file declares (an image's header, a gridmap's ``size_x, size_y``,
the grid a resolution resamples to) against ``max_cells`` (default :data:`MAX_CELLS`) before it
allocates a cell: a 1 MB PNG can declare 30000 x 30000 pixels, and a YAML's ``resolution: 1e-9``
would resample its image over a billion-cell window. The refusal is a ``ValueError`` naming the
file, its declared size and ``max_cells``.
"""

from __future__ import annotations

import dataclasses
import gzip
import math
import pathlib
import struct
import zlib

import numpy as np
import scipy.ndimage

from .._files import check_budget, read_image
from ._buildings import Building, GridMap
from ._grid import DEFAULT_RESOLUTION, FREE, MAX_CELLS, OCCUPIED, UNKNOWN, read_text_as
from ._semantics import (
    apply_annotations,
    building_footprint,
    find_doors,
    footprint_cells,
    largest_open_region,
    read_annotations,
    semantic_grid,
)

#: Square metres of free space with half a metre of clearance a map's outside needs to hold
#: Inside-Outside goals; with less, its largest open area (a hall) stands in for the outside.
MIN_OUTSIDE_AREA = 50.0
#: Square metres the largest open area needs to stand in for a missing outside.
MIN_HALL_AREA = 5.0
_IMAGE_SUFFIXES = (".png", ".pgm", ".ppm", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


@dataclasses.dataclass(frozen=True)
class OccupancyGrid(GridMap):
    """A three-state occupancy grid as read from a map file (numpy, ``[row, col] = [y, x]``).

    occupancy: (H, W) int8 in {UNKNOWN, FREE, OCCUPIED} = {-1, 0, 1}; row 0 at the lowest y.
    origin: (2,) world (x, y) of the corner of cell [0, 0]; resolution: metres per cell.
    source: the file it came from.
    """

    occupancy: np.ndarray
    origin: np.ndarray
    resolution: float
    source: str = ""

    @property
    def extent_m(self) -> tuple:
        """(width, height) in metres."""
        h, w = self.occupancy.shape
        return (w * self.resolution, h * self.resolution)


def load_occupancy(
    path,
    *,
    resolution: float | None = None,
    origin=None,
    hatch_px: float | None = None,
    max_cells: int = MAX_CELLS,
) -> OccupancyGrid:
    """Reads a ROS map_server YAML, an MRPT gridmap or a plain image (``resolution`` needed).

    hatch_px: for a plain image whose obstacles are drawn as hatched outlines (e.g. ir-sim's
    HM3D house drawings): light regions no wider than ``2 * hatch_px`` pixels anywhere (their
    largest inscribed circle has a radius of at most ``hatch_px``) lie between hatch lines and
    are occupied.
    max_cells: the most cells (image pixels) a file may declare; checked on its header before
        any cell is read (default :data:`MAX_CELLS`, 8192 x 8192).

    Raises:
      ValueError: naming the file and the field for a missing file, an unknown format, a bad or
        missing field, a truncated cell array, a plain image without ``resolution``, or a declared
        size over ``max_cells`` (then naming the size and ``max_cells``).
    """
    max_cells = check_budget("max_cells", max_cells)
    path = pathlib.Path(path)
    if not path.is_file():
        raise ValueError(f"path: no such map file {str(path)!r}")
    name = path.name.lower()
    if name.endswith((".yaml", ".yml")):
        grid = _read_ros_yaml(path, max_cells)
    elif name.endswith((".gridmap", ".gridmap.gz")):
        grid = _read_mrpt_gridmap(path, max_cells)
    elif name.endswith(_IMAGE_SUFFIXES):
        if resolution is None:
            raise ValueError(f"{path}: a plain image map needs resolution= (metres per pixel)")
        occ = _read_image(path, max_cells)
        dark = occ < 128
        if hatch_px is not None:
            if not (math.isfinite(hatch_px) and hatch_px > 0):
                raise ValueError(f"hatch_px: expected a positive number of pixels, got {hatch_px}")
            labels, n = scipy.ndimage.label(~dark)  # type: ignore[misc]
            if n:
                widest = np.asarray(
                    scipy.ndimage.maximum(scipy.ndimage.distance_transform_edt(~dark), labels, np.arange(1, n + 1))
                )
                dark = dark | np.isin(labels, 1 + np.nonzero(widest <= hatch_px)[0])
                # A plotted figure's padding: light bands across the image's whole width (or
                # height) at its top / bottom (left / right) edge are not part of the map.
                for band in (dark[:, ::1], dark.T):
                    for rows in (range(band.shape[0]), range(band.shape[0] - 1, -1, -1)):
                        for r in rows:
                            if band[r].mean() > 0.02:  # the frame line (a 1-2 % edge line is not)
                                break
                            band[r] = True
        binary = np.where(dark, OCCUPIED, FREE).astype(np.int8)[::-1]
        grid = OccupancyGrid(binary, np.zeros(2), 1.0, str(path))
    else:
        raise ValueError(
            f"{path}: unknown map format (expected .yaml (ROS map_server), .gridmap[.gz] (MRPT) or an image)"
        )
    if resolution is not None:
        if not (math.isfinite(resolution) and resolution > 0):
            raise ValueError(f"resolution: expected a positive number of metres per cell, got {resolution}")
        grid = dataclasses.replace(grid, resolution=float(resolution))
    if origin is not None:
        o = np.asarray(origin, float).reshape(-1)
        if o.shape != (2,) or not np.all(np.isfinite(o)):
            raise ValueError(f"origin: expected finite world (x, y), got {origin!r}")
        grid = dataclasses.replace(grid, origin=o)
    return grid


def load_map(
    path,
    *,
    resolution: float | None = None,
    origin=None,
    unknown_is_obstacle: bool = True,
    cell_size: float | None = DEFAULT_RESOLUTION,
    doors: bool = True,
    annotations=None,
    footprint_gap: float = 2.0,
    hatch_px: float | None = None,
    footprint: str = "auto",
    max_cells: int = MAX_CELLS,
) -> Building:
    """A :class:`Building` from a map file (see the module docstring for formats and rules).

    resolution, origin: override the file's (a plain image needs ``resolution``).
    unknown_is_obstacle: unknown cells block the robot (default) or count as free space.
    cell_size: metres per cell of the planner's grid; the map is resampled to it (default
        0.1 m, the grid the LSD network was trained on: its 160-cell window must cover 16 m);
        None keeps the file's cells.
    doors: find doors from the occupancy (:func:`find_doors`); annotations: a JSON file (or its
        dict) of hand-drawn boxes (:func:`read_annotations`); footprint_gap: widest wall opening
        (m) closed when the building's footprint is separated from the outside; hatch_px: see
        :func:`load_occupancy`; footprint: how the inside is told from the outside,
        :func:`building_footprint`'s ``method`` or ``"none"`` (the whole map is the building, e.g.
        a drawing of a house's floor).
    max_cells: the most cells the file may declare, the resampled grid may have, and the
        footprint's work may take (default :data:`MAX_CELLS`, 8192 x 8192).

    Raises:
      ValueError: naming the file (see :func:`load_occupancy`), also for a map smaller than one
        cell of ``cell_size`` (a resolution off by orders of magnitude) or one over ``max_cells``
        once resampled; naming the argument for a bad one (:func:`grid_to_building`).
    """
    grid = load_occupancy(path, resolution=resolution, origin=origin, hatch_px=hatch_px, max_cells=max_cells)
    if cell_size is not None:
        grid = resample_occupancy(grid, cell_size, max_cells=max_cells)
    return grid_to_building(
        grid,
        unknown_is_obstacle=unknown_is_obstacle,
        doors=doors,
        annotations=annotations,
        footprint_gap=footprint_gap,
        footprint=footprint,
        max_cells=max_cells,
    )


def resample_occupancy(grid: OccupancyGrid, cell_size: float, *, max_cells: int = MAX_CELLS) -> OccupancyGrid:
    """``grid`` on cells of ``cell_size`` metres over the same extent (the last row / column may
    reach past it; what lies past it is unknown). A new cell is occupied when any cell it overlaps
    is, else unknown when any is, else free: walls stay closed and nothing unseen becomes free.

    Raises:
      ValueError: naming the grid's file when its extent is smaller than one new cell (its
        resolution is off by orders of magnitude: every cell would be one mixed cell) or the new
        grid would have more than ``max_cells`` cells (a coarse map resampled finely).
    """
    if not (math.isfinite(cell_size) and cell_size > 0):
        raise ValueError(f"cell_size: expected a positive number of metres per cell, got {cell_size}")
    max_cells = check_budget("max_cells", max_cells)
    if abs(cell_size - grid.resolution) <= 1e-9 * cell_size:
        return grid
    occ = np.asarray(grid.occupancy)
    ratio = cell_size / grid.resolution
    h, w = occ.shape
    source = grid.source or "grid"
    if min(h, w) < ratio * (1 - 1e-9):
        raise ValueError(
            f"{source}: the map is {w} x {h} cells of {grid.resolution:g} m ({w * grid.resolution:.3g} x "
            f"{h * grid.resolution:.3g} m), smaller than one cell of cell_size={cell_size:g} m; check its resolution"
        )
    shape_out = [max(int(math.ceil(n / ratio - 1e-9)), 1) for n in (h, w)]
    if shape_out[0] * shape_out[1] > max_cells:
        raise ValueError(
            f"{source}: {w} x {h} cells of {grid.resolution:g} m resample to {shape_out[1]} x {shape_out[0]} = "
            f"{shape_out[0] * shape_out[1]:,} cells of cell_size={cell_size:g} m, more than max_cells={max_cells:,}"
        )
    rank = np.array([1, 0, 2], np.int8)[occ + 1]  # unknown 1, free 0, occupied 2

    def pool(a, axis):
        n_src = a.shape[axis]
        n_out = max(int(math.ceil(n_src / ratio - 1e-9)), 1)
        lo = np.floor(np.arange(n_out) * ratio + 1e-9).astype(np.int64)
        hi = np.ceil((np.arange(n_out) + 1) * ratio - 1e-9).astype(np.int64) - 1
        width = int((hi - lo).max()) + 1  # at most ratio + 1 <= n_src + 1 (checked above)
        padded = np.concatenate([a, np.ones_like(np.take(a, [0], axis=axis)).repeat(width + 1, axis=axis)], axis=axis)
        out = np.take(padded, lo, axis=axis)
        for k in range(1, width):
            idx = np.minimum(lo + k, hi)
            out = np.maximum(out, np.take(padded, idx, axis=axis))
        return out

    pooled = pool(pool(rank, 0), 1)
    occ_out = np.array([FREE, UNKNOWN, OCCUPIED], np.int8)[pooled]
    return OccupancyGrid(occ_out, np.asarray(grid.origin, float), float(cell_size), grid.source)


def grid_to_building(
    grid: OccupancyGrid,
    *,
    unknown_is_obstacle: bool = True,
    doors: bool = True,
    annotations=None,
    footprint_gap: float = 2.0,
    footprint: str = "auto",
    max_cells: int = MAX_CELLS,
) -> Building:
    """The planner's world of an :class:`OccupancyGrid`: occupied cells are walls, doors found
    from the occupancy (``doors``) are DOOR, the footprint (:func:`building_footprint`) is
    indoor; where less than ``MIN_OUTSIDE_AREA`` m^2 with half a metre of clearance lies outside
    it, the largest open region (:func:`largest_open_region`, 5 m across, else 4, 3, 2 or 1.5 m) is
    taken as the outside (``outside_is_outdoors=False``: its goals are indoors, and the LSD
    network is told so). ``annotations`` (a JSON path or its dict, validated alike:
    :func:`read_annotations`) are applied last. ``max_cells``: the footprint's work budget
    (:func:`building_footprint`).

    Raises:
      ValueError: naming the argument (``footprint_gap`` not a finite number >= 0, ``footprint``,
        ``annotations`` with an unknown key or a bad box), or naming the grid's file when no cell
        of the result is free: a robot could not stand anywhere, so no start or goal exists (a
        map whose free grey level was read as unknown or occupied: its thresholds or ``negate``).
    """
    occ = np.asarray(grid.occupancy)
    res = float(grid.resolution)
    max_cells = check_budget("max_cells", max_cells)
    if not (isinstance(footprint_gap, (int, float, np.number)) and math.isfinite(footprint_gap) and footprint_gap >= 0):
        raise ValueError(f"footprint_gap: expected a finite number of metres >= 0, got {footprint_gap!r}")
    if footprint not in ("auto", "walls", "density", "none"):
        raise ValueError(f"footprint: expected 'auto', 'walls', 'density' or 'none', got {footprint!r}")
    if footprint != "none" and footprint_cells(occ.shape, footprint_gap, res) > max_cells:
        raise ValueError(
            f"{grid.source or 'grid'}: footprint_gap={footprint_gap:g} m at the map's {res:g} m per cell pads its "
            f"{occ.shape[1]} x {occ.shape[0]} cells to {footprint_cells(occ.shape, footprint_gap, res):,}, more than "
            f"max_cells={max_cells:,}; check the map's resolution"
        )
    if annotations is not None:
        annotations = read_annotations(annotations)
    door_mask = find_doors(occ, res) if doors else np.zeros(occ.shape, bool)
    semantic = semantic_grid(occ, door_mask)
    free = occ == FREE
    if footprint == "none":
        indoor = np.ones(occ.shape, bool)
    else:
        indoor = building_footprint(occ, res, gap=footprint_gap, method=footprint, max_cells=max_cells)
    if (free & indoor).sum() < 0.1 * max(int(free.sum()), 1):
        # No enclosing wall was found (a drawing of one floor's inside, open at the image's
        # edges): the whole map is the building.
        indoor = np.ones_like(indoor)
    roomy = np.asarray(scipy.ndimage.distance_transform_edt(free), float) * res >= 0.5
    outside_is_outdoors = True
    drawn_outside = bool(annotations) and len(annotations.get("outdoor", ())) > 0
    if (roomy & ~indoor).sum() * res**2 < MIN_OUTSIDE_AREA and not drawn_outside:
        # (Hand-drawn "outdoor" boxes, applied below, are the outside: no stand-in then.)
        # The widest open area that is a room's size (5 m across, else 4, 3, 2, 1.5 m: a house's
        # largest room) stands in for the outside.
        for across in (5.0, 4.0, 3.0, 2.0, 1.5):
            hall = largest_open_region(occ, res, across=across)
            if hall.sum() * res**2 >= MIN_HALL_AREA:
                indoor = indoor & ~hall
                outside_is_outdoors = False
                break
    if annotations:
        occ, semantic, indoor, unused = apply_annotations(occ, semantic, indoor, annotations, grid.grid)
        if unused:
            raise ValueError(
                f"annotations: {', '.join(unused)} mark no cell of the map (outside it, or a window / "
                "exit sign box with no occupied cell)"
            )
    blocked = (occ == OCCUPIED) | ((occ == UNKNOWN) if unknown_is_obstacle else False)
    if np.all(blocked):
        unknown = int((occ == UNKNOWN).sum())
        raise ValueError(
            f"{grid.source or 'grid'}: no free cell in the map ({occ.size - unknown} occupied, {unknown} unknown"
            f"{', blocked with unknown_is_obstacle=True' if unknown_is_obstacle and unknown else ''}): no start or "
            "goal can be placed; check the map's thresholds and negate"
        )
    return Building(
        occupancy=np.asarray(blocked, bool),
        semantic=semantic,
        indoor=np.asarray(indoor, bool),
        origin=np.asarray(grid.origin, float),
        resolution=res,
        known=occ != UNKNOWN,
        outside_is_outdoors=outside_is_outdoors,
    )


# ----------------------------------------------------------------------------------------------


def _read_image(path: pathlib.Path, max_cells: int) -> np.ndarray:
    """(H, W) uint8 grey levels of an image file (colour images are averaged), after its header's
    size has been checked against ``max_cells``."""
    img = read_image(path, max_pixels=max_cells, argument="max_cells")
    if img.ndim == 3:
        img = img[..., :3].mean(axis=-1, dtype=np.float32)
    if img.dtype == np.uint16:
        img = img / np.float32(257.0)
    if img.dtype == np.uint8:
        return img
    return np.asarray(np.clip(np.round(img), 0, 255), np.uint8)


def _parse_yaml(path: pathlib.Path) -> dict:
    import yaml  # deferred: only ROS map files need it

    data = read_text_as(path, yaml.safe_load, (yaml.YAMLError,), "YAML file")
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping of map_server fields, got {type(data).__name__}")
    return data


def _number(path, data, key, default=None) -> float:
    if key not in data:
        if default is None:
            raise ValueError(f"{path}: missing field {key!r}")
        return default
    try:
        value = float(data[key])
    except (TypeError, ValueError):
        raise ValueError(f"{path}: field {key!r} must be a number, got {data[key]!r}") from None
    if not math.isfinite(value):
        raise ValueError(f"{path}: field {key!r} must be finite, got {data[key]!r}")
    return value


def _read_ros_yaml(path: pathlib.Path, max_cells: int) -> OccupancyGrid:
    data = _parse_yaml(path)
    if not isinstance(data.get("image"), str) or not data["image"]:
        raise ValueError(f"{path}: missing field 'image' (the map image's file name)")
    image = pathlib.Path(data["image"])
    image = image if image.is_absolute() else path.parent / image
    if not image.is_file():
        raise ValueError(f"{path}: field 'image' names {str(image)!r}, which does not exist")
    resolution = _number(path, data, "resolution")
    if resolution <= 0:
        raise ValueError(f"{path}: field 'resolution' must be positive, got {resolution}")
    origin = data.get("origin")
    if not isinstance(origin, (list, tuple)) or len(origin) not in (2, 3):
        raise ValueError(f"{path}: field 'origin' must be [x, y, yaw], got {origin!r}")
    try:
        origin = [float(v) for v in origin]
    except (TypeError, ValueError):
        raise ValueError(f"{path}: field 'origin' must hold numbers, got {data['origin']!r}") from None
    if not all(math.isfinite(v) for v in origin):
        raise ValueError(f"{path}: field 'origin' must be finite, got {data['origin']!r}")
    if len(origin) == 3 and abs(origin[2]) > 1e-9:
        raise ValueError(f"{path}: field 'origin' has yaw {origin[2]}; only axis-aligned maps (yaw 0) are supported")
    negate = int(_number(path, data, "negate", 0.0))
    if negate not in (0, 1):
        raise ValueError(f"{path}: field 'negate' must be 0 or 1, got {data['negate']!r}")
    occupied_thresh = _number(path, data, "occupied_thresh", 0.65)
    free_thresh = _number(path, data, "free_thresh", 0.196)
    if not 0 <= free_thresh <= occupied_thresh <= 1:
        raise ValueError(
            f"{path}: fields 'free_thresh' ({free_thresh}) and 'occupied_thresh' ({occupied_thresh}) "
            "must satisfy 0 <= free_thresh <= occupied_thresh <= 1"
        )
    mode = str(data.get("mode", "trinary"))
    if mode not in ("trinary", "scale", "raw"):
        raise ValueError(f"{path}: field 'mode' must be trinary, scale or raw, got {mode!r}")
    try:
        pixels = _read_image(image, max_cells).astype(np.float32)
    except ValueError as exc:
        raise ValueError(f"{path}: field 'image': {exc}") from None
    if mode == "raw":
        p = pixels / 100.0
        occ = np.where(pixels > 100, UNKNOWN, np.where(p >= 0.5, OCCUPIED, FREE))
    else:
        p = pixels / 255.0 if negate else (255.0 - pixels) / 255.0
        occ = np.where(p > occupied_thresh, OCCUPIED, np.where(p < free_thresh, FREE, UNKNOWN))
    return OccupancyGrid(occ.astype(np.int8)[::-1].copy(), np.asarray(origin[:2]), resolution, str(path))


def _read_mrpt_gridmap(path: pathlib.Path, max_cells: int) -> OccupancyGrid:
    # The header first, then exactly the cells it declares (within the budget): a gzip stream
    # is never decompressed past them (1 MB of .gz can hold gigabytes).
    opener = gzip.open if path.name.lower().endswith(".gz") else open
    try:
        with opener(path, "rb") as f:
            head = f.read(1 + 127 + 30)
            if not head or not head[0] & 0x80:
                raise ValueError(f"{path}: not an MRPT serialised object (bad first byte)")
            n = head[0] & 0x7F
            name = head[1 : 1 + n].decode("ascii", "replace")
            if name != "COccupancyGridMap2D":
                raise ValueError(f"{path}: class {name!r}, expected COccupancyGridMap2D")
            o = 1 + n
            if len(head) < o + 30:
                raise ValueError(f"{path}: truncated header")
            version, bits = head[o], head[o + 1]
            if version != 3:
                raise ValueError(f"{path}: serialisation version {version}, only version 3 is supported")
            if bits != 8:
                raise ValueError(f"{path}: {bits} bits per cell, only 8 are supported")
            size_x, size_y = struct.unpack_from("<II", head, o + 2)
            x_min, x_max, y_min, y_max, resolution = struct.unpack_from("<5f", head, o + 10)
            o += 30
            if size_x == 0 or size_y == 0 or not (resolution > 0 and math.isfinite(resolution)):
                raise ValueError(f"{path}: bad header (size {size_x} x {size_y}, resolution {resolution})")
            if not (math.isfinite(x_min) and math.isfinite(y_min)):
                raise ValueError(f"{path}: bad header: origin (x_min, y_min) = ({x_min}, {y_min}) must be finite")
            if size_x * size_y > max_cells:
                raise ValueError(
                    f"{path}: declares {size_x} x {size_y} = {size_x * size_y:,} cells, more than "
                    f"max_cells={max_cells:,}; pass a larger max_cells to read it"
                )
            raw = head[o:] + f.read(max(size_x * size_y - (len(head) - o), 0))
    except (OSError, EOFError, zlib.error) as exc:
        raise ValueError(f"{path}: not a readable MRPT gridmap ({exc})") from None
    if len(raw) < size_x * size_y:
        raise ValueError(f"{path}: truncated cells ({len(raw)} bytes for {size_x} x {size_y})")
    cells = np.frombuffer(raw, np.int8, size_x * size_y).reshape(size_y, size_x)
    occ = np.where(cells < 0, OCCUPIED, np.where(cells > 0, FREE, UNKNOWN)).astype(np.int8)
    # x_max / y_max are implied by the size; the stored ones are rounded floats.
    del x_max, y_max
    # The header's float32 resolution (0.08 reads 0.0799999982): rounded to a micrometre.
    return OccupancyGrid(occ, np.array([x_min, y_min], float), round(float(resolution), 6), str(path))
