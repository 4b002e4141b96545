"""Object-map store (thesis 5.8.2-5.8.3): association, fusion, footprints, ground-truth buildings."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import ndimage
from scipy.spatial import ConvexHull

from jaxsem import mapping, planning, quadrics


def _random_ellipsoids(seed, n, spread=5.0):
    rng = np.random.default_rng(seed)
    key = jax.random.PRNGKey(seed)
    rot = np.asarray(quadrics.random_rotation(key, (n,)))
    center = rng.uniform(-spread, spread, (n, 3))
    radii = rng.uniform(0.15, 1.2, (n, 3))
    return rot, center, radii


def _dilate_has(grid, cls):
    return ndimage.binary_dilation(grid == cls, structure=np.ones((3, 3), bool))


# --------------------------------------------------------------------------------------------
# Footprints against an independent reference: dense surface samples seen from above.


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_footprint_matches_dense_surface_samples(seed):
    rot, center, radii = _random_ellipsoids(seed, 4, spread=3.0)
    res, shape = 0.05, (200, 200)
    origin = np.array([-5.0, -5.0])
    pts = np.asarray(quadrics.surface_points(jax.random.PRNGKey(seed + 10), rot, center, radii, 40000))
    for j in range(4):
        dets = mapping.ellipsoids(
            quadrics.Ellipsoid(rot[j : j + 1], center[j : j + 1], radii[j : j + 1]), [planning.DOOR]
        )
        grid = np.asarray(mapping.semantic_grid(dets, quadrics.Grid.create(origin, res, shape), window=None))
        rows, cols = np.nonzero(grid == planning.DOOR)
        xs, ys = origin[0] + (cols + 0.5) * res, origin[1] + (rows + 0.5) * res
        xy = pts[j, :, :2]
        # Top-down extents agree to within one cell.
        np.testing.assert_allclose([xs.min(), ys.min()], xy.min(0), atol=res)
        np.testing.assert_allclose([xs.max(), ys.max()], xy.max(0), atol=res)
        # Area agrees with the convex hull of the projected samples (the footprint is convex).
        hull_area = ConvexHull(xy).volume
        np.testing.assert_allclose(len(rows) * res * res, hull_area, rtol=0.05)
        # The tiled drawing is the same grid.
        tiled = np.asarray(mapping.semantic_grid(dets, quadrics.Grid.create(origin, res, shape), window=64))
        np.testing.assert_array_equal(tiled, grid)


def test_tiled_equals_full_grid_for_many_objects_and_edges():
    rot, center, radii = _random_ellipsoids(5, 20, spread=6.0)  # some hang off the grid
    cls = np.random.default_rng(5).choice(list(planning.OBJECT_CLASSES), 20)
    dets = mapping.ellipsoids(quadrics.Ellipsoid(rot, center, radii), cls, valid=np.arange(20) % 7 != 3)
    origin, res, shape = np.array([-4.0, -3.0]), 0.1, (70, 90)
    full = np.asarray(mapping.semantic_grid(dets, quadrics.Grid.create(origin, res, shape), window=None))
    tiled = np.asarray(mapping.semantic_grid(dets, quadrics.Grid.create(origin, res, shape), window=32))
    np.testing.assert_array_equal(tiled, full)
    assert tiled.dtype == np.int8 and set(np.unique(tiled)) <= {0, 2, 3, 4}


def test_window_too_small_names_window():
    dets = mapping.ellipsoids(quadrics.Ellipsoid(None, [[0.0, 0.0, 1.0]], [[3.0, 0.5, 1.0]]), [planning.DOOR])
    with pytest.raises(ValueError, match="window"):
        mapping.semantic_grid(dets, quadrics.Grid.create((-5.0, -5.0), 0.1, (100, 100)), window=16)


# --------------------------------------------------------------------------------------------
# The generator's semantic grid from its ground-truth objects.


@pytest.mark.parametrize("family,seed", [("train", 3), ("test", 0)])
def test_ground_truth_map_reproduces_generator_semantics(family, seed):
    b = planning.generate_building(seed, family)
    objs = mapping.building_objects(b)
    assert set(np.unique(objs.class_id)) == {
        planning.DOOR,
        planning.WINDOW,
        planning.EXIT_SIGN,
    }
    state = mapping.ground_truth_map(b, capacity=len(objs) + 8)
    assert int(state.valid.sum()) == len(objs) and int(state.dropped) == 0
    grid = np.asarray(mapping.semantic_grid(state, b.grid))
    truth = np.where(np.isin(b.semantic, planning.OBJECT_CLASSES), b.semantic, planning.NONE)
    assert grid.shape == truth.shape
    for cls in planning.OBJECT_CLASSES:
        got, want = grid == cls, truth == cls
        # Every cell of difference lies within one cell of that class in the other grid.
        assert not np.any(got & ~_dilate_has(truth, cls)), cls
        assert not np.any(want & ~_dilate_has(grid, cls)), cls
        # And most cells agree exactly (the inscribed ellipse misses only box corners).
        assert (got & want).sum() >= 0.7 * want.sum()
    # Objects sit inside the building's walls' height range and on the grid.
    assert np.all(objs.box_max[:, 2] <= mapping.ObjectHeights().wall[1])


# --------------------------------------------------------------------------------------------
# Association and fusion.


def _frame(center, cls, radii=0.5, valid=None):
    center = np.asarray(center, float)
    radii = np.broadcast_to(np.asarray(radii, float), center.shape)
    return mapping.ellipsoids(quadrics.Ellipsoid(None, center, radii), np.asarray(cls, np.int32), valid)


def test_repeated_detections_associate_and_new_ones_create():
    D, W, S = planning.DOOR, planning.WINDOW, planning.EXIT_SIGN
    state = mapping.init(8)
    state = mapping.update(state, _frame([[0, 0, 1], [4, 0, 1], [0, 4, 1]], [D, D, W]), gate=1.0)
    assert state.valid.sum() == 3
    # The same objects moved by 0.3 m, a far new door, a sign on top of the window (other class),
    # and one padded entry that must be ignored.
    f2 = _frame(
        [[4.3, 0, 1], [0.2, 0.2, 1], [10, 0, 1], [0, 4, 1], [0, 0, 1]],
        [D, D, D, S, D],
        valid=np.array([True, True, True, True, False]),
    )
    assoc = mapping.associate(state, f2, gate=1.0)
    np.testing.assert_array_equal(assoc.slot, [1, 0, 3, 4, 8])
    np.testing.assert_array_equal(assoc.matched, [True, True, False, False, False])
    np.testing.assert_array_equal(assoc.created, [False, False, True, True, False])
    state = mapping.update(state, f2, gate=1.0)
    assert state.valid.sum() == 5
    np.testing.assert_array_equal(state.observations, [2, 2, 1, 1, 1, 0, 0, 0])
    np.testing.assert_allclose(state.center[1], [4.3, 0, 1])  # "latest" overwrites (thesis)
    np.testing.assert_array_equal(state.class_id[:5], [D, D, W, D, S])
    # Without class awareness the sign would have matched the window.
    a2 = mapping.associate(mapping.init(8), f2)
    assert not np.any(a2.matched)


def test_greedy_is_global_and_order_independent():
    D = planning.DOOR
    state = mapping.update(mapping.init(4), _frame([[0, 0, 1], [1.0, 0, 1]], [D, D]))
    # Detection a at 0.6 is nearest to object 1 (0.4) but detection b at 0.95 is nearer still
    # (0.05): global greedy gives object 1 to b, then a takes object 0 (0.6 < gate).
    f = _frame([[0.6, 0, 1], [0.95, 0, 1]], [D, D])
    np.testing.assert_array_equal(mapping.associate(state, f, gate=1.0).slot, [0, 1])
    f_rev = _frame([[0.95, 0, 1], [0.6, 0, 1]], [D, D])
    np.testing.assert_array_equal(mapping.associate(state, f_rev, gate=1.0).slot, [1, 0])


def test_capacity_overflow_is_counted():
    D = planning.DOOR
    state = mapping.update(mapping.init(2), _frame([[0, 0, 1], [5, 0, 1], [10, 0, 1]], [D, D, D]))
    assert state.valid.all() and int(state.dropped) == 1
    state = mapping.update(state, _frame([[20, 0, 1], [0.1, 0, 1]], [D, D]))
    assert int(state.dropped) == 2 and int(state.observations[0]) == 2


def test_mean_fusion_averages_centres_and_shape_matrices():
    D = planning.DOOR
    rot, center, radii = _random_ellipsoids(7, 3, spread=0.2)
    state = mapping.init(4)
    for j in range(3):
        f = mapping.ellipsoids(quadrics.Ellipsoid(rot[j : j + 1], center[j : j + 1], radii[j : j + 1]), [D])
        state = mapping.update(state, f, gate=2.0, fusion="mean")
    assert int(state.valid.sum()) == 1 and int(state.observations[0]) == 3
    np.testing.assert_allclose(state.center[0], center.mean(0), atol=1e-12)
    S = np.einsum("nij,nj,nkj->nik", rot, radii**2, rot).mean(0)
    R, r = np.asarray(state.rotation[0]), np.asarray(state.radii[0])
    np.testing.assert_allclose(R @ np.diag(r**2) @ R.T, S, atol=1e-6)
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) > 0


def test_jit_vmap_grad():
    D = planning.DOOR
    upd = jax.jit(functools.partial(mapping.update, gate=1.0, fusion="mean"))
    states = jax.vmap(lambda _: mapping.init(4))(jnp.arange(3))
    centers = jnp.asarray(np.random.default_rng(0).normal(size=(3, 2, 3)))
    frames = jax.vmap(lambda c: _frame_jax(c, D))(centers)
    states = jax.vmap(upd)(states, frames)
    states = jax.vmap(upd)(states, frames)
    assert states.valid.shape == (3, 4)
    np.testing.assert_array_equal(states.observations[:, :2], 2)

    def loss(c):  # spheres: repeated radii, the eigendecomposition's singular case
        s = mapping.update(mapping.init(2), _frame_jax(c, D), fusion="mean")
        s = mapping.update(s, _frame_jax(c + 0.1, D), fusion="mean")
        return jnp.sum(s.center**2) + jnp.sum(s.radii) + jnp.sum(s.rotation)

    g = jax.grad(loss)(centers[0])
    assert np.all(np.isfinite(g))
    grid = jax.jit(lambda s, g: mapping.semantic_grid(s, g))(
        mapping.update(mapping.init(2), _frame_jax(jnp.array([[2.0, 2, 1], [1, 1, 1]]), D)),
        quadrics.Grid.create(jnp.zeros(2), 0.1, (40, 40)),  # a traced origin and resolution
    )
    assert grid.dtype == jnp.int8 and int((grid == D).sum()) > 0


def _frame_jax(c, cls):
    n = c.shape[0]
    return mapping.Ellipsoids(
        jnp.broadcast_to(jnp.eye(3, dtype=c.dtype), (n, 3, 3)),
        c,
        jnp.full((n, 3), 0.5, c.dtype),
        jnp.full((n,), cls, jnp.int32),
        jnp.ones((n,), bool),
    )


def test_float32_stays_float32():
    state = mapping.init(3, jnp.float32)
    f = mapping.ellipsoids(quadrics.Ellipsoid(None, np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32)), [2])
    state = mapping.update(state, f, fusion="mean")
    state = mapping.update(state, f, fusion="mean")
    assert state.center.dtype == jnp.float32 and state.radii.dtype == jnp.float32
    np.testing.assert_allclose(state.radii[0], 1.0, rtol=1e-4)


def test_bad_arguments_name_themselves():
    with pytest.raises(ValueError, match="capacity"):
        mapping.init(0)
    with pytest.raises(ValueError, match="radii"):
        mapping.ellipsoids(quadrics.Ellipsoid(None, np.zeros((2, 3)), np.ones((3, 3))), [2, 2])
    with pytest.raises(ValueError, match=r"grid: expected a jaxsem\.quadrics\.Grid"):
        mapping.semantic_grid(mapping.init(2), (40, 40))  # a bare shape where the grid belongs
    with pytest.raises(ValueError, match=r"ellipsoid: expected a jaxsem\.quadrics\.Ellipsoid"):
        mapping.ellipsoids(np.zeros((2, 3)), [2, 2])  # loose arrays where the typed one belongs
    with pytest.raises(ValueError, match="class_id"):
        mapping.ellipsoids(quadrics.Ellipsoid(None, np.zeros((2, 3)), np.ones((2, 3))), [2.0, 2.0])
    with pytest.raises(ValueError, match="fusion"):
        mapping.update(mapping.init(2), _frame([[0, 0, 0]], [2]), fusion="median")
    with pytest.raises(ValueError, match="detections"):
        mapping.update(mapping.init(2), np.zeros((1, 3)))


# --------------------------------------------------------------------------------------------
# Planning glue.


def test_object_map_sampler_sees_the_object_map_crop():
    b = planning.generate_building(1, "train")
    state = mapping.ground_truth_map(b, capacity=128)
    sem = mapping.semantic_grid(state, b.grid)
    ms = mapping.with_object_map(planning.empty_map_state(b.shape), state, b.grid)
    np.testing.assert_array_equal(ms.semantic, sem)
    xy = b.entrance
    reference = planning.local_inputs(ms, xy, xy, False, b)
    seen = {}

    def sampler(inputs):
        seen["semantic"] = inputs.semantic
        return jnp.ones((planning.CROP_SIZE, planning.CROP_SIZE)) / planning.CROP_SIZE**2

    own = planning.local_inputs(planning.empty_map_state(b.shape), xy, xy, False, b)
    mapping.object_map_sampler(sampler, sem)(own)
    np.testing.assert_array_equal(seen["semantic"], reference.semantic)
    assert int((reference.semantic > 0).sum()) > 0
