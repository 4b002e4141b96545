"""A lift grafted on a detector: the grafted network's detections are the detector's and its
ellipsoids at any box are the lift's network's; networks that differ outside the lift are refused."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_rcnn import INIT, TINY, _frames

from jaxsem.models._rcnn import VoluMonRCNN  # layers: white-box
from jaxsem.training import LoadedModel
from jaxsem.volumon.rcnn import RCNNTrainConfig, graft_lift, rcnn_batch

CROP = dataclasses.replace(TINY, lift_crop=16, lift_at="proposal")


def _trained(seed, cfg):
    """A network of ``cfg`` whose every weight and statistic is moved off its initial value."""
    v = INIT(jax.random.PRNGKey(seed), cfg)
    v = jax.tree.map(lambda x: x + 0.01 * seed * jnp.sin(jnp.arange(x.size, dtype=x.dtype).reshape(x.shape)), v)
    config = RCNNTrainConfig(model=cfg, class_names=("a", "b", "c"))
    return LoadedModel(VoluMonRCNN(cfg), v, config, {"name": f"net{seed}"})


@pytest.mark.slow
def test_grafted_network_detects_as_the_detector_and_lifts_as_the_lifter():
    detector = _trained(1, dataclasses.replace(TINY, lift_at="proposal"))
    lifter = _trained(2, CROP)
    grafted = graft_lift(detector, lifter)
    assert grafted.config.model.lift_features == "backbone" and grafted.config.model.lift_crop == 16
    b = rcnn_batch(_frames(2, 0), TINY, ("a", "b", "c"), 4)
    boxes = jnp.asarray(b["boxes"], jnp.float32)
    valid = jnp.asarray(b["box_valid"])
    run = lambda m: jax.jit(m.model.apply)(m.variables, b["image"], b["K"], boxes, valid)
    d, l, g = run(detector), run(lifter), run(grafted)
    close = lambda x, y: np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-5, atol=1e-6)
    for field in ("rpn_logits", "rpn_deltas", "rois", "class_logits", "box_deltas"):
        close(getattr(g, field), getattr(d, field))
    # the given boxes (after the proposals) are the same RoIs in every network: there the grafted
    # network's ellipsoids are the lifter's
    G = boxes.shape[1]
    close(g.phi[:, -G:], l.phi[:, -G:])
    assert float(jnp.max(jnp.abs(d.phi[:, -G:] - l.phi[:, -G:]))) > 1e-3  # the two lifts differ


def _shapes_only(cfg):
    """A network of ``cfg`` whose variables are shapes (the refusals read settings, not values)."""
    v = jax.eval_shape(lambda: INIT(jax.random.PRNGKey(0), cfg))
    config = RCNNTrainConfig(model=cfg, class_names=("a", "b", "c"))
    return LoadedModel(VoluMonRCNN(cfg), v, config, {"name": "shapes"})


def test_graft_refuses_networks_that_differ_outside_the_lift():
    detector = _shapes_only(TINY)
    other = _shapes_only(dataclasses.replace(TINY, hidden=32))
    with pytest.raises(ValueError, match="lifter"):
        graft_lift(detector, other)
    own = _shapes_only(dataclasses.replace(TINY, lift_features="own"))
    with pytest.raises(ValueError, match="lifter"):
        graft_lift(detector, own)
