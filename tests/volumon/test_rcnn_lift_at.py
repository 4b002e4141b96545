"""Where the R-CNN's lift reads its features outside training: at each RoI's refined box (pooled
a second time) or at the RoI itself; training always reads the RoI, which its losses use."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_rcnn import TINY, _frames  # the tiny network of the R-CNN tests

from jaxsem.models._rcnn import (  # layers: white-box
    HEAD_WEIGHTS,
    RCNNConfig,
    VoluMonRCNN,
    _clip,
    decode_boxes,
    init_rcnn,
)
from jaxsem.volumon.rcnn import rcnn_batch

REFINED = dataclasses.replace(TINY, lift_at="refined")
PROPOSAL = dataclasses.replace(TINY, lift_at="proposal")


def _variables(config):
    """The network's variables, filled without running it (its init compiles the whole forward
    pass): small random weights and the box head's bias set, so the refined boxes move off the
    RoIs."""
    W, H = config.input_size
    shapes = jax.eval_shape(
        VoluMonRCNN(config).init,
        jax.random.PRNGKey(0),
        jnp.zeros((2, H, W, 3), jnp.float32),
        jnp.tile(jnp.eye(3, dtype=jnp.float32), (2, 1, 1)),
    )
    leaves, tree = jax.tree_util.tree_flatten(shapes)
    rng = np.random.default_rng(0)
    filled = [(0.05 * rng.standard_normal(x.shape)).astype(x.dtype) for x in leaves]
    v = jax.tree_util.tree_unflatten(tree, filled)
    v["batch_stats"] = jax.tree_util.tree_map(lambda x: np.abs(x) + 1.0, v["batch_stats"])  # variances > 0
    v["params"]["box_out"]["bias"] = np.array([2.0, -1.0, 1.0, 1.5], np.float32)
    return v


@pytest.fixture(scope="module")
def setup():
    v = _variables(REFINED)
    shapes_p = jax.eval_shape(lambda: init_rcnn(jax.random.PRNGKey(1), PROPOSAL, 2)[1])
    assert jax.tree_util.tree_structure(v) == jax.tree_util.tree_structure(shapes_p)  # one set of weights
    batch = rcnn_batch(_frames(2, 5), TINY, "abc", 3)
    return VoluMonRCNN(REFINED), VoluMonRCNN(PROPOSAL), v, batch


def _apply(model, v, batch, *extra, train=False):
    """One jitted forward pass (op by op, the tiny network takes far longer)."""
    if train:
        run = lambda vv, img, K: model.apply(vv, img, K, train=True, mutable=["batch_stats"])[0]
    else:
        run = lambda vv, img, K, *e: model.apply(vv, img, K, *e)
    return jax.jit(run)(v, batch["image"], batch["K"], *extra)


def test_the_refined_lift_is_the_proposal_lift_read_at_the_refined_boxes(setup):
    model_r, model_p, v, batch = setup
    out_r = _apply(model_r, v, batch)
    W, H = TINY.input_size
    refined = _clip(decode_boxes(out_r.rois, out_r.box_deltas, HEAD_WEIGHTS), (W, H))
    assert float(np.max(np.abs(np.asarray(refined - out_r.rois)))) > 1.0  # the boxes did move
    # the proposal rule fed the refined boxes as extra RoIs: the same features, by another route
    both = _apply(model_p, v, batch, refined, out_r.roi_valid)
    P = out_r.rois.shape[1]
    np.testing.assert_allclose(np.asarray(out_r.phi), np.asarray(both.phi[:, P:]), rtol=1e-4, atol=1e-5)
    assert not np.allclose(np.asarray(out_r.phi), np.asarray(both.phi[:, :P]), atol=1e-5)  # not the RoIs' lift
    # detection itself is the same under both rules
    for a, b in ((out_r.rois, both.rois[:, :P]), (out_r.class_logits, both.class_logits[:, :P])):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-5)


@pytest.mark.slow  # two more compiles of the network
def test_training_reads_the_rois_under_either_rule(setup):
    model_r, model_p, v, batch = setup
    run = lambda m: _apply(m, v, batch, train=True).phi
    np.testing.assert_allclose(np.asarray(run(model_r)), np.asarray(run(model_p)), rtol=1e-5, atol=1e-6)


def test_an_unknown_rule_is_refused():
    with pytest.raises(ValueError, match="lift_at"):
        RCNNConfig(lift_at="detected")
