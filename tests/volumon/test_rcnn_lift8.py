"""The stride-8 lift branch: a trained network grows it and starts from its very own outputs; the
branch then learns (its gradient is not zero); a different network is refused as a start."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_rcnn import INIT, TINY, _frames

from jaxsem.models._rcnn import RCNNConfig, VoluMonRCNN  # layers: white-box
from jaxsem.volumon.rcnn import _adopt, rcnn_batch  # layers: white-box


def _init(key, cfg, n):
    return VoluMonRCNN(cfg), INIT(key, cfg)


def _batch():
    return rcnn_batch(_frames(2, 0), TINY, ("a", "b", "c"), 4)


@pytest.mark.slow
def test_grown_network_starts_from_the_trained_outputs_and_its_branch_learns():
    b = _batch()
    _, trained = _init(jax.random.PRNGKey(1), TINY, 2)
    # A "trained" network: perturb every weight so that nothing sits at its initial value.
    trained = jax.tree.map(lambda x: x + 0.01 * jnp.sin(jnp.arange(x.size, dtype=x.dtype).reshape(x.shape)), trained)
    grown_cfg = dataclasses.replace(TINY, lift_stride8=True)
    model8, fresh = _init(jax.random.PRNGKey(2), grown_cfg, 2)
    start = _adopt(trained, fresh)
    assert start is not None and "lift8_fc" in start["params"]
    plain = VoluMonRCNN(TINY)
    a = jax.jit(plain.apply)(trained, b["image"], b["K"])
    c = jax.jit(model8.apply)(start, b["image"], b["K"])
    # the same to float32 rounding: two programs that XLA compiles apart need not round alike
    np.testing.assert_allclose(np.asarray(a.phi), np.asarray(c.phi), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.asarray(a.class_logits), np.asarray(c.class_logits), rtol=1e-5, atol=1e-6)

    def depth_sum(p):
        out = model8.apply({**start, "params": p}, b["image"], b["K"])
        return jnp.sum(jnp.where(out.roi_valid[..., None], out.phi[..., 9], 0.0))

    g = jax.jit(jax.grad(depth_sum))(start["params"])["lift8_fc"]["kernel"]
    assert bool(jnp.all(jnp.isfinite(g))) and float(jnp.max(jnp.abs(g))) > 0


@pytest.mark.slow
def test_a_different_network_is_no_start():
    _, fresh = _init(jax.random.PRNGKey(0), dataclasses.replace(TINY, lift_stride8=True), 1)
    _, wider = _init(jax.random.PRNGKey(0), dataclasses.replace(TINY, hidden=32), 1)
    assert _adopt(wider, fresh) is None
    _, grown = _init(jax.random.PRNGKey(0), dataclasses.replace(TINY, lift_stride8=True), 1)
    _, plain = _init(jax.random.PRNGKey(0), TINY, 1)
    assert _adopt(grown, plain) is None  # a start holding a branch the network lacks


def test_lift_stride8_needs_the_plain_backbone():
    with pytest.raises(ValueError, match="lift_stride8"):
        RCNNConfig(backbone="mobilenet_v2", lift_stride8=True)
