"""Fixed-shape detection pieces: NMS against the usual greedy loop, RoI bilinear pooling against
a feature map whose bilinear interpolation is exact, one compile for new values."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from jaxsem import models


def _reference_nms(boxes, scores, iou_threshold, score_threshold):
    """The textbook loop: highest score first, drop everything overlapping it, repeat."""

    def iou(a, b):
        w = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
        h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
        inter = w * h
        area = lambda x: max(0.0, x[2] - x[0]) * max(0.0, x[3] - x[1])
        union = area(a) + area(b) - inter
        return inter / union if union > 0 else 0.0

    order = sorted((i for i in range(len(scores)) if scores[i] > score_threshold), key=lambda i: (-scores[i], i))
    kept = []
    while order:
        i = order.pop(0)
        kept.append(i)
        order = [j for j in order if iou(boxes[i], boxes[j]) <= iou_threshold]
    return kept


_NMS_PAD = 12  # every example pads to this many boxes, so the jitted NMS compiles once per k


@functools.partial(jax.jit, static_argnums=2)
def _jit_nms(boxes, scores, k, thr):
    return models.nms(boxes, scores, k, iou_threshold=thr, score_threshold=0.05)


@settings(max_examples=30, deadline=None)
@given(
    st.integers(1, _NMS_PAD), st.integers(0, 2**31 - 1), st.sampled_from([0.3, 0.5, 0.7]), st.sampled_from([1, 3, 8])
)
def test_nms_matches_the_greedy_loop(n, seed, thr, k):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 40, (_NMS_PAD, 2))
    wh = rng.uniform(2, 20, (_NMS_PAD, 2))
    boxes = np.concatenate([xy, xy + wh], 1)
    scores = np.round(rng.uniform(0, 1, _NMS_PAD), 1)  # ties on purpose
    scores[n:] = 0.0  # the padding scores below the threshold: never kept
    index, valid = _jit_nms(jnp.array(boxes), jnp.array(scores), k, thr)
    want = _reference_nms(boxes[:n], scores[:n], thr, 0.05)[:k]
    got = [int(i) for i, v in zip(np.asarray(index), np.asarray(valid)) if v]
    assert got == want
    assert np.asarray(valid).tolist() == [True] * len(want) + [False] * (k - len(want))


def test_nms_batches_and_compiles_once(compiles):
    f = jax.jit(lambda b, s: models.nms(b, s, 3))
    rng = np.random.default_rng(0)
    b = jnp.array(rng.uniform(0, 10, (2, 5, 4)).cumsum(-1))  # ordered coordinates
    idx, ok = f(b, jnp.array(rng.uniform(size=(2, 5))))
    assert idx.shape == (2, 3) and ok.shape == (2, 3)
    b2, s2 = b + 1.0, jnp.array(rng.uniform(size=(2, 5)))
    with compiles() as c:
        f(b2, s2)
    assert c.count == 0


def test_nms_refuses_bad_shapes():
    with pytest.raises(ValueError, match="scores"):
        models.nms(jnp.zeros((4, 4)), jnp.zeros(3), 2)
    with pytest.raises(ValueError, match="max_detections"):
        models.nms(jnp.zeros((4, 4)), jnp.zeros(4), 0)


def test_roi_align_of_a_linear_map_is_the_map_at_the_bin_centres():
    H, W = 16, 20
    yy, xx = np.meshgrid(np.arange(H) + 0.5, np.arange(W) + 0.5, indexing="ij")  # pixel centres
    feats = jnp.array(np.stack([2.0 * xx + 3.0 * yy + 1.0, xx - yy], -1))
    boxes = jnp.array([[2.0, 3.0, 10.0, 11.0], [4.5, 1.5, 16.5, 7.5]])  # inside the centres' hull
    out = np.asarray(models.roi_align(feats, boxes, (4, 3), samples=2))
    for r, (u0, v0, u1, v1) in enumerate(np.asarray(boxes)):
        cu = u0 + (np.arange(3) + 0.5) * (u1 - u0) / 3
        cv = v0 + (np.arange(4) + 0.5) * (v1 - v0) / 4
        V, U = np.meshgrid(cv, cu, indexing="ij")
        np.testing.assert_allclose(out[r, ..., 0], 2 * U + 3 * V + 1, rtol=1e-10)
        np.testing.assert_allclose(out[r, ..., 1], U - V, rtol=1e-10, atol=1e-10)


def test_roi_align_reads_zero_outside_and_has_finite_gradients():
    feats = jnp.ones((8, 8, 1))
    roi_align = jax.jit(models.roi_align, static_argnums=2)  # one program, not one per operation
    out = roi_align(feats, jnp.array([[100.0, 100, 120, 120]]), (2, 2))
    assert float(jnp.abs(out).max()) == 0.0
    g = jax.jit(jax.grad(lambda b: roi_align(feats, b, (2, 2)).sum()))(jnp.array([[1.0, 1, 5, 5]]))
    assert bool(jnp.all(jnp.isfinite(g)))
