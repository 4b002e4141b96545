"""The "volumon" lift: the separate VoluMon network inside the one network, reading its two
inputs cut from the network's image. It reads only each RoI's padded surroundings, learns, adopts
a trained detector as it is, and an adopted separate network lifts a box as it does alone."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_rcnn import INIT, TINY

from jaxsem.models import ReconstructionConfig, box_features, init_volumon
from jaxsem.models._rcnn import RCNNConfig, VoluMonRCNN, _detection_rows  # layers: white-box
from jaxsem.training import LoadedModel
from jaxsem.volumon import TrainConfig, prepare_inputs
from jaxsem.volumon.rcnn import (  # layers: white-box
    LIFT_LAYERS,
    RCNNTrainConfig,
    _adopt,
    _without_missing_lift,
    adopt_separate_lift,
)

VOL = dataclasses.replace(TINY, lift_features="volumon", lift_at="proposal")
_K = jnp.array([[[120.0, 0.0, 64.0], [0.0, 120.0, 48.0], [0.0, 0.0, 1.0]]])
_BOX = jnp.array([[[40.0, 30.0, 70.0, 60.0]]])  # (1, 1, 4): one given RoI of a 128 x 96 image


def _phi_at_box(variables, image):
    out = VoluMonRCNN(VOL).apply(variables, image, _K, _BOX)
    return out.phi[:, -1]  # the given RoI comes after the proposals


def test_the_lift_reads_only_the_padded_box_and_its_surroundings():
    variables = INIT(jax.random.PRNGKey(0), VOL)
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
    variables = INIT(jax.random.PRNGKey(1), VOL)
    image = jnp.asarray(np.random.default_rng(1).uniform(0, 1, (1, 96, 128, 3)), jnp.float32)

    def depth_and_rest(p):
        phi = _phi_at_box({**variables, "params": p}, image)
        return jnp.sum(phi[..., 9]) + jnp.sum(phi[..., :9])

    g = jax.jit(jax.grad(depth_and_rest))(variables["params"])
    net = g["volumon_net"]
    for layer in ("local_backbone", "global_backbone", "local_fc0", "global_fc0", "local_out", "global_out"):
        leaves = jax.tree.leaves(net[layer])
        assert all(bool(jnp.all(jnp.isfinite(x))) for x in leaves)
        assert max(float(jnp.max(jnp.abs(x))) for x in leaves) > 0, layer


def test_adopting_a_trained_network_keeps_its_detector_and_output_heads():
    trained = INIT(jax.random.PRNGKey(2), TINY)
    fresh = INIT(jax.random.PRNGKey(3), VOL)
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
    a = jax.jit(VoluMonRCNN(TINY).apply)(trained, image, _K)
    b = jax.jit(VoluMonRCNN(VOL).apply)(start, image, _K)
    np.testing.assert_allclose(np.asarray(a.class_logits), np.asarray(b.class_logits), rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(np.asarray(a.rois), np.asarray(b.rois), rtol=1e-5, atol=1e-4)


def test_outside_training_it_lifts_the_detections_alike_and_leaves_other_rows_empty():
    variables = INIT(jax.random.PRNGKey(5), VOL)
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


def _separate_network(seed: int, config=VOL):
    """A stand-in trained separate VoluMon network of the lift's design (weights moved off their
    start so that every layer matters) and its loader's form."""
    model, variables = init_volumon(jax.random.PRNGKey(seed), config.volumon_lift)
    rng = np.random.default_rng(seed)
    variables = jax.tree.map(lambda x: x + 0.05 * jnp.asarray(rng.standard_normal(x.shape), x.dtype), variables)
    variables = {
        **variables,
        "batch_stats": jax.tree.map(lambda x: jnp.abs(x) + 0.5, variables["batch_stats"]),
    }
    recon = ReconstructionConfig(alpha_y=0.1, eps_s=0.03, depth_mode="disparity", baseline_focal=6.6)
    config = TrainConfig(model=config.volumon_lift, recon=recon, class_names=("a", "b", "c"))
    return LoadedModel(model, variables, config, {"name": "stand-in"})


def _detector(seed: int):
    config = RCNNTrainConfig(model=TINY, class_names=("a", "b", "c"))
    return LoadedModel(VoluMonRCNN(TINY), INIT(jax.random.PRNGKey(seed), TINY), config, {"name": "tiny"})


def test_an_adopted_separate_network_lifts_a_box_as_it_does_alone():
    separate, detector = _separate_network(6), _detector(7)
    one = adopt_separate_lift(detector, separate)
    assert one.config.model.reconstruction == separate.config.recon
    rng = np.random.default_rng(8)
    image = rng.uniform(0, 1, (96, 128, 3)).astype(np.float32)
    # one network, the box given as its own RoI (pixel centres at integer + 0.5) ...
    out = jax.jit(one.model.apply)(one.variables, jnp.asarray(image[None]), _K, _BOX)
    ours = np.asarray(out.phi[0, -1])
    # ... and the separate network alone on the same pixels (pixel centres at integers)
    box = np.asarray(_BOX[0]) - 0.5
    K = np.asarray(_K[0]).copy()
    K[:2, 2] -= 0.5
    local, whole = prepare_inputs(image, box, config=separate.config)
    alone = jax.jit(separate.model.apply)(separate.variables, local, whole, box_feats=box_features(jnp.asarray(box), K))
    np.testing.assert_allclose(ours, np.asarray(alone.phi[0]), rtol=1e-3, atol=1e-3)
    # the detector is the detector's (to float rounding: the given RoI joins the batch of RoIs)
    base = jax.jit(detector.model.apply)(detector.variables, jnp.asarray(image[None]), _K)
    np.testing.assert_allclose(np.asarray(out.class_logits[:, :-1]), np.asarray(base.class_logits), atol=1e-6)


def test_adopting_a_separate_network_of_another_design_or_classes_is_refused():
    separate, detector = _separate_network(9), _detector(10)
    other = separate._replace(config=dataclasses.replace(separate.config, class_names=("a", "c", "b")))
    with pytest.raises(ValueError, match="classes"):
        adopt_separate_lift(detector, other)
    wide = separate._replace(
        config=dataclasses.replace(separate.config, model=dataclasses.replace(separate.config.model, input_size=64))
    )
    with pytest.raises(ValueError, match="input_size"):
        adopt_separate_lift(detector, wide)
