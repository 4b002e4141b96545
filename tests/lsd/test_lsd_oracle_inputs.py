"""The oracle's inputs: expert shards whose crops come from the true map (``with_full_map``)."""

import numpy as np
import pytest

from jaxsem.lsd import with_full_map
from jaxsem.lsd._expert import full_map_state  # layers: white-box
from jaxsem.planning import (
    DOOR,
    EXIT_SIGN,
    FREE,
    NONE,
    OCCUPIED,
    UNKNOWN,
    WINDOW,
    generate_building,
)

SIZE = 160


@pytest.fixture(scope="module")
def building():
    return generate_building(3, "train")


def _shard(building, n, seed=0):
    """A shard-like dict: random robot positions (some near the map's edge), placeholder crops."""
    rng = np.random.default_rng(seed)
    H, W = building.occupancy.shape
    rows = rng.integers(0, H, n)
    cols = rng.integers(0, W, n)
    rows[0], cols[0] = 0, W - 1  # a corner: most of the crop is off the map
    xy = building.origin + (np.stack([cols, rows], -1) + 0.5) * building.resolution
    return (
        {
            "occupancy": np.full((n, SIZE, SIZE), UNKNOWN, np.int8),
            "semantic": np.zeros((n, SIZE, SIZE), np.int8),
            "context": rng.normal(size=(n, 4)).astype(np.float32),
            "path_mask": rng.random((n, SIZE, SIZE)) < 0.01,
            "robot_xy": xy.astype(np.float32),
            "building_seed": np.int64(building.seed),
            "family": np.str_(building.family),
            "resolution": np.float32(building.resolution),
        },
        rows,
        cols,
    )


def test_crops_match_the_true_map_cell_by_cell(building):
    shard, rows, cols = _shard(building, 6)
    out = with_full_map(shard, building)
    H, W = building.occupancy.shape
    is_object = np.isin(building.semantic, (DOOR, WINDOW, EXIT_SIGN))
    rng = np.random.default_rng(7)
    for i in range(len(rows)):
        for a, b in rng.integers(0, SIZE, (300, 2)):  # brute force: crop cells against the building
            r, c = rows[i] - SIZE // 2 + a, cols[i] - SIZE // 2 + b
            inside = 0 <= r < H and 0 <= c < W
            want_occ = (OCCUPIED if building.occupancy[r, c] else FREE) if inside else OCCUPIED
            want_sem = int(building.semantic[r, c]) if inside and is_object[r, c] else NONE
            assert out["occupancy"][i, a, b] == want_occ, (i, a, b)
            assert out["semantic"][i, a, b] == want_sem, (i, a, b)
        assert out["occupancy"][i, SIZE // 2, SIZE // 2] == (OCCUPIED if building.occupancy[rows[i], cols[i]] else FREE)
    assert not (out["occupancy"] == UNKNOWN).any()
    # everything but the crops is carried over unchanged
    for k in ("context", "path_mask", "robot_xy"):
        np.testing.assert_array_equal(out[k], shard[k])
    assert out["occupancy"].dtype == np.int8 and out["semantic"].dtype == np.int8


def test_regenerates_the_building_from_the_shard(building):
    shard, _, _ = _shard(building, 3, seed=1)
    np.testing.assert_array_equal(with_full_map(shard)["occupancy"], with_full_map(shard, building)["occupancy"])


def test_full_map_state_has_no_unknown_and_object_classes_only(building):
    st = full_map_state(building)
    occ, sem = np.asarray(st.occupancy), np.asarray(st.semantic)
    assert set(np.unique(occ)) <= {FREE, OCCUPIED}
    assert set(np.unique(sem)) <= {NONE, DOOR, WINDOW, EXIT_SIGN}
    assert (sem == DOOR).any() and (sem == WINDOW).any()


def test_bad_shards(building):
    shard, _, _ = _shard(building, 2)
    with pytest.raises(ValueError, match="robot_xy"):
        with_full_map({k: v for k, v in shard.items() if k != "robot_xy"})
    other = generate_building(4, "train")
    with pytest.raises(ValueError, match="building"):
        with_full_map(shard, other)


def test_the_oracle_sampler_sees_the_true_map_at_the_robots_window(building):
    # In the online loop the robot's partial map is all unknown here; the wrapped sampler must be
    # handed the true map's crops at the same window (and the same goal context).
    from jaxsem.lsd import full_map_sampler
    from jaxsem.planning import empty_map_state, local_inputs

    seen = []

    def stub(inputs):
        seen.append(inputs)
        return np.full((SIZE, SIZE), 1.0 / SIZE**2)

    fn = full_map_sampler(stub, building)
    H, W = building.occupancy.shape
    is_object = np.isin(building.semantic, (DOOR, WINDOW, EXIT_SIGN))
    rng = np.random.default_rng(3)
    for row, col in [(H // 2, W // 3), (2, W - 3)]:
        xy = building.origin + (np.array([col, row]) + 0.5) * building.resolution
        partial = local_inputs(empty_map_state((H, W)), xy, xy + 7.0, True, building)
        out = fn(partial)
        assert out.shape == (SIZE, SIZE)
        got = seen[-1]
        np.testing.assert_array_equal(np.asarray(got.context), np.asarray(partial.context))
        for a, b in rng.integers(0, SIZE, (300, 2)):
            r, c = row - SIZE // 2 + a, col - SIZE // 2 + b
            inside = 0 <= r < H and 0 <= c < W
            want_occ = (OCCUPIED if building.occupancy[r, c] else FREE) if inside else OCCUPIED
            want_sem = int(building.semantic[r, c]) if inside and is_object[r, c] else NONE
            assert got.occupancy[a, b] == want_occ and got.semantic[a, b] == want_sem, (row, col, a, b)
