"""Map readers (ROS map_server YAML + image, MRPT gridmap, plain image) on small written files,
against hand-made expectations; bad files are named with the field; the real MRPT campus map when
present (``JAXSEM_MAPS_DIR`` pointing at ``jaxsem data fetch maps``' folder), else skipped."""

import gzip
import os
import pathlib
import struct
import time
import tracemalloc
import zlib

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


def test_a_yaml_syntax_slip_is_one_line_naming_the_file(tmp_path):
    # The YAML parser's message spans lines (it draws a caret under the column); a command's last
    # line of output was "^)", naming nothing.
    (tmp_path / "m.yaml").write_text("image: [room.pgm\nresolution: : :\n")
    with pytest.raises(ValueError) as exc:
        planning.load_map(tmp_path / "m.yaml")
    assert "\n" not in str(exc.value) and str(exc.value).startswith(
        f"{tmp_path / 'm.yaml'}: not a readable YAML file ("
    )


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


# ------------------------------------------------ declared sizes against the budget (issue 45 item 4)


def _one_colour_png(path, width, height):
    """A valid 1-bit grey PNG of one colour: ``height`` equal rows deflate to a few hundred kB."""
    row = b"\x00" + b"\xff" * ((width + 7) // 8)
    squeeze = zlib.compressobj(9)
    body = b"".join(squeeze.compress(row) for _ in range(height)) + squeeze.flush()

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    head = struct.pack(">IIBBBBB", width, height, 1, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", head) + chunk(b"IDAT", body) + chunk(b"IEND", b""))
    return path


def _refused_fast(call, *words):
    """``call()`` raises a ValueError holding ``words`` within a second, allocating under 100 MB."""
    tracemalloc.start()
    start = time.perf_counter()
    try:
        with pytest.raises(ValueError) as info:
            call()
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert time.perf_counter() - start < 1.0
    assert peak < 100e6, peak
    for word in words:
        assert word in str(info.value), str(info.value)


@pytest.fixture(scope="module")
def huge_png(tmp_path_factory):
    return _one_colour_png(tmp_path_factory.mktemp("huge") / "huge.png", 30000, 30000)


def test_a_huge_png_is_refused_from_its_header(huge_png, tmp_path):
    assert huge_png.stat().st_size < 1_000_000  # a small file that declares 900 million pixels
    _refused_fast(lambda: planning.load_map(huge_png, resolution=0.05), "huge.png", "30000 x 30000", "max_cells")
    (tmp_path / "huge.yaml").write_text(f"image: {huge_png}\nresolution: 0.05\norigin: [0, 0, 0]\n")
    _refused_fast(lambda: planning.load_map(tmp_path / "huge.yaml"), "huge.yaml", "huge.png", "30000 x 30000")


def test_the_budget_is_an_argument(tmp_path):
    small = _one_colour_png(tmp_path / "small.png", 40, 30)
    with pytest.raises(ValueError, match=r"small.png: declares 40 x 30 = 1,200 pixels, more than max_cells=1,000"):
        planning.load_occupancy(small, resolution=0.1, max_cells=1000)
    grid = planning.load_occupancy(small, resolution=0.1, max_cells=1200)
    assert grid.shape == (30, 40) and np.all(grid.occupancy == FREE)
    with pytest.raises(ValueError, match="^max_cells: expected a positive whole number"):
        planning.load_occupancy(small, resolution=0.1, max_cells=0)


def test_a_pgm_header_claiming_60000_squared_is_refused(tmp_path):
    path = tmp_path / "claim.pgm"
    path.write_bytes(b"P5\n60000 60000\n255\n" + bytes(64))
    _refused_fast(lambda: planning.load_map(path, resolution=0.05), "claim.pgm", "60000 x 60000", "max_cells")


def test_a_gridmap_header_over_the_budget_is_refused_before_its_cells(tmp_path):
    head = _gridmap_bytes([[0]])[:50]  # the 19-letter class name, version, bits, sizes, floats
    blob = head[:22] + struct.pack("<II", 60000, 60000) + head[30:]
    path = tmp_path / "claim.gridmap.gz"
    # 360 MB of cells behind the header deflate to a few hundred kB: they must not be inflated.
    squeeze = zlib.compressobj(9, zlib.DEFLATED, 31)
    zeros = bytes(1 << 20)
    path.write_bytes(squeeze.compress(blob) + b"".join(squeeze.compress(zeros) for _ in range(360)) + squeeze.flush())
    _refused_fast(lambda: planning.load_map(path), "claim.gridmap.gz", "60000 x 60000", "max_cells")


def test_a_resolution_off_by_orders_of_magnitude_is_refused(tmp_path):
    path = _ros_map(tmp_path, resolution="1e-9")
    _refused_fast(lambda: planning.load_map(path), "m.yaml", "5 x 4 cells", "cell_size")
    # The other way: a coarse map resampled finely would outgrow the budget.
    (tmp_path / "coarse").mkdir()
    coarse = _ros_map(tmp_path / "coarse", resolution=1000.0)
    _refused_fast(lambda: planning.load_map(coarse), "m.yaml", "max_cells")
    # Kept on its own cells, the footprint's closing would pad it by a billion cells.
    _refused_fast(lambda: planning.load_map(path, cell_size=None), "m.yaml", "footprint_gap", "max_cells")


def test_a_gridmap_with_a_nan_origin_is_refused(tmp_path):
    path = tmp_path / "nan.gridmap"
    path.write_bytes(_gridmap_bytes([[0, 1]], x_min=float("nan")))
    with pytest.raises(ValueError, match=r"nan.gridmap: bad header: origin"):
        planning.load_occupancy(path)


# ---------------------------------------------- annotations and map arguments (issue 45 item 6)


def _room():
    """A 3 x 2 m room (0.1 m cells) walled all round: its inside is free."""
    occ = np.full((20, 30), OCCUPIED, np.int8)
    occ[1:-1, 1:-1] = FREE
    return planning.OccupancyGrid(occ, np.zeros(2), 0.1, "room.yaml")


@pytest.mark.parametrize(
    ("note", "words"),
    [
        ({"door": [[1.0, 0.0, 1.5, 0.1]]}, ["annotations", "unknown field", "'door'"]),
        ({"doors": [[float("nan"), 0.0, 1.5, 0.1]]}, ["annotations", "'doors'[0]", "finite"]),
        ({"windows": [[0.0, 0.0, 0.1, 1.0], [2.0, 0.0, 1.0, 0.1]]}, ["'windows'[1]", "x0 <= x1"]),
        ({"outdoor": [[0.0, 0.0, 1.0]]}, ["annotations", "'outdoor'", "[x0, y0, x1, y1]"]),
        ({"indoor": "all"}, ["annotations", "'indoor'"]),
    ],
    ids=["misspelt-key", "nan-box", "flipped-box", "three-numbers", "text"],
)
def test_a_dict_of_annotations_is_checked_as_a_file_is(note, words):
    with pytest.raises(ValueError) as info:
        planning.grid_to_building(_room(), annotations=note)
    for word in words:
        assert word in str(info.value), str(info.value)


def test_a_good_dict_of_annotations_marks_its_cells():
    b = planning.grid_to_building(_room(), annotations={"windows": [[0.0, 0.5, 0.1, 1.5]]}, doors=False)
    assert b.semantic[10, 0] == planning.WINDOW and b.semantic[10, 29] == WALL


@pytest.mark.parametrize("gap", [float("nan"), -3.0, float("inf"), "2"])
def test_a_bad_footprint_gap_is_refused(gap, tmp_path):
    with pytest.raises(ValueError, match="^footprint_gap: expected a finite number of metres >= 0"):
        planning.grid_to_building(_room(), footprint_gap=gap)
    with pytest.raises(ValueError, match="^footprint_gap: expected"):
        planning.load_map(_ros_map(tmp_path), cell_size=None, footprint_gap=gap)


def test_a_map_with_no_free_cell_is_refused_naming_the_file(tmp_path):
    # Every pixel the ROS grey of unknown: a robot could stand nowhere, so no task exists.
    _write_pgm(tmp_path / "m.pgm", np.full((20, 30), 205))
    (tmp_path / "m.yaml").write_text("image: m.pgm\nresolution: 0.1\norigin: [0, 0, 0]\n")
    with pytest.raises(ValueError, match=r"m.yaml: no free cell in the map \(0 occupied, 600 unknown"):
        planning.load_map(tmp_path / "m.yaml", cell_size=None)
    # Read with unknown as free, the same map is a building.
    assert not planning.load_map(tmp_path / "m.yaml", cell_size=None, unknown_is_obstacle=False).occupancy.all()
    walls = planning.OccupancyGrid(np.full((4, 5), OCCUPIED, np.int8), np.zeros(2), 0.1, "walls.gridmap")
    with pytest.raises(ValueError, match=r"walls.gridmap: no free cell in the map \(20 occupied, 0 unknown\)"):
        planning.grid_to_building(walls)
