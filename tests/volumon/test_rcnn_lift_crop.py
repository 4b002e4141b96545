"""The image-crop lift branch: a trained network grows it and starts from its very own outputs;
the branch then learns (its gradient is not zero)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_rcnn import INIT, TINY, _frames

from jaxsem.models._rcnn import RCNNConfig, VoluMonRCNN  # layers: white-box
from jaxsem.volumon.rcnn import _adopt, rcnn_batch  # layers: white-box

CROP = dataclasses.replace(TINY, lift_crop=16)


@pytest.mark.slow
def test_grown_network_starts_from_the_trained_outputs_and_its_crop_branch_learns():
    b = rcnn_batch(_frames(2, 0), TINY, ("a", "b", "c"), 4)
    trained = INIT(jax.random.PRNGKey(1), TINY)
    trained = jax.tree.map(lambda x: x + 0.01 * jnp.sin(jnp.arange(x.size, dtype=x.dtype).reshape(x.shape)), trained)
    start = _adopt(trained, INIT(jax.random.PRNGKey(2), CROP))
    assert start is not None and "crop_fc" in start["params"] and "crop_conv0" in start["params"]
    a = jax.jit(VoluMonRCNN(TINY).apply)(trained, b["image"], b["K"])
    grown = VoluMonRCNN(CROP)
    c = jax.jit(grown.apply)(start, b["image"], b["K"])
    # the same to float32 rounding: two programs that XLA compiles apart need not round alike
    np.testing.assert_allclose(np.asarray(a.phi), np.asarray(c.phi), rtol=1e-5, atol=1e-6)

    def depth_sum(p, image):
        out = grown.apply({**start, "params": p}, image, b["K"])
        return jnp.sum(jnp.where(out.roi_valid[..., None], out.phi[..., 9], 0.0))

    g = jax.jit(jax.grad(depth_sum))(start["params"], b["image"])["crop_fc"]["kernel"]
    assert bool(jnp.all(jnp.isfinite(g))) and float(jnp.max(jnp.abs(g))) > 0


def test_lift_crop_is_a_multiple_of_eight():
    with pytest.raises(ValueError, match="lift_crop"):
        RCNNConfig(lift_crop=12)
    with pytest.raises(ValueError, match="lift_crop"):
        RCNNConfig(lift_crop=-8)
