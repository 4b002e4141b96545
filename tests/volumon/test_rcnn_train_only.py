"""Training the lift alone on a trained detector: the detector's layers and batch-norm
statistics stay bit for bit, the lift's layers move; a run that would freeze an untrained
detector is refused."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_rcnn import TINY, _frames

from jaxsem.models._rcnn import init_rcnn  # layers: white-box
from jaxsem.volumon.rcnn import (  # layers: white-box
    HEAD_LAYERS,
    LIFT_LAYERS,
    RCNNLossConfig,
    RCNNTrainConfig,
    _optimizer,
    make_rcnn_step,
    rcnn_batch,
    train_rcnn,
)

CROP = dataclasses.replace(TINY, lift_crop=16)


@pytest.mark.slow
@pytest.mark.parametrize("only", ["lift", "heads"])
def test_train_only_steps_move_their_layers_and_nothing_else(optax_promotion, only):
    b = rcnn_batch(_frames(2, 0), CROP, ("a", "b", "c"), 4)
    model, v = init_rcnn(jax.random.PRNGKey(0), CROP, 2)
    config = RCNNTrainConfig(model=CROP, train_only=only, init_from="trained", class_names=("a", "b", "c"))
    tx = _optimizer(config)
    params, stats, opt = v["params"], v["batch_stats"], tx.init(v["params"])
    step = make_rcnn_step(model, CROP, RCNNLossConfig(burn_in=0), tx, freeze_stats=True)
    for i in range(3):
        params, stats, opt, terms = step(params, stats, opt, b, jnp.asarray(i))
    assert all(np.isfinite(float(x)) for x in terms.values())
    moved = {
        k
        for k in params
        if any(bool(jnp.any(a != c)) for a, c in zip(jax.tree.leaves(params[k]), jax.tree.leaves(v["params"][k])))
    }
    lift = {k for k in params if k.startswith(LIFT_LAYERS)}
    heads = {k for k in params if k.startswith(HEAD_LAYERS)}
    assert "crop_fc" in lift and "phi_depth" in lift and "volumon_fc0" in lift
    assert {"rpn_conv", "rpn_cls", "rpn_box", "cls_out", "box_out"} <= heads and not heads & lift
    trained = lift if only == "lift" else heads
    assert moved and moved <= trained, moved - trained
    if only == "heads":
        assert {"cls_out", "box_out"} <= moved  # the RoI features and the backbone stay
        assert "roi_fc0" not in moved and "roi_fc1" not in moved
    for a, c in zip(jax.tree.leaves(stats), jax.tree.leaves(v["batch_stats"])):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(c))


def test_lift_only_needs_a_trained_detector(tmp_path):
    frames = {"image": np.zeros((1, 96, 128, 3), np.float32)}
    with pytest.raises(ValueError, match="init_from"):
        train_rcnn(RCNNTrainConfig(model=TINY, train_only="lift", class_names=("a", "b", "c")), tmp_path, frames)
    with pytest.raises(ValueError, match="train_only"):
        train_rcnn(
            RCNNTrainConfig(model=TINY, train_only="head", init_from="x", class_names=("a", "b", "c")), tmp_path, frames
        )


def test_a_scaled_detector_rate_slows_only_the_detector_layers(optax_promotion):
    # Adam's first step moves each weight by about its rate, whatever the gradient's size.
    params = {"volumon_fc0": {"kernel": jnp.ones((3, 2))}, "rpn_conv": {"kernel": jnp.ones((4,))}}
    grads = {"volumon_fc0": {"kernel": jnp.full((3, 2), 0.003)}, "rpn_conv": {"kernel": jnp.full((4,), -0.002)}}
    for scale in (0.1, 0.5, 1.0):
        tx = _optimizer(RCNNTrainConfig(model=TINY, learning_rate=1e-2, detector_lr_scale=scale))
        updates, _ = tx.update(grads, tx.init(params), params)
        np.testing.assert_allclose(np.abs(updates["volumon_fc0"]["kernel"]), 1e-2, rtol=1e-4)
        np.testing.assert_allclose(np.abs(updates["rpn_conv"]["kernel"]), 1e-2 * scale, rtol=1e-4)


def test_a_detector_rate_outside_zero_to_one_is_refused(tmp_path):
    frames = {"image": np.zeros((1, 96, 128, 3), np.float32)}
    for scale in (0.0, -0.5, 2.0):
        with pytest.raises(ValueError, match="detector_lr_scale"):
            train_rcnn(
                RCNNTrainConfig(model=TINY, detector_lr_scale=scale, class_names=("a", "b", "c")), tmp_path, frames
            )
    with pytest.raises(ValueError, match="detector_lr_scale"):
        train_rcnn(
            RCNNTrainConfig(
                model=TINY, train_only="lift", init_from="x", detector_lr_scale=0.1, class_names=("a", "b", "c")
            ),
            tmp_path,
            frames,
        )


@pytest.mark.slow
def test_a_run_resumes_for_more_steps_and_refuses_another_recipe(tmp_path, optax_promotion):
    from jaxsem.training import ConfigMismatchError
    from jaxsem.volumon.data import frame_arrays

    renders = frame_arrays(_frames(4, 0), TINY.input_size, ("a", "b", "c"), 4)
    base = RCNNTrainConfig(
        model=TINY, batch_size=2, num_steps=2, checkpoint_every=1, eval_every=0, class_names=("a", "b", "c")
    )
    train_rcnn(base, tmp_path, renders, progress=False)
    lines: list = []
    longer = dataclasses.replace(base, num_steps=3, checkpoint_every=2, keep=3)
    _, _, rows = train_rcnn(longer, tmp_path, renders, progress=False, log=lines.append)
    assert any("resumed from step 2" in line for line in lines)  # continued, not started again
    assert [r["step"] for r in rows] == [2, 3]
    with pytest.raises(ConfigMismatchError, match="learning_rate"):
        train_rcnn(dataclasses.replace(longer, num_steps=4, learning_rate=5e-4), tmp_path, renders, progress=False)


@pytest.mark.slow
def test_zoomed_renders_reach_each_step_with_their_intrinsics(tmp_path, optax_promotion, monkeypatch):
    from jaxsem.volumon import rcnn
    from jaxsem.volumon.data import frame_arrays

    renders = frame_arrays(_frames(4, 0), TINY.input_size, ("a", "b", "c"), 4)
    seen: list = []
    real_augment = rcnn.augment_batch

    def spy(batch, rng, **kw):
        out = real_augment(batch, rng, **kw)
        seen.append((kw["scale_range"], out["K"][:, 0, 0] / batch["K"][:, 0, 0]))
        return out

    monkeypatch.setattr(rcnn, "augment_batch", spy)
    base = RCNNTrainConfig(
        model=TINY, batch_size=2, num_steps=2, checkpoint_every=0, eval_every=0, class_names=("a", "b", "c")
    )
    train_rcnn(base, tmp_path / "plain", renders, progress=False)
    assert not seen  # no zoom unless asked
    train_rcnn(dataclasses.replace(base, zoom_renders=1.5), tmp_path / "zoom", renders, progress=False)
    assert len(seen) == 2  # every step's renders
    for scale_range, ratio in seen:
        assert scale_range == pytest.approx((1 / 1.5, 1.5))
        assert np.all((ratio >= 1 / 1.5 - 1e-6) & (ratio <= 1.5 + 1e-6)) and np.any(np.abs(ratio - 1) > 1e-3)
    for bad in (0.5, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="zoom_renders"):
            train_rcnn(dataclasses.replace(base, zoom_renders=bad), tmp_path / "bad", renders, progress=False)
