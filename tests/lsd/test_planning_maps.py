"""Map readers (ROS map_server YAML + image, MRPT gridmap, plain image) on small written files,
against hand-made expectations; bad files are named with the field; the real MRPT campus map when
present (``JAXSEM_MAPS_DIR`` pointing at ``jaxsem data fetch maps``' folder), else skipped."""

import gzip
import os
import pathlib
import struct

import numpy as np
import pytest

from jaxsem import planning
from jaxsem.planning import FREE, OCCUPIED, UNKNOWN, WALL


def _write_pgm(path, pixels):
    pixels = np.asarray(pixels, np.uint8)
    h, w = pixels.shape
    path.write_bytes(f"P5\n{w} {h}\n255\n".encode() + pixels.tobytes())


# A 5 x 4 image (top row first, as stored): 0 black, 254 white, 205 ROS grey (unknown).
PIXELS = [
    [0, 0, 0, 0, 0],
    [0, 254, 254, 205, 0],
    [0, 254, 0, 205, 0],
    [0, 0, 0, 0, 0],
]


def _ros_map(tmp_path, **fields):
    _write_pgm(tmp_path / "m.pgm", PIXELS)
    text = {"image": "m.pgm", "resolution": 0.05, "origin": "[-1.0, 2.0, 0.0]", "negate": 0}
    text.update(fields)
    body = "".join(f"{k}: {v}\n" for k, v in text.items() if v is not None)
    (tmp_path / "m.yaml").write_text(body + "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    return tmp_path / "m.yaml"


def test_ros_map_cells_origin_and_flip(tmp_path):
    grid = planning.load_occupancy(_ros_map(tmp_path))
    assert grid.shape == (4, 5)
    assert grid.resolution == pytest.approx(0.05)
    np.testing.assert_allclose(grid.origin, [-1.0, 2.0])
    # Row 0 of the grid is the image's bottom row (lowest y).
    expected_top_down = [
        [OCCUPIED] * 5,
        [OCCUPIED, FREE, FREE, UNKNOWN, OCCUPIED],
        [OCCUPIED, FREE, OCCUPIED, UNKNOWN, OCCUPIED],
        [OCCUPIED] * 5,
    ]
    np.testing.assert_array_equal(grid.occupancy, np.array(expected_top_down)[::-1])


def test_ros_negate_swaps_free_and_occupied(tmp_path):
    grid = planning.load_occupancy(_ros_map(tmp_path, negate=1))
    # With negate, black (0) means free and white occupied.
    assert grid.occupancy[0, 0] == FREE
    assert grid.occupancy[2, 1] == OCCUPIED


def test_building_from_map_blocks_unknown_and_marks_walls(tmp_path):
    world = planning.load_map(_ros_map(tmp_path), cell_size=None)
    assert world.occupancy.dtype == bool
    # Free cells: the three white pixels only (unknown ones are blocked by default).
    assert int((~world.occupancy).sum()) == 3
    assert int((world.semantic == WALL).sum()) == 15
    assert world.family == "scanned" and world.rooms.shape == (0, 4)
    open_world = planning.load_map(_ros_map(tmp_path), unknown_is_obstacle=False, cell_size=None)
    assert int((~open_world.occupancy).sum()) == 5


def _gridmap_bytes(cells, x_min=-2.0, y_min=1.0, res=0.5, version=3, bits=8):
    cells = np.asarray(cells, np.int8)
    sy, sx = cells.shape
    name = b"COccupancyGridMap2D"
    head = bytes([0x80 | len(name)]) + name + bytes([version, bits])
    head += struct.pack("<II", sx, sy) + struct.pack("<5f", x_min, x_min + sx * res, y_min, y_min + sy * res, res)
    return head + cells.tobytes() + b"\x00" * 16  # MRPT writes its options after the cells


def test_mrpt_gridmap_reads_log_odds(tmp_path):
    cells = [[-50, 0, 127], [10, -1, 0]]  # row 0 at y_min; negative occupied, 0 unknown, positive free
    path = tmp_path / "lab.gridmap.gz"
    path.write_bytes(gzip.compress(_gridmap_bytes(cells)))
    grid = planning.load_occupancy(path)
    np.testing.assert_array_equal(grid.occupancy, [[OCCUPIED, UNKNOWN, FREE], [FREE, OCCUPIED, UNKNOWN]])
    np.testing.assert_allclose(grid.origin, [-2.0, 1.0])
    assert grid.resolution == 0.5


def test_plain_image_needs_resolution(tmp_path):
    _write_pgm(tmp_path / "plain.pgm", PIXELS)
    with pytest.raises(ValueError, match="resolution"):
        planning.load_occupancy(tmp_path / "plain.pgm")
    grid = planning.load_occupancy(tmp_path / "plain.pgm", resolution=0.1, origin=(3.0, 4.0))
    assert set(np.unique(grid.occupancy)) <= {FREE, OCCUPIED}
    assert grid.occupancy[1, 1] == FREE and grid.occupancy[0, 0] == OCCUPIED


@pytest.mark.parametrize(
    ("fields", "words"),
    [
        ({"resolution": None}, ["m.yaml", "resolution"]),
        ({"resolution": "abc"}, ["m.yaml", "resolution"]),
        ({"origin": "[1.0, 2.0, 0.5]"}, ["m.yaml", "origin", "yaw"]),
        ({"image": "missing.pgm"}, ["m.yaml", "image", "missing.pgm"]),
        ({"negate": 3}, ["m.yaml", "negate"]),
    ],
)
def test_bad_ros_fields_are_named(tmp_path, fields, words):
    path = _ros_map(tmp_path, **fields)
    with pytest.raises(ValueError) as info:
        planning.load_occupancy(path)
    for word in words:
        assert word in str(info.value)


@pytest.mark.parametrize(
    ("blob", "word"),
    [
        (_gridmap_bytes([[0, 1]], version=2), "version"),
        (_gridmap_bytes([[0, 1]], bits=16), "bits"),
        (_gridmap_bytes([[0, 1, 2, 3]])[:52], "truncated"),
        (b"\x85hello", "COccupancyGridMap2D"),
    ],
    ids=["version", "bits", "truncated", "class"],
)
def test_bad_gridmaps_are_named(tmp_path, blob, word):
    path = tmp_path / "bad.gridmap"
    path.write_bytes(blob)
    with pytest.raises(ValueError, match=word) as info:
        planning.load_occupancy(path)
    assert "bad.gridmap" in str(info.value)


def test_unknown_suffix_and_missing_file(tmp_path):
    with pytest.raises(ValueError, match="no such map file"):
        planning.load_occupancy(tmp_path / "nope.yaml")
    (tmp_path / "m.txt").write_text("x")
    with pytest.raises(ValueError, match="unknown map format"):
        planning.load_occupancy(tmp_path / "m.txt")


def test_real_campus_map_when_present():
    root = os.environ.get("JAXSEM_MAPS_DIR")
    path = pathlib.Path(root or "/nonexistent") / "2006-MalagaCampus.gridmap.gz"
    if not path.is_file():
        pytest.skip("real maps absent (set JAXSEM_MAPS_DIR to the folder of `jaxsem data fetch maps`)")
    grid = planning.load_occupancy(path)
    assert grid.shape == (2738, 1888)
    assert grid.resolution == pytest.approx(0.08)
    unknown = float(np.mean(grid.occupancy == UNKNOWN))
    assert 0.55 < unknown < 0.7  # the 63 % unknown
