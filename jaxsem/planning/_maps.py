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
"""

from __future__ import annotations

import dataclasses
import gzip
import math
import os
import pathlib
import struct

import numpy as np

from ._buildings import Building
from ._grid import FREE, OCCUPIED, UNKNOWN, WALL

_IMAGE_SUFFIXES = (".png", ".pgm", ".ppm", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


@dataclasses.dataclass(frozen=True)
class OccupancyGrid:
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
    def shape(self) -> tuple:
        return tuple(self.occupancy.shape)

    @property
    def extent_m(self) -> tuple:
        """(width, height) in metres."""
        h, w = self.occupancy.shape
        return (w * self.resolution, h * self.resolution)


def load_occupancy(path, *, resolution: float | None = None, origin=None) -> OccupancyGrid:
    """Reads a ROS map_server YAML, an MRPT gridmap or a plain image (``resolution`` needed).

    Raises:
      ValueError: naming the file and the field for a missing file, an unknown format, a bad or
        missing field, a truncated cell array, or a plain image without ``resolution``.
    """
    path = pathlib.Path(path)
    if not path.is_file():
        raise ValueError(f"path: no such map file {str(path)!r}")
    name = path.name.lower()
    if name.endswith((".yaml", ".yml")):
        grid = _read_ros_yaml(path)
    elif name.endswith((".gridmap", ".gridmap.gz")):
        grid = _read_mrpt_gridmap(path)
    elif name.endswith(_IMAGE_SUFFIXES):
        if resolution is None:
            raise ValueError(f"{path}: a plain image map needs resolution= (metres per pixel)")
        occ = _read_image(path)
        binary = np.where(occ < 128, OCCUPIED, FREE).astype(np.int8)[::-1]
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


def load_map(path, *, resolution: float | None = None, origin=None, unknown_is_obstacle: bool = True) -> Building:
    """A :class:`Building` from a map file (see the module docstring for formats and rules).

    unknown_is_obstacle: unknown cells block the robot (default) or count as free space.
    """
    grid = load_occupancy(path, resolution=resolution, origin=origin)
    return grid_to_building(grid, unknown_is_obstacle=unknown_is_obstacle)


def grid_to_building(grid: OccupancyGrid, *, unknown_is_obstacle: bool = True) -> Building:
    """The planner's world of an :class:`OccupancyGrid` (occupied cells are walls; the observed
    area is indoor)."""
    occ = np.asarray(grid.occupancy)
    blocked = (occ == OCCUPIED) | ((occ == UNKNOWN) if unknown_is_obstacle else False)
    semantic = np.where(occ == OCCUPIED, WALL, 0).astype(np.int8)
    return Building(
        occupancy=np.asarray(blocked, bool),
        semantic=semantic,
        indoor=occ != UNKNOWN,
        origin=np.asarray(grid.origin, float),
        resolution=float(grid.resolution),
        entrance=np.full(2, np.nan),
        exterior_doors=np.zeros((0, 4), np.int64),
        rooms=np.zeros((0, 4), np.int64),
        family="scanned",
        seed=-1,
    )


# ----------------------------------------------------------------------------------------------


def _read_image(path: pathlib.Path) -> np.ndarray:
    """(H, W) uint8 grey levels of an image file (colour images are averaged)."""
    import cv2

    img = cv2.imread(os.fspath(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{path}: not a readable image")
    if img.ndim == 3:
        img = img[..., :3].mean(axis=-1)
    if img.dtype == np.uint16:
        img = img / 257.0
    return np.asarray(np.clip(np.round(img), 0, 255), np.uint8)


def _parse_yaml(path: pathlib.Path) -> dict:
    import yaml

    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise ValueError(f"{path}: not a readable YAML file ({exc})") from None
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


def _read_ros_yaml(path: pathlib.Path) -> OccupancyGrid:
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
    pixels = _read_image(image).astype(np.float64)
    if mode == "raw":
        p = pixels / 100.0
        occ = np.where(pixels > 100, UNKNOWN, np.where(p >= 0.5, OCCUPIED, FREE))
    else:
        p = pixels / 255.0 if negate else (255.0 - pixels) / 255.0
        occ = np.where(p > occupied_thresh, OCCUPIED, np.where(p < free_thresh, FREE, UNKNOWN))
    return OccupancyGrid(occ.astype(np.int8)[::-1].copy(), np.asarray(origin[:2]), resolution, str(path))


def _read_mrpt_gridmap(path: pathlib.Path) -> OccupancyGrid:
    try:
        raw = gzip.open(path).read() if path.name.lower().endswith(".gz") else path.read_bytes()
    except (OSError, EOFError) as exc:
        raise ValueError(f"{path}: not a readable MRPT gridmap ({exc})") from None
    if not raw or not raw[0] & 0x80:
        raise ValueError(f"{path}: not an MRPT serialised object (bad first byte)")
    n = raw[0] & 0x7F
    name = raw[1 : 1 + n].decode("ascii", "replace")
    if name != "COccupancyGridMap2D":
        raise ValueError(f"{path}: class {name!r}, expected COccupancyGridMap2D")
    o = 1 + n
    if len(raw) < o + 30:
        raise ValueError(f"{path}: truncated header")
    version, bits = raw[o], raw[o + 1]
    if version != 3:
        raise ValueError(f"{path}: serialisation version {version}, only version 3 is supported")
    if bits != 8:
        raise ValueError(f"{path}: {bits} bits per cell, only 8 are supported")
    size_x, size_y = struct.unpack_from("<II", raw, o + 2)
    x_min, x_max, y_min, y_max, resolution = struct.unpack_from("<5f", raw, o + 10)
    o += 30
    if size_x == 0 or size_y == 0 or not (resolution > 0 and math.isfinite(resolution)):
        raise ValueError(f"{path}: bad header (size {size_x} x {size_y}, resolution {resolution})")
    if len(raw) < o + size_x * size_y:
        raise ValueError(f"{path}: truncated cells ({len(raw) - o} bytes for {size_x} x {size_y})")
    cells = np.frombuffer(raw, np.int8, size_x * size_y, o).reshape(size_y, size_x)
    occ = np.where(cells < 0, OCCUPIED, np.where(cells > 0, FREE, UNKNOWN)).astype(np.int8)
    # x_max / y_max are implied by the size; the stored ones are rounded floats.
    del x_max, y_max
    # The header's float32 resolution (0.08 reads 0.0799999982): rounded to a micrometre.
    return OccupancyGrid(occ, np.array([x_min, y_min], float), round(float(resolution), 6), str(path))
