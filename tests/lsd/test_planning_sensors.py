"""Ray-cast sensors against slow per-ray references; line of sight; batching; bad input."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsem import quadrics as Q
from jaxsem.planning import DOOR, EXIT_SIGN, FREE, OCCUPIED, UNKNOWN, WINDOW, SensorConfig, empty_map_state, sense
from jaxsem.planning._sensors import cast_rays  # layers: white-box

RES = 0.1
ORIGIN = np.array([-1.0, -2.0])
SMALL = SensorConfig(rays=48)


def _random_world(seed, shape=(90, 110)):
    rng = np.random.default_rng(seed)
    occ = np.zeros(shape, bool)
    occ[[0, -1], :] = True
    occ[:, [0, -1]] = True
    for _ in range(14):
        r, c = rng.integers(2, shape[0] - 6), rng.integers(2, shape[1] - 6)
        occ[r : r + rng.integers(1, 6), c : c + rng.integers(1, 6)] = True
    sem = np.where(occ, 1, 0).astype(np.int8)
    walls = np.argwhere(occ)
    pick = walls[rng.choice(len(walls), 40, replace=False)]
    sem[pick[:20, 0], pick[:20, 1]] = WINDOW
    sem[pick[20:, 0], pick[20:, 1]] = EXIT_SIGN
    free = np.argwhere(~occ)
    doors = free[rng.choice(len(free), 200, replace=False)]
    sem[doors[:, 0], doors[:, 1]] = DOOR
    return occ, sem


def _reference_sense(occ, sem, state_occ, state_sem, pose, cfg):
    """Per-ray, per-sample Python loop of the documented discretisation."""
    occ_out, sem_out = state_occ.copy(), state_sem.copy()
    H, W = occ.shape
    x, y, yaw = pose
    max_range = max(cfg.depth_range, cfg.object_range)
    n = int(math.ceil(max_range / (RES * cfg.step_cells)))
    step = max_range / n
    wide = max(cfg.depth_fov_deg, cfg.object_fov_deg)
    angles = yaw + np.linspace(-math.radians(wide) / 2, math.radians(wide) / 2, cfg.rays)
    rr, cc = int(math.floor((y - ORIGIN[1]) / RES)), int(math.floor((x - ORIGIN[0]) / RES))
    occ_out[rr, cc] = OCCUPIED if occ[rr, cc] else FREE
    for a in angles:
        for i in range(n):
            t = (i + 1) * step
            c = int(math.floor((x + t * math.cos(a) - ORIGIN[0]) / RES))
            r = int(math.floor((y + t * math.sin(a) - ORIGIN[1]) / RES))
            if not (0 <= r < H and 0 <= c < W):
                break
            rel = abs(a - yaw)
            if rel <= math.radians(cfg.depth_fov_deg) / 2 + 1e-6 and t <= cfg.depth_range + 1e-6:
                occ_out[r, c] = OCCUPIED if occ[r, c] else FREE
            if rel <= math.radians(cfg.object_fov_deg) / 2 + 1e-6 and t <= cfg.object_range + 1e-6:
                if sem[r, c] in (DOOR, WINDOW, EXIT_SIGN):
                    sem_out[r, c] = sem[r, c]
            if occ[r, c]:
                break
    return occ_out, sem_out


@pytest.mark.parametrize("seed", [0, 1])
def test_sense_matches_per_ray_reference(seed):
    occ, sem = _random_world(seed)
    rng = np.random.default_rng(seed + 10)
    free = np.argwhere(~occ)
    rc = free[rng.integers(len(free))]
    pose = np.array([ORIGIN[0] + (rc[1] + 0.37) * RES, ORIGIN[1] + (rc[0] + 0.61) * RES, rng.uniform(-3, 3)])
    st = empty_map_state(occ.shape)
    got = sense(occ, sem, st, pose, Q.Grid.host(ORIGIN, RES, occ.shape), SMALL)
    ref_occ, ref_sem = _reference_sense(occ, sem, np.asarray(st.occupancy), np.asarray(st.semantic), pose, SMALL)
    got_occ = np.asarray(got.occupancy)
    assert got.occupancy.dtype == jnp.int8 and got.semantic.dtype == jnp.int8
    assert (got_occ != UNKNOWN).sum() > 100
    np.testing.assert_array_equal(got_occ, ref_occ)
    np.testing.assert_array_equal(np.asarray(got.semantic), ref_sem)
    # What is known is true.
    known = got_occ != UNKNOWN
    assert np.array_equal(got_occ[known] == OCCUPIED, occ[known])


def _dda_range(occ, x, y, a, max_range):
    """Exact entry distance of the first occupied cell along a ray (Amanatides-Woo)."""
    H, W = occ.shape
    px, py = (x - ORIGIN[0]) / RES, (y - ORIGIN[1]) / RES
    dx, dy = math.cos(a), math.sin(a)
    c, r = int(math.floor(px)), int(math.floor(py))
    sx, sy = (1 if dx > 0 else -1), (1 if dy > 0 else -1)
    tdx = abs(1 / dx) if dx != 0 else math.inf
    tdy = abs(1 / dy) if dy != 0 else math.inf
    tx = ((c + (sx > 0)) - px) / dx if dx != 0 else math.inf
    ty = ((r + (sy > 0)) - py) / dy if dy != 0 else math.inf
    t = 0.0
    while t * RES <= max_range:
        if tx < ty:
            t, tx, c = tx, tx + tdx, c + sx
        else:
            t, ty, r = ty, ty + tdy, r + sy
        if not (0 <= r < H and 0 <= c < W) or occ[r, c]:
            return min(t * RES, max_range)
    return max_range


def test_cast_rays_against_exact_traversal():
    occ, _ = _random_world(3)
    x, y = ORIGIN[0] + 55.5 * RES, ORIGIN[1] + 45.5 * RES
    occ[44:48, 54:58] = False
    angles = np.linspace(-math.pi, math.pi, 181)[:-1]
    got = np.asarray(cast_rays(occ, Q.Grid.host(ORIGIN, RES, occ.shape), [x, y], angles, 6.0))
    ref = np.array([_dda_range(occ, x, y, a, 6.0) for a in angles])
    step = 6.0 / math.ceil(6.0 / (0.5 * RES))
    # Samples can only find a cell after entering it, and within one step of the entry, except
    # for rays that clip a corner for less than a step.
    assert np.all(got >= ref - 1e-9)
    close = np.abs(got - ref) <= step + 1e-9
    assert close.mean() >= 0.95, np.c_[angles, ref, got][~close]


def test_nothing_seen_through_walls():
    occ = np.zeros((80, 120), bool)
    occ[[0, -1], :] = True
    occ[:, [0, -1]] = True
    occ[:, 60:62] = True  # a two-cell wall across the map
    sem = np.where(occ, 1, 0).astype(np.int8)
    sem[10:70, 80:82] = DOOR  # doors and a window behind the wall
    sem[30:40, 60:62] = WINDOW
    for yaw in (0.0, 0.3, -0.4):
        st = sense(
            occ,
            sem,
            empty_map_state(occ.shape),
            [ORIGIN[0] + 3.05, ORIGIN[1] + 4.05, yaw],
            Q.Grid.host(ORIGIN, RES, occ.shape),
        )
        o = np.asarray(st.occupancy)
        assert (o[:, :60] != UNKNOWN).sum() > 500
        assert np.all(o[:, 62:] == UNKNOWN), "cells behind the wall were seen"
        s = np.asarray(st.semantic)
        assert not np.any(s[:, 62:])
        if yaw == 0.0:
            assert np.any(s == WINDOW), "the window in the wall itself is seen"
    # Depth reaches 5 m only; the object camera sees doors up to 10 m.
    occ2 = np.zeros((40, 200), bool)
    occ2[[0, -1], :] = True
    sem2 = np.where(occ2, 1, 0).astype(np.int8)
    sem2[18:22, 150:152] = DOOR  # 7.5 m ahead
    sem2[18:22, 185:187] = DOOR  # 11 m ahead
    st = sense(
        occ2,
        sem2,
        empty_map_state(occ2.shape),
        [ORIGIN[0] + 7.55, ORIGIN[1] + 2.05, 0.0],
        Q.Grid.host(ORIGIN, RES, occ2.shape),
    )
    o = np.asarray(st.occupancy)
    assert np.all(o[:, 127:] == UNKNOWN) and o[20, 120] == FREE
    s = np.asarray(st.semantic)
    assert (s[18:22, 150:152] == DOOR).any() and not (s[:, 180:] == DOOR).any()


def test_batched_sense_matches_single_and_jit():
    occ, sem = _random_world(5)
    free = np.argwhere(~occ)[::97][:3]
    poses = np.c_[ORIGIN[0] + (free[:, 1] + 0.5) * RES, ORIGIN[1] + (free[:, 0] + 0.5) * RES, [0.1, 2.0, -1.0]]
    st0 = empty_map_state(occ.shape)
    batch = jax.tree.map(lambda x: jnp.stack([x] * 3), st0)
    out = sense(occ, sem, batch, poses, Q.Grid.host(ORIGIN, RES, occ.shape), SMALL)
    for i in range(3):
        one = sense(occ, sem, st0, poses[i], Q.Grid.host(ORIGIN, RES, occ.shape), SMALL)
        np.testing.assert_array_equal(np.asarray(out.occupancy[i]), np.asarray(one.occupancy))
        np.testing.assert_array_equal(np.asarray(out.semantic[i]), np.asarray(one.semantic))
    # Sensing twice from the same pose changes nothing; sensing accumulates.
    again = sense(occ, sem, one, poses[2], Q.Grid.host(ORIGIN, RES, occ.shape), SMALL)
    np.testing.assert_array_equal(np.asarray(again.occupancy), np.asarray(one.occupancy))


def test_bad_input():
    occ, sem = _random_world(0)
    st = empty_map_state(occ.shape)
    grid = Q.Grid.host(ORIGIN, RES, occ.shape)
    with pytest.raises(ValueError, match="true_occupancy"):
        sense(occ.astype(np.int32), sem, st, [0.0, 0.0, 0.0], grid)
    with pytest.raises(ValueError, match="true_semantic"):
        sense(occ, sem[:-1], st, [0.0, 0.0, 0.0], grid)
    with pytest.raises(ValueError, match="pose"):
        sense(occ, sem, st, [0.0, 0.0], grid)
    with pytest.raises(ValueError, match="^grid: expected a jaxsem.quadrics.Grid"):
        sense(occ, sem, st, [0.0, 0.0, 0.0], ORIGIN, RES)  # pyright: ignore[reportArgumentType]
    with pytest.raises(ValueError, match="grid: expected a finite \\(2,\\) origin"):
        sense(occ, sem, st, [0.0, 0.0, 0.0], Q.Grid(np.zeros(3), np.asarray(RES), occ.shape))
    with pytest.raises(ValueError, match="resolution"):
        sense(occ, sem, st, [0.0, 0.0, 0.0], Q.Grid(ORIGIN, np.asarray(-0.1), occ.shape))
    with pytest.raises(ValueError, match="grid: expected a grid of shape"):
        sense(occ, sem, st, [0.0, 0.0, 0.0], Q.Grid.host(ORIGIN, RES, (5, 5)))
    with pytest.raises(ValueError, match="shape"):
        empty_map_state((5,))


def test_state_must_match_map():
    occ, sem = _random_world(0)
    with pytest.raises(ValueError, match="state.occupancy"):
        sense(occ, sem, empty_map_state((10, 10)), [0.5, 0.5, 0.0], Q.Grid.host(ORIGIN, RES, occ.shape))


def test_loose_arrays_where_a_grid_belongs_are_refused_naming_the_argument():
    from jaxsem.planning._sampling import sample_points  # layers: white-box
    from jaxsem.planning._semantics import apply_annotations  # layers: white-box

    occ = np.zeros((8, 9), bool)
    with pytest.raises(ValueError, match="^grid: expected a jaxsem.quadrics.Grid"):
        cast_rays(occ, ORIGIN, [0.0, 0.0], [0.0], 1.0)  # pyright: ignore[reportArgumentType]
    with pytest.raises(ValueError, match="^grid: expected occupancy's shape"):
        cast_rays(occ, Q.Grid.host(ORIGIN, RES, (9, 8)), [0.0, 0.0], [0.0], 1.0)
    with pytest.raises(ValueError, match="^grid: expected a jaxsem.quadrics.Grid"):
        sample_points(jax.random.PRNGKey(0), jnp.ones((8, 9)), 4, ORIGIN)  # pyright: ignore[reportArgumentType]
    with pytest.raises(ValueError, match="^grid: expected a jaxsem.quadrics.Grid"):
        apply_annotations(occ.astype(np.int8), occ.astype(np.int8), occ, {}, ORIGIN)
