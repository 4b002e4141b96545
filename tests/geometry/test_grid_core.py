"""The geometry core's grids (``quadrics.Grid``, ``world_to_cell``, ``cell_to_world``,
``cell_in_grid``): checked against the definition of a cell as a half-open square of the plane,
under jit and vmap, in numpy and jax alike."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import example, given, settings, strategies as st

from jaxsem import quadrics as Q

finite = st.floats(-50.0, 50.0, allow_nan=False)


@settings(max_examples=40, deadline=None)
@example(x=0.0, y=0.4, ox=0.0, oy=-1.0, res=0.05)  # on a border: numpy 27, XLA 28 (both right)
@given(
    x=finite,
    y=finite,
    ox=st.floats(-20.0, 20.0),
    oy=st.floats(-20.0, 20.0),
    res=st.sampled_from([0.05, 0.1, 0.25, 1.0]),
)
def test_a_point_lies_inside_the_square_of_its_cell(x, y, ox, oy, res):
    xy, origin = np.array([x, y]), np.array([ox, oy])
    rc = Q.world_to_cell(xy, origin, res, xp=np)
    low = Q.cell_to_world(rc, origin, res, offset=0.0, xp=np)
    high = Q.cell_to_world(rc, origin, res, offset=1.0, xp=np)
    # half-open square [low, high), with float64 rounding at the edges
    assert np.all(low <= xy + 1e-9) and np.all(xy < high + 1e-9)
    # jax (int32 cells) agrees with numpy (int64), except for a point on a cell border, which
    # either side's rounding may put in the next cell (XLA and numpy divide differently)
    rc_j = np.asarray(Q.world_to_cell(jnp.asarray(xy), jnp.asarray(origin), res))
    assert rc_j.dtype == np.int32 and rc.dtype == np.int64
    on_border = np.abs((xy - origin) / res - np.round((xy - origin) / res))[::-1] < 1e-9
    assert np.all((rc_j == rc) | (on_border & (np.abs(rc_j - rc) == 1)))


def test_cell_centres_round_trip_and_follow_row_col_order():
    rc = np.stack(np.meshgrid(np.arange(-2, 5), np.arange(-3, 4), indexing="ij"), -1).reshape(-1, 2)
    origin = np.array([1.5, -2.0])
    xy = Q.cell_to_world(rc, origin, 0.1, xp=np)
    np.testing.assert_array_equal(Q.world_to_cell(xy, origin, 0.1, xp=np), rc)
    # row is y, column is x: cell (0, 3) is three cells right of the origin corner
    np.testing.assert_allclose(Q.cell_to_world(np.array([0, 3]), origin, 0.1, xp=np), [1.85, -1.95])


def test_cell_in_grid_against_a_drawn_grid():
    shape = (3, 4)
    drawn = np.zeros((7, 8), bool)
    drawn[2:5, 2:6] = True  # the grid's cells, shifted by (2, 2)
    rc = np.argwhere(np.ones_like(drawn)) - 2
    np.testing.assert_array_equal(Q.cell_in_grid(rc, shape, xp=np), drawn.reshape(-1))
    np.testing.assert_array_equal(np.asarray(Q.cell_in_grid(jnp.asarray(rc), shape)), drawn.reshape(-1))


def test_grid_is_a_pytree_under_jit_and_vmap_without_recompiling():
    grid = Q.Grid.create(origin=(-5.0, -5.0), resolution=0.1, shape=(100, 120))
    f = jax.jit(lambda g, xy: (g.world_to_cell(xy), g.contains(g.world_to_cell(xy))))
    xy = jnp.array([[0.05, -4.95], [7.0, 0.0]])
    rc, ok = f(grid, xy)
    np.testing.assert_array_equal(np.asarray(rc), [[0, 50], [50, 120]])
    np.testing.assert_array_equal(np.asarray(ok), [True, False])
    f(Q.Grid.create(origin=(1.0, 2.0), resolution=0.2, shape=(100, 120)), xy + 1.0)
    assert f._cache_size() == 1  # a new origin and resolution are data, not a new program
    # a batch of grids (leading axes on origin and resolution) maps over points
    grids = jax.vmap(lambda o, r: Q.Grid(o, r, (10, 10)))(jnp.zeros((3, 2)), jnp.array([0.1, 0.2, 0.5]))
    cells = jax.vmap(lambda g: g.world_to_cell(jnp.array([0.55, 0.95])))(grids)
    np.testing.assert_array_equal(np.asarray(cells), [[9, 5], [4, 2], [1, 1]])
    np.testing.assert_allclose(np.asarray(grids.extent), [[1.0, 1.0], [2.0, 2.0], [5.0, 5.0]])


@pytest.mark.parametrize(
    "kwargs, word",
    [
        ({"origin": (0.0,), "resolution": 0.1, "shape": (2, 2)}, "origin"),
        ({"origin": (0.0, np.nan), "resolution": 0.1, "shape": (2, 2)}, "origin"),
        ({"origin": (0.0, 0.0), "resolution": 0.0, "shape": (2, 2)}, "resolution"),
        ({"origin": (0.0, 0.0), "resolution": 0.1, "shape": (2, 0)}, "shape"),
        ({"origin": (0.0, 0.0), "resolution": 0.1, "shape": 5}, "shape"),
    ],
)
def test_grid_create_refuses_bad_input_naming_the_argument(kwargs, word):
    with pytest.raises(ValueError, match=word):
        Q.Grid.create(**kwargs)


# World coordinates on a 1/64 m lattice: every difference and quotient below is exact.
lattice = st.integers(-256, 256).map(lambda i: i / 64)


@settings(max_examples=60, deadline=None)
@example(x0=1.0, y0=0.5, w=0.0, h=1.5, ox=0.0, oy=0.0, res=0.25)  # zero width on a cell border
@example(x0=0.3125, y0=0.3125, w=0.0, h=0.0, ox=0.0, oy=0.0, res=0.25)  # a point inside one cell
@example(x0=-4.0, y0=-4.0, w=4.0, h=4.0, ox=-1.0, oy=-0.5, res=0.25)  # past the low edges
@given(
    x0=lattice,
    y0=lattice,
    w=lattice.map(abs),
    h=lattice.map(abs),
    ox=st.sampled_from([-2.0, -1.0, 0.0, 0.5]),
    oy=st.sampled_from([-2.0, -0.5, 0.0]),
    res=st.sampled_from([0.25, 0.5, 1.0]),
)
def test_box_to_cells_marks_the_cells_whose_interior_meets_the_box(x0, y0, w, h, ox, oy, res):
    x1, y1 = x0 + w, y0 + h
    shape = (9, 11)
    r0, r1, c0, c1 = Q.box_to_cells((x0, y0, x1, y1), (ox, oy), res, shape)
    got = np.zeros(shape, bool)
    got[r0:r1, c0:c1] = True
    # brute force: cell [r, c] is the open square (ox + c res, ox + (c + 1) res) x (...), marked
    # when it meets the closed box
    rr, cc = np.mgrid[: shape[0], : shape[1]]
    want = (ox + cc * res < x1) & (ox + (cc + 1) * res > x0) & (oy + rr * res < y1) & (oy + (rr + 1) * res > y0)
    np.testing.assert_array_equal(got, want)
    assert r0 <= r1 and c0 <= c1
    grid = Q.Grid.create(origin=(ox, oy), resolution=res, shape=shape)
    assert grid.box_to_cells((x0, y0, x1, y1)) == (r0, r1, c0, c1)


@pytest.mark.parametrize(
    ("call", "word"),
    [
        (lambda g: g.world_to_cell(jnp.array([1.0, 2.0, 0.5])), "xy"),  # a 3D point
        (lambda g: g.world_to_cell(jnp.ones((4, 3))), "xy"),
        (lambda g: Q.world_to_cell(jnp.ones((4, 2)), jnp.zeros(3), 0.1), "origin"),
        (lambda g: g.cell_to_world(jnp.array([1, 2, 3])), "rc"),
        (lambda g: g.world_to_cell(jnp.float32(1.0)), "xy"),
    ],
    ids=["point-3d", "points-3d", "origin-3d", "cell-3", "scalar"],
)
def test_points_that_are_not_pairs_are_refused_naming_the_argument(call, word):
    grid = Q.Grid.create((0.0, 0.0), 0.1, (10, 10))
    with pytest.raises(ValueError, match=rf"{word}: expected shape \(\.\.\., 2\)"):
        call(grid)
    with pytest.raises(ValueError, match=rf"{word}: expected shape \(\.\.\., 2\)"):
        jax.jit(call)(grid)  # static shapes: refused under jit too
