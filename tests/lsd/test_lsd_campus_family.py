"""The campus building family (issue 25 item 4): long university buildings with wide corridors,
deterministic per seed, one connected indoor network, and passages as wide as the scanned
Malaga campus' (3-6 m corridors, where the train family draws 1.8-2.4 m)."""

import hashlib

import numpy as np
import pytest
import scipy.ndimage

from jaxsem.planning import generate_building

CAMPUS_SEEDS = (0, 4)


@pytest.fixture(scope="module")
def campuses():
    return [generate_building(s, "campus") for s in CAMPUS_SEEDS]


def test_campus_is_deterministic_and_its_own_stream(campuses):
    again = generate_building(CAMPUS_SEEDS[0], "campus")
    np.testing.assert_array_equal(again.occupancy, campuses[0].occupancy)
    assert again.family == "campus"
    train = generate_building(CAMPUS_SEEDS[0], "train")
    assert train.occupancy.shape != campuses[0].occupancy.shape


def test_campus_is_long_connected_and_wide(campuses, script):
    stats = script("benchmarks/lsd/lsd_map_stats.py")
    train_w = np.concatenate(
        [stats.ridge_widths(~b.occupancy & b.indoor, b.resolution) for b in map(generate_building, (0, 4))]
    )
    for b in campuses:
        rows, cols = np.nonzero(b.indoor)
        extent = np.array([np.ptp(rows) + 1, np.ptp(cols) + 1]) * b.resolution
        assert 60.0 <= extent.max() <= 110.0 and 26.0 <= extent.min() <= 44.0, extent
        labels, _ = scipy.ndimage.label(~b.occupancy)
        entrance = tuple(np.floor((b.entrance - b.origin) / b.resolution).astype(int)[::-1])
        inside = ~b.occupancy & b.indoor
        assert np.all(labels[inside] == labels[entrance])  # every room reached from outside
        w = stats.ridge_widths(inside, b.resolution)
        # the campus' ridge widths: p75 4.0 m (benchmarks/results/lsd_map_stats_campus.json)
        assert np.percentile(w, 75) >= 3.0 > np.percentile(train_w, 75)


def test_campus_family_is_pinned():
    # the buildings of the campus fine-tune (train/lsd_house_gpu.py --family campus): a change of
    # the generator that moves them needs a new model or a new family name
    h = hashlib.sha1()
    for seed in (0, 1, 20, 73):
        b = generate_building(seed, "campus")
        for a in (b.occupancy, b.semantic, b.indoor, b.rooms, b.exterior_doors, b.entrance):
            h.update(np.ascontiguousarray(a).tobytes())
    assert h.hexdigest() == "a382ec2cedddbee99395486a2f3bc634cdc15557"


def test_campus_model_loads_by_name():
    import jax

    from jaxsem import lsd

    _, params, config, _ = lsd.load_model("campus")
    _, default_params, default_config, _ = lsd.load_model("default")
    assert config.model == default_config.model  # the same network, other weights
    leaves = [np.asarray(x) for x in jax.tree_util.tree_leaves(params)]
    assert all(np.isfinite(x).all() for x in leaves)
    other = [np.asarray(x) for x in jax.tree_util.tree_leaves(default_params)]
    assert any(not np.array_equal(a, b) for a, b in zip(leaves, other))
    assert lsd.PRETRAINED_CAMPUS.stat().st_size < 2_000_000
