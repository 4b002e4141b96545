"""The "volumon" lift: the separate VoluMon network's two inputs cut inside the one network. It
reads only each RoI's padded surroundings, learns, and adopts a trained detector as it is."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_rcnn import TINY

from jaxsem.models._rcnn import RCNNConfig, VoluMonRCNN, _detection_rows, init_rcnn  # layers: white-box
from jaxsem.models._volumon import SmallCNN  # layers: white-box
from jaxsem.volumon.rcnn import LIFT_LAYERS, _adopt, _without_missing_lift  # layers: white-box

VOL = dataclasses.replace(TINY, lift_features="volumon", lift_at="proposal")
_INIT = jax.jit(lambda key, cfg, n: init_rcnn(key, cfg, n)[1], static_argnums=(1, 2))
_K = jnp.array([[[120.0, 0.0, 64.0], [0.0, 120.0, 48.0], [0.0, 0.0, 1.0]]])
_BOX = jnp.array([[[40.0, 30.0, 70.0, 60.0]]])  # (1, 1, 4): one given RoI of a 128 x 96 image


def _phi_at_box(variables, image):
    out = VoluMonRCNN(VOL).apply(variables, image, _K, _BOX)
    return out.phi[:, -1]  # the given RoI comes after the proposals


def test_the_lift_reads_only_the_padded_box_and_its_surroundings():
    variables = _INIT(jax.random.PRNGKey(0), VOL, 1)
    rng = np.random.default_rng(0)
    image = jnp.asarray(rng.uniform(0, 1, (1, 96, 128, 3)), jnp.float32)
    far = np.ones((96, 128), bool)
    far[30 - 6 : 60 + 6, 40 - 6 : 70 + 6] = False  # the box padded by a tenth, and a margin of pixels
    changed = jnp.where(
        jnp.asarray(far)[None, ..., None], jnp.asarray(rng.uniform(0, 1, image.shape), jnp.float32), image
    )
    near = image.at[:, 44, 55, :].set(1.0 - image[:, 44, 55, :])  # pixels inside the box
    near = near.at[:, 35:55:3, 45:65:3, :].set(0.0)
    f = jax.jit(_phi_at_box)
    a, b, c = f(variables, image), f(variables, changed), f(variables, near.astype(jnp.float32))
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-6)
    assert float(jnp.max(jnp.abs(a - c))) > 1e-6  # the object's own pixels do move it


def test_the_lift_learns_with_finite_gradients_in_both_branches():
    variables = _INIT(jax.random.PRNGKey(1), VOL, 1)
    image = jnp.asarray(np.random.default_rng(1).uniform(0, 1, (1, 96, 128, 3)), jnp.float32)

    def depth_and_rest(p):
        phi = _phi_at_box({**variables, "params": p}, image)
        return jnp.sum(phi[..., 9]) + jnp.sum(phi[..., :9])

    g = jax.jit(jax.grad(depth_and_rest))(variables["params"])
    for layer in ("volumon_local_cnn", "volumon_global_cnn", "volumon_local_fc", "volumon_global_fc"):
        leaves = jax.tree.leaves(g[layer])
        assert all(bool(jnp.all(jnp.isfinite(x))) for x in leaves)
        assert max(float(jnp.max(jnp.abs(x))) for x in leaves) > 0, layer


def test_adopting_a_trained_network_keeps_its_detector_and_output_heads():
    trained = _INIT(jax.random.PRNGKey(2), TINY, 1)
    fresh = _INIT(jax.random.PRNGKey(3), VOL, 1)
    assert _adopt(trained, fresh) is None  # the old lift's first layer has no place in the new network
    start = _adopt(_without_missing_lift(trained, fresh), fresh)
    assert start is not None
    for layer, value in trained["params"].items():
        if layer in fresh["params"]:
            for x, y in zip(jax.tree.leaves(value), jax.tree.leaves(start["params"][layer])):
                np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
        else:
            assert layer.startswith(LIFT_LAYERS), layer  # only the old lift's own layers are dropped
    image = jnp.asarray(np.random.default_rng(4).uniform(0, 1, (1, 96, 128, 3)), jnp.float32)
    a = VoluMonRCNN(TINY).apply(trained, image, _K)
    b = VoluMonRCNN(VOL).apply(start, image, _K)
    np.testing.assert_allclose(np.asarray(a.class_logits), np.asarray(b.class_logits), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(a.rois), np.asarray(b.rois), rtol=1e-5, atol=1e-4)


def test_outside_training_it_lifts_the_detections_alike_and_leaves_other_rows_empty():
    variables = _INIT(jax.random.PRNGKey(5), VOL, 1)
    variables = jax.tree.map(
        lambda x: x + 0.05 * jnp.cos(jnp.arange(x.size, dtype=x.dtype).reshape(x.shape)), variables
    )
    image = jnp.asarray(np.random.default_rng(5).uniform(0, 1, (1, 96, 128, 3)), jnp.float32)
    apply = jax.jit(VoluMonRCNN(VOL).apply)
    out = apply(variables, image, _K)
    rows = _detection_rows(out.rois, out.roi_valid, out.class_logits, out.box_deltas, VOL)[0]
    kept = np.zeros(out.rois.shape[:2], bool)
    kept[0, np.asarray(rows[0])] = True
    assert np.all(np.asarray(out.phi)[~kept] == 0.0) and np.any(np.asarray(out.phi)[kept] != 0.0)
    # the same RoIs given as the caller's own: every RoI given is lifted, the same as a detection
    given = jnp.take_along_axis(out.rois, rows[..., None], axis=1)
    again = apply(variables, image, _K, given)
    ours = jnp.take_along_axis(out.phi, rows[..., None, None], axis=1)
    np.testing.assert_allclose(np.asarray(again.phi[:, -rows.shape[1] :]), np.asarray(ours), rtol=1e-5, atol=1e-6)


def test_the_volumon_lift_takes_no_other_crop_branch():
    with pytest.raises(ValueError, match="lift_features"):
        RCNNConfig(lift_features="volumon", lift_crop=16)
    with pytest.raises(ValueError, match="lift_features"):
        RCNNConfig(backbone="plain_cnn", lift_features="volumon", lift_stride8=True)
    with pytest.raises(ValueError, match="norm"):
        SmallCNN(8, "layer").init(jax.random.PRNGKey(0), jnp.zeros((1, 16, 16, 3)))
