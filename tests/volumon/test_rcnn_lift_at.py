"""Where the R-CNN's lift reads its features outside training: at each RoI's refined box (pooled
a second time) or at the RoI itself; training always reads the RoI, which its losses use."""

import dataclasses

import jax
import numpy as np
import pytest
from test_rcnn import TINY, _frames  # the tiny network of the R-CNN tests

from jaxsem.models._rcnn import HEAD_WEIGHTS, RCNNConfig, _clip, decode_boxes, init_rcnn  # layers: white-box
from jaxsem.volumon.rcnn import rcnn_batch

REFINED = dataclasses.replace(TINY, lift_at="refined")
PROPOSAL = dataclasses.replace(TINY, lift_at="proposal")


def _nudged(variables):
    """The variables with the box head's bias set, so the refined boxes move off the RoIs."""
    params = dict(variables["params"])
    params["box_out"] = {**params["box_out"], "bias": np.array([2.0, -1.0, 1.0, 1.5], np.float32)}
    return {**variables, "params": params}


@pytest.fixture(scope="module")
def setup():
    model_r, v = init_rcnn(jax.random.PRNGKey(1), REFINED, 2)
    model_p, v_p = init_rcnn(jax.random.PRNGKey(1), PROPOSAL, 2)
    assert jax.tree_util.tree_structure(v) == jax.tree_util.tree_structure(v_p)  # one set of weights
    batch = rcnn_batch(_frames(2, 5), TINY, "abc", 3)
    return model_r, model_p, _nudged(v), batch


def test_the_refined_lift_is_the_proposal_lift_read_at_the_refined_boxes(setup):
    model_r, model_p, v, batch = setup
    out_r = model_r.apply(v, batch["image"], batch["K"])
    out_p = model_p.apply(v, batch["image"], batch["K"])
    W, H = TINY.input_size
    refined = _clip(decode_boxes(out_p.rois, out_p.box_deltas, HEAD_WEIGHTS), (W, H))
    assert float(np.max(np.abs(np.asarray(refined - out_p.rois)))) > 1.0  # the boxes did move
    # the proposal rule fed the refined boxes as extra RoIs: the same features, by another route
    extra = model_p.apply(v, batch["image"], batch["K"], refined, out_p.roi_valid)
    P = out_p.rois.shape[1]
    np.testing.assert_allclose(np.asarray(out_r.phi), np.asarray(extra.phi[:, P:]), rtol=1e-4, atol=1e-5)
    assert not np.allclose(np.asarray(out_r.phi), np.asarray(out_p.phi), atol=1e-5)
    # detection itself is the same under both rules
    for a, b in ((out_r.rois, out_p.rois), (out_r.class_logits, out_p.class_logits)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_training_reads_the_rois_under_either_rule(setup):
    model_r, model_p, v, batch = setup
    run = lambda m: m.apply(v, batch["image"], batch["K"], train=True, mutable=["batch_stats"])[0]
    np.testing.assert_allclose(np.asarray(run(model_r).phi), np.asarray(run(model_p).phi), rtol=1e-5, atol=1e-6)


def test_an_unknown_rule_is_refused():
    with pytest.raises(ValueError, match="lift_at"):
        RCNNConfig(lift_at="detected")
