"""The lift's own RoI layers (and, with ``lift_features`` "stage" or "backbone", its own last
backbone stage or whole backbone): a network trained with shared features grows them as copies and starts from its very own
outputs; trained alone, they move while the detector's layers stay."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_rcnn import INIT, TINY, _frames

from jaxsem.models._rcnn import RCNNConfig, VoluMonRCNN  # layers: white-box
from jaxsem.volumon.rcnn import (  # layers: white-box
    RCNNLossConfig,
    RCNNTrainConfig,
    _adopt,
    _optimizer,
    _own_lift_features,
    make_rcnn_step,
    rcnn_batch,
)

OWN = dataclasses.replace(TINY, lift_features="own")


@pytest.mark.slow
@pytest.mark.parametrize("features", ["own", "stage", "backbone"])
def test_own_lift_features_start_as_the_detectors_and_learn_alone(features, optax_promotion):
    own = dataclasses.replace(TINY, lift_features=features)
    b = rcnn_batch(_frames(2, 0), TINY, ("a", "b", "c"), 4)
    trained = INIT(jax.random.PRNGKey(1), TINY)
    trained = jax.tree.map(lambda x: x + 0.01 * jnp.sin(jnp.arange(x.size, dtype=x.dtype).reshape(x.shape)), trained)
    start = _adopt(trained, INIT(jax.random.PRNGKey(2), own))
    assert start is not None and "volumon_roi0" in start["params"]
    start = {k: _own_lift_features(start[k], trained[k]) for k in ("params", "batch_stats")}
    for lift_at in ("refined", "proposal"):
        a = jax.jit(VoluMonRCNN(dataclasses.replace(TINY, lift_at=lift_at)).apply)(trained, b["image"], b["K"])
        c = jax.jit(VoluMonRCNN(dataclasses.replace(own, lift_at=lift_at)).apply)(start, b["image"], b["K"])
        for x, y in zip(a, c):  # to float32 rounding: XLA compiles the two programs apart
            np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-5, atol=1e-6)
    # Trained alone, the lift's own layers move and the detector's layers stay.
    model = VoluMonRCNN(own)
    tx = _optimizer(RCNNTrainConfig(model=own, train_only="lift", init_from="trained", class_names=("a", "b", "c")))
    params, stats, opt = start["params"], start["batch_stats"], tx.init(start["params"])
    step = make_rcnn_step(model, own, RCNNLossConfig(burn_in=0), tx, freeze_stats=True)
    for i in range(3):
        params, stats, opt, _ = step(params, stats, opt, b, jnp.asarray(i))
    moved = lambda k: any(
        bool(jnp.any(x != y)) for x, y in zip(jax.tree.leaves(params[k]), jax.tree.leaves(start["params"][k]))
    )
    assert moved("volumon_roi0") and moved("volumon_roi1")
    assert not moved("roi_fc0") and not moved("roi_fc1") and not moved("cls_out")
    assert not any(moved(k) for k in params if k.startswith("plain_"))
    own_backbone = sorted(k for k in params if k.startswith("volumon_plain"))
    assert all(moved(k) for k in own_backbone)
    expected = {
        "own": [],
        "stage": ["volumon_plain_3_0", "volumon_plain_3_1"],
        "backbone": sorted(f"volumon_{k}" for k in params if k.startswith("plain_")),
    }
    assert own_backbone == expected[features]


def test_own_features_copy_only_into_a_network_that_lacks_them():
    p = {"roi_fc0": {"kernel": np.ones(2)}, "roi_fc1": {"kernel": np.zeros(2)}, "volumon_roi0": 0, "volumon_roi1": 0}
    grown = _own_lift_features(p, {"roi_fc0": 1, "roi_fc1": 1})
    assert grown["volumon_roi0"] is p["roi_fc0"] and grown["volumon_roi1"] is p["roi_fc1"]
    assert _own_lift_features(p, {"volumon_roi0": 1, "volumon_roi1": 1}) is p  # trained with its own: kept
    # a backbone stage of its own grown on a network that had own RoI layers: only the stage copied
    q = {**p, "plain_3_0": {"mean": np.ones(3)}, "volumon_plain_3_0": 0, "volumon_fc0": 0}
    grown = _own_lift_features(q, {"roi_fc0": 1, "volumon_roi0": 1, "volumon_roi1": 1, "plain_3_0": 1})
    assert grown["volumon_plain_3_0"] is q["plain_3_0"] and grown["volumon_roi0"] == 0 and grown["volumon_fc0"] == 0
    with pytest.raises(ValueError, match="lift_features"):
        RCNNConfig(lift_features="mine")
