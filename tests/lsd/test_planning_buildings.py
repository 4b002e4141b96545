"""Procedural buildings: connectivity, doors in walls, exit signs by exterior doors, families."""

import numpy as np
import pytest
import scipy.ndimage

from jaxsem.planning import DOOR, EXIT_SIGN, WALL, WINDOW, generate_building
from jaxsem.planning._buildings import TEST_PARAMS, TRAIN_PARAMS  # layers: white-box

SEEDS = [("train", 0), ("train", 7), ("test", 0), ("test", 11)]


@pytest.fixture(scope="module", params=SEEDS, ids=[f"{f}{s}" for f, s in SEEDS])
def building(request):
    family, seed = request.param
    return generate_building(seed, family)


def _cell(b, xy):
    return tuple(np.floor((np.asarray(xy) - b.origin) / b.resolution).astype(int)[::-1])


def test_every_free_cell_reachable_from_entrance(building):
    b = building
    # 4-connectivity: stricter than the 8-connected planner graph.
    labels, _ = scipy.ndimage.label(~b.occupancy)
    entrance = _cell(b, b.entrance)
    assert not b.occupancy[entrance]
    assert b.indoor.any() and (~b.indoor & ~b.occupancy).any()
    assert np.all(labels[~b.occupancy] == labels[entrance])


def test_rooms_need_their_doors(building):
    # Without the door openings, free space falls apart: doors are what connects the rooms.
    b = building
    closed = b.occupancy | (b.semantic == DOOR)
    _, n = scipy.ndimage.label(~closed)
    assert n > len(b.rooms) // 2


def test_doors_lie_in_walls(building):
    b = building
    door = b.semantic == DOOR
    assert door.any()
    assert not np.any(b.occupancy & door)
    labels, n = scipy.ndimage.label(door)
    for i, sl in enumerate(scipy.ndimage.find_objects(labels)):
        h, w = sl[0].stop - sl[0].start, sl[1].stop - sl[1].start
        assert min(h, w) == 2, "a door cuts through a two-cell wall"
        r0, r1, c0, c1 = sl[0].start, sl[0].stop, sl[1].start, sl[1].stop
        if h == 2:  # opening along columns: walls at both ends of the opening
            ends = [b.occupancy[r0:r1, c0 - 1], b.occupancy[r0:r1, c1]]
        else:
            ends = [b.occupancy[r0 - 1, c0:c1], b.occupancy[r1, c0:c1]]
        assert all(e.all() for e in ends), f"door {i} is not flanked by wall on both ends"


def test_exit_signs_beside_exterior_doors(building):
    b = building
    assert len(b.exterior_doors) >= 1
    ext = np.zeros(b.shape, bool)
    for r0, c0, r1, c1 in b.exterior_doors:
        ext[r0:r1, c0:c1] = True
        assert (b.semantic[r0:r1, c0:c1] == DOOR).all()
        # an exterior door touches the outdoors
        touch = scipy.ndimage.binary_dilation(ext[r0 - 1 : r1 + 1, c0 - 1 : c1 + 1])
        assert (
            touch & ~b.indoor[r0 - 1 : r1 + 1, c0 - 1 : c1 + 1] & ~b.occupancy[r0 - 1 : r1 + 1, c0 - 1 : c1 + 1]
        ).any()
    near_ext = scipy.ndimage.binary_dilation(ext, iterations=3)
    sign = b.semantic == EXIT_SIGN
    assert sign.any()
    assert np.all(near_ext[sign]), "every exit sign sits within 3 cells of an exterior door"
    assert np.all(b.occupancy[sign]) and np.all(b.indoor[sign]), "exit signs hang on the inside wall"
    for r0, c0, r1, c1 in b.exterior_doors:
        box = np.zeros(b.shape, bool)
        box[r0:r1, c0:c1] = True
        assert (scipy.ndimage.binary_dilation(box, iterations=3) & sign).any(), "door without exit sign"


def test_windows_on_exterior_walls(building):
    b = building
    win = b.semantic == WINDOW
    assert win.any()
    assert np.all(b.occupancy[win])
    outdoors = scipy.ndimage.binary_dilation(~b.indoor, iterations=2)
    assert np.all(outdoors[win])


def test_semantic_and_occupancy_consistent(building):
    b = building
    occ_classes = np.isin(b.semantic, [WALL, WINDOW, EXIT_SIGN])
    assert np.array_equal(occ_classes, b.occupancy)
    assert b.semantic.dtype == np.int8 and b.occupancy.dtype == bool and b.indoor.dtype == bool
    # Open outdoor space all around the building, fenced at the map border.
    assert b.occupancy[0].all() and b.occupancy[:, 0].all()
    assert not b.indoor[:5].any() and not b.indoor[:, :5].any()


def test_deterministic_and_families_differ():
    a, a2 = generate_building(3, "train"), generate_building(3, "train")
    assert np.array_equal(a.occupancy, a2.occupancy) and np.array_equal(a.semantic, a2.semantic)
    t = generate_building(3, "test")
    assert a.shape != t.shape or not np.array_equal(a.occupancy, t.occupancy)
    # The families draw from different ranges: test buildings are larger on average.
    tr = [generate_building(s, "train").indoor.sum() for s in range(6)]
    te = [generate_building(s, "test").indoor.sum() for s in range(6)]
    assert np.mean(te) > np.mean(tr)
    assert TRAIN_PARAMS != TEST_PARAMS
    assert TRAIN_PARAMS.seed_offset != TEST_PARAMS.seed_offset


def test_bad_family_and_resolution():
    with pytest.raises(ValueError, match="family"):
        generate_building(0, "val")
    with pytest.raises(ValueError, match="resolution"):
        generate_building(0, "train", resolution=-1.0)
