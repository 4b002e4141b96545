"""Image boxes: area and IoU against dense sampling of the image plane, finite gradients on
degenerate boxes, broadcasting, and the refusal of badly shaped input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from jaxsem import quadrics as q

coord = st.floats(0.0, 20.0, allow_nan=False)
box = st.tuples(coord, coord, coord, coord).map(
    lambda t: [min(t[0], t[2]), min(t[1], t[3]), max(t[0], t[2]), max(t[1], t[3])]
)


def _dense_iou(a, b, step=0.05):
    """IoU by counting the centres of a fine lattice of cells inside each box."""
    u, v = np.meshgrid(np.arange(0, 20, step) + step / 2, np.arange(0, 20, step) + step / 2)
    inside = lambda x: (u >= x[0]) & (u <= x[2]) & (v >= x[1]) & (v <= x[3])
    ia, ib = inside(a), inside(b)
    union = (ia | ib).sum()
    return (ia & ib).sum() / union if union else 0.0


@settings(max_examples=40, deadline=None)
@given(box, box)
def test_iou_matches_dense_sampling(a, b):
    got = float(q.box_iou(jnp.array(a), jnp.array(b)))
    wide = min(a[2] - a[0], a[3] - a[1], b[2] - b[0], b[3] - b[1]) > 1.0
    if wide:  # the lattice resolves boxes a few cells across to about a percent
        assert got == pytest.approx(_dense_iou(a, b), abs=0.02)
    assert 0.0 <= got <= 1.0
    assert got == pytest.approx(float(q.box_iou(jnp.array(b), jnp.array(a))))


def test_area_iou_broadcast_and_pairwise():
    a = jnp.array([[0.0, 0, 2, 2], [1, 1, 3, 3]])
    m = q.box_iou(a[:, None], a[None])
    np.testing.assert_allclose(np.asarray(m), [[1.0, 1 / 7], [1 / 7, 1.0]], rtol=1e-12)
    np.testing.assert_allclose(np.asarray(q.box_area(a)), [4.0, 4.0])
    assert q.box_area(jnp.array([3.0, 3, 1, 1])) == 0.0  # inverted


def test_degenerate_boxes_give_zero_and_finite_gradients():
    empty = jnp.array([1.0, 1, 1, 1])
    assert float(q.box_iou(empty, empty)) == 0.0
    g = jax.grad(lambda x: q.box_iou(x, empty))(empty)
    assert bool(jnp.all(jnp.isfinite(g)))
    g2 = jax.grad(lambda x: q.box_iou(x, jnp.array([0.0, 0, 2, 2])))(jnp.array([0.5, 0.5, 1.5, 1.5]))
    assert bool(jnp.all(jnp.isfinite(g2)))


def test_bad_shapes_are_refused_with_the_argument_name():
    with pytest.raises(ValueError, match="a: expected shape"):
        q.box_iou(jnp.zeros(3), jnp.zeros(4))
    with pytest.raises(ValueError, match="boxes: expected shape"):
        q.box_area(jnp.zeros((2, 5)))
