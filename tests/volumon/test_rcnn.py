"""VoluMon R-CNN: box coding, anchors, the loss's finite gradients, fixed shapes under jit, the
detection AP metric on a hand-counted case, and (slow) a detector that learns a few frames."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from hypothesis import given, settings, strategies as st

from jaxsem import metrics
from jaxsem.models._rcnn import (  # layers: white-box
    RCNNConfig,
    VoluMonRCNN,
    anchors,
    decode_boxes,
    detect,
    encode_boxes,
    init_rcnn,
)
from jaxsem.volumon.rcnn import RCNNLossConfig, make_rcnn_step, rcnn_batch, rcnn_loss

TINY = RCNNConfig(
    num_classes=3,
    input_size=(128, 96),
    backbone="plain_cnn",
    cnn_width=8,
    anchor_sizes=(16.0, 32.0, 48.0),
    pre_nms=100,
    proposals=16,
    hidden=64,
    max_detections=8,
)


# init_rcnn's variables through one jitted program per config (flax's init op by op compiled some
# 300 small programs, 10-20 s, per call); the dummy batch of one, as the variables do not depend
# on it. The other test modules import this one, so a config's program is compiled once a session.
INIT = jax.jit(lambda key, cfg: init_rcnn(key, cfg, 1)[1], static_argnums=1)
_INIT = INIT


def _init(key, cfg=TINY):
    return VoluMonRCNN(cfg), _INIT(key, cfg)


def _frames(n, seed, W=128, H=96):
    """Flat coloured rectangles (class = colour) on a noisy grey image, with their boxes."""
    rng = np.random.default_rng(seed)
    cols = np.array([[230, 40, 40], [40, 200, 40], [40, 60, 230]], np.uint8)
    K = np.array([[120.0, 0, W / 2], [0, 120, H / 2], [0, 0, 1]])
    out = []
    for _ in range(n):
        img = (np.full((H, W, 3), 128) + rng.integers(0, 20, (H, W, 3))).astype(np.uint8)
        objs = []
        for _ in range(int(rng.integers(1, 3))):
            c = int(rng.integers(3))
            w, h = (int(x) for x in rng.integers(16, 40, 2))
            x0, y0 = int(rng.integers(0, W - w)), int(rng.integers(0, H - h))
            if any(abs(x0 - o["visible_box"][0]) < 24 for o in objs):
                continue
            img[y0 : y0 + h, x0 : x0 + w] = cols[c]
            b = np.array([x0, y0, x0 + w, y0 + h], float)
            objs.append(
                {
                    "class_name": "abc"[c],
                    "visible_box": b,
                    "box_left": b,
                    "box_right": b - [6, 0, 6, 0],
                    "rotation": np.eye(3),
                    "center": np.array([0.0, 0, 1]),
                    "radii": np.full(3, 0.05),
                }
            )
        out.append({"rgb": img, "K": K, "objects": objs})
    return out


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(2.0, 100.0), min_size=8, max_size=8))
def test_box_coding_round_trips(v):
    # sizes within 50x of each other: the decoder clamps larger scale changes (1000 / 16)
    ref = jnp.array([v[0], v[1], v[0] + v[2], v[1] + v[3]])
    tgt = jnp.array([v[4], v[5], v[4] + v[6], v[5] + v[7]])
    for w in ((1.0, 1.0, 1.0, 1.0), (10.0, 10.0, 5.0, 5.0)):
        np.testing.assert_allclose(
            np.asarray(decode_boxes(ref, encode_boxes(ref, tgt, w), w)), np.asarray(tgt), rtol=1e-9, atol=1e-7
        )


def test_anchors_tile_the_feature_map_at_stride_16():
    a = anchors(TINY)
    h, w = TINY.feature_shape
    assert a.shape == (h * w * 9, 4)
    centres = 0.5 * (a[:, :2] + a[:, 2:])
    np.testing.assert_allclose(np.unique(centres[:, 0]), (np.arange(w) + 0.5) * 16)
    sides = np.sqrt((a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1]))
    np.testing.assert_allclose(np.unique(sides.round(6)), [16, 32, 48])


@pytest.mark.slow
def test_forward_detect_and_loss_are_finite_fixed_shape_and_compile_once(compiles):
    model, v = _init(jax.random.PRNGKey(0))
    batch = rcnn_batch(_frames(2, 1), TINY, "abc", 3)
    f = jax.jit(lambda vv, b: detect(model.apply(vv, b["image"], b["K"]), b["K"], TINY))
    d = f(v, batch)
    assert d.box.shape == (2, 8, 4) and d.ellipsoid.center.shape == (2, 8, 3) and d.valid.dtype == bool
    assert all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree_util.tree_leaves(d))
    b2 = dict(batch, image=batch["image"][::-1].copy())
    with compiles() as c:
        f(v, b2)
    assert c.count == 0

    def loss(params):
        out = model.apply(
            {"params": params, "batch_stats": v["batch_stats"]},
            batch["image"],
            batch["K"],
            batch["boxes"],
            batch["box_valid"],
        )
        return rcnn_loss(out, batch, TINY, RCNNLossConfig(), 1.0)[0]

    g = jax.jit(jax.grad(loss))(v["params"])
    assert all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree_util.tree_leaves(g))


@pytest.mark.slow
def test_the_thesis_backbone_gives_the_same_heads_and_finite_detections():
    cfg = dataclasses.replace(TINY, backbone="mobilenet_v2", width_multiplier=0.35)
    model, v = _init(jax.random.PRNGKey(0), cfg)
    _, v_plain = _init(jax.random.PRNGKey(0))
    heads = lambda p: {k for k in p if not k.startswith(("features_", "plain_"))}
    assert heads(v["params"]) == heads(v_plain["params"]) and "features_13" in v["params"]
    batch = rcnn_batch(_frames(1, 4), cfg, "abc", 3)
    d = jax.jit(lambda vv, b: detect(model.apply(vv, b["image"], b["K"]), b["K"], cfg))(v, batch)
    assert all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree_util.tree_leaves(d))


def test_config_and_batch_refuse_bad_input():
    with pytest.raises(ValueError, match="input_size"):
        RCNNConfig(input_size=(100, 96))
    with pytest.raises(ValueError, match="param_rule"):
        RCNNConfig(param_rule="mean")
    with pytest.raises(ValueError, match="backbone"):
        RCNNConfig(backbone="resnet")
    with pytest.raises(ValueError, match="max_objects"):
        rcnn_batch(_frames(6, 2), TINY, "abc", 0)


def test_average_precision_on_a_hand_counted_case():
    truth = (
        np.array([0, 0, 1]),
        np.array([[0, 0, 10, 10], [20, 20, 30, 30], [0, 0, 10, 10]], float),
        np.array([0, 1, 0]),
    )
    dets = (
        np.array([0, 0, 1, 1]),
        np.array([[0, 0, 10, 10], [21, 21, 30, 30], [50, 50, 60, 60], [0, 0, 9, 10]], float),
        np.array([0, 1, 0, 0]),
        np.array([0.9, 0.8, 0.95, 0.5]),
    )
    ap, recall = metrics.average_precision(dets, truth, 3)
    # class 0 in score order: miss, hit, hit -> precision 0, 1/2, 2/3 at recall 0, 1/2, 1
    np.testing.assert_allclose(ap[:2], [2 / 3, 1.0])
    assert np.isnan(ap[2]) and recall[0] == 1.0


@pytest.mark.slow
def test_detector_learns_a_few_frames_to_ap_one(optax_promotion):
    frames = _frames(4, 0)
    batch = rcnn_batch(frames, TINY, "abc", 3)
    model, v = _init(jax.random.PRNGKey(0))
    tx = optax.adam(1e-3)
    params, stats, opt = v["params"], v["batch_stats"], tx.init(v["params"])
    step = make_rcnn_step(model, TINY, RCNNLossConfig(burn_in=200), tx)
    for i in range(400):
        params, stats, opt, terms = step(params, stats, opt, batch, jnp.asarray(i))
    assert all(np.isfinite(float(x)) for x in terms.values())
    d = jax.jit(lambda vv, img, K: detect(model.apply(vv, img, K), K, TINY))(
        {"params": params, "batch_stats": stats}, batch["image"], batch["K"]
    )
    ok = np.asarray(d.valid)
    img = np.nonzero(ok)[0]
    dets = (img, np.asarray(d.box)[ok], np.asarray(d.class_id)[ok], np.asarray(d.score)[ok])
    tv = batch["box_valid"]
    truth = (np.nonzero(tv)[0], batch["boxes"][tv], batch["class_id"][tv])
    ap, _ = metrics.average_precision(dets, truth, 3)
    assert np.nanmean(ap) == pytest.approx(1.0)


@pytest.mark.slow
def test_export_load_and_the_detect_command_on_a_photo_of_another_size(tmp_path):
    import json

    import cv2

    from jaxsem import cli
    from jaxsem.volumon.rcnn import RCNNTrainConfig, at_input_size, detect_image, export_rcnn, load_rcnn

    config = RCNNTrainConfig(model=TINY, class_names=("a", "b", "c"))
    _, v = _init(jax.random.PRNGKey(1))
    npz = export_rcnn(tmp_path / "m", v, config, {"steps": 0})
    loaded = load_rcnn(npz)
    assert loaded.config == config
    photo = _frames(1, 3, W=256, H=192)[0]
    K = np.array([[240.0, 0, 128], [0, 240, 96], [0, 0, 1]])
    d = detect_image(loaded, photo["rgb"], K)
    assert d["box"].shape[1:] == (4,) and np.all(d["box"][:, 2] <= 255.5)  # the photo's pixels
    assert len(d["class_name"]) == len(d["score"]) and np.all(np.isfinite(d["center"]))
    cv2.imwrite(str(tmp_path / "photo.png"), photo["rgb"][..., ::-1])
    status = cli.main(
        [
            "volumon",
            "detect",
            "--model",
            str(npz),
            "--image",
            str(tmp_path / "photo.png"),
            "--K",
            "240,240,128,96",
            "--out",
            str(tmp_path / "out"),
            "--min-score",
            "0",
        ]
    )
    assert status == 0
    rows = json.loads((tmp_path / "out" / "detections.json").read_text())["detections"]
    assert len(rows) == len(d["score"]) and (tmp_path / "out" / "detections.png").is_file()
    with pytest.raises(ValueError, match="image"):
        detect_image(loaded, photo["rgb"].astype(np.float32), K)
    # the same weights at another input size: boxes still in the photograph's pixels
    bigger = at_input_size(loaded, (192, 144))
    assert bigger.config.model.input_size == (192, 144) and bigger.variables is loaded.variables
    d2 = detect_image(bigger, photo["rgb"], K)
    assert np.all(np.isfinite(d2["box"])) and np.all(d2["box"][:, 2] <= 256.0 + 1e-3)


@pytest.mark.slow
def test_the_shipped_lmo_model_loads_and_detects_on_a_photo_of_any_size():
    from jaxsem.volumon.rcnn import detect_image, load_rcnn

    loaded = load_rcnn()
    assert load_rcnn("lmo-rcnn").meta == loaded.meta  # the name the commands use
    assert loaded.meta["step"] > 0 and len(loaded.config.class_names) == loaded.config.model.num_classes == 8
    photo = np.random.default_rng(0).integers(0, 255, (300, 400, 3), dtype=np.uint8)
    d = detect_image(loaded, photo, np.array([[500.0, 0, 200], [0, 500, 150], [0, 0, 1]]))
    for k in ("box", "score", "center", "radii"):
        assert np.all(np.isfinite(d[k])), k
    assert set(d["class_name"]) <= set(loaded.config.class_names)
    # the library's box convention (the image from -0.5 to size - 0.5): the separate VoluMon
    # network takes the boxes as they come, also those that touch the photograph's edge
    assert np.all(d["box"][:, :2] >= -0.5) and np.all(d["box"][:, 2:] <= np.array([399.5, 299.5]))
    if len(d["box"]):
        from jaxsem.volumon import load_pretrained, prepare_inputs

        local, _ = prepare_inputs(photo, d["box"], config=load_pretrained(kind="lmo").config.model)
        assert local.shape[0] == len(d["box"])
